#!/usr/bin/env python3
"""A thin-limbed figure under a low sun, for self-shadowing on thin parts (docs/results/accuracy.md,
"A thin-limbed figure under a low sun"): a four-legged animal 1.7 units long, body and head
ellipsoids, neck, legs, tail, ears, claws and whiskers as closed tapered tubes and cones (separate
closed shells). Limb radii relative to the longest side (as built, then scaled by 1.04 to 1.7
units): legs 2.1 % tapering to 1.25 %, tail 1.6 % to 0.6 %, claws 0.6 % at the root, ears 3.1 % at
the root, whiskers 0.36 %. 5 096 triangles in 29 shells, every one closed and facing outwards.

Writes OUTDIR/figure.obj and per image size OUTDIR/figure_<size>.json (the object on a grey
ground, a 3/4 view, the city map at 0.25 and a sun 8 degrees above the horizon as a disk light)
and OUTDIR/figure_noground_<size>.json (the same without the ground: the object's coverage mask).

    /usr/bin/python3 research/experiments/thin_figure/make_figure.py OUTDIR [--sizes 256,384]
"""
import json
import math
import os
import sys

import numpy as np

LENGTH = 1.7  # the figure's longest side (nose to tail tip, along x)
SUN_ELEVATION_DEG = 8.0
SUN_AZIMUTH_DEG = 35.0  # from +z towards +x: the sun lights the side the camera sees, low


class Mesh:
    def __init__(self):
        self.v, self.f = [], []

    def add(self, verts, faces):
        base = len(self.v)
        self.v.extend(map(tuple, verts))
        self.f.extend(tuple(base + i for i in t) for t in faces)

    def ellipsoid(self, c, radii, rings=20, segs=40):
        """A closed UV ellipsoid centred at c with semi-axes radii (x, y, z)."""
        v = [(c[0], c[1] + radii[1], c[2])]
        for i in range(1, rings):
            th = math.pi * i / rings
            for j in range(segs):
                ph = 2 * math.pi * j / segs
                v.append((c[0] + radii[0] * math.sin(th) * math.cos(ph),
                          c[1] + radii[1] * math.cos(th),
                          c[2] + radii[2] * math.sin(th) * math.sin(ph)))
        v.append((c[0], c[1] - radii[1], c[2]))
        f, last = [], len(v) - 1
        for j in range(segs):  # caps, then quads; counter-clockwise seen from outside
            f.append((0, 1 + (j + 1) % segs, 1 + j))
            f.append((last, last - segs + j, last - segs + (j + 1) % segs))
        for i in range(rings - 2):
            for j in range(segs):
                a, b = 1 + i * segs + j, 1 + i * segs + (j + 1) % segs
                f += [(a, b, a + segs), (b, b + segs, a + segs)]
        self.add(v, f)

    def tube(self, pts, radii, segs=12, tip=False):
        """A closed tapered tube along the polyline pts with a radius per point: a flat cap at the
        start, a flat cap (or a point, tip=True: a cone's end) at the end. Frames are carried
        along the polyline (parallel transport), so bends do not twist."""
        pts = np.asarray(pts, float)
        n = len(pts)
        tang = np.gradient(pts, axis=0)
        tang /= np.linalg.norm(tang, axis=1)[:, None]
        ref = np.array([0.0, 1.0, 0.0]) if abs(tang[0][1]) < 0.9 else np.array([1.0, 0.0, 0.0])
        u = np.cross(tang[0], ref)
        u /= np.linalg.norm(u)
        v, f = [], []
        for k in range(n):
            if k:
                u = u - tang[k] * np.dot(u, tang[k])
                u /= np.linalg.norm(u)
            w = np.cross(tang[k], u)
            if tip and k == n - 1:
                v.append(tuple(pts[k]))
                break
            for j in range(segs):
                a = 2 * math.pi * j / segs
                v.append(tuple(pts[k] + radii[k] * (math.cos(a) * u + math.sin(a) * w)))
        rings = n - 1 if tip else n
        for k in range(rings - 1):
            for j in range(segs):
                a, b = k * segs + j, k * segs + (j + 1) % segs
                f += [(a, a + segs, b), (b, a + segs, b + segs)]
        c0 = len(v)
        v.append(tuple(pts[0]))
        for j in range(segs):
            f.append((c0, j, (j + 1) % segs))
        last = (rings - 1) * segs
        if tip:
            apex = rings * segs
            for j in range(segs):
                f.append((last + j, apex, last + (j + 1) % segs))
        else:
            c1 = len(v)
            v.append(tuple(pts[-1]))
            for j in range(segs):
                f.append((c1, last + (j + 1) % segs, last + j))
        # Wound above with the frame (u, t x u), which makes every face point inwards: reversed,
        # the tube faces outwards as the ellipsoids do (an inside-out shell renders with the
        # sphere model: the renderer shades a triangle seen from its back with the spheres).
        self.add(v, [(a, c, b) for a, b, c in f])

    def write(self, path):
        with open(path, "w") as fh:
            fh.write("# thin-limbed figure, research/experiments/thin_figure/make_figure.py\n")
            for p in self.v:
                fh.write("v %.6f %.6f %.6f\n" % p)
            for t in self.f:
                fh.write("f %d %d %d\n" % tuple(i + 1 for i in t))


