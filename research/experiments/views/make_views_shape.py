"""Scenes, cameras, views files and tasks of the multi-view deformation and shape-from-shadow
experiment (run_views_shape.sh; docs/results/views.md, "Deformation and shape from shadow from
several views").

The two single-view tasks of research/experiments/optimize, with their settings (groups,
iterations, smoothness; "target", "scene" and "ground_truth" replaced), given 1, 2, 4 and 8 views
instead of one target:

  deformation  start <mesh>_truth.json (the unbent mesh), truth <mesh>_bent_truth.json (the
               mesh bent sideways by bend_obj.py), the city map with "lights": "none"
  shape        start <mesh>_shadow_init.json (perturbed proxy spheres), truth
               <mesh>_shadow_truth.json (the true 32-sphere fit), lit by their own 4-band sun

Placements (an ordered list of 8 cameras at 128x128; the n-view task uses the first n):

  ring  make_views.py's ring around <mesh>_truth.json's camera: its elevation (17 degrees) and
        distance, azimuths 0, 180, 90, 270, 45, 225, 135, 315 from it; 1 view = the camera of
        the single-view deformation task, at 128x128
  top   (shape only) 1 view = the single-view shape task's own camera (straight down over the
        shadow's middle, 4 above the ground, 40 degrees wide), then 7 cameras at 50 degrees
        elevation, the same distance from the same point, at azimuths 0, 180, 90, 270, 45,
        225, 135 from the ring's first camera: views of the whole shadow from the side

Writes into OUT: start_<task>.json and truth_<task>.json (absolute paths), cam_<task>_<key>.json
(the truth with that camera, for `penumbra reference`), views_<task>_<placement>_<n>.json (the
targets t_<task>_<key>.exr, made by run_views_shape.sh) and task_<task>_<placement>_<n>.json;
prints the camera files' keys, one "<task>_<key>" each.
Usage: python3 make_views_shape.py OUT MESH
"""
import json
import math
import os
import sys

from make_views import COUNTS, SIZE, load_scene, placements, task_path

TOP_ELEVATION = 50
TASKS_OF = {"deformation": ("truth", "bent_truth", "deformation", ("ring",)),
            "shape": ("shadow_init", "shadow_truth", "shape_from_shadow", ("ring", "top"))}


def top_cameras(shadow_cam, ring_cam):
    """The top placement: the shadow task's camera, then 7 oblique views of the same point."""
    target = shadow_cam["target"]
    r = math.sqrt(sum((e - t) ** 2 for e, t in zip(shadow_cam["eye"], target)))
    azim0 = math.atan2(ring_cam["eye"][0] - ring_cam["target"][0],
                       ring_cam["eye"][2] - ring_cam["target"][2])
    cams = [dict(shadow_cam, width=SIZE, height=SIZE)]
    e = math.radians(TOP_ELEVATION)
    for azimuth in (0, 180, 90, 270, 45, 225, 135):
        a = azim0 + math.radians(azimuth)
        direction = (math.cos(e) * math.sin(a), math.sin(e), math.cos(e) * math.cos(a))
        cams.append({"width": SIZE, "height": SIZE, "fov_y_deg": shadow_cam["fov_y_deg"],
                     "eye": [round(t + r * v, 6) for t, v in zip(target, direction)],
                     "target": target, "up": [0, 1, 0]})
    keys = ["top"] + ["a%d_e%d" % (a, TOP_ELEVATION) for a in (0, 180, 90, 270, 45, 225, 135)]
    return dict(zip(keys, cams)), keys


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    out, mesh = os.path.abspath(sys.argv[1]), sys.argv[2]
    os.makedirs(out, exist_ok=True)

    def write(name, obj):
        with open(os.path.join(out, name), "w") as f:
            json.dump(obj, f, indent=1)

    ring_cams, ring = placements(load_scene("%s_truth" % mesh)["camera"])
    keys = []
    for task, (start, truth, single, names) in TASKS_OF.items():
        truth_scene = load_scene("%s_%s" % (mesh, truth))
        write("start_%s.json" % task, load_scene("%s_%s" % (mesh, start)))
        write("truth_%s.json" % task, truth_scene)
        with open(task_path("%s_%s" % (mesh, single))) as f:
            settings = json.load(f)
        for key in ("_comment", "scene", "target", "ground_truth"):
            settings.pop(key, None)
        for name in names:
            if name == "ring":
                cams, order = ring_cams, ring["ring"]
            else:
                cams, order = top_cameras(truth_scene["camera"], ring_cams[ring["ring"][0]])
            for key in order:
                write("cam_%s_%s.json" % (task, key), dict(truth_scene, camera=cams[key]))
                if "%s_%s" % (task, key) not in keys:
                    keys.append("%s_%s" % (task, key))
            for n in COUNTS:
                views = "views_%s_%s_%d.json" % (task, name, n)
                write(views, {"views": [{"camera": cams[k], "target": "t_%s_%s.exr" % (task, k)}
                                        for k in order[:n]]})
                write("task_%s_%s_%d.json" % (task, name, n),
                      dict(settings, scene="start_%s.json" % task,
                           ground_truth="truth_%s.json" % task, views=views))
    print(" ".join(keys))


if __name__ == "__main__":
    main()
