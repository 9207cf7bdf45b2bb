#!/usr/bin/env python3
"""penumbra and Mitsuba 3 side by side, on the same scene and the same machine.

Optional tooling: nothing in `make test`, `make demo` or the install uses it.
Results of a run and how to read them: docs/results/mitsuba.md.

What it measures
----------------
(a) Image error against time. The truth is penumbra's Embree reference with the full
    environment map (`penumbra reference SCENE --lighting envmap --spp 1024`, with its coverage
    image), i.e. L_o = rho/pi * integral of L V cos over the whole map with exact visibility and
    direct light only. Against it:
      - penumbra: `penumbra render SCENE` (its forward time as printed, and the image's
        relative RMSE), and the step time of `penumbra bench --case headline --case transfer`
        (forward + L2 loss + backward);
      - Mitsuba 3 (LLVM CPU variant `llvm_ad_rgb`, integrator `prb`, max_depth 2 = direct light
        only, as penumbra's model): a forward render at several sample counts (time and relative
        RMSE), and a forward + backward step (an L2 loss against the truth, `dr.backward` into the
        albedo texture and the environment map, the two parameter groups of penumbra's `transfer`
        case) at the same counts.
    The relative RMSE is `penumbra compare`'s: sqrt(mean (A - B)^2) / sqrt(mean B^2) over every
    pixel and channel, and the same over the pixels whose coverage exceeds 0.5 ("surfaces").
    From the ladder the script reads off the spp and the time at which Mitsuba's error falls to
    penumbra's (log-log interpolation between the two bracketing sample counts).
(b) The pose task of examples/optimize (spot_pose.json: Spot's 6-D pose from 10.8 degrees and 0.1
    away, 256x256, target ray traced by `penumbra reference --spp 256 --lighting envmap` from the
    true scene). penumbra runs `penumbra optimize` on it; Mitsuba optimises the same rotation
    (axis-angle, radians) and translation with Adam at the same learning rate, rendering with the
    projective integrator `direct_projective` (visibility-aware gradients: silhouettes and shadow
    edges; its silhouette guiding off, --pose-guiding, which cost minutes per iteration here)
    against the same target, until it reaches penumbra's rotation and translation errors,
    a time budget or an iteration limit. Reported: time and iterations to reach them, and the
    best errors reached.

The Mitsuba scene is built from the scene JSON (no hard-coded scene): the mesh (.obj, with its
UVs; smooth area-weighted vertex normals of the posed mesh, as penumbra's reference computes
them), the albedo texture or colour, the pose (axis-angle rotation, translation, scale), the
ground square, the environment map (scale, rotation about +Y; penumbra's equirectangular
convention turned into Mitsuba's with a 180-degree rotation about +Y, which the script checks on
the background pixels against three other rotations) and the camera (eye, target, up, vertical
field of view, size). Keys it cannot express (calibrated cameras, framing, units, on_ground,
explicit SH or disk lights, materials from .mtl files, coloured backgrounds) stop it with a
message.

How to run it
-------------
    python3 -m venv /tmp/mitsuba-venv && /tmp/mitsuba-venv/bin/pip install mitsuba drjit numpy
    /tmp/mitsuba-venv/bin/python bench/mitsuba_compare.py --libllvm /path/to/libLLVM.so.19 \
        [--scene examples/scenes/spot_city.json] [--out out/mitsuba] [--threads 2]

Needs: Python 3 with numpy, mitsuba and drjit (tested with Mitsuba 3.9.1, Dr.Jit 1.5.0); the
LLVM shared library for the LLVM variant (Dr.Jit 1.5 needs LLVM >= 15, and LLVM 15 itself fails
to compile its kernels: "LLVM ERROR: Cannot select: ... f32 = fminimum"; LLVM 19 works: on
Debian 12 `apt-get download libllvm19 && dpkg -x libllvm19_*.deb /tmp/llvm19/root` gives
/tmp/llvm19/root/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1 without installing anything; --libllvm sets
DRJIT_LIBLLVM_PATH); a built penumbra (--penumbra, default build/penumbra). About 15-20 minutes
on 2 cores: the truth (1024 spp), the Mitsuba ladder, and the pose budget (--pose-budget-s).
Reuse a truth with --truth FILE --coverage FILE. --skip-image / --skip-pose run one part.

Output: OUT/results.json (every number below, the versions and the settings) and a table on
stdout; OUT/mitsuba_<spp>spp.exr, the renders.
"""
import argparse
import json
import math
import os
import platform
import re
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def parse_args():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scene", default=os.path.join(ROOT, "examples/scenes/spot_city.json"))
    p.add_argument("--penumbra", default=os.path.join(ROOT, "build/penumbra"))
    p.add_argument("--out", default=os.path.join(ROOT, "out/mitsuba"))
    p.add_argument("--libllvm", default=None, help="path of libLLVM (sets DRJIT_LIBLLVM_PATH)")
    p.add_argument("--variant", default="llvm_ad_rgb")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--truth", default=None, help="reuse this truth EXR (needs --coverage)")
    p.add_argument("--coverage", default=None)
    p.add_argument("--truth-spp", type=int, default=1024)
    p.add_argument("--spp", default="1,4,16,64,256", help="Mitsuba forward sample counts")
    p.add_argument("--grad-spp", default="1,4,16,64", help="Mitsuba forward+backward counts")
    p.add_argument("--sampler", default="independent")
    p.add_argument("--bench-repeat", type=int, default=5)
    p.add_argument("--pose-task", default=os.path.join(ROOT, "examples/optimize/spot_pose.json"))
    p.add_argument("--pose-target", default=None, help="the task's target EXR (else rendered)")
    p.add_argument("--pose-spp", type=int, default=4)
    p.add_argument("--pose-integrator", default="direct_projective")
    p.add_argument("--pose-guiding", default="none", help="projective integrators' guiding")
    p.add_argument("--pose-lr", type=float, default=0.01)
    p.add_argument("--pose-budget-s", type=float, default=480)
    p.add_argument("--pose-iterations", type=int, default=400)
    p.add_argument("--skip-image", action="store_true")
    p.add_argument("--skip-pose", action="store_true")
    p.add_argument("--tables-from", default=None,
                   help="print the tables of an earlier results.json (re-deriving the fits)")
    return p.parse_args()