def curve(a, b, bend, n):
    """n points from a to b bowed by the vector bend at the middle."""
    a, b, bend = map(np.asarray, (a, b, bend))
    t = np.linspace(0.0, 1.0, n)[:, None]
    return a + t * (b - a) + 4 * t * (1 - t) * bend


def figure():
    L = LENGTH
    m = Mesh()
    leg_top, body_c = 0.62, np.array([0.0, 0.72, 0.0])
    m.ellipsoid(body_c, (0.42, 0.17, 0.15))                     # body
    head = np.array([0.62, 0.98, 0.0])
    m.ellipsoid(head, (0.12, 0.085, 0.08), rings=16, segs=32)   # head
    m.ellipsoid(head + [0.11, -0.03, 0.0], (0.06, 0.04, 0.04), rings=10, segs=20)  # muzzle
    m.tube(curve(body_c + [0.32, 0.05, 0], head - [0.06, 0.02, 0], [0.02, 0.03, 0], 6),
           np.linspace(0.07, 0.05, 6), segs=16)                 # neck
    r_top, r_foot = 0.020 * L, 0.012 * L
    for x, z, knee in ((0.30, 0.08, 0.04), (0.30, -0.08, -0.03), (-0.30, 0.08, -0.05),
                       (-0.32, -0.09, -0.04)):
        foot = np.array([x + 0.06 * np.sign(x), r_foot, z * 1.3])
        pts = curve([x, leg_top, z], foot, [knee, 0.0, 0.0], 8)
        m.tube(pts, np.linspace(r_top, r_foot, 8))              # leg
        for dz in (-0.018, 0.0, 0.018):                         # claws: cones forward and down
            a = foot + [0.01, 0.0, dz]
            m.tube(curve(a, a + [0.05, -r_foot + 0.002, dz * 0.6], [0, 0.006, 0], 4),
                   [0.006 * L, 0.005 * L, 0.003 * L, 0.0], segs=8, tip=True)
    tail = curve(body_c + [-0.38, 0.06, 0.0], body_c + [-0.82, 0.40, 0.10], [-0.05, -0.12, 0.04],
                 12)
    m.tube(tail, np.linspace(0.015 * L, 0.006 * L, 12))        # tail
    for s in (1, -1):
        base = head + [-0.03, 0.07, 0.045 * s]
        m.tube(curve(base, base + [-0.02, 0.16, 0.05 * s], [0.0, 0.0, 0.01 * s], 4),
               [0.03 * L, 0.02 * L, 0.01 * L, 0.0], segs=12, tip=True)  # ear
        for k in range(3):                                      # whiskers
            a = head + [0.15, -0.035 + 0.012 * k, 0.035 * s]
            m.tube(curve(a, a + [0.02, -0.02 + 0.02 * k, 0.16 * s], [0.02, 0, 0], 5),
                   [0.0035 * L] * 4 + [0.0], segs=6, tip=True)
    # Stand it on y = 0 and centre it on the y axis.
    v = np.array(m.v)
    lo, hi = v.min(axis=0), v.max(axis=0)
    v -= [(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2]
    s = L / (hi - lo).max()
    m.v = [tuple(p) for p in v * s]
    return m


def scene(obj, size, ground=True):
    el, az = math.radians(SUN_ELEVATION_DEG), math.radians(SUN_AZIMUTH_DEG)
    sun = [math.cos(el) * math.sin(az), math.sin(el), math.cos(el) * math.cos(az)]
    env = os.path.abspath(os.path.join(os.path.dirname(__file__), "../../../data/envmaps/city.hdr"))
    sc = {"camera": {"width": size, "height": size, "fov_y_deg": 32, "eye": [1.6, 1.5, 3.0],
                     "target": [0.0, 0.55, 0.0], "up": [0, 1, 0]},
          "lighting": {"envmap": env, "scale": 0.25,
                       "lights": [{"direction": sun, "angular_radius_deg": 0.27,
                                   "irradiance": [3.0, 2.9, 2.7]}]},
          "sh_bands": 4, "objects": [{"mesh": obj, "albedo": [0.6, 0.6, 0.6],
                                      "spheres": {"fit": 32}}],
          "background": [0, 0, 0]}
    if ground:
        sc["ground"] = {"height": 0, "albedo": [0.8, 0.8, 0.8], "half_size": 4}
    return sc


def main():
    args = sys.argv[1:]
    out = args[0] if args else "."
    sizes = [256, 384]
    if "--sizes" in args:
        sizes = [int(x) for x in args[args.index("--sizes") + 1].split(",")]
    os.makedirs(out, exist_ok=True)
    obj = os.path.abspath(os.path.join(out, "figure.obj"))
    m = figure()
    m.write(obj)
    print("figure.obj: %d vertices, %d triangles" % (len(m.v), len(m.f)))
    for size in sizes:
        for ground, name in ((True, "figure_%d.json"), (False, "figure_noground_%d.json")):
            with open(os.path.join(out, name % size), "w") as f:
                json.dump(scene(obj, size, ground), f, indent=1)


if __name__ == "__main__":
    main()
