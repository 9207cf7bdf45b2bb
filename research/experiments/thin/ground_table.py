"""The ground's shadows of thin parts (docs/visibility.md, "Thin parts on the ground"): the chair
of make_frame.py under a sun 8 degrees up and the city map, 384x384. Renders the default and
finer ground grids and measures each against the full-map truth (`penumbra reference`, 256 spp)
over the truth's cast shadows on the ground (ground pixels the chair darkens by more than 10 %),
with the render's wall time (the minimum of --runs).

    python3 research/experiments/thin/ground_table.py PENUMBRA [--out out/thin_ground]
        [--grids 0,192,384,768] [--runs 3] [--lighting envmap|sh] [--find-map-lights]
        [--truth-spp 256]

--lighting sh: the truth lit as `render` is (the map's SH plus the sun), so that only the
visibility differs. --find-map-lights: the scenes as `make_frame.py --find-map-lights` writes them
(the map's sun found as a disk light, the low sun added). The truth and the mask are kept in OUT
between runs, so use one OUT per lighting, scene form and --truth-spp. --truth-spp: the truth's
samples per pixel; with the map's sun found, the truth's own noise at 256 spp is most of the
render's error over the cast shadows (two seeds' truths differ by more than the render from
either), and 2048 brings it to about a third.

Grid 0 is the default. About two minutes on the shared 2-core machine.
"""
import json
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "accuracy"))
from visibility_table import parse_options, rgb, run, write_png  # noqa: E402


def main():
    opts, flags = parse_options(sys.argv[2:], {"--out": "out/thin_ground",
                                               "--grids": "0,192,384,768", "--runs": "3",
                                               "--lighting": "envmap", "--truth-spp": "256"},
                                ("--find-map-lights",))
    pen = os.path.abspath(sys.argv[1])
    out = os.path.abspath(opts["--out"])
    subprocess.run([sys.executable, os.path.join(HERE, "make_frame.py"), out]
                   + sorted(flags), check=True)
    truth, bare = os.path.join(out, "truth.exr"), os.path.join(out, "bare.exr")
    cover, mask = os.path.join(out, "cover.exr"), os.path.join(out, "cast.png")
    if not os.path.exists(mask):
        if not os.path.exists(truth):  # the truth is kept between builds
            run([pen, "reference", os.path.join(out, "frame.json"), "-o", truth,
                 "--spp", opts["--truth-spp"], "--lighting", opts["--lighting"]])
        run([pen, "reference", os.path.join(out, "frame_empty.json"), "-o", bare, "--spp", "64",
             "--lighting", opts["--lighting"]])
        with open(os.path.join(out, "frame.json")) as f:
            sc = json.load(f)
        del sc["ground"]
        with open(os.path.join(out, "frame_noground.json"), "w") as f:
            json.dump(sc, f)
        run([pen, "reference", os.path.join(out, "frame_noground.json"), "-o",
             os.path.join(out, "obj.exr"), "--spp", "4", "--coverage", cover])
        w, h, t = rgb(truth)
        _, _, b = rgb(bare)
        _, _, c = rgb(cover)
        m = [c[0][i] < 0.5 and sum(t[k][i] for k in range(3)) < 0.9 * sum(b[k][i] for k in range(3))
             for i in range(w * h)]
        write_png(mask, w, h, [(255,) * 3 if v else (0,) * 3 for v in m])
        print("cast-shadow pixels: %d of %d" % (sum(m), w * h))
    print("| ground grid | cast-shadow rel. RMSE | whole image | render wall s (min of %s) |"
          % opts["--runs"])
    print("|---|---|---|---|")
    for g in [int(x) for x in opts["--grids"].split(",")]:
        scene = os.path.join(out, "frame.json" if g == 0 else "frame_g%d.json" % g)
        img = os.path.join(out, "render_%d.exr" % g)
        best = 1e30
        for _ in range(int(opts["--runs"])):
            t0 = time.time()
            run([pen, "render", scene, "-o", img])
            best = min(best, time.time() - t0)
        j = json.loads(run([pen, "compare", img, truth, "--mask", mask]))
        print("| %s | %.4f | %.4f | %.2f |" % (g or "96 (default)", j["mask"]["rel_rmse"],
                                              j["rel_rmse"], best), flush=True)


if __name__ == "__main__":
    main()
