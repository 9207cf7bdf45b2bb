"""Capsules against spheres for the sun's cast shadow (docs/results/optimize.md, "Capsules against
spheres for the sun's cast shadow"). Cost: about 3 minutes on the shared 2-core machine (two
1024-spp references 1.7 min, the sphere fits and renders at 256 and 1024 pixels 0.5 min, the
capsule models in numpy 15 s); python3 + numpy only. Prints a markdown table.

The chair of research/experiments/thin_pose/make_frame.py --seat (tubes of radius 0.01, a
1.1 x 0.05 x 1.1 seat) under the sun of chair_shadow.py (10 degrees up, 0.27 degrees) and NO sky
(SH lighting all zero), so the only shadow is the sun's, 256x256. The truth is `penumbra reference
--lighting sh` of the mesh at SPP spp, twice with seeds 1 and 2, their mean: its noise (half the
RMS difference of the two) is removed from every error in quadrature. Pixels: the ground pixels
with no part of the chair in them or in their 8 neighbours (16-spp coverage) and off the ground's
far edge; the cast shadow: those the chair darkens by more than 10 % in the truth. Models:

- spheres N: `penumbra render` with "self": "spheres", "ground_shadow": "spheres" (N fitted);
- default: `penumbra render` (the meshes' transfer, the ground grid's 64 disk directions);
- capsules, exact: the 13 tubes as capsules (segment, radius = the 12-sided prism's mean
  half-width) and the seat as its box, the sun's disk sampled (256 stratified directions a
  pixel), ray-capsule and ray-box tests analytic, the union of the blockers;
- capsules, closed form: per capsule the fraction of the disk (planar, small-angle) inside its
  angular stadium, taken as a rectangle: across, the strip between the tube's two tangent planes
  through the receiver (half-width asin(r / rho), rho the depth of the axis along the sun's ray);
  along, the segment's gnomonic end points extended by pi h_end / 4 (the half-disk end caps by
  rectangles of the same area); the disk-rectangle area from the disk-quadrant area in closed
  form. The seat: the product over the box's silhouette edges (its outline seen along the sun)
  of the disk's fraction inside each edge's plane through the receiver (exact for one edge,
  approximate at corners). Combined as the renderer combines spheres for a disk light,
  V = prod_i (1 - f_i), the blockers opaque (q = 1).

Every model is measured shaded at the pixel centre (as the renderer shades) and at SUB x SUB
points a pixel (the reference's box filter): the renderer at SUB x the size averaged down, the
capsules at SUB^2 points (exact: 256 / SUB^2 directions each). The ground of a sun-only scene is
rho/pi E D(n.w, b) V: every capsule image is the renderer's own `--no-shadows` image times V, so
the scale is the renderer's.

    python3 research/experiments/thin_capsule/capsule_shadow.py PENUMBRA [--spp 1024]
        [--counts 32,128,512] [--sub 4] [--out out/thin_capsule]
"""
import json
import math
import os
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "accuracy"))
sys.path.insert(0, os.path.join(HERE, "..", "thin_pose"))
from visibility_table import parse_options, read_exr, run, write_png  # noqa: E402
import make_frame  # noqa: E402

SUN = {"direction": [0.788, 0.174, -0.591], "angular_radius_deg": 0.27,
       "irradiance": [1.6, 1.5, 1.3]}  # chair_shadow.py's: 10 degrees up
CAMERA = {"width": 256, "height": 256, "fov_y_deg": 40, "eye": [1.2, 2.6, 4.2],
          "target": [-0.9, 0.3, 0.9], "up": [0, 1, 0]}
# The 12-sided prism's mean width is its perimeter / pi: a capsule of that radius casts the same
# mean shadow width.
R_CAPSULE = make_frame.RADIUS * make_frame.SIDES * math.sin(math.pi / make_frame.SIDES) / math.pi


def scene(mesh, shadow, fit, objects=True, ground=True, scale=1):
    s = {"camera": dict(CAMERA, width=256 * scale, height=256 * scale),
            "lighting": {"sh": [[0, 0, 0]] * 16, "lights": [SUN]},
            "sh_bands": 4, "shadow": dict({"exp": "calibrated"}, **shadow),
            "objects": [{"mesh": mesh, "albedo": [0.5, 0.5, 0.5], "spheres": {"fit": fit}}]
            if objects else [],
            "background": [0, 0, 0]}
    if ground:
        s["ground"] = {"height": 0, "albedo": [0.8, 0.8, 0.8], "half_size": 6}
    return s


