#!/usr/bin/env python3
"""Where the tube chair's object error against the full map comes from (docs/results/accuracy.md,
"A thin-limbed figure under a low sun", the 2026-11-29 decomposition). Run after run.py, whose
chair truths it reuses (OUTDIR/chair: chair_truth_envmap, chair_truth_sh, chair_half_envmap,
chair_cover).

    /usr/bin/python3 research/experiments/thin_figure/decompose.py PENUMBRA [--out out/thin_figure]
        [--spp 1024] [--candidate PENUMBRA2]

The chair's scene lists its low sun ("lights": [...]), so the loader finds no light in the city
map and projects the whole map, its own sun included, onto 4 SH bands. Variants, each with its
own truth `reference --lighting sh` (exact visibility under what the variant's render lights
with), N spp, seed 1:
  bB         sh_bands B (4, 5, 6): the whole map on B bands
  found_bB   the map's lights found as with "lights": {"max": 4} (its sun, 24 % of its light),
             written out as disk lights next to the listed sun, "sh" the projection of what they
             leave (the Python binding's load_scene): what a loader that finds the map's lights
             besides the listed ones would render
Every truth and render is compared with the full-map truth over the object's pixels (coverage >
0.5), split into seat and tube pixels (a reference of the seat alone, white, and the tubes, black)
and into silhouette pixels (some of the 3 x 3 neighbours not fully covered) and interior; per
class its share of the rel. RMSE (sqrt of its squared error over the whole object's squared truth)
and its mean signed error relative to the object's mean. --candidate: a second binary's renders of
the same scenes, one more row each. Writes OUTDIR/chair/decompose_*.{json,exr} and
OUTDIR/chair/map_decompose.png (full-map truth | signed error of: the sh truth, the default
render, the found-lights render, the candidate's; red = too bright, saturating at 30 % of the
object's mean). Needs numpy and the Python binding (PENUMBRA_LIB: the binary's build folder).
"""
import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "accuracy"))
sys.path.insert(0, os.path.join(HERE, "..", "..", "..", "python"))
from visibility_table import parse_options, rgb, run, srgb8, write_png  # noqa: E402

TH = ["--threads", "2"]


def load(path):
    w, h, c = rgb(path)
    return np.stack([np.asarray(x, dtype=np.float64) for x in c], -1).reshape(h, w, 3)


def variants(chair, bands_list):
    """Writes the scenes decompose_bB.json and decompose_found_bB.json; returns their names."""
    os.environ.setdefault("PENUMBRA_LIB", os.path.dirname(PEN))
    import penumbra  # noqa: E402 (after PENUMBRA_LIB)
    with open(os.path.join(chair, "frame.json")) as f:
        base = json.load(f)
    names = []
    for b in bands_list:
        sc = json.loads(json.dumps(base))
        sc["sh_bands"] = b
        names.append(("b%d" % b, sc))
        auto = json.loads(json.dumps(sc))
        auto["lighting"]["lights"] = {"max": 4}
        path = os.path.join(chair, "decompose_auto.json")
        with open(path, "w") as f:
            json.dump(auto, f)
        s = penumbra.load_scene(path)
        found = [{"direction": l[:3], "angular_radius_deg": l[3], "irradiance": l[4:7]}
                 for l in s.lights.tolist()]
        fs = json.loads(json.dumps(sc))
        fs["lighting"]["lights"] = found + base["lighting"]["lights"]
        fs["lighting"]["sh"] = s.sh.tolist()
        names.append(("found_b%d" % b, fs))
    for tag, sc in names:
        with open(os.path.join(chair, "decompose_%s.json" % tag), "w") as f:
            json.dump(sc, f, indent=1)
    return [t for t, _ in names]


def classes(chair):
    """Object mask and its four classes (seat/tube x interior/silhouette)."""
    cov = load(os.path.join(chair, "chair_cover.exr"))[..., 0]
    obj = cov > 0.5
    lab_png = os.path.join(chair, "decompose_label.exr")
    if not os.path.exists(lab_png):
        with open(os.path.join(chair, "frame.obj")) as f:
            lines = f.read().split("\n")
        v = [l for l in lines if l.startswith("v ")]
        t = [l for l in lines if l.startswith("f ")]
        # make_frame.py writes the seat's box first: 24 corners, 12 triangles
        with open(os.path.join(chair, "decompose_seat.obj"), "w") as f:
            f.write("\n".join(v[:24] + t[:12]) + "\n")
        with open(os.path.join(chair, "decompose_tubes.obj"), "w") as f:
            f.write("\n".join(v[24:] + ["f %d %d %d" % tuple(int(x) - 24 for x in l.split()[1:])
                                        for l in t[12:]]) + "\n")
        with open(os.path.join(chair, "frame_noground.json")) as f:
            sc = json.load(f)
        sh = [[0.0] * 3 for _ in range(16)]
        sh[0] = [3.5449077] * 3  # a constant light: radiance = albedo
        sc["lighting"], sc["sh_bands"] = {"sh": sh, "lights": "none"}, 4
        o = sc["objects"][0]
        o.pop("spheres", None)
        sc["objects"] = [dict(o, mesh=os.path.join(chair, "decompose_seat.obj"), albedo=[1] * 3),
                         dict(o, mesh=os.path.join(chair, "decompose_tubes.obj"), albedo=[0] * 3)]
        with open(os.path.join(chair, "decompose_label.json"), "w") as f:
            json.dump(sc, f)
        run([PEN, "reference", os.path.join(chair, "decompose_label.json"), "-o", lab_png,
             "--spp", "16"] + TH)
    lab = load(lab_png)[..., 0]
    seat = obj & (lab > 0.5 * lab[obj].max())
    pad, full = np.pad(cov, 1), np.ones_like(obj)
    for dy in range(3):
        for dx in range(3):
            full &= pad[dy:dy + cov.shape[0], dx:dx + cov.shape[1]] > 0.999
    sil = obj & ~full
    return obj, {"seat interior": seat & ~sil, "seat silhouette": seat & sil,
                 "tube interior": obj & ~seat & ~sil, "tube silhouette": obj & ~seat & sil}


