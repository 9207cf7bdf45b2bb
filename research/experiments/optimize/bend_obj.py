#!/usr/bin/env python3
"""Bends a Wavefront OBJ about an axis: the targets of the deformation experiments.

The mesh is bent in the plane of two coordinate axes, ALONG (the axis that curves) and TOWARD
(the direction its ends move), like a beam bent into a circular arc of radius R = 1/curvature.
With u = p.along - center and w = p.toward, a point (u, w) goes to

    u' = (R - w) sin(theta),   w' = R - (R - w) cos(theta),   theta = u / R,

so the line w = 0 keeps its length (it becomes the arc), the point u = 0 does not move, and
the ends of the object swing towards +TOWARD (away from it for a negative curvature). The
third coordinate is kept. Normals (vn) follow the local rotation by theta (with the inverse
transpose of the stretch along u); everything else in the file (vt, f, o, usemtl, comments) is
copied unchanged, so the vertex order, count and texture coordinates stay those of the input:
the bent mesh can serve as the ground truth of a deformation task whose scene is the input.
Standard library only. Example (docs/optimize.md, Spot's body bent sideways):

    python3 bend_obj.py spot_triangulated.obj spot_bent.obj --along z --toward x --curvature 0.4
"""
import argparse
import math
import os
import sys

AXES = {"x": 0, "y": 1, "z": 2}


def bend(p, a, b, center, R):
    u, w = p[a] - center, p[b]
    theta = u / R
    q = list(p)
    q[a] = center + (R - w) * math.sin(theta)
    q[b] = R - (R - w) * math.cos(theta)
    return q


def bend_normal(n, p, a, b, center, R):
    """The normal at p after the bend: J^-T n, J = Rot(theta) diag(s, 1), s = (R - w) / R."""
    u, w = p[a] - center, p[b]
    theta, s = u / R, (R - w) / R
    na, nb = n[a] / s if s != 0 else n[a], n[b]
    c, si = math.cos(theta), math.sin(theta)
    q = list(n)
    q[a] = c * na - si * nb
    q[b] = si * na + c * nb
    length = math.sqrt(sum(v * v for v in q)) or 1.0
    return [v / length for v in q]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("input")
    ap.add_argument("output")
    ap.add_argument("--along", choices="xyz", required=True, help="the axis that curves")
    ap.add_argument("--toward", choices="xyz", required=True, help="where the ends move")
    ap.add_argument("--curvature", type=float, required=True, help="1 / radius (scene units)")
    ap.add_argument("--center", type=float, default=None,
                    help="the point of ALONG that stays (default: the middle of the extent)")
    args = ap.parse_args()
    a, b = AXES[args.along], AXES[args.toward]
    if a == b:
        ap.error("--along and --toward must differ")
    if args.curvature == 0.0:
        ap.error("--curvature must not be 0")
    with open(args.input) as f:
        lines = f.readlines()
    vertices, vertex_lines = [], []
    for k, line in enumerate(lines):
        if line.startswith("v "):
            fields = line.split()
            try:
                vertices.append([float(v) for v in fields[1:4]])
            except (ValueError, IndexError):
                sys.exit("%s:%d: bad vertex" % (args.input, k + 1))
            vertex_lines.append(k)
    if not vertices:
        sys.exit("%s: no vertices" % args.input)
    center = args.center
    if center is None:
        values = [p[a] for p in vertices]
        center = 0.5 * (min(values) + max(values))
    R = 1.0 / args.curvature
    # Normals: an OBJ's normals are not tied to vertices by index in general; the nearest bent
    # frame is that of the vertex the face corners pair them with, found from the f lines.
    normal_vertex = {}
    for line in lines:
        if line.startswith("f "):
            for corner in line.split()[1:]:
                parts = corner.split("/")
                if len(parts) == 3 and parts[2]:
                    vi, ni = int(parts[0]), int(parts[2])
                    normal_vertex.setdefault(ni, vi)
    out, normal_index = [], 0
    nv = len(vertices)
    vertex_index = 0
    for line in lines:
        if line.startswith("v "):
            q = bend(vertices[vertex_index], a, b, center, R)
            rest = line.split()[4:]  # optional vertex colours
            out.append("v %.6f %.6f %.6f%s\n" % (q[0], q[1], q[2],
                                                   "".join(" " + r for r in rest)))
            vertex_index += 1
        elif line.startswith("vn "):
            normal_index += 1
            vi = normal_vertex.get(normal_index)
            if vi is None:
                out.append(line)
                continue
            vi = vi - 1 if vi > 0 else nv + vi
            n = [float(v) for v in line.split()[1:4]]
            q = bend_normal(n, vertices[vi], a, b, center, R)
            out.append("vn %.6f %.6f %.6f\n" % (q[0], q[1], q[2]))
        else:
            out.append(line)
    tmp = args.output + ".tmp"
    with open(tmp, "w") as f:
        f.writelines(out)
    os.replace(tmp, args.output)


if __name__ == "__main__":
    main()
