"""Cameras, scenes, views files and tasks of the multi-view lighting experiment (run_views.sh).

The truth is examples/optimize/<mesh>_truth.json (the mesh on the ground, "lights": "none", so
the map's 4-band projection is the true lighting) under the bundled map ENVMAP, rendered at
128x128. Cameras look at the scene camera's target from an azimuth (degrees from the scene
camera's, about the vertical axis), an elevation above the ground plane and a distance (a
factor of the scene camera's). A placement is an ordered list of 8 cameras; its n-view task
uses the first n, so the n-view sets grow by adding views, and 1 view is the scene camera's
(at the placement's distance):

  ring      today's placement: the scene camera's elevation (17 degrees), its distance,
            azimuths 0, 180, 90, 270, 45, 225, 135, 315
  ring_far  the same at 1.4x the distance (the shadow wholly in frame, the object smaller)
  ring_near the same at 0.75x (the object larger, the shadow's far end cut off)
  elev      several elevations: (0, 17), (180, 70), (90, 40), (270, 15), (45, 89: top-down),
            (225, 40), (135, 15), (315, 70)

Two held-back views that no placement uses, (60, 30) and (250, 55), are the validation views
of every task. Solvers: ls = least squares, default ridge 1e-2; ls4 = ridge 1e-4; adam = Adam
with the task defaults (from black, no ridge, 500 iterations at most, rate 0.01); pose = not the lighting
but the 6-D pose (Adam, at most 400 iterations) from examples/optimize/<mesh>_pose_init.json
(10.8 degrees and 0.1 off), the lighting known (map targets only). Targets: t_<name>.exr, the
full map ray-traced (the experiment); the controls t_<name>_sh.exr (ray-traced with the map's
4-band projection: exact visibility, band-limited light) and t_<name>_model.exr (penumbra's own
render of the truth: the model exact), whose views files and tasks carry the suffix _sh and
_model (least squares only).
Writes into OUT: cam_<name>.json (the truth with that camera, absolute paths, for `penumbra
reference` and `penumbra render`), truth.json (the truth under ENVMAP, the scene and ground truth
of every task), pose_init.json (the pose tasks' start), views_<placement>_<n>[_sh|_model].json, views_val[_sh|_model].json and
task_<placement>_<n>_<solver>[_sh|_model].json; the targets are made by run_views.sh.
Usage: python3 make_views.py OUT MESH ENVMAP
"""
import json
import math
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
# The scenes and tasks read: the user examples' (the truths, the pose starts) and the experiments'
# own (deformation and shape from shadow); a name is looked up in this order.
TASKS = (os.path.join(HERE, "..", "..", "..", "examples", "optimize"),
         os.path.join(HERE, "..", "optimize"))
SIZE = 128
COUNTS = (1, 2, 4, 8)
SOLVERS = {"ls": {"lighting_solver": "least_squares"},
           "ls4": {"lighting_solver": "least_squares", "lighting_ridge": 1e-4},
           "adam": {"lighting_solver": "adam"},
           "pose": {"scene": "pose_init.json", "optimize": ["pose"], "iterations": 400}}
RING = (0, 180, 90, 270, 45, 225, 135, 315)
ELEV = ((0, None), (180, 70), (90, 40), (270, 15), (45, 89), (225, 40), (135, 15), (315, 70))
VALIDATION = {"val1": (60, 30), "val2": (250, 55)}


def task_path(name):
    """The path of NAME.json in the first folder of TASKS that has it."""
    for folder in TASKS:
        path = os.path.normpath(os.path.join(folder, name + ".json"))
        if os.path.exists(path):
            return path
    sys.exit("make_views: %s.json is in none of %s" % (name, ", ".join(TASKS)))


def load_scene(name, envmap="city"):
    """NAME.json of TASKS with absolute paths (its map replaced by the bundled ENVMAP)."""
    path = task_path(name)
    with open(path) as f:
        scene = json.load(f)

    def absolute(p):
        return os.path.normpath(os.path.join(os.path.dirname(path), p))

    if "envmap" in scene["lighting"]:
        scene["lighting"]["envmap"] = absolute(scene["lighting"]["envmap"]).replace(
            "/city.hdr", "/%s.hdr" % envmap)
    for ob in scene["objects"]:
        for key in ("mesh", "albedo_texture", "spheres"):
            if isinstance(ob.get(key), str):
                ob[key] = absolute(ob[key])
    return scene


