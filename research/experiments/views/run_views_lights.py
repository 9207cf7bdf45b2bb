"""The multi-view lighting experiment again, with the map's lights (docs/results/views.md, "With the
map's lights held"): the scenes of run_views.sh keep the disk lights the loader finds in the map
(their "lights": "none" removed), the lights are held at those values and the SH part is solved
by least squares (default ridge) from 1, 2, 4 and 8 views of the ring and ring_near placements,
against the same full-map targets. The held-back views are compared with the truth's own render
with its lights (penumbra, the model's floor there).

Usage: python3 research/experiments/views/run_views_lights.py PENUMBRA_BIN [MESH_ENVMAP ...]
  after `sh research/experiments/views/run_views.sh PENUMBRA_BIN MESH:ENVMAP` has made
  out/views/MESH_ENVMAP (default: spot_city spot_interior bob_city bob_interior). Writes
  truth_lights.json, cam_val*_lights.json, true_val*_lights.exr, task_<placement>_<n>_lights.json
  and run_<placement>_<n>_lights/ into each folder and a markdown table on stdout.
"""
import json
import os
import subprocess
import sys

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "..")


def without_lights_none(src, dst):
    with open(src) as f:
        scene = json.load(f)
    scene["lighting"].pop("lights", None)
    with open(dst, "w") as f:
        json.dump(scene, f, indent=1)


def rel(pen, a, b):
    """`penumbra compare`'s rel. RMSE of image a against b."""
    return json.loads(subprocess.check_output([pen, "compare", a, b]))["rel_rmse"]


def held_back_floor(pen, d):
    """The mean rel. RMSE of the truth's own lights rendered by penumbra at the two held-back
    views (true_val<i>_lights.exr, made by main) against their full-map targets: the model's
    floor there."""
    return sum(rel(pen, os.path.join(d, "true_%s_lights.exr" % v), os.path.join(d, "t_%s.exr" % v))
               for v in ("val1", "val2")) / 2


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    pen = os.path.abspath(sys.argv[1])
    cases = sys.argv[2:] or ["spot_city", "spot_interior", "bob_city", "bob_interior"]

    print("| scene | placement | lighting error (sky), 1 / 2 / 4 / 8 views | 4 / 1 view (sky) "
          "| held-back at 4 views: recovered / true lights |")
    print("|---|---|---|---|---|")
    for case in cases:
        d = os.path.join(ROOT, "out", "views", case)
        without_lights_none(os.path.join(d, "truth.json"), os.path.join(d, "truth_lights.json"))
        for v in ("val1", "val2"):
            cam = os.path.join(d, "cam_%s_lights.json" % v)
            without_lights_none(os.path.join(d, "cam_%s.json" % v), cam)
            img = os.path.join(d, "true_%s_lights.exr" % v)
            subprocess.check_call([pen, "render", cam, "-o", img], stdout=subprocess.DEVNULL)
        floor = held_back_floor(pen, d)
        for placement in ("ring", "ring_near"):
            err = {}
            for n in (1, 2, 4, 8):
                with open(os.path.join(d, "task_%s_%d_ls.json" % (placement, n))) as f:
                    task = json.load(f)
                task["scene"] = task["ground_truth"] = "truth_lights.json"
                path = os.path.join(d, "task_%s_%d_lights.json" % (placement, n))
                with open(path, "w") as f:
                    json.dump(task, f, indent=1)
                run = os.path.join(d, "run_%s_%d_lights" % (placement, n))
                result = os.path.join(run, "result.json")
                if not os.path.exists(result):
                    subprocess.check_call([pen, "optimize", path, "-o", run, "-q"])
                with open(result) as f:
                    err[n] = json.load(f)
            m = {n: (r["metrics"]["lighting_rel_error"], r["metrics"]["lighting_rel_error_sky"])
                 for n, r in err.items()}
            val = [v["image_rel_rmse"] for v in err[4]["validation_views"]]
            held = sum(val) / len(val)
            mesh, envmap = case.split("_", 1)
            print("| %s, %s | %s | %s | %.2f× (%.2f×) | %.4f / %.4f = %.2f× |" % (
                mesh, envmap, placement,
                " / ".join("%.3f (%.3f)" % m[n] for n in (1, 2, 4, 8)),
                m[4][0] / m[1][0], m[4][1] / m[1][1], held, floor, held / floor))


if __name__ == "__main__":
    main()
