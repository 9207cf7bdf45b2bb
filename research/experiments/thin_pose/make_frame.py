"""Writes frame.obj: an object made only of thin tubes (a stool's frame: four legs, a square
of top rails and a ring of lower braces), every tube a closed 12-sided prism with caps, radius
1 % of the object's size (its longest side, 1 unit). The parts overlap where they meet, as welded
tubes do; each is closed, so the fitter and the reference see a solid. With --seat a flat box
(1.1 x 0.05 x 1.1) lies on the top rails, its lower face on their axes: a chair whose seat meets
its frame at an edge.

    python3 make_frame.py OUT.obj [--seat]
"""
import math
import sys

SIDES = 12
RADIUS = 0.01


def tube(verts, faces, a, b, r=RADIUS):
    """A closed prism of SIDES sides around the segment a-b."""
    d = [b[k] - a[k] for k in range(3)]
    n = math.sqrt(sum(x * x for x in d))
    d = [x / n for x in d]
    # two unit vectors across the axis
    h = [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0]
    u = [d[1] * h[2] - d[2] * h[1], d[2] * h[0] - d[0] * h[2], d[0] * h[1] - d[1] * h[0]]
    un = math.sqrt(sum(x * x for x in u))
    u = [x / un for x in u]
    v = [d[1] * u[2] - d[2] * u[1], d[2] * u[0] - d[0] * u[2], d[0] * u[1] - d[1] * u[0]]
    base = len(verts)
    for end in (a, b):
        for i in range(SIDES):
            t = 2 * math.pi * i / SIDES
            c, s = math.cos(t) * r, math.sin(t) * r
            verts.append([end[k] + c * u[k] + s * v[k] for k in range(3)])
    verts.append(list(a))
    verts.append(list(b))
    ca, cb = base + 2 * SIDES, base + 2 * SIDES + 1
    for i in range(SIDES):
        j = (i + 1) % SIDES
        p0, p1, q0, q1 = base + i, base + j, base + SIDES + i, base + SIDES + j
        faces.append((p0, q1, q0))  # counter-clockwise seen from outside
        faces.append((p0, p1, q1))
        faces.append((ca, p1, p0))
        faces.append((cb, q0, q1))


def box(verts, faces, lo, hi):
    """A closed axis-aligned box, faces counter-clockwise seen from outside. Each face has its own
    four corners, so that a loader averaging normals over shared vertices keeps them flat (shared
    corners would lean every face's normals 55 degrees at its corners, and the seat would shade
    itself)."""
    corner = [[hi[k] if (i >> k) & 1 else lo[k] for k in range(3)] for i in range(8)]
    for q in ((0, 4, 6, 2), (1, 3, 7, 5), (0, 1, 5, 4), (2, 6, 7, 3), (0, 2, 3, 1), (4, 5, 7, 6)):
        base = len(verts)
        verts.extend(corner[i] for i in q)
        faces.append((base, base + 1, base + 2))
        faces.append((base, base + 2, base + 3))


def main():
    args = [a for a in sys.argv[1:] if a != "--seat"]
    out = args[0] if args else "frame.obj"
    verts, faces = [], []
    w, top, low = 0.5, 1.0, 0.35  # half width of the top square, heights of the rails
    corners = [(-w, -w), (w, -w), (w, w), (-w, w)]
    for x, z in corners:  # the legs splay a little, as a stool's do
        tube(verts, faces, (1.1 * x, 0.0, 1.1 * z), (x, top, z))
    for i in range(4):
        (x0, z0), (x1, z1) = corners[i], corners[(i + 1) % 4]
        tube(verts, faces, (x0, top, z0), (x1, top, z1))
        s = 1.1 - 0.1 * low / top  # the legs' position at the braces' height
        tube(verts, faces, (s * x0, low, s * z0), (s * x1, low, s * z1))
    tube(verts, faces, (-w, top, -w), (w, top, w))  # one diagonal, so that turns are not symmetric
    if "--seat" in sys.argv[1:]:
        box(verts, faces, (-0.55, top, -0.55), (0.55, top + 0.05, 0.55))
    with open(out, "w") as f:
        f.write("# thin-tube frame, research/experiments/thin_pose/make_frame.py\n")
        for p in verts:
            f.write("v %.6f %.6f %.6f\n" % tuple(p))
        for t in faces:
            f.write("f %d %d %d\n" % (t[0] + 1, t[1] + 1, t[2] + 1))


if __name__ == "__main__":  # thin/make_frame.py imports the tubes
    main()