def placements(cam0):
    """The cameras around cam0's target (key -> camera) and the placements (name -> the
    ordered keys of its 8 cameras; "val" the two held-back views)."""
    target = cam0["target"]
    d0 = [e - t for e, t in zip(cam0["eye"], target)]
    dist0 = math.sqrt(sum(v * v for v in d0))
    elev0 = math.degrees(math.asin(d0[1] / dist0))
    azim0 = math.atan2(d0[0], d0[2])

    def camera(azimuth, elevation, factor=1.0):
        a, e = azim0 + math.radians(azimuth), math.radians(elevation)
        r = dist0 * factor
        direction = (math.cos(e) * math.sin(a), math.sin(e), math.cos(e) * math.cos(a))
        eye = [t + r * v for t, v in zip(target, direction)]
        # looking almost straight down, "up" is the horizontal direction away from the camera
        up = [0, 1, 0] if elevation < 80 else [-math.sin(a), 0, -math.cos(a)]
        return {"width": SIZE, "height": SIZE, "fov_y_deg": cam0["fov_y_deg"],
                "eye": [round(v, 6) for v in eye], "target": target,
                "up": [round(v, 6) for v in up]}

    def placement(name):
        if name.startswith("ring"):
            factor = {"ring": 1.0, "ring_far": 1.4, "ring_near": 0.75}[name]
            return [(a, elev0, factor) for a in RING]
        return [(a, elev0 if e is None else e, 1.0) for a, e in ELEV]

    cameras = {}
    views = {}
    for name in ("ring", "ring_far", "ring_near", "elev"):
        views[name] = []
        for spec in placement(name):
            key = "a%d_e%d_d%d" % (round(spec[0]), round(spec[1]), round(100 * spec[2]))
            cameras[key] = camera(*spec)
            views[name].append(key)
    for key, (a, e) in VALIDATION.items():
        cameras[key] = camera(a, e)
    views["val"] = sorted(VALIDATION)
    return cameras, views


def main():
    out, mesh, envmap = os.path.abspath(sys.argv[1]), sys.argv[2], sys.argv[3]
    truth = load_scene("%s_truth" % mesh, envmap)
    cameras, views = placements(truth["camera"])
    views.pop("val")

    os.makedirs(out, exist_ok=True)

    def write(name, obj):
        with open(os.path.join(out, name), "w") as f:
            json.dump(obj, f, indent=1)

    write("truth.json", truth)
    with open(task_path("%s_pose_init" % mesh)) as f:
        pose_init = json.load(f)
    pose_init.update(lighting=truth["lighting"], objects=[
        dict(ob, pose=p["pose"]) for ob, p in zip(truth["objects"], pose_init["objects"])])
    write("pose_init.json", pose_init)
    for key, cam in cameras.items():
        write("cam_%s.json" % key, dict(truth, camera=cam))

    def views_file(keys, suffix):
        return {"views": [{"camera": cameras[k], "target": "t_%s%s.exr" % (k, suffix)} for k in keys]}

    for suffix in ("", "_sh", "_model"):
        write("views_val%s.json" % suffix, views_file(sorted(VALIDATION), suffix))
        for name, keys in views.items():
            for n in COUNTS:
                write("views_%s_%d%s.json" % (name, n, suffix), views_file(keys[:n], suffix))
                for solver, extra in SOLVERS.items():
                    if suffix and solver in ("adam", "pose"):
                        continue
                    task = {"scene": "truth.json", "ground_truth": "truth.json",
                            "optimize": ["lighting"], "views": "views_%s_%d%s.json" % (name, n, suffix),
                            "validation_views": "views_val%s.json" % suffix}
                    task.update(extra)
                    write("task_%s_%d_%s%s.json" % (name, n, solver, suffix), task)
    print(" ".join(sorted(cameras)))


if __name__ == "__main__":
    main()