def write(path, obj):
    with open(path, "w") as f:
        json.dump(obj, f)
    return path


def image(path):
    w, h, names, planes = read_exr(path)
    if len(planes) == 1:
        planes = planes * 3
        names = ["R", "G", "B"]
    a = np.array([planes[names.index(c)] for c in "RGB"], dtype=np.float64)
    return a.reshape(3, h, w)


def geometry(mesh):
    """The segments and the box make_frame.py writes (its tube() and box() calls recorded)."""
    segs, boxes = [], []
    tube, box, argv = make_frame.tube, make_frame.box, sys.argv
    make_frame.tube = lambda v, f, a, b, r=make_frame.RADIUS: (segs.append((a, b)),
                                                               tube(v, f, a, b, r))
    make_frame.box = lambda v, f, lo, hi: (boxes.append((lo, hi)), box(v, f, lo, hi))
    sys.argv = ["make_frame.py", mesh, "--seat"]
    try:
        make_frame.main()
    finally:
        make_frame.tube, make_frame.box, sys.argv = tube, box, argv
    return np.array(segs, dtype=np.float64), np.array(boxes[0], dtype=np.float64)


def ground_points(sub):
    """World points of the ground (y = 0) seen through pixel (x + jx, y + jy), the camera of
    src/scene/camera.c; sub x sub stratified points per pixel (sub = 1: the centre). Returns
    (H, W, sub*sub, 3) and the mask of rays that reach the plane."""
    eye, tgt, up = (np.array(CAMERA[k], dtype=np.float64) for k in ("eye", "target", "up"))
    f = tgt - eye
    f /= np.linalg.norm(f)
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    W, H = CAMERA["width"], CAMERA["height"]
    foc = H / (2 * math.tan(math.radians(CAMERA["fov_y_deg"]) / 2))
    off = (np.arange(sub) + 0.5) / sub
    jx, jy = np.meshgrid(off, off)
    px = np.arange(W)[None, :, None] + jx.ravel()[None, None, :]
    py = np.arange(H)[:, None, None] + jy.ravel()[None, None, :]
    px, py = np.broadcast_arrays(px, py)
    d = ((px - W / 2) / foc)[..., None] * r + ((H / 2 - py) / foc)[..., None] * u + f
    t = -eye[1] / d[..., 1]
    ok = t > 0
    return eye + np.where(ok, t, 0)[..., None] * d, ok