ARGS = parse_args()
if ARGS.libllvm:
    os.environ["DRJIT_LIBLLVM_PATH"] = ARGS.libllvm
import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

mi.set_variant(ARGS.variant)
if hasattr(dr, "set_thread_count"):
    dr.set_thread_count(ARGS.threads)


def log(*a):
    print(*a, file=sys.stderr, flush=True)


# ---- the scene JSON -> geometry ------------------------------------------------------------------

def rodrigues(axis_angle_rad):
    r = np.asarray(axis_angle_rad, dtype=np.float64)
    th = np.linalg.norm(r)
    if th == 0.0:
        return np.eye(3)
    k = r / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * (K @ K)


def rotation_angle_deg(Ra, Rb):
    """The angle of Ra Rb^T, accurate at small angles (atan2 of its sine and cosine parts)."""
    M = Ra @ Rb.T
    s = 0.5 * np.linalg.norm([M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1]])
    c = 0.5 * (np.trace(M) - 1.0)
    return math.degrees(math.atan2(s, c))


def load_obj(path):
    """Positions, UVs and triangles (position and UV indices) of an .obj; polygons as fans."""
    P, T, fp, ft, mtl = [], [], [], [], False
    with open(path) as f:
        for line in f:
            w = line.split()
            if not w:
                continue
            if w[0] == "v":
                P.append([float(x) for x in w[1:4]])
            elif w[0] == "vt":
                T.append([float(x) for x in w[1:3]])
            elif w[0] == "mtllib":
                mtl = True
            elif w[0] == "f":
                vi, ti = [], []
                for c in w[1:]:
                    s = c.split("/")
                    a = int(s[0])
                    vi.append(a - 1 if a > 0 else len(P) + a)
                    if len(s) > 1 and s[1]:
                        b = int(s[1])
                        ti.append(b - 1 if b > 0 else len(T) + b)
                    else:
                        ti.append(-1)
                for k in range(1, len(vi) - 1):
                    fp.append([vi[0], vi[k], vi[k + 1]])
                    ft.append([ti[0], ti[k], ti[k + 1]])
    return (np.array(P, np.float64), np.array(T, np.float64).reshape(-1, 2),
            np.array(fp, np.int64), np.array(ft, np.int64), mtl)


def area_normals(P, F):
    """Area-weighted vertex normals (unnormalised face cross products summed, then normalised)."""
    n = np.cross(P[F[:, 1]] - P[F[:, 0]], P[F[:, 2]] - P[F[:, 0]])
    N = np.zeros_like(P)
    for k in range(3):
        np.add.at(N, F[:, k], n)
    ln = np.linalg.norm(N, axis=1, keepdims=True)
    return N / np.where(ln > 0, ln, 1)


