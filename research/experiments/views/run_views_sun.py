"""The lights found from 1, 2, 4 and 8 views (docs/results/views.md, "The lights found from several
views"): the scenes of run_views.sh start with no disk lights and the SH lighting from black,
and the task optimises ["lighting", "lights"] with "light_count" lights: the global search
creates them over every view, then Adam refines directions, radii, irradiances and the SH
together (the sphere model: light directions take gradients), against the full-map targets of
the ring placement. Judged by each found light's angle to the nearest light the loader finds in
the map, the SH part's error against the map's residual (the truth with its lights), and the
held-back views' image error over that of the truth's own lights rendered by penumbra there.

Usage: python3 research/experiments/views/run_views_sun.py PENUMBRA_BIN [MESH_ENVMAP[:COUNT] ...]
  after `sh research/experiments/views/run_views.sh PENUMBRA_BIN MESH:ENVMAP` made
  out/views/MESH_ENVMAP and `python3 research/experiments/views/run_views_lights.py PENUMBRA_BIN`
  its truth_lights.json and true_val*_lights.exr (default: spot_city:1 bob_city:1; COUNT the
  lights to find). Writes task_ring_<n>_sun.json and run_ring_<n>_sun/ into each folder and a
  markdown table on stdout.
Environment: PEN_SUN_RIDGE=R sets the task's "lighting_ridge" (Adam's default is none; the search
  solves its SH at 1e-2 either way); its files are then named ..._sun_r<R>.
"""
import json
import os
import subprocess
import sys

from run_views_lights import held_back_floor

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "..")


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    pen = os.path.abspath(sys.argv[1])
    cases = sys.argv[2:] or ["spot_city:1", "bob_city:1"]
    ridge = os.environ.get("PEN_SUN_RIDGE")
    tag = "_sun" + ("_r" + ridge if ridge else "")

    print("| scene | views | light's angle to the map's (deg) | SH error (sky) | held-back: found / "
          "true lights | iterations, stop | search: renders, s | s/it |")
    print("|---|---|---|---|---|---|---|---|")
    for case in cases:
        name, _, count = case.partition(":")
        d = os.path.join(ROOT, "out", "views", name)
        floor = held_back_floor(pen, d)
        for n in (1, 2, 4, 8):
            task = {"scene": "truth.json", "ground_truth": "truth_lights.json",
                    "optimize": ["lighting", "lights"], "light_count": int(count or 1),
                    "iterations": 300, "views": "views_ring_%d.json" % n,
                    "validation_views": "views_val.json"}
            if ridge:
                task["lighting_ridge"] = float(ridge)
            path = os.path.join(d, "task_ring_%d%s.json" % (n, tag))
            with open(path, "w") as f:
                json.dump(task, f, indent=1)
            run = os.path.join(d, "run_ring_%d%s" % (n, tag))
            result = os.path.join(run, "result.json")
            if not os.path.exists(result):
                subprocess.check_call(["nice", pen, "optimize", path, "-o", run, "-q"])
            with open(result) as f:
                r = json.load(f)
            m = r["metrics"]
            held = sum(v["image_rel_rmse"] for v in r["validation_views"]) / 2
            mesh, envmap = name.split("_", 1)
            print("| %s, %s | %d | %.2f | %.3f (%.3f) | %.4f / %.4f = %.2f× | %d, %s | %d, %.1f "
                  "| %.3f |" % (mesh, envmap, n, m["light_direction_error_deg"],
                                m["lighting_rel_error"], m["lighting_rel_error_sky"], held, floor,
                                held / floor, r["iterations"], r["stop_reason"],
                                r["light_search"]["renders"], r["light_search"]["seconds"],
                                r["seconds_per_iteration"]), flush=True)


if __name__ == "__main__":
    main()
