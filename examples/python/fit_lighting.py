"""Recover a scene's environment lighting (SH coefficients) from an image of it, with a torch
optimizer and penumbra's differentiable soft-shadow renderer.

    /usr/bin/python3 examples/python/fit_lighting.py [SCENE.json] [--size 128] [--iterations 200]
        [--lr 0.05] [--target IMAGE.exr] [--out DIR]

The target is the scene rendered with its own lighting, or an observed linear image (--target:
e.g. the ray-traced `penumbra reference SCENE.json -o target.exr --spp 256` at the same size).
The fit starts from black lighting (supplement section 5.2) and runs Adam on the L2 image loss.
Run from the repository root after `make build` (the package is found in ../../python and the
library in build/, or through PYTHONPATH and PENUMBRA_LIB).
"""

import argparse
import dataclasses
import os
import sys
import time

import torch

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "..", "python"))
import penumbra  # noqa: E402


def fit_lighting(scene, target, iterations=200, lr=0.05, shadows=True, log=None):
    """Fits scene.sh to the target image (H, W, 3) from zero; returns the fitted SH (bands^2, 3)
    and the loss per iteration. The scene is left as it was. shadows=False fits with the
    unshadowed renderer (visibility 1), the baseline of shadow-free differentiable renderers."""
    truth = scene.sh
    # The whole fit, as in docs/python.md:
    scene.sh = torch.zeros_like(truth, requires_grad=True)
    opt = torch.optim.Adam([scene.sh], lr=lr)
    renderer = penumbra.Renderer()  # keeps the render state and its caches between iterations
    losses = []
    for it in range(iterations):
        opt.zero_grad()
        loss = (renderer.render_scene(scene, shadows=shadows) - target).square().mean()
        loss.backward()
        opt.step()
        losses.append(loss.item())
        if log and (it % 25 == 0 or it == iterations - 1):
            log("iteration %4d  loss %.3e" % (it, losses[-1]))
    fitted = scene.sh.detach()
    scene.sh = truth
    return fitted, losses


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", nargs="?",
                    default=os.path.join(HERE, "..", "scenes", "spot_city.json"))
    ap.add_argument("--size", type=int, default=128, help="render size (square), default 128")
    ap.add_argument("--iterations", type=int, default=200)
    ap.add_argument("--lr", type=float, default=0.05)
    ap.add_argument("--target", help="observed linear image (EXR/HDR) of the scene at --size")
    ap.add_argument("--no-shadows", action="store_true", help="fit without shadows")
    ap.add_argument("--out", help="folder for target.png, initial.png and fitted.png")
    args = ap.parse_args()

    scene = penumbra.load_scene(args.scene)  # fits {"fit": N} sphere sets once (cached)
    scene.camera = dataclasses.replace(scene.camera, width=args.size, height=args.size)
    if args.target:
        target = penumbra.load_image(args.target)
    else:
        target = penumbra.render_scene(scene)
    t0 = time.time()
    shadows = not args.no_shadows
    sh, losses = fit_lighting(scene, target, args.iterations, args.lr, shadows, log=print)
    seconds = time.time() - t0
    rel = float((sh - scene.sh).norm() / scene.sh.norm())
    print("%d iterations in %.1f s (%.0f ms each); loss %.3e -> %.3e; "
          "lighting relative error %.3f" % (len(losses), seconds, 1000 * seconds / len(losses),
                                            losses[0], losses[-1], rel))
    if args.out:
        os.makedirs(args.out, exist_ok=True)
        fitted = dataclasses.replace(scene, sh=sh)
        black = dataclasses.replace(scene, sh=torch.zeros_like(sh))
        for name, img in (("target", target),
                          ("initial", penumbra.render_scene(black, shadows=shadows)),
                          ("fitted", penumbra.render_scene(fitted, shadows=shadows))):
            penumbra.save_image(os.path.join(args.out, name + ".png"), img)
        print("wrote %s/{target,initial,fitted}.png" % args.out)


if __name__ == "__main__":
    main()
