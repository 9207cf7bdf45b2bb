#!/usr/bin/env python3
"""How much of a least-squares lighting error is the SH-shadow model's, and how much the view's.

`penumbra optimize` with "lighting_solver": "least_squares" solves, per colour channel,
    min_L  sum_p (sum_k L_k T_k(p) - target(p))^2 + mu |L|^2,   mu = ridge * max_k (T_k . T_k),
where T_k is the render with SH coefficient k = 1 in every channel (the scene's transfer image of
coefficient k: albedo / pi times the visibility-weighted clamped cosine's k-th coefficient). This
script solves the same problem with three transfers:
    exact      T_k ray-traced by `penumbra reference --lighting sh` against the real meshes and
               ground (the 4-band lighting's image with exact visibility; linear in the
               coefficients because the reference does not clamp the SH radiance)
    shadows    T_k rendered by penumbra (sphere proxies, SH visibility): what optimize uses
    no-shadows T_k rendered with V = 1 (the unshadowed baseline)
against two targets: the given image (normally the ray-traced render of the environment map
itself) and sum_k L_true,k T_k^exact, the image of the true 4-band lighting with exact visibility.
The "exact" column is what a renderer with perfect visibility could reach from this one view with
this ridge: the floor of the problem, not of the model.

Usage (from the repository root, after `make`):
    PYTHONPATH=python python3 research/experiments/optimize/lighting_bound.py build/penumbra \\
        examples/optimize/spot_truth.json out/optimize/targets/spot.exr [--spp 512]
        [--ridges 1e-3,3e-3,1e-2,3e-2] [--envmap interior]
The scene's lighting (its map's projection, or its "sh") is the truth. --envmap interior swaps
the bundled city map for the interior one (as run_table.sh does). Prints a markdown table.
Cost: 16 reference renders (about 4 s each at 256x256, 512 spp, 2 cores) and 32 penumbra renders.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile

import numpy as np
import torch

import penumbra


def absolute_scene(path, envmap):
    """The scene JSON with its file paths made absolute, so that copies may live elsewhere."""
    with open(path) as f:
        scene = json.load(f)
    here = os.path.dirname(os.path.abspath(path))

    def fix(p):
        return os.path.normpath(os.path.join(here, p))

    # The transfer images are renders lit by one coefficient each: only a black background
    # leaves them nothing but the surfaces (with an envmap the background defaults to the map).
    if scene.get("background") != [0, 0, 0]:
        sys.exit("lighting_bound: %s: \"background\" must be [0, 0, 0], got %s"
                 % (path, json.dumps(scene.get("background", "the default"))))
    lighting = scene.get("lighting", {})
    if "envmap" in lighting:
        lighting["envmap"] = fix(lighting["envmap"])
        if envmap:
            lighting["envmap"] = lighting["envmap"].replace("/city.hdr", "/%s.hdr" % envmap)
    for ob in scene["objects"]:
        for key in ("mesh", "albedo_texture"):
            if key in ob:
                ob[key] = fix(ob[key])
        if isinstance(ob.get("spheres"), str):
            ob["spheres"] = fix(ob["spheres"])
    return scene


def exact_transfer(binary, scene, coefficients, spp, folder):
    """T_k ray-traced: the reference render lit by SH basis function k alone."""
    out = []
    for k in range(coefficients):
        basis = dict(scene)
        basis["lighting"] = {"sh": [[1.0, 1.0, 1.0] if i == k else [0.0, 0.0, 0.0]
                                    for i in range(coefficients)]}
        scene_path = os.path.join(folder, "basis_%d.json" % k)
        image_path = os.path.join(folder, "basis_%d.exr" % k)
        with open(scene_path, "w") as f:
            json.dump(basis, f)
        subprocess.run([binary, "reference", scene_path, "-o", image_path, "--spp", str(spp),
                        "--lighting", "sh"], check=True, stdout=subprocess.DEVNULL)
        out.append(penumbra.load_image(image_path).numpy().astype(np.float64))
    return np.stack(out)


def model_transfer(scene, coefficients, shadows):
    """T_k rendered by penumbra, as optimize's lighting solver renders them."""
    truth = scene.sh
    out = []
    for k in range(coefficients):
        basis = torch.zeros(coefficients, 3)
        basis[k] = 1.0
        scene.sh = basis
        out.append(penumbra.render_scene(scene, shadows=shadows).numpy().astype(np.float64))
    scene.sh = truth
    return np.stack(out)


