"""Small scenes built in Python for the binding's tests (no files needed)."""

import math

import torch

import penumbra

# 4-band lighting: a bright overhead lobe with a side component and some colour.
_BASE = [1.6, -1.1, 0.25, -0.35, 0.1, -0.3, 0.45, 0.2, -0.1, 0.05, -0.1, 0.15, -0.1, 0.05, 0.08,
         -0.05]


def lighting():
    sh = torch.tensor(_BASE, dtype=torch.float32)[:, None].repeat(1, 3)
    sh[0] *= torch.tensor([1.0, 0.9, 0.8])
    return sh


def octasphere(level=1, radius=0.45):
    """A subdivided octahedron on a sphere: (vertices (V, 3), faces (F, 3) int64), counter-
    clockwise seen from outside, and per-vertex uvs (V, 2) from the x and z coordinates."""
    P = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]
    F = [(0, 2, 4), (4, 2, 1), (1, 2, 5), (5, 2, 0), (0, 4, 3), (4, 1, 3), (1, 5, 3), (5, 0, 3)]
    verts, index = [], {}

    def vid(p):
        n = math.sqrt(sum(c * c for c in p))
        key = tuple(round(c / n, 6) for c in p)
        if key not in index:
            index[key] = len(verts)
            verts.append(key)
        return index[key]

    def split(a, b, c, lv, out):
        if lv == 0:
            out.append((vid(a), vid(b), vid(c)))
            return
        ab, bc, ca = ([(x + y) / 2 for x, y in zip(u, v)] for u, v in ((a, b), (b, c), (c, a)))
        for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca)):
            split(*t, lv - 1, out)

    faces = []
    for f in F:
        split(P[f[0]], P[f[1]], P[f[2]], level, faces)
    v = torch.tensor(verts, dtype=torch.float32) * radius
    uvs = torch.stack([v[:, 0] / (2 * radius) + 0.5, v[:, 2] / (2 * radius) + 0.5], dim=1)
    return v, torch.tensor(faces, dtype=torch.int64), uvs


def ball_scene(size=16, textured=False, level=1):
    """An ellipsoid (an octasphere stretched 1.25 in x, 0.8 in y) hovering over the ground
    (translation y = 0.55, a small rotation), two proxy spheres inside it with their overlap
    weights held fixed (as load_scene gives them; gradcheck moves the spheres), 4-band lighting,
    in the sphere model (gradient_model)."""
    v, f, uvs = octasphere(level)
    v = v * torch.tensor([1.25, 0.8, 1.0])
    spheres = torch.tensor([[-0.15, 0.0, 0.02, 0.32], [0.17, 0.02, -0.03, 0.3]])
    ob = penumbra.Object(
        vertices=v, faces=f, albedo=torch.tensor([0.8, 0.5, 0.3]), spheres=spheres,
        pose=penumbra.pose((10.0, 25.0, 0.0), (0.0, 0.55, 0.0), 1.0),
        sphere_weights=penumbra.overlap_weights(spheres))
    if textured:
        g = torch.Generator().manual_seed(5)
        ob.uvs = uvs
        ob.texture = 0.2 + 0.7 * torch.rand(5, 6, 3, generator=g)
    cam = penumbra.Camera(size, size, 40.0, (0.3, 1.5, 2.4), (0.0, 0.35, 0.0))
    scene = penumbra.Scene(camera=cam, sh=lighting(), objects=[ob],
                           ground_albedo=torch.tensor([0.7, 0.6, 0.5]), ground_half_size=3.0,
                           background=(0.2, 0.3, 0.4))
    # The model in which every gradient group is exact (own shadows from the spheres, point
    # texture lookups): these scenes are for gradient checks of every group.
    return penumbra.gradient_model(scene, list(penumbra.GRAD_GROUPS))