class MeshData:
    """A mesh split into (position, uv) vertices: object-space positions (scale applied), the
    texture coordinates in Mitsuba's convention (v flipped: penumbra's image row 0 is v = 1,
    Mitsuba's bitmap row 0 is v = 0) and the triangles."""

    def __init__(self, path, scale):
        P, T, fp, ft, self.has_mtl = load_obj(path)
        self.has_uv = len(T) > 0 and (ft >= 0).all()
        P = P * scale
        if self.has_uv:
            key = fp.reshape(-1) * (len(T) + 1) + ft.reshape(-1)
        else:
            key = fp.reshape(-1)
        uniq, inv = np.unique(key, return_inverse=True)
        first = np.zeros(len(uniq), np.int64)
        first[inv[::-1]] = np.arange(len(key))[::-1]
        self.pos_index = fp.reshape(-1)[first]  # which original position each vertex is
        self.faces = inv.reshape(-1, 3).astype(np.uint32)
        self.p_orig = P
        self.f_orig = fp
        self.P = P[self.pos_index]
        if self.has_uv:
            uv = T[ft.reshape(-1)[first]]
            self.UV = np.stack([uv[:, 0], 1.0 - uv[:, 1]], axis=1)
        else:
            self.UV = None

    def posed(self, R, t):
        """Vertices and normals of the posed mesh: normals from the posed positions (the same as
        rotating the object-space ones, for a rotation and a uniform scale)."""
        Pw = self.p_orig @ R.T + t
        Nw = area_normals(Pw, self.f_orig)
        return Pw[self.pos_index], Nw[self.pos_index]


def mi_mesh(name, md, V, N, bsdf):
    props = mi.Properties()
    props["bsdf"] = bsdf
    m = mi.Mesh(name, len(V), len(md.faces), props=props, has_vertex_normals=True,
                has_vertex_texcoords=md.UV is not None)
    p = mi.traverse(m)
    p["vertex_positions"] = mi.Float(V.astype(np.float32).reshape(-1))
    p["vertex_normals"] = mi.Float(N.astype(np.float32).reshape(-1))
    if md.UV is not None:
        p["vertex_texcoords"] = mi.Float(md.UV.astype(np.float32).reshape(-1))
    p["faces"] = mi.UInt32(md.faces.reshape(-1))
    p.update()
    return m


def unsupported(what):
    sys.exit(f"mitsuba_compare: {what} cannot be expressed in the Mitsuba scene (unsupported)")


def look_at(eye, target, up):
    T = mi.ScalarTransform4f
    try:
        return T().look_at(origin=eye, target=target, up=up)
    except TypeError:
        return T.look_at(origin=eye, target=target, up=up)


def rotate_y(deg):
    return mi.ScalarTransform4f().rotate(axis=[0, 1, 0], angle=deg)


