"""Collects the finished runs of run_views_shape.sh into OUT/results.tsv and a markdown table.

One line per run (MESH/run_<task>_<placement>_<n>[_it<N>][_t<T>]/result.json; _it<N>: the limit
raised to N iterations, "limit" column; _t<T>: T threads, "threads" column, else the default,
all): the task's metrics against the
ground truth (deformation: vertex_rmse against the bent mesh; shape: shadow_iou, the silhouette
seen from the light, sphere_iou and sphere_chamfer against the true fit), the image RMSE over
every view's pixels, the iterations and stop reason, seconds per iteration and the first and
best losses (the sum over the views, so not comparable between view counts); and per mesh and
task a "start" line: the unbent mesh's vertex RMSE from the bent one (the objects' scale times
the RMS distance between the two OBJs' vertices) and the shape start's metrics
(MESH/run_shape_start: one step without shadows, in which the spheres do not move).
Usage: python3 views_shape_table.py OUT   (OUT = out/views_shape)
"""
import glob
import json
import math
import os
import re
import sys

RUN = re.compile(r"run_(deformation|shape)_(?:(ring|top)_(\d+)(?:_it(\d+))?(?:_t(\d+))?|start)$")
METRICS = {"deformation": ("vertex_rmse",),
           "shape": ("shadow_iou", "sphere_iou", "sphere_chamfer")}


def vertex_rmse(start, truth):
    """The deformation's start metric: the bent truth's object against the start's."""
    def vertices(scene):
        with open(scene["objects"][0]["mesh"]) as f:
            return [[float(c) for c in line.split()[1:4]] for line in f if line.startswith("v ")]
    a, b = vertices(start), vertices(truth)
    sq = sum((x - y) ** 2 for p, q in zip(a, b) for x, y in zip(p, q))
    return truth["objects"][0]["pose"].get("scale", 1) * math.sqrt(sq / len(a))


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    out = sys.argv[1]
    rows = []
    for path in glob.glob(os.path.join(out, "*", "run_*", "result.json")):
        m = RUN.match(os.path.basename(os.path.dirname(path)))
        if not m:
            continue
        with open(path) as f:
            r = json.load(f)
        mesh_dir = os.path.dirname(os.path.dirname(path))
        with open(r["task"]) as f:
            limit = int(m.group(4) or json.load(f)["iterations"])
        rows.append(dict(mesh=os.path.basename(mesh_dir), task=m.group(1),
                         placement=m.group(2) or "start", n=int(m.group(3) or 0), limit=limit,
                         threads=m.group(5) or "all", r=r))
        if m.group(1) == "deformation" and m.group(3) == "1" and not (m.group(4) or m.group(5)):
            scenes = []
            for name in ("start_deformation.json", "truth_deformation.json"):
                with open(os.path.join(mesh_dir, name)) as f:
                    scenes.append(json.load(f))
            rows.append(dict(mesh=rows[-1]["mesh"], task="deformation", placement="start", n=0,
                             limit=0, threads="",
                             r={"metrics": {"vertex_rmse": vertex_rmse(*scenes)}}))
    order = {"start": 0, "ring": 1, "top": 2}
    meshes = {"spot": 0, "bob": 1}
    rows.sort(key=lambda x: (meshes.get(x["mesh"], 2), x["mesh"], x["task"],
                             order[x["placement"]], x["limit"], x["threads"] != "all",
                             x["threads"], x["n"]))
    cols = (("mesh", "task", "placement", "views", "limit", "threads") + METRICS["deformation"]
            + METRICS["shape"] + ("image_rmse", "iterations", "stop_reason",
                                  "seconds_per_iteration", "initial_loss", "final_loss"))
    print("| mesh | task | placement | views | limit | threads | vertex RMSE / shadow IoU, "
          "sphere IoU, Chamfer | image RMSE | iterations, stop | s/it |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    with open(os.path.join(out, "results.tsv"), "w") as f:
        f.write("\t".join(cols) + "\n")
        for x in rows:
            met = x["r"]["metrics"]
            line = dict(x["r"], views=x["n"], **x)
            line.update(met)
            f.write("\t".join(str(line.get(c, "")) for c in cols) + "\n")
            metric = ", ".join("%.4f" % met[k] for k in METRICS[x["task"]])
            if x["placement"] == "start":
                print("| %s | %s | start | - | - | - | %s | | | |" % (x["mesh"], x["task"], metric))
                continue
            r = x["r"]
            print("| %s | %s | %s | %d | %d | %s | %s | %.4f | %d, %s | %.3f |" % (
                x["mesh"], x["task"], x["placement"], x["n"], x["limit"], x["threads"], metric,
                met["image_rmse"],
                r["iterations"], r["stop_reason"], r["seconds_per_iteration"]))

if __name__ == "__main__":
    main()
