#!/usr/bin/env python3
"""Self-shadowing on thin limbs under a low sun (docs/results/accuracy.md, "A thin-limbed figure
under a low sun"): the figure of make_figure.py rendered with the defaults (`penumbra render`: the
self transfer, 32 fitted spheres) against the exact-visibility truth (`penumbra reference
--lighting sh`), over the whole image and over the object's pixels (coverage > 0.5 of a
reference of the scene without the ground, as visibility_table.py masks the object). Also the
tube chair of thin/make_frame.py under its sun, against the same truth and against the full-map
truth (`--lighting envmap`).

    /usr/bin/python3 research/experiments/thin_figure/run.py PENUMBRA [--out out/thin_figure]
        [--sizes 256,384] [--spp 1024] [--no-chair] [--candidate PENUMBRA2] [--find-map-lights]

Per scene: the truth at N spp (seed 1) and a second at N/2 (seed 2); the truth's own noise is
err(second vs truth) / sqrt(3) (e^2 = s^2 (2/N + 1/N) for independent estimates) and is removed
in quadrature from the render's error ("net"). Writes OUTDIR/*.exr and OUTDIR/map_*.png (truth |
render | signed error on the object, red = render too bright, blue = too dark, saturating at 30 %
of the object's mean; map_figure_256.png is docs/images/thin_figure_low_sun.png) and prints
markdown tables. Existing images are reused (delete them to
start over). --candidate: a second binary (a candidate change of the renderer) whose default
render is measured against the same truths, one more row per table. About 15 minutes at 256 and
384 with 1024 spp on 2 shared cores, the chair's two truths included. --find-map-lights: the
chair's scene as `make_frame.py --find-map-lights` writes it (the city map's own sun found as a
disk light besides the listed low sun), in OUTDIR/chair_found.
"""
import json
import math
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "accuracy"))
from visibility_table import analyse, parse_options, run  # noqa: E402

TH = ["--threads", "2"]


def once(path, args):
    if not os.path.exists(path):
        run(args)
    return path


def compare(pen, a, b, mask):
    j = json.loads(run([pen, "compare", a, b, "--mask", mask]))
    return j["rel_rmse"], j["mask"]["rel_rmse"]


def net(e, s):
    return math.sqrt(max(0.0, e * e - s * s))


def measure(pen, out, name, scene, scene_noground, spp, lighting, renders):
    """Rows (label, image, object, image net, object net) of each render against the truth."""
    img = lambda n: os.path.join(out, n + ".exr")
    truth = once(img("%s_truth_%s" % (name, lighting)),
                 [pen, "reference", scene, "-o", img("%s_truth_%s" % (name, lighting)), "--spp",
                  str(spp), "--seed", "1", "--lighting", lighting] + TH)
    half = once(img("%s_half_%s" % (name, lighting)),
                [pen, "reference", scene, "-o", img("%s_half_%s" % (name, lighting)), "--spp",
                 str(spp // 2), "--seed", "2", "--lighting", lighting] + TH)
    mask = img(name + "_cover")
    once(mask, [pen, "reference", scene_noground, "-o", img(name + "_obj"), "--spp", "4",
                "--coverage", mask] + TH)
    ni, no = (e / math.sqrt(3) for e in compare(pen, half, truth, mask))
    rows = [("truth noise (N spp)", ni, no, None, None)]
    for label, tag, variant, flags, binary in renders:
        sc = scene if variant is None else variant(scene)
        r = once(img("%s_%s" % (name, tag)),
                 [binary or pen, "render", sc, "-o", img("%s_%s" % (name, tag)), "-q"] + TH +
                 flags)
        ei, eo = compare(pen, r, truth, mask)
        rows.append((label, ei, eo, net(ei, ni), net(eo, no)))
    return rows, truth, mask


def self_spheres(scene):
    """A copy of the scene with "shadow": {"self": "spheres"} (the sphere model, ground too)."""
    with open(scene) as f:
        sc = json.load(f)
    sc.setdefault("shadow", {})["self"] = "spheres"
    path = scene.replace(".json", "_spheres.json")
    with open(path, "w") as f:
        json.dump(sc, f, indent=1)
    return path


def table(title, rows):
    print("\n%s\n" % title)
    print("| render | image | object | image, noise removed | object, noise removed |")
    print("|---|---|---|---|---|")
    for label, ei, eo, ni, no in rows:
        f = lambda v: "" if v is None else "%.3f" % v
        print("| %s | %s | %s | %s | %s |" % (label, f(ei), f(eo), f(ni), f(no)))
    sys.stdout.flush()


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    opts, flags = parse_options(sys.argv[2:], {"--out": "out/thin_figure", "--sizes": "256,384",
                                               "--spp": "1024", "--candidate": ""},
                                ("--no-chair", "--find-map-lights"))
    pen, out = os.path.abspath(sys.argv[1]), os.path.abspath(opts["--out"])
    sizes, spp = [int(s) for s in opts["--sizes"].split(",")], int(opts["--spp"])
    subprocess.run([sys.executable, os.path.join(HERE, "make_figure.py"), out, "--sizes",
                    opts["--sizes"]], check=True)
    renders = [("default (self transfer)", "render", None, [], None),
               ('"self": "spheres"', "spheres", self_spheres, [], None),
               ("no shadows", "unshadowed", None, ["--no-shadows"], None)]
    cand = opts["--candidate"]
    if cand:
        renders.insert(1, ("candidate, default", "candidate", None, [], os.path.abspath(cand)))
    for size in sizes:
        name = "figure_%d" % size
        rows, truth, mask = measure(pen, out, name, os.path.join(out, name + ".json"),
                                    os.path.join(out, "figure_noground_%d.json" % size), spp, "sh",
                                    renders)
        table("Figure %d x %d, truth `reference --lighting sh` %d spp" % (size, size, spp), rows)
        a = analyse(truth, os.path.join(out, name + "_render.exr"),
                    os.path.join(out, name + "_unshadowed.exr"), mask,
                    os.path.join(out, "map_%s.png" % name))
        print("object pixels %d; share of the squared error where the render is too bright %.2f;"
              " shadow captured %.2f" % (a["pixels"], a["too_bright_share"], a["captured"]))
    if "--no-chair" in flags:
        return
    found = "--find-map-lights" in flags
    chair = os.path.join(out, "chair_found" if found else "chair")
    subprocess.run([sys.executable, os.path.join(HERE, "..", "thin", "make_frame.py"), chair]
                   + (["--find-map-lights"] if found else []), check=True)
    with open(os.path.join(chair, "frame.json")) as f:
        sc = json.load(f)
    del sc["ground"]
    with open(os.path.join(chair, "frame_noground.json"), "w") as f:
        json.dump(sc, f)
    for lighting in ("sh", "envmap"):
        rows, _, _ = measure(pen, chair, "chair", os.path.join(chair, "frame.json"),
                             os.path.join(chair, "frame_noground.json"), spp, lighting,
                             renders[:2] if cand else renders[:1])
        table("Chair (thin/make_frame.py) 384 x 384, truth `reference --lighting %s` %d spp"
              % (lighting, spp), rows)


if __name__ == "__main__":
    main()