class Scene:
    """The scene JSON, resolved for Mitsuba."""

    def __init__(self, path):
        self.path = os.path.abspath(path)
        base = os.path.dirname(self.path)
        with open(path) as f:
            js = json.load(f)
        self.js = js
        res = lambda p: p if os.path.isabs(p) else os.path.normpath(os.path.join(base, p))
        cam = js["camera"]
        for k in ("intrinsics", "world_to_camera", "frame"):
            if k in cam and cam[k] not in (False, None):
                unsupported(f"camera.{k}")
        self.width, self.height = int(cam["width"]), int(cam["height"])
        self.fov = float(cam["fov_y_deg"])
        self.eye, self.target = cam["eye"], cam["target"]
        self.up = cam.get("up", [0, 1, 0])
        lt = js.get("lighting", {})
        if "sh" in lt:
            unsupported("lighting.sh")
        if isinstance(lt.get("lights"), list) and lt["lights"]:
            unsupported("lighting.lights (disk lights)")
        if "envmap" not in lt:
            unsupported("a scene without lighting.envmap")
        self.envmap = res(lt["envmap"])
        self.env_scale = float(lt.get("scale", 1.0))
        self.env_rot = float(lt.get("rotation_y_deg", 0.0))
        bg = js.get("background", "envmap")
        if bg == "envmap":
            self.hide_emitters = False
        elif isinstance(bg, list) and all(float(x) == 0 for x in bg):
            self.hide_emitters = True
        else:
            unsupported(f"background {bg}")
        g = js.get("ground")
        self.ground = None
        if g is not None:
            self.ground = dict(height=float(g.get("height", 0)),
                               albedo=g.get("albedo", [0.8, 0.8, 0.8]),
                               half_size=float(g.get("half_size", 4)))
        self.objects = []
        for i, o in enumerate(js["objects"]):
            if "units" in o:
                unsupported(f"objects[{i}].units")
            pose = o.get("pose", {})
            for k in ("on_ground", "centre"):
                if pose.get(k):
                    unsupported(f"objects[{i}].pose.{k}")
            if "albedo_texture_layout" in o and o["albedo_texture_layout"] != "mesh":
                unsupported(f"objects[{i}].albedo_texture_layout")
            md = MeshData(res(o["mesh"]), float(pose.get("scale", 1.0)))
            if "albedo_texture" in o:
                if not md.has_uv:
                    unsupported(f"objects[{i}]: a texture on a mesh without UVs")
                refl = {"type": "bitmap", "filename": res(o["albedo_texture"]),
                        "filter_type": "bilinear", "wrap_mode": "repeat"}
            else:
                if "albedo" not in o and md.has_mtl:
                    unsupported(f"objects[{i}]: albedo from the mesh's materials")
                refl = {"type": "rgb", "value": o.get("albedo", [0.8, 0.8, 0.8])}
            self.objects.append(dict(mesh=md, reflectance=refl,
                                     rot=[math.radians(x) for x in
                                          pose.get("rotation_axis_angle_deg", [0, 0, 0])],
                                     t=[float(x) for x in pose.get("translation", [0, 0, 0])]))

    def mitsuba(self, spp, integrator=None, env_extra_deg=180.0, sampler=None):
        """The Mitsuba scene. env_extra_deg: the rotation about +Y that takes Mitsuba's map
        directions to penumbra's (180 by the two conventions; other values for the check)."""
        d = {"type": "scene"}
        d["integrator"] = integrator or {"type": "prb", "max_depth": 2,
                                         "hide_emitters": self.hide_emitters}
        d["sensor"] = {
            "type": "perspective", "fov": self.fov, "fov_axis": "y",
            "to_world": look_at(self.eye, self.target, self.up),
            "film": {"type": "hdrfilm", "width": self.width, "height": self.height,
                     "rfilter": {"type": "box"}, "pixel_format": "rgb"},
            "sampler": {"type": sampler or ARGS.sampler, "sample_count": spp}}
        d["envmap"] = {"type": "envmap", "filename": self.envmap, "scale": self.env_scale,
                       "to_world": rotate_y(self.env_rot + env_extra_deg)}
        if self.ground:
            g = self.ground
            T = mi.ScalarTransform4f
            d["ground"] = {
                "type": "rectangle",
                "to_world": T().translate([0, g["height"], 0]) @ T().rotate(
                    axis=[1, 0, 0], angle=-90) @ T().scale([g["half_size"], g["half_size"], 1]),
                "bsdf": {"type": "twosided", "bsdf": {
                    "type": "diffuse", "reflectance": {"type": "rgb", "value": g["albedo"]}}}}
        for i, o in enumerate(self.objects):
            V, N = o["mesh"].posed(rodrigues(o["rot"]), np.array(o["t"]))
            bsdf = mi.load_dict({"type": "twosided", "bsdf": {
                "type": "diffuse", "reflectance": o["reflectance"]}})
            d[f"object{i}"] = mi_mesh(f"object{i}", o["mesh"], V, N, bsdf)
        return mi.load_dict(d)


# ---- images and metrics ------------------------------------------------------------------------

def read_exr(path):
    a = np.array(mi.Bitmap(path), dtype=np.float64)
    return a if a.ndim == 3 else a[:, :, None]


def rel_rmse(a, b, mask=None):
    """penumbra compare's rel_rmse: sqrt(mean (a - b)^2) / sqrt(mean b^2) over every pixel and
    channel; with a mask, over the pixels where the mask's channel mean exceeds 0.5."""
    if mask is not None:
        sel = mask.mean(axis=2) > 0.5
        a, b = a[sel], b[sel]
    return float(math.sqrt(np.mean((a - b) ** 2)) / math.sqrt(np.mean(b ** 2)))


def run(cmd, **kw):
    log("$ " + " ".join(cmd))
    t = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, **kw)
    wall = time.perf_counter() - t
    if r.returncode != 0:
        sys.exit(f"command failed ({r.returncode}): {' '.join(cmd)}\n{r.stderr}")
    return r.stdout, wall


def timed_render(scene, spp, seed, params=None):
    dr.sync_thread()
    t = time.perf_counter()
    img = mi.render(scene, params, spp=spp, seed=seed)
    dr.eval(img)
    dr.sync_thread()
    a = np.array(img, dtype=np.float64)
    return a, time.perf_counter() - t


