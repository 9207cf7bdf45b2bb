"""The chair's cast shadow through its spheres (docs/results/optimize.md, "A frame seen only by
its shadow", the chair below it): the frame of make_frame.py with a seat, a sun 10 degrees up over
the city map's SH, 256x256. Renders the sphere model pose and shape tasks use
("self": "spheres", "ground_shadow": "spheres") with N fitted spheres and the default render
(the objects' and the ground's transfer), and measures each against the exact visibility
(`penumbra reference --lighting sh`, the model's lighting) over the truth's cast shadow on the
ground: ground pixels the chair darkens by more than 10 %.

    python3 research/experiments/thin_pose/chair_shadow.py PENUMBRA [--old OLD_PENUMBRA]
        [--counts 32,64,128] [--out out/thin_chair]

OLD_PENUMBRA: another build whose spheres are measured beside (its own fits, its own cache).
About a minute per build on the shared 2-core machine.
"""
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "accuracy"))
from visibility_table import parse_options, rgb, run, write_png  # noqa: E402

SUN = {"direction": [0.788, 0.174, -0.591], "angular_radius_deg": 0.27,
       "irradiance": [1.6, 1.5, 1.3]}  # 10 degrees up


def scene(mesh, shadow, fit, objects=True, ground=True):
    s = {"camera": {"width": 256, "height": 256, "fov_y_deg": 40, "eye": [1.2, 2.6, 4.2],
                    "target": [-0.9, 0.3, 0.9], "up": [0, 1, 0]},
         "lighting": {"envmap": os.path.join(HERE, "..", "..", "..", "data", "envmaps",
                                             "city.hdr"), "scale": 0.25, "lights": [SUN]},
         "sh_bands": 4, "shadow": dict({"exp": "calibrated"}, **shadow),
         "objects": [{"mesh": mesh, "albedo": [0.5, 0.5, 0.5], "spheres": {"fit": fit}}]
         if objects else [],
         "background": [0, 0, 0]}
    if ground:
        s["ground"] = {"height": 0, "albedo": [0.8, 0.8, 0.8], "half_size": 6}
    return s


def write(path, obj):
    with open(path, "w") as f:
        json.dump(obj, f)
    return path


def main():
    opts, _ = parse_options(sys.argv[2:], {"--old": "", "--counts": "32,64,128",
                                          "--out": "out/thin_chair"})
    pen = os.path.abspath(sys.argv[1])
    out = os.path.abspath(opts["--out"])
    os.makedirs(out, exist_ok=True)
    mesh = os.path.join(out, "chair.obj")
    subprocess.run([sys.executable, os.path.join(HERE, "make_frame.py"), mesh, "--seat"],
                   check=True)
    counts = [int(c) for c in opts["--counts"].split(",")]
    # The truth, the bare ground, the chair's own pixels: the mask of the cast shadow.
    truth = os.path.join(out, "truth.exr")
    run([pen, "reference", write(os.path.join(out, "truth.json"), scene(mesh, {}, 32)), "-o",
         truth, "--spp", "256", "--lighting", "sh"])
    bare = os.path.join(out, "bare.exr")
    run([pen, "reference", write(os.path.join(out, "bare.json"), scene(mesh, {}, 32, False)),
         "-o", bare, "--spp", "64", "--lighting", "sh"])
    cover = os.path.join(out, "cover.exr")
    run([pen, "reference", write(os.path.join(out, "obj.json"), scene(mesh, {}, 32, True, False)),
         "-o", os.path.join(out, "obj.exr"), "--spp", "4", "--coverage", cover])
    w, h, t = rgb(truth)
    _, _, b = rgb(bare)
    _, _, c = rgb(cover)
    mask = []
    for i in range(w * h):
        lt, lb = sum(t[k][i] for k in range(3)), sum(b[k][i] for k in range(3))
        mask.append(c[0][i] < 0.5 and lt < 0.9 * lb)
    write_png(os.path.join(out, "cast.png"), w, h, [(255,) * 3 if m else (0,) * 3 for m in mask])
    print("cast-shadow pixels: %d of %d" % (sum(mask), w * h))
    builds = [("now", pen)] + ([("before", os.path.abspath(opts["--old"]))] if opts["--old"] else [])
    print("| render | build | spheres | cast-shadow rel. RMSE | whole image |")
    print("|---|---|---|---|---|")
    for label, binary in builds:
        env = dict(os.environ, XDG_CACHE_HOME=os.path.join(out, "cache_" + label))
        for n in counts:
            for route, shadow in (("spheres", {"self": "spheres", "ground_shadow": "spheres"}),
                                  ("default", {})):
                if route == "default" and (label != "now" or n != counts[0]):
                    continue  # the default's shadows do not come from the spheres
                js = write(os.path.join(out, "%s_%s_%d.json" % (route, label, n)),
                           scene(mesh, shadow, n))
                img = js[:-5] + ".exr"
                subprocess.run([binary, "render", js, "-o", img, "-q"], env=env, check=True,
                               stderr=subprocess.DEVNULL)
                j = json.loads(run([binary, "compare", img, truth, "--mask",
                                    os.path.join(out, "cast.png")]))
                print("| %s | %s | %s | %.4f | %.4f |" % (route, label,
                      n if route == "spheres" else "-", j["mask"]["rel_rmse"], j["rel_rmse"]))


main()