def sun_frame():
    w = np.array(SUN["direction"], dtype=np.float64)
    w /= np.linalg.norm(w)
    e1 = np.cross(w, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return w, e1, np.cross(w, e1), math.radians(SUN["angular_radius_deg"])


def disk_dirs(n_side, rng, count):
    """count sets of n_side^2 directions stratified over the sun's disk (uniform in the planar,
    small-angle disk: concentric map of jittered strata)."""
    w, e1, e2, b = sun_frame()
    i, j = np.meshgrid(np.arange(n_side), np.arange(n_side))
    a = (i.ravel()[None] + rng.random((count, n_side * n_side))) / n_side * 2 - 1
    c = (j.ravel()[None] + rng.random((count, n_side * n_side))) / n_side * 2 - 1
    big = np.abs(a) > np.abs(c)
    rad = np.where(big, a, c)
    phi = np.where(big, (math.pi / 4) * c / np.where(a == 0, 1, a),
                   math.pi / 2 - (math.pi / 4) * a / np.where(c == 0, 1, c))
    t = math.tan(b)
    d = w + t * (rad * np.cos(phi))[..., None] * e1 + t * (rad * np.sin(phi))[..., None] * e2
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def hits_capsule(x, d, a, b, r):
    """Whether rays x + s d (x (P, 3), d (P, S, 3) unit, s >= 0) pass within r of segment a-b
    (Ericson's closest points of two segments, the ray's parameter clamped to [0, inf))."""
    e = b - a
    ee = e @ e
    rr = x - a
    f = (rr @ e)[:, None]
    c = np.einsum("psk,pk->ps", d, rr)
    bb = d @ e
    den = ee - bb * bb
    ok = den > 1e-12 * ee
    s = np.maximum(np.where(ok, (bb * f - c * ee) / np.where(ok, den, 1), 0), 0)
    t = (bb * s + f) / ee
    lo, hi = t < 0, t > 1
    t = np.clip(t, 0, 1)
    s = np.where(lo, np.maximum(-c, 0), np.where(hi, np.maximum(bb - c, 0), s))
    p = rr[:, None, :] + s[..., None] * d - t[..., None] * e
    return np.einsum("psk,psk->ps", p, p) <= r * r


def hits_box(x, d, lo, hi):
    inv = 1.0 / np.where(np.abs(d) < 1e-15, 1e-15, d)
    t0 = (lo - x[..., None, :]) * inv
    t1 = (hi - x[..., None, :]) * inv
    tn = np.minimum(t0, t1).max(-1)
    tf = np.maximum(t0, t1).min(-1)
    return (tn <= tf) & (tf > 0)


def exact_visibility(pts, segs, box, dirs):
    """Unblocked fraction of the disk at points pts (..., 3) with per-point directions dirs
    (..., S, 3): the union of the capsules and the box."""
    blocked = hits_box(pts, dirs, box[0], box[1])
    w, _, _, b = sun_frame()
    for a, bb in segs:
        # cull: a ray within b of w passes within r of the segment only if the central ray passes
        # within r + (|x - a| + |ab|) tan b of it
        near = hits_capsule(pts, np.broadcast_to(w, (len(pts), 1, 3)), a, bb,
                            R_CAPSULE + (np.linalg.norm(pts - a, axis=-1).max() +
                                         np.linalg.norm(bb - a)) * math.tan(b) * 1.01)[..., 0]
        if near.any():
            blocked[near] |= hits_capsule(pts[near], dirs[near], a, bb, R_CAPSULE)
    return 1.0 - blocked.mean(-1)


def half_disk(c):
    """Fraction of the unit disk with coordinate <= c."""
    c = np.clip(c, -1, 1)
    return (c * np.sqrt(1 - c * c) + np.arcsin(c)) / math.pi + 0.5


def _prim(u):
    """Integral of sqrt(1 - u^2)."""
    return 0.5 * (u * np.sqrt(np.maximum(1 - u * u, 0)) + np.arcsin(u))


def quadrant(a, c):
    """Area of the unit disk in {u <= a, v <= c}, closed form."""
    a = np.clip(a, -1, 1)
    c = np.clip(c, -1, 1)
    m = np.sqrt(1 - c * c)
    inner = lambda lo, hi: _prim(hi) - _prim(lo) + c * (hi - lo)  # noqa: E731
    am = np.clip(a, -m, m)
    pos = (2 * (_prim(np.minimum(a, -m)) - _prim(-1.0)) + inner(-m, am) +
           2 * (_prim(np.maximum(a, m)) - _prim(m)))
    return np.where(c >= 0, pos, inner(-m, am))


def disk_in_rect(u0, u1, v0, v1):
    """Fraction of the unit disk in [u0, u1] x [v0, v1]."""
    return (quadrant(u1, v1) - quadrant(u0, v1) - quadrant(u1, v0) + quadrant(u0, v0)) / math.pi


def capsule_fraction(x, a, bpt, r, w, b, zmin=1e-4):
    """Closed-form fraction of the sun's disk (direction w, angular radius b) that capsule a-b,
    radius r, covers seen from points x (..., 3): the disk against the capsule's stadium taken as
    a rectangle (planar, small-angle)."""
    e = bpt - a
    za, zb = (a - x) @ w, (bpt - x) @ w
    # clip the segment to the half-space in front of the receiver along the sun
    ta = np.where(za < zmin, (zmin - za) / np.where(zb - za == 0, 1, zb - za), 0.0)
    tb = np.where(zb < zmin, (zmin - za) / np.where(zb - za == 0, 1, zb - za), 1.0)
    live = (za >= zmin) | (zb >= zmin)
    pa = a + ta[..., None] * e
    pb = a + tb[..., None] * e
    # the sun's central ray against the axis line: depth rho and the across offset
    ew = e @ w
    ee = e @ e
    rr = x - a
    den = ee - ew * ew
    s = ((rr @ e) * ew - (rr @ w) * ee) / den  # ray parameter of the closest approach
    t = np.clip((ew * s + rr @ e) / ee, ta, tb)
    q = a + t[..., None] * e - x  # the axis point at the closest approach (clamped)
    rho = np.maximum(q @ w, zmin)
    n = np.cross(w, e)
    n /= np.linalg.norm(n)
    across = (rr @ n) * -1.0 / rho / b  # the axis line's offset from the disk's centre, in b
    h = np.arcsin(np.minimum(r / rho, 1.0)) / b
    # along: the gnomonic positions of the clipped end points on the axis' projected direction
    ep = e - ew * w
    ep /= np.linalg.norm(ep)
    ua = ((pa - x) @ ep) / ((pa - x) @ w) / b
    ub = ((pb - x) @ ep) / ((pb - x) @ w) / b
    ca = np.arcsin(np.minimum(r / np.linalg.norm(pa - x, axis=-1), 1.0)) / b * (math.pi / 4)
    cb = np.arcsin(np.minimum(r / np.linalg.norm(pb - x, axis=-1), 1.0)) / b * (math.pi / 4)
    lo = np.minimum(ua - ca, ub - cb)
    hi = np.maximum(ua + ca, ub + cb)
    f = disk_in_rect(lo, hi, across - h, across + h)
    return np.where(live, f, 0.0)


def box_outline(lo, hi, w):
    """The box's silhouette along w: its outline's corners in order (indices into corners)."""
    corners = np.array([[hi[k] if (i >> k) & 1 else lo[k] for k in range(3)] for i in range(8)])
    _, e1, e2, _ = sun_frame()
    p = np.stack([corners @ e1, corners @ e2], 1)
    order = sorted(range(8), key=lambda i: (p[i, 0], p[i, 1]))  # monotone chain hull

    def cross(o, a, b):
        return (p[a, 0] - p[o, 0]) * (p[b, 1] - p[o, 1]) - (p[a, 1] - p[o, 1]) * (p[b, 0] - p[o, 0])
    lower, upper = [], []
    for i in order:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], i) <= 1e-12:
            lower.pop()
        lower.append(i)
    for i in reversed(order):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], i) <= 1e-12:
            upper.pop()
        upper.append(i)
    return corners, lower[:-1] + upper[:-1]