def crossing(ladder, key, target):
    """The spp (log-log interpolation) and time (linear in spp) where ladder[key] falls to target;
    None when the ladder never gets there, '<first' when its first point is already below."""
    pts = [(r["spp"], r[key], r["seconds"]) for r in ladder]
    if pts[0][1] <= target:
        return {"spp": f"<= {pts[0][0]}", "seconds": f"<= {pts[0][2]:.3g}"}
    for (s0, e0, t0), (s1, e1, t1) in zip(pts, pts[1:]):
        if e1 <= target < e0:
            f = math.log(e0 / target) / math.log(e0 / e1)
            s = math.exp(math.log(s0) + f * math.log(s1 / s0))
            return {"spp": round(s, 1), "seconds": round(t0 + (t1 - t0) * (s - s0) / (s1 - s0), 3)}
    return None


def noise_fit(ladder, key, target, grad_ladder):
    """Least-squares fit of err^2 = a + c / spp over the ladder (a: what no spp removes, the
    truth's own noise and any difference of the models; c: Mitsuba's per-sample variance), and
    the spp where it reaches target, c / (target^2 - a); times scaled linearly from the largest
    measured spp (forward, and forward+backward)."""
    x = np.array([1.0 / r["spp"] for r in ladder])
    y = np.array([r[key] ** 2 for r in ladder])
    A = np.stack([np.ones_like(x), x], axis=1)
    (a, c), *_ = np.linalg.lstsq(A, y, rcond=None)
    out = {"floor": math.sqrt(max(a, 0.0)), "one_spp": math.sqrt(max(a + c, 0.0))}
    if target ** 2 > a and c > 0:
        spp = c / (target ** 2 - a)
        f, g = ladder[-1], grad_ladder[-1] if grad_ladder else None
        out.update(spp=round(spp, 1), forward_seconds=round(f["seconds"] * spp / f["spp"], 2))
        if g:
            out["forward_backward_seconds"] = round(g["seconds"] * spp / g["spp"], 2)
    return out


def derive(res):
    """The numbers read off the ladders (also for --tables-from)."""
    fwd, grad, pen = res["mitsuba_forward"], res["mitsuba_forward_backward"], res["penumbra"]
    cross = {}
    gt = {r["spp"]: r["seconds"] for r in grad}
    for key in ("rel_rmse", "rel_rmse_surfaces"):
        c = crossing(fwd, key, pen["render"][key]) or {}
        if isinstance(c.get("spp"), float):
            sp = sorted(gt)
            for s0, s1 in zip(sp, sp[1:]):
                if s0 <= c["spp"] <= s1:
                    c["forward_backward_seconds"] = round(
                        gt[s0] + (gt[s1] - gt[s0]) * (c["spp"] - s0) / (s1 - s0), 3)
        c["fit"] = noise_fit(fwd, key, pen["render"][key], grad)
        cross[key] = c
    res["mitsuba_reaches_penumbra"] = cross


# ---- (a) image error against time ------------------------------------------------------------