def solve(transfer, target, ridge):
    """The ridge least-squares lighting, per channel, as src/optim/loss.c solves it."""
    coefficients = transfer.shape[0]
    lighting = np.zeros((coefficients, 3))
    for c in range(3):
        a = transfer[..., c].reshape(coefficients, -1).T
        gram = a.T @ a
        mu = ridge * gram.diagonal().max()
        lighting[:, c] = np.linalg.solve(gram + (mu + 1e-30) * np.eye(coefficients),
                                         a.T @ target[..., c].ravel())
    return lighting


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("binary")
    ap.add_argument("scene")
    ap.add_argument("target")
    ap.add_argument("--spp", type=int, default=512)
    ap.add_argument("--ridges", default="1e-3,3e-3,1e-2,3e-2")
    ap.add_argument("--envmap", choices=["city", "interior"], default=None)
    args = ap.parse_args()
    ridges = [float(r) for r in args.ridges.split(",")]

    with tempfile.TemporaryDirectory() as folder:
        scene_json = absolute_scene(args.scene, args.envmap if args.envmap != "city" else None)
        scene_path = os.path.join(folder, "scene.json")
        with open(scene_path, "w") as f:
            json.dump(scene_json, f)
        scene = penumbra.load_scene(scene_path)
        truth = scene.sh.numpy().astype(np.float64)
        coefficients = truth.shape[0]
        transfers = {
            "exact": exact_transfer(args.binary, scene_json, coefficients, args.spp, folder),
            "shadows": model_transfer(scene, coefficients, True),
            "no-shadows": model_transfer(scene, coefficients, False),
        }
    target = penumbra.load_image(args.target).numpy().astype(np.float64)
    if target.shape != transfers["exact"].shape[1:]:
        sys.exit("lighting_bound: %s is %s, the scene renders %s" % (
            args.target, target.shape, transfers["exact"].shape[1:]))
    targets = {"target image": target,
               "true SH light, exact visibility": np.einsum("khwc,kc->hwc",
                                                            transfers["exact"], truth)}

    def error(lighting):
        return np.linalg.norm(lighting - truth) / np.linalg.norm(truth)

    print("| target | ridge | exact | shadows | no-shadows | shadows / no-shadows | exact / no-shadows |")
    print("|---|---|---|---|---|---|---|")
    for tname, t in targets.items():
        for ridge in ridges:
            e = {name: error(solve(tr, t, ridge)) for name, tr in transfers.items()}
            print("| %s | %g | %.3f | %.3f | %.3f | %.2f | %.2f |" % (
                tname, ridge, e["exact"], e["shadows"], e["no-shadows"],
                e["shadows"] / e["no-shadows"], e["exact"] / e["no-shadows"]))
    # How far the proxies' transfer is from the exact one, per band.
    d = transfers["shadows"] - transfers["exact"]
    bands = int(round(coefficients ** 0.5))
    rel = []
    for band in range(bands):
        ks = range(band * band, (band + 1) * (band + 1))
        rel.append(np.sqrt(sum((d[k] ** 2).sum() for k in ks) /
                           sum((transfers["exact"][k] ** 2).sum() for k in ks)))
    print("\ntransfer error of the shadows model, per band (rel. RMS against exact): " +
          ", ".join("%d: %.2f" % (b, r) for b, r in enumerate(rel)))


if __name__ == "__main__":
    main()