def box_fraction(x, lo, hi, w, b):
    """Closed-form fraction of the disk behind the box: the product over its silhouette edges of
    the disk's share inside each edge's plane through the receiver."""
    corners, ring = box_outline(lo, hi, w)
    centre = 0.5 * (lo + hi)
    f = np.ones(x.shape[:-1])
    for i in range(len(ring)):
        p0, p1 = corners[ring[i]] - x, corners[ring[(i + 1) % len(ring)]] - x
        n = np.cross(p0, p1)
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        n *= np.sign(np.einsum("...k,...k", n, centre - x))[..., None]
        f *= half_disk(np.arcsin(np.clip(n @ w, -1, 1)) / b)
    return f


def closed_visibility(pts, segs, box, reach=None):
    """V = (1 - f_box) prod_i (1 - f_i); reach (optional, per point) counts the capsules whose
    stadium meets the disk."""
    w, _, _, b = sun_frame()
    v = 1.0 - box_fraction(pts, box[0], box[1], w, b)
    for a, bb in segs:
        f = capsule_fraction(pts, a, bb, R_CAPSULE, w, b)
        v *= 1.0 - f
        if reach is not None:
            reach += f > 0
    return v


def main():
    opts, _ = parse_options(sys.argv[2:], {"--spp": "1024", "--counts": "32,128,512", "--sub": "4",
                                          "--out": "out/thin_capsule"})
    pen = os.path.abspath(sys.argv[1])
    out = os.path.abspath(opts["--out"])
    os.makedirs(out, exist_ok=True)
    mesh = os.path.join(out, "chair.obj")
    segs, box = geometry(mesh)
    env = dict(os.environ, XDG_CACHE_HOME=os.path.join(out, "cache"))
    spp = opts["--spp"]
    tj = write(os.path.join(out, "truth.json"), scene(mesh, {}, 32))
    t0 = time.time()
    truths = []
    for seed in ("1", "2"):
        p = os.path.join(out, "truth_%s_s%s.exr" % (spp, seed))
        if not os.path.exists(p):
            run([pen, "reference", tj, "-o", p, "--spp", spp, "--seed", seed, "--lighting", "sh"])
        truths.append(image(p))
    cover = os.path.join(out, "cover.exr")  # the chair's own pixels, from a scene without ground
    if not os.path.exists(cover):
        oj = write(os.path.join(out, "obj.json"), scene(mesh, {}, 32, ground=False))
        run([pen, "reference", oj, "-o", os.path.join(out, "cover_img.exr"), "--spp", "16",
             "--coverage", cover])
    bares = []  # the renderer's unshadowed image at the pixel centres and box-filtered
    for scale in (1, int(opts["--sub"])):
        bj = write(os.path.join(out, "bare_x%d.json" % scale), scene(mesh, {}, 32, scale=scale))
        run([pen, "render", bj, "-o", bj[:-5] + ".exr", "-q", "--no-shadows"])
        bares.append(image(bj[:-5] + ".exr").reshape(3, 256, scale, 256, scale).mean((2, 4)))
    print("references: %.0f s" % (time.time() - t0), file=sys.stderr)
    truth = 0.5 * (truths[0] + truths[1])
    bare = bares[0]
    cov = image(cover)[0]
    # Ground pixels: no part of the chair in them nor in their 8 neighbours (chair_shadow.py
    # kept pixels with coverage up to 0.5: a tube 1 pixel wide then counts as its own shadow).
    seen = np.pad(cov > 0, 1)
    near = np.zeros_like(cov, dtype=bool)
    for dy in range(3):
        for dx in range(3):
            near |= seen[dy:dy + 256, dx:dx + 256]
    ground = ~near & (bare.sum(0) > 0) & (np.abs(bares[1] - bare).sum(0) < 1e-4 * bare.sum(0))
    cast = ground & (truth.sum(0) < 0.9 * bare.sum(0))
    write_png(os.path.join(out, "cast.png"), 256, 256,
              [(255,) * 3 if m else (0,) * 3 for m in cast.ravel()])

    def err(img, mask):
        d2 = ((img - truth)[:, mask] ** 2).mean()
        n2 = ((0.5 * (truths[0] - truths[1]))[:, mask] ** 2).mean()  # the mean's noise
        ref = (truth[:, mask] ** 2).mean()
        return math.sqrt(max(d2 - n2, 0) / ref), math.sqrt(d2 / ref), math.sqrt(n2 / ref)

    sub = int(opts["--sub"])

    def render(name, shadow, n):
        """The renderer's image at 256x256 (shaded at the pixel centres) and at sub x the size,
        box-filtered down to 256 (the reference's filter, sub x sub points)."""
        imgs = []
        for scale in (1, sub):
            js = write(os.path.join(out, "%s_x%d.json" % (name, scale)),
                       scene(mesh, shadow, n, scale=scale))
            subprocess.run([pen, "render", js, "-o", js[:-5] + ".exr", "-q"], env=env,
                           check=True, stderr=subprocess.DEVNULL)
            img = image(js[:-5] + ".exr")
            imgs.append(img.reshape(3, 256, scale, 256, scale).mean((2, 4)))
        return imgs

    centre, filtered = [], []
    t0 = time.time()
    for n in [int(c) for c in opts["--counts"].split(",")]:
        a, b = render("spheres_%d" % n, {"self": "spheres", "ground_shadow": "spheres"}, n)
        centre.append(("spheres, %d fitted" % n, a))
        filtered.append(("spheres, %d fitted" % n, b))
    a, b = render("default", {}, 32)
    centre.append(("default render (the mesh's transfer)", a))
    filtered.append(("default render (the mesh's transfer)", b))
    print("renders: %.0f s" % (time.time() - t0), file=sys.stderr)

    # The capsule models on the ground pixels.
    t0 = time.time()
    rng = np.random.default_rng(1)
    gy, gx = np.nonzero(ground)
    c1 = ground_points(1)[0][gy, gx, 0]
    cs = ground_points(sub)[0][gy, gx]
    nd = max(1, int(round(16 / sub)))  # nd x nd directions per point: 256 per pixel in all
    v_ex1 = np.empty(len(gy))
    v_exs = np.empty(len(gy))
    for k in range(0, len(gy), 1024):
        pts = c1[k:k + 1024]
        v_ex1[k:k + 1024] = exact_visibility(pts, segs, box, disk_dirs(16, rng, len(pts)))
        pts = cs[k:k + 1024].reshape(-1, 3)
        v_exs[k:k + 1024] = exact_visibility(pts, segs, box, disk_dirs(nd, rng, len(pts))).reshape(
            -1, sub * sub).mean(1)
    t_ex = time.time() - t0
    t0 = time.time()
    reach = np.zeros(len(c1))
    v_c1 = closed_visibility(c1, segs, box, reach)
    t_c1 = time.time() - t0
    v_cs = closed_visibility(cs.reshape(-1, 3), segs, box).reshape(-1, sub * sub).mean(1)
    print("capsules: exact %.0f s, closed form %.1f s (%d centres)" % (t_ex, t_c1, len(gy)),
          file=sys.stderr)

    def as_image(v):
        img = bare.copy()
        img[:, gy, gx] *= v
        return img
    centre += [("capsules + box, exact (256 directions)", as_image(v_ex1)),
               ("capsules + box, closed form", as_image(v_c1))]
    filtered += [("capsules + box, exact (%d directions a point)" % (nd * nd), as_image(v_exs)),
                 ("capsules + box, closed form", as_image(v_cs))]
    for i, (name, img) in enumerate(centre + filtered):
        np.save(os.path.join(out, "model_%d.npy" % i), img.astype(np.float32))

    print("truth: %s spp x 2 seeds; cast-shadow pixels %d, ground pixels %d of %d" %
          (spp, cast.sum(), ground.sum(), cast.size))
    print()
    print("| model | shaded at | cast shadow, noise removed | (raw) | ground, noise removed "
          "| (raw) |")
    print("|---|---|---|---|---|---|")
    for where, rows in (("pixel centre", centre), ("%dx%d points" % (sub, sub), filtered)):
        for name, img in rows:
            a, ar, _ = err(img, cast)
            g, gr, _ = err(img, ground)
            print("| %s | %s | %.4f | %.4f | %.4f | %.4f |" % (name, where, a, ar, g, gr))
    print()
    print("truth's own noise (the mean of two seeds): %.4f over the cast shadow, %.4f over the "
          "ground" % (err(truth, cast)[2], err(truth, ground)[2]))
    in_cast = cast[gy, gx]
    print("capsules whose stadium meets the disk, per pixel centre: %.3f on the ground, %.2f in "
          "the cast shadow (most %d); %d capsules"
          % (reach.mean(), reach[in_cast].mean(), reach.max(), len(segs)))
    for label, v, ve in (("pixel centre", v_c1, v_ex1), ("%dx%d points" % (sub, sub), v_cs, v_exs)):
        d = v - ve
        print("closed form minus exact, V on the ground pixels, %s: RMS %.4f, worst %+.3f / %+.3f"
              % (label, math.sqrt((d ** 2).mean()), d.min(), d.max()))

    # The picture: truth | spheres 128 | capsules (closed form, centre), sRGB.
    pics = [truth] + [img for name, img in filtered if name.startswith("spheres, 128")] + \
        [filtered[-1][1]]
    if len(pics) == 3:
        peak = float(np.percentile(truth[:, ground], 99.5))

        def srgb(img):
            x = np.clip(img / peak, 0, 1)
            x = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
            return (x * 255 + 0.5).astype(np.uint8)
        sheet = np.concatenate([srgb(p) for p in pics], axis=2)
        write_png(os.path.join(out, "sheet.png"), sheet.shape[2], sheet.shape[1],
                  [tuple(int(c) for c in px) for px in sheet.reshape(3, -1).T])


main()