def part_image(res):
    sc = Scene(ARGS.scene)
    out = ARGS.out
    if ARGS.truth:
        truth_path, cov_path = ARGS.truth, ARGS.coverage
        if not cov_path:
            sys.exit("--truth needs --coverage")
        res["truth"] = {"file": truth_path, "reused": True}
    else:
        truth_path, cov_path = os.path.join(out, "truth.exr"), os.path.join(out, "coverage.exr")
        so, wall = run([ARGS.penumbra, "reference", sc.path, "-o", truth_path, "--spp",
                        str(ARGS.truth_spp), "--lighting", "envmap", "--coverage", cov_path,
                        "--threads", str(ARGS.threads)])
        res["truth"] = json.loads(so.strip().splitlines()[-1])
    truth, cov = read_exr(truth_path), read_exr(cov_path)
    bg = 1.0 - cov  # the background pixels, for the orientation check
    H, W = truth.shape[:2]
    assert (H, W) == (sc.height, sc.width), "truth size differs from the scene's"

    # penumbra: render (default scene) and the bench's step times
    pen = {}
    render_path = os.path.join(out, "penumbra.exr")
    so, wall = run([ARGS.penumbra, "render", sc.path, "-o", render_path,
                    "--threads", str(ARGS.threads)])
    m = re.search(r"([0-9.]+) s\s*$", so.strip().splitlines()[-1])
    img = read_exr(render_path)[:, :, :3]
    pen["render"] = {"forward_s": float(m.group(1)) if m else None, "wall_s": round(wall, 3),
                     "rel_rmse": rel_rmse(img, truth), "rel_rmse_surfaces": rel_rmse(img, truth, cov)}
    so, _ = run([ARGS.penumbra, "compare", render_path, truth_path, "--mask", cov_path])
    pen["render"]["penumbra_compare"] = json.loads(so)
    so, _ = run([ARGS.penumbra, "bench", "--scene", sc.path, "--case", "headline", "--case",
                 "transfer", "--json", "--no-reference", "--repeat", str(ARGS.bench_repeat),
                 "--threads", str(ARGS.threads)])
    pen["bench"] = {}
    for line in so.strip().splitlines():
        j = json.loads(line)
        pen["bench"][j.get("case", j.get("name", "?"))] = {
            k: j.get(k) for k in ("forward_ms", "backward_ms", "total_ms", "forward_min_ms",
                                  "backward_min_ms", "total_min_ms", "self", "ground_shadow")}
    res["penumbra"] = pen

    # Mitsuba: the map's orientation, checked on the background pixels
    orient = {}
    for extra in (0.0, 90.0, 180.0, 270.0):
        s = sc.mitsuba(4, env_extra_deg=extra)
        a, _ = timed_render(s, 4, 1)
        orient[str(int(extra))] = rel_rmse(a, truth, bg)
    res["envmap_orientation_check"] = {"background_rel_rmse_by_extra_rotation_deg": orient,
                                       "used": "180"}
    best = min(orient, key=orient.get)
    if best != "180":
        log(f"WARNING: the background matches best with an extra rotation of {best} degrees")

    # Mitsuba: forward ladder
    fwd = []
    for spp in [int(x) for x in ARGS.spp.split(",")]:
        s = sc.mitsuba(spp)
        a, t1 = timed_render(s, spp, 11 + spp)
        row = {"spp": spp, "first_s": round(t1, 3), "rel_rmse": rel_rmse(a, truth),
               "rel_rmse_surfaces": rel_rmse(a, truth, cov)}
        mi.Bitmap(a.astype(np.float32)).write(os.path.join(out, f"mitsuba_{spp}spp.exr"))
        if t1 < 30:  # a second, warm run (the kernels compiled): the time reported
            _, t2 = timed_render(s, spp, 1000 + spp)
            row["seconds"] = round(t2, 3)
        else:
            row["seconds"] = round(t1, 3)
        log(f"mitsuba forward {spp} spp: {row}")
        fwd.append(row)
    res["mitsuba_forward"] = fwd

    # Mitsuba: forward + backward (L2 loss against the truth; texture and map gradients)
    grad = []
    target = mi.TensorXf(truth.astype(np.float32))
    for spp in [int(x) for x in ARGS.grad_spp.split(",")]:
        s = sc.mitsuba(spp)
        params = mi.traverse(s)
        keys = [k for k in params.keys() if k.endswith("reflectance.data") or k == "envmap.data"]
        times = []
        for rep in range(2):
            params = mi.traverse(s)
            for k in keys:
                dr.enable_grad(params[k])
            params.update()
            dr.sync_thread()
            t = time.perf_counter()
            img = mi.render(s, params, spp=spp, seed=77 + rep)
            loss = dr.mean(dr.square(img - target), axis=None)
            dr.backward(loss)
            gs = [dr.grad(params[k]) for k in keys]
            dr.eval(*gs)
            dr.sync_thread()
            times.append(time.perf_counter() - t)
            if times[0] > 30:
                break
        row = {"spp": spp, "keys": keys, "first_s": round(times[0], 3),
               "seconds": round(times[-1], 3)}
        log(f"mitsuba forward+backward {spp} spp: {row}")
        grad.append(row)
    res["mitsuba_forward_backward"] = grad

    derive(res)


# ---- (b) the pose task --------------------------------------------------------------------------

