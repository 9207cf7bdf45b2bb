"""Cameras, scenes, views files and tasks of the multi-view experiment (views_experiment.sh).

Spot under the city map (examples/optimize/spot_truth.json), seen by cameras on a circle around it
at the height and distance of the scene's own camera; 128x128. The view lists grow as 1, 2
(opposite), 4 (every 90 degrees); one held-back view between them (45 degrees on, a little
higher) is the validation view of every task. Writes into OUT: cam_<i>.json (the truth scene
with camera i, paths made absolute, for `penumbra reference`), views_<n>[_sh].json,
views_val[_sh].json, task_<n>_<solver>[_sh].json (solver: ls = least squares with the default
ridge 1e-2, ls1e-4 = ridge 1e-4, adam_fit = Adam from the unshadowed least-squares fit over the
same views, at most 300 iterations; _sh: the targets lit by the map's 4-band projection, least
squares only).
Usage: python3 views_setup.py OUT
"""
import json
import math
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
EXAMPLES = os.path.join(HERE, "..", "..", "..", "examples", "optimize")
OUT = os.path.abspath(sys.argv[1])
SIZE = 128
TRUTH = os.path.normpath(os.path.join(EXAMPLES, "spot_truth.json"))

with open(TRUTH) as f:
    truth = json.load(f)


def absolute(path):
    return os.path.normpath(os.path.join(EXAMPLES, path))


truth["lighting"]["envmap"] = absolute(truth["lighting"]["envmap"])
for ob in truth["objects"]:
    ob["mesh"] = absolute(ob["mesh"])
    ob["albedo_texture"] = absolute(ob["albedo_texture"])
cam0 = truth["camera"]
eye0, target = cam0["eye"], cam0["target"]
dx, dz = eye0[0] - target[0], eye0[2] - target[2]
radius, angle0 = math.hypot(dx, dz), math.atan2(dx, dz)


def camera(degrees, lift=0.0):
    a = angle0 + math.radians(degrees)
    eye = [target[0] + radius * math.sin(a), eye0[1] + lift, target[2] + radius * math.cos(a)]
    return {"width": SIZE, "height": SIZE, "fov_y_deg": cam0["fov_y_deg"],
            "eye": [round(v, 6) for v in eye], "target": target, "up": [0, 1, 0]}


# view i: 0, 180, 90, 270 degrees on from the scene's camera; "val": 45 degrees, 0.4 higher
cameras = {"0": camera(0), "1": camera(180), "2": camera(90), "3": camera(270),
           "val": camera(45, 0.4)}
os.makedirs(OUT, exist_ok=True)
for name, cam in cameras.items():
    scene = dict(truth, camera=cam)
    with open(os.path.join(OUT, "cam_%s.json" % name), "w") as f:
        json.dump(scene, f, indent=1)


def views(names, suffix):
    return {"views": [{"camera": cameras[n], "target": "t_%s%s.exr" % (n, suffix)} for n in names]}


# suffix "": targets lit by the map itself; "_sh": by its 4-band projection, which the model
# represents exactly (what is left is the proxies' and SH visibility's error)
for suffix in ("", "_sh"):
    for n in (1, 2, 4):
        with open(os.path.join(OUT, "views_%d%s.json" % (n, suffix)), "w") as f:
            json.dump(views([str(i) for i in range(n)], suffix), f, indent=1)
        solvers = [("ls", {"lighting_solver": "least_squares"}),
                   ("ls1e-4", {"lighting_solver": "least_squares", "lighting_ridge": 1e-4})]
        if not suffix:
            solvers.append(("adam_fit", {"lighting_solver": "adam", "init": "fit",
                                         "iterations": 300}))
        for solver, extra in solvers:
            task = {"scene": TRUTH, "ground_truth": TRUTH, "optimize": ["lighting"],
                    "views": "views_%d%s.json" % (n, suffix),
                    "validation_views": "views_val%s.json" % suffix}
            task.update(extra)
            with open(os.path.join(OUT, "task_%d_%s%s.json" % (n, solver, suffix)), "w") as f:
                json.dump(task, f, indent=1)
    with open(os.path.join(OUT, "views_val%s.json" % suffix), "w") as f:
        json.dump(views(["val"], suffix), f, indent=1)
