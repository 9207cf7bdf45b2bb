#!/usr/bin/env python3
"""A chair of thin tubes for the ground's shadows of thin parts (docs/visibility.md, "Thin parts on
the ground"): a box seat panel on a frame of closed 12-sided tubes whose radius is 1 % of the
object's size (1.7 units tall), and scenes under a sun 8 degrees above the horizon with the city
map. Writes frame.obj, frame.json (the object), frame_empty.json (the ground alone, for the mask
of the cast shadows). Usage: make_frame.py OUTDIR [--find-map-lights]

The scenes list the low sun ("lights": [SUN]), so the loader finds no light in the map and the
map's own sun (47.8 degrees up) is projected onto the SH with the rest of it (the tables measured
so far). --find-map-lights writes "lights": {"max": 4, "add": [SUN]} instead: the map's sun found
as a disk light, the low sun after it, the SH the projection of what the found one leaves
(docs/file-formats.md, "Lights found in a map")."""
import importlib.util
import json
import math
import os
import sys

# The pose experiment's tubes (closed 12-sided prisms) and flat-faced boxes, by path: this file
# has the same name.
_spec = importlib.util.spec_from_file_location(
    "thin_pose_frame", os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "thin_pose",
                                    "make_frame.py"))
_frame = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_frame)
box, tube = _frame.box, _frame.tube

SIZE = 1.7
R = 0.01 * SIZE


class Mesh:
    def __init__(self):
        self.v, self.f = [], []

    def box(self, lo, hi):
        box(self.v, self.f, lo, hi)

    def tube(self, a, c):
        tube(self.v, self.f, a, c, R)

    def write(self, path):
        with open(path, "w") as f:
            f.write("# chair of thin tubes, research/experiments/thin/make_frame.py\n")
            for p in self.v:
                f.write("v %.6f %.6f %.6f\n" % tuple(p))
            for t in self.f:
                f.write("f %d %d %d\n" % tuple(i + 1 for i in t))


def chair():
    m = Mesh()
    sx, sz, sy = 0.5, 0.45, 0.5  # seat half sizes and height
    m.box([-sx, sy, -sz], [sx, sy + 0.06, sz])
    legs = [(-sx + R, -sz + R), (sx - R, -sz + R), (-sx + R, sz - R), (sx - R, sz - R)]
    for x, z in legs:  # legs meet the panel at its underside edge
        m.tube([x, 0.0, z], [x, sy, z])
    y = 0.2  # side rails between the legs
    m.tube([-sx + R, y, -sz + R], [-sx + R, y, sz - R])
    m.tube([sx - R, y, -sz + R], [sx - R, y, sz - R])
    m.tube([-sx + R, y, sz - R], [sx - R, y, sz - R])
    top = SIZE
    for x in (-sx + R, sx - R):  # the back: two uprights, a top rail, a bent middle bar
        m.tube([x, sy + 0.06, -sz + R], [x, top, -sz - 0.1])
    m.tube([-sx + R, top, -sz - 0.1], [sx - R, top, -sz - 0.1])
    prev = None
    for k in range(9):  # a bend of eight straight pieces
        t = k / 8.0
        p = [-sx + R + t * (2 * sx - 2 * R), 1.1 + 0.15 * math.sin(math.pi * t),
             -sz - 0.05]
        if prev:
            m.tube(prev, p)
        prev = p
    return m


def scene(obj, with_object, ground_grid=None, find_map_lights=False):
    el, az = math.radians(8.0), math.radians(-60.0)
    sun = [math.cos(el) * math.sin(az), math.sin(el), math.cos(el) * math.cos(az)]
    lights = [{"direction": sun, "angular_radius_deg": 0.27, "irradiance": [3.0, 2.9, 2.7]}]
    sc = {"camera": {"width": 384, "height": 384, "fov_y_deg": 40, "eye": [3.2, 3.6, 4.2],
                     "target": [1.1, 0.2, -0.4], "up": [0, 1, 0]},
          "lighting": {"envmap": os.path.abspath(os.path.join(os.path.dirname(__file__),
                                                              "../../../data/envmaps/city.hdr")),
                       "scale": 0.25,
                       "lights": {"max": 4, "add": lights} if find_map_lights else lights},
          "sh_bands": 4, "shadow": {"exp": "calibrated"},
          "objects": [], "ground": {"height": 0, "albedo": [0.8, 0.8, 0.8], "half_size": 4},
          "background": [0, 0, 0]}
    if ground_grid:
        sc["shadow"]["ground_grid"] = ground_grid
    if with_object:
        sc["objects"].append({"mesh": obj, "albedo": [0.6, 0.6, 0.6], "spheres": {"fit": 64}})
    return sc


def main():
    args = sys.argv[1:]
    found = "--find-map-lights" in args
    args = [a for a in args if a != "--find-map-lights"]
    if any(a.startswith("-") for a in args) or len(args) > 1:
        sys.exit(__doc__)
    out = args[0] if args else "."
    os.makedirs(out, exist_ok=True)
    obj = os.path.abspath(os.path.join(out, "frame.obj"))
    chair().write(obj)
    with open(os.path.join(out, "frame_empty.json"), "w") as f:
        json.dump(scene(obj, False, None, found), f, indent=1)
    for g in (None, 192, 384, 768):
        name = "frame.json" if g is None else "frame_g%d.json" % g
        with open(os.path.join(out, name), "w") as f:
            json.dump(scene(obj, True, g, found), f, indent=1)


if __name__ == "__main__":
    main()