def part_pose(res):
    out = ARGS.out
    task_path = os.path.abspath(ARGS.pose_task)
    tdir = os.path.dirname(task_path)
    with open(task_path) as f:
        task = json.load(f)
    init = Scene(os.path.join(tdir, task["scene"]))
    truth_scene = Scene(os.path.join(tdir, task["ground_truth"]))
    target_path = ARGS.pose_target
    if not target_path:
        tp = os.path.normpath(os.path.join(tdir, task["target"]))
        if os.path.exists(tp):
            target_path = tp
        else:
            target_path = os.path.join(out, "pose_target.exr")
            if not os.path.exists(target_path):
                run([ARGS.penumbra, "reference", truth_scene.path, "-o", target_path, "--spp",
                     "256", "--lighting", "envmap", "--threads", str(ARGS.threads)])
    target_np = read_exr(target_path)[:, :, :3]
    pr = {"task": os.path.relpath(task_path, ROOT), "target": target_path}

    # penumbra
    pdir = os.path.join(out, "penumbra_pose")
    _, wall = run([ARGS.penumbra, "optimize", task_path, "--target", target_path, "-o", pdir,
                   "-q", "--threads", str(ARGS.threads)])
    with open(os.path.join(pdir, "result.json")) as f:
        r = json.load(f)
    met = r["metrics"]
    pr["penumbra"] = {"iterations": r["iterations"], "seconds": r["seconds"], "wall_s": round(wall, 2),
                      "stop_reason": r.get("stop_reason"),
                      "rotation_error_deg": met["rotation_error_deg"],
                      "translation_error": met["translation_error"]}
    goal_rot, goal_tr = met["rotation_error_deg"], met["translation_error"]

    # Mitsuba: the same start, rotation (axis-angle, radians) and translation by Adam
    o0, ot = init.objects[0], truth_scene.objects[0]
    R_true, t_true = rodrigues(ot["rot"]), np.array(ot["t"])
    md = o0["mesh"]
    integ = {"type": ARGS.pose_integrator}
    try:
        mi.load_dict(dict(integ, hide_emitters=init.hide_emitters))
        integ["hide_emitters"] = init.hide_emitters
    except Exception:
        pass
    if ARGS.pose_integrator in ("prb", "prb_projective", "path"):
        integ["max_depth"] = 2
    if ARGS.pose_integrator.endswith("_projective"):
        # no silhouette guiding: with its default octree the guiding pass made one iteration
        # take 130-450 s here instead of about 3 s
        integ["guiding"] = ARGS.pose_guiding
    s = init.mitsuba(ARGS.pose_spp, integrator=integ)
    params = mi.traverse(s)
    P0 = mi.Vector3f(md.P.astype(np.float32).T)
    N0 = mi.Vector3f(area_normals(md.p_orig, md.f_orig)[md.pos_index].astype(np.float32).T)
    opt = mi.ad.Adam(lr=ARGS.pose_lr)
    opt["rot"] = mi.Vector3f(*[float(x) for x in o0["rot"]])
    opt["t"] = mi.Vector3f(*[float(x) for x in o0["t"]])
    target = mi.TensorXf(target_np.astype(np.float32))

    def rot_apply(r, v):
        th = dr.norm(r)
        k = r / th
        c, sn = dr.cos(th), dr.sin(th)
        return v * c + dr.cross(k, v) * sn + k * dr.dot(k, v) * (1 - c)

    def errors():
        rv = np.array(opt["rot"], dtype=np.float64).reshape(-1)
        tv = np.array(opt["t"], dtype=np.float64).reshape(-1)
        return rotation_angle_deg(rodrigues(rv), R_true), float(np.linalg.norm(tv - t_true))

    traj, reached, best = [], None, None
    e0 = errors()
    traj.append({"it": 0, "s": 0.0, "rot_deg": e0[0], "trans": e0[1], "loss": None})
    t_start = time.perf_counter()
    for it in range(1, ARGS.pose_iterations + 1):
        r, t = opt["rot"], opt["t"]
        params["object0.vertex_positions"] = dr.ravel(rot_apply(r, P0) + t)
        params["object0.vertex_normals"] = dr.ravel(rot_apply(r, N0))
        params.update()
        img = mi.render(s, params, spp=ARGS.pose_spp, seed=it)
        loss = dr.mean(dr.square(img - target), axis=None)
        dr.backward(loss)
        opt.step()
        lv = float(np.array(loss).reshape(-1)[0])
        el = time.perf_counter() - t_start
        er, et = errors()
        traj.append({"it": it, "s": round(el, 3), "rot_deg": er, "trans": et, "loss": lv})
        if best is None or lv < best["loss"]:
            best = traj[-1]
        if reached is None and er <= goal_rot and et <= goal_tr:
            reached = traj[-1]
        if it % 10 == 0:
            log(f"mitsuba pose it {it} {el:.1f} s loss {lv:.5g} rot {er:.3f} deg trans {et:.4f}")
        if el > ARGS.pose_budget_s:
            break
    pr["mitsuba"] = {
        "integrator": integ, "spp": ARGS.pose_spp, "lr": ARGS.pose_lr,
        "iterations": traj[-1]["it"], "seconds": traj[-1]["s"],
        "seconds_per_iteration": round(traj[-1]["s"] / max(traj[-1]["it"], 1), 3),
        "first_iteration_s": traj[1]["s"] if len(traj) > 1 else None,
        "reached_penumbra": reached,
        "min_rotation_error_deg": min(x["rot_deg"] for x in traj),
        "min_translation_error": min(x["trans"] for x in traj),
        "final": traj[-1], "lowest_loss_iterate": best,
        "trajectory": traj}
    res["pose"] = pr