def row(label, A, T, obj, cls):
    norm, tm = (T[obj] ** 2).sum(), T[obj].mean()
    parts = [(np.sqrt(((A - T)[m] ** 2).sum() / norm), (A - T)[m].mean() / tm)
             for m in cls.values()]
    return [label, np.sqrt(((A - T)[obj] ** 2).sum() / norm)] + parts


def error_tile(A, T, obj):
    d = np.clip((A - T).mean(-1) / (0.3 * T[obj].mean()), -1, 1)
    v = (255 * (1 - np.abs(d))).astype(int)
    t = np.stack([np.where(d > 0, 255, v), v, np.where(d > 0, v, 255)], -1)
    t[~obj] = 0
    return t


def main():
    global PEN
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    opts, _ = parse_options(sys.argv[2:], {"--out": "out/thin_figure", "--spp": "1024",
                                           "--candidate": ""})
    PEN = os.path.abspath(sys.argv[1])
    chair, spp = os.path.join(os.path.abspath(opts["--out"]), "chair"), int(opts["--spp"])
    img = lambda n: os.path.join(chair, n + ".exr")
    tags = variants(chair, (4, 5, 6))
    obj, cls = classes(chair)
    Tenv = load(img("chair_truth_envmap"))
    rows = [row("full-map truth, second (N/2 spp): its noise x sqrt(3)", load(img(
        "chair_half_envmap")), Tenv, obj, cls),
            row("sh truth (whole map on 4 bands, exact visibility)", load(img("chair_truth_sh")),
                Tenv, obj, cls)]
    bins = [("default", PEN)] + ([("candidate", os.path.abspath(opts["--candidate"]))]
                                  if opts["--candidate"] else [])
    tiles = [error_tile(load(img("chair_truth_sh")), Tenv, obj)]
    for tag in tags:
        scene = os.path.join(chair, "decompose_%s.json" % tag)
        truth = img("decompose_truth_%s" % tag)
        if not os.path.exists(truth):
            run([PEN, "reference", scene, "-o", truth, "--spp", str(spp), "--seed", "1",
                 "--lighting", "sh"] + TH)
        rows.append(row("%s: its sh truth" % tag, load(truth), Tenv, obj, cls))
        for name, binary in bins:
            r = img("decompose_%s_%s" % (name, tag))
            if not os.path.exists(r):
                run([binary, "render", scene, "-o", r, "-q"] + TH)
            R = load(r)
            rows.append(row("%s: %s render" % (tag, name), R, Tenv, obj, cls))
            rows.append(row("%s: %s render vs its sh truth" % (tag, name), R, load(truth), obj,
                            cls))
            if tag in ("b4", "found_b4"):
                tiles.append(error_tile(R, Tenv, obj))
    print("\nChair 384 x 384, object pixels %d (%s), against the full-map truth "
          "(`reference --lighting envmap`, %d spp) unless said\n"
          % (obj.sum(), ", ".join("%s %d" % (k, m.sum()) for k, m in cls.items()), spp))
    print("| compared | object | " + " | ".join(cls) + " |")
    print("|---|---|" + "---|" * len(cls))
    for r in rows:
        print("| %s | %.4f | " % (r[0], r[1]) +
              " | ".join("%.3f (%+.3f)" % p for p in r[2:]) + " |")
    with open(os.path.join(chair, "decompose_rows.json"), "w") as f:
        json.dump([[r[0], r[1]] + [list(p) for p in r[2:]] for r in rows], f, indent=1)
    ys, xs = np.nonzero(obj)
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    truth8 = np.vectorize(srgb8)(Tenv).astype(int)
    im = np.concatenate([truth8[y0:y1, x0:x1]] + [t[y0:y1, x0:x1] for t in tiles], 1)
    h, w = im.shape[:2]
    write_png(os.path.join(chair, "map_decompose.png"), w, h,
              [tuple(int(c) for c in im[y, x]) for y in range(h) for x in range(w)])


PEN = None
if __name__ == "__main__":
    main()
