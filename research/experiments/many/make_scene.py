#!/usr/bin/env python3
"""Many small objects: an n x n grid of octahedra (8 triangles, 6 vertices, one sphere each) over
a ground of half size 4, city.hdr with its found sun, the default self and ground transfer. The
scene of bench/NOTES.md "Many small objects" (n = 64: 4096 objects, the scene format's maximum).

    python3 research/experiments/many/make_scene.py [--n 64] [--size 512] [--self transfer]
        [--out out/many]
    /usr/bin/time penumbra render out/many/many_64.json -o out/many/many_64.png

Writes the octahedron's OBJ and the scene JSON into --out (default out/many, ignored by git);
prints the scene's path. Costs nothing; the render is what it measures (seconds to a minute).
"""
import argparse
import json
import os

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.normpath(os.path.join(HERE, "..", "..", ".."))


def octahedron_obj(path, r):
    v = [(r, 0, 0), (-r, 0, 0), (0, r, 0), (0, -r, 0), (0, 0, r), (0, 0, -r)]
    # Counter-clockwise seen from outside: (x, y, z) octants.
    f = [(1, 3, 5), (3, 2, 5), (2, 4, 5), (4, 1, 5), (3, 1, 6), (2, 3, 6), (4, 2, 6), (1, 4, 6)]
    with open(path, "w") as fh:
        for p in v:
            fh.write("v %g %g %g\n" % p)
        for t in f:
            fh.write("f %d %d %d\n" % t)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=64, help="objects per side (n^2 objects, at most 64)")
    ap.add_argument("--size", type=int, default=512, help="image width and height")
    ap.add_argument("--self", dest="self_", default="transfer", help="shadow.self")
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "many"))
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    half = 4.0
    pitch = 2 * half / a.n
    r = 0.35 * pitch  # the octahedron's half diagonal: gaps of 0.3 pitch between neighbours
    obj = os.path.join(a.out, "octahedron.obj")
    octahedron_obj(obj, r)
    objects = []
    for j in range(a.n):
        for i in range(a.n):
            x = -half + (i + 0.5) * pitch
            z = -half + (j + 0.5) * pitch
            objects.append({
                "mesh": "octahedron.obj",
                "albedo": [0.7, 0.6, 0.5],
                "spheres": [{"center": [0, 0, 0], "radius": 0.8 * r}],
                "pose": {"translation": [x, r, z]},
            })
    scene = {
        "camera": {"width": a.size, "height": a.size, "fov_y_deg": 40,
                   "eye": [0.0, 6.0, 7.5], "target": [0, 0, 0], "up": [0, 1, 0]},
        "lighting": {"envmap": os.path.join(ROOT, "..", "shared", "data", "envmaps", "city.hdr"),
                     "scale": 0.25},
        "sh_bands": 4,
        "shadow": {"exp": "calibrated", "self": a.self_},
        "objects": objects,
        "ground": {"height": 0, "albedo": [0.8, 0.8, 0.8], "half_size": half},
        "background": "envmap",
    }
    path = os.path.join(a.out, "many_%d_%d_%s.json" % (a.n, a.size, a.self_))
    with open(path, "w") as fh:
        json.dump(scene, fh)
    print(path)


if __name__ == "__main__":
    main()