# ---- report -------------------------------------------------------------------------------------

def versions():
    v = {"mitsuba": mi.__version__, "drjit": dr.__version__, "variant": ARGS.variant,
         "python": platform.python_version(), "threads": ARGS.threads,
         "DRJIT_LIBLLVM_PATH": os.environ.get("DRJIT_LIBLLVM_PATH")}
    try:
        v["llvm"] = ".".join(str(x) for x in dr.detail.llvm_version())
    except Exception:
        pass
    try:
        v["penumbra_commit"] = subprocess.run(["git", "-C", ROOT, "rev-parse", "--short", "HEAD"],
                                              capture_output=True, text=True).stdout.strip()
        cpu = subprocess.run(["lscpu"], capture_output=True, text=True).stdout
        v["cpu"] = re.search(r"Model name:\s*(.*)", cpu).group(1).strip()
    except Exception:
        pass
    try:
        v["load_average"] = os.getloadavg()
    except Exception:
        pass
    return v


def print_tables(res):
    if "penumbra" in res:
        p = res["penumbra"]
        print("\n(a) image error against the full-map truth"
              f" ({res['truth'].get('spp', '?')} spp), relative RMSE image / surfaces")
        r = p["render"]
        print(f"penumbra render: {r['rel_rmse']:.4f} / {r['rel_rmse_surfaces']:.4f}, forward "
              f"{r['forward_s']} s")
        for c, b in p["bench"].items():
            print(f"penumbra bench {c}: forward {b['forward_ms']} ms, backward {b['backward_ms']}"
                  f" ms, step {b['total_ms']} ms (self {b['self']})")
        print("| spp | Mitsuba rel_rmse (image) | (surfaces) | forward s | forward+backward s |")
        print("|---|---|---|---|---|")
        g = {x["spp"]: x["seconds"] for x in res["mitsuba_forward_backward"]}
        for x in res["mitsuba_forward"]:
            print(f"| {x['spp']} | {x['rel_rmse']:.4f} | {x['rel_rmse_surfaces']:.4f} | "
                  f"{x['seconds']} | {g.get(x['spp'], '-')} |")
        print("Mitsuba reaches penumbra's error at:", json.dumps(res["mitsuba_reaches_penumbra"]))
        print("map orientation check (background rel_rmse by extra rotation):",
              json.dumps(res["envmap_orientation_check"]))
    if "pose" in res:
        p, m = res["pose"]["penumbra"], res["pose"]["mitsuba"]
        print("\n(b) pose task")
        print(f"penumbra: {p['iterations']} it, {p['seconds']:.2f} s, rotation "
              f"{p['rotation_error_deg']:.3f} deg, translation {p['translation_error']:.4f}")
        rc = m["reached_penumbra"]
        print(f"Mitsuba ({m['integrator']['type']}, {m['spp']} spp): {m['iterations']} it, "
              f"{m['seconds']:.1f} s ({m['seconds_per_iteration']} s/it); reached penumbra's "
              f"errors: {'at it %d, %.1f s' % (rc['it'], rc['s']) if rc else 'no'}; best rotation "
              f"{m['min_rotation_error_deg']:.3f} deg, best translation "
              f"{m['min_translation_error']:.4f}; final {m['final']['rot_deg']:.3f} deg / "
              f"{m['final']['trans']:.4f}")


def main():
    if ARGS.tables_from:
        with open(ARGS.tables_from) as f:
            res = json.load(f)
        if "mitsuba_forward" in res:
            derive(res)
        print_tables(res)
        return
    os.makedirs(ARGS.out, exist_ok=True)
    res = {"versions": versions(), "args": vars(ARGS)}
    path = os.path.join(ARGS.out, "results.json")
    if not ARGS.skip_image:
        part_image(res)
        with open(path, "w") as f:
            json.dump(res, f, indent=1)
    if not ARGS.skip_pose:
        part_pose(res)
    res["versions"]["load_average_end"] = os.getloadavg()
    with open(path, "w") as f:
        json.dump(res, f, indent=1)
    print_tables(res)
    print(f"\nwritten: {path}")


if __name__ == "__main__":
    main()
