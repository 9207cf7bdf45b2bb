"""Collects the finished runs of run_views.sh into OUT/results.tsv and a markdown table.

One line per run (MESH_ENVMAP/run_<placement>_<n>_<solver>/result.json): the lighting errors
(all 16 coefficients, bands 0-2, the sky = upper hemisphere), the ratio of each to the same
case's 1-view ring run with the same solver (the experiment asks 4 views <= 0.5x), the held-back
views' mean rel. RMSE ("val") beside that of the true map's 4-band projection there ("true",
true_val<i>.json, against the full map's targets; for the controls the ratio is not the
experiment's) and their ratio, and the solver's iterations, stop reason, seconds per
iteration and final loss; the pose runs in a table of their own.
Usage: python3 views_table.py OUT   (OUT = out/views)
"""
import glob
import json
import os
import re
import sys

out = sys.argv[1]
RUN = re.compile(r"run_(ring|ring_far|ring_near|elev)_(\d+)_(ls4|ls|adam|pose)(_sh|_model)?$")
ORDER = {"ring": 0, "elev": 1, "ring_far": 2, "ring_near": 3}
rows = []
poses = []
for case in sorted(os.listdir(out)):
    cdir = os.path.join(out, case)
    true_files = sorted(glob.glob(os.path.join(cdir, "true_val*.json")))
    if not true_files:
        continue
    true = [json.load(open(f))["rel_rmse"] for f in true_files]
    for path in glob.glob(os.path.join(cdir, "run_*", "result.json")):
        m = RUN.match(os.path.basename(os.path.dirname(path)))
        if not m:
            continue
        r = json.load(open(path))
        met = r["metrics"]
        if m.group(3) == "pose":
            poses.append((case, m.group(1), int(m.group(2)), met["rotation_error_deg"],
                          met["translation_error_rel"], r["iterations"], r["stop_reason"],
                          r["seconds_per_iteration"]))
            continue
        val = [v["image_rel_rmse"] for v in r["validation_views"]]
        rows.append({"case": case, "targets": (m.group(4) or "_map")[1:],
                     "placement": m.group(1), "n": int(m.group(2)), "solver": m.group(3), "err": met["lighting_rel_error"],
                     "b02": met["lighting_rel_error_bands_0_2"],
                     "sky": met["lighting_rel_error_sky"],
                     "val": sum(val) / len(val), "true": sum(true) / len(true),
                     "iterations": r["iterations"], "stop": r["stop_reason"],
                     "s_per_it": r["seconds_per_iteration"], "seconds": r["seconds"],
                     "loss": r["final_loss"]})
base = {(r["case"], r["targets"], r["solver"]): r for r in rows
        if r["placement"] == "ring" and r["n"] == 1}
rows.sort(key=lambda r: (r["case"], r["targets"], r["solver"], ORDER[r["placement"]], r["n"]))
cols = ("case", "targets", "placement", "n", "solver", "err", "err_x1", "b02", "sky", "sky_x1", "val",
        "true", "val_ratio", "iterations", "stop", "s_per_it", "seconds", "loss")
with open(os.path.join(out, "results.tsv"), "w") as f:
    f.write("\t".join(cols) + "\n")
    print("| case | targets | placement | views | solver | lighting error (x 1 view) | bands 0-2 | sky "
          "(x 1 view) | held-back rel. RMSE / true's (ratio) | iterations, stop | s/it |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        b = base.get((r["case"], r["targets"], r["solver"]))
        r["err_x1"] = r["err"] / b["err"] if b else float("nan")
        r["sky_x1"] = r["sky"] / b["sky"] if b else float("nan")
        r["val_ratio"] = r["val"] / r["true"]
        f.write("\t".join(str(r[c]) for c in cols) + "\n")
        # (seconds_per_iteration is null for a solve without Adam steps)
        s_per_it = "-" if r["s_per_it"] is None else "%.3f" % r["s_per_it"]
        print("| %s | %s | %s | %d | %s | %.3f (%.2fx) | %.3f | %.3f (%.2fx) | %.4f / %.4f (%.2f) "
              "| %d, %s | %s |" % (r["case"], r["targets"], r["placement"], r["n"], r["solver"], r["err"],
                                 r["err_x1"], r["b02"], r["sky"], r["sky_x1"], r["val"],
                                 r["true"], r["val_ratio"], r["iterations"], r["stop"],
                                 s_per_it))

# The summary of docs/results/views.md: per case, targets, solver and placement the lighting error
# (sky) at 1, 2, 4 and 8 views, 4 views against the 1-view ring run, and the held-back ratio at
# 4 views (the views at every count for Adam: its iterations and stop reason).
print()
print("| case | targets | solver | placement | 1 view | 2 views | 4 views | 8 views | 4 views "
      "/ 1 view: all (sky) | held-back / true's, 4 views |")
print("|---|---|---|---|---|---|---|---|---|---|")
groups = {}
for r in rows:
    groups.setdefault((r["case"], r["targets"], r["solver"], r["placement"]), {})[r["n"]] = r
for (case, targets, solver, placement), runs in groups.items():
    def cell(n):
        r = runs.get(n)
        if r is None:
            return "-"
        text = "%.3f (%.3f)" % (r["err"], r["sky"])
        if solver == "adam":
            text += ", %d%s" % (r["iterations"], "" if r["stop"] == "converged" else " (limit)")
        return text
    four = runs.get(4)
    ratio = "%.2fx (%.2fx)" % (four["err_x1"], four["sky_x1"]) if four else "-"
    held = "%.2f" % four["val_ratio"] if four and targets == "map" else "-"
    print("| %s | %s | %s | %s | %s | %s | %s | %s | %s | %s |"
          % (case, targets, solver, placement, cell(1), cell(2), cell(4), cell(8), ratio, held))

# The pose from several views: rotation error, translation error as a share of the object's
# size, iterations and seconds per iteration.
if poses:
    print()
    print("The pose (solver \"pose\": from examples/optimize/<mesh>_pose_init.json, 10.8 deg and "
          "0.1 off, the lighting known):")
    print()
    print("| case | placement | views | rotation error (deg) | translation error (% of size) "
          "| iterations, stop | s/it |")
    print("|---|---|---|---|---|---|---|")
    for p in sorted(poses, key=lambda p: (p[0], ORDER[p[1]], p[2])):
        print("| %s | %s | %d | %.2f | %.1f%% | %d, %s | %.2f |"
              % (p[0], p[1], p[2], p[3], 100 * p[4], p[5], p[6], p[7]))
