#!/usr/bin/env python3
"""Self-shadowing accuracy of `penumbra render` on the development meshes (design.md sec. 1.15).

Usage: python3 research/experiments/accuracy/visibility_table.py PENUMBRA_BIN OUTDIR [--size S]
           [--spp N] [--meshes a,b] [--maps a,b] [--no-proxy] [--suffix S] [--plain] [--self MODE]
           [--quick]

For every mesh x map cell (data/meshes x data/envmaps/*.exr) it renders the scene with
`penumbra render` and measures rel. RMSE against `penumbra reference --lighting sh` (exact
visibility of the real mesh under the SH light `render` uses), over the whole image and over the
object's own pixels (the ground left out). Standard library only (no numpy): it reads the ZIP
EXR files the library writes and writes PNG error maps itself.

Per cell:
  truth     reference --lighting sh, N spp (default 1024), seed 1
  noise     the same at N/4 spp, seed 2: the truth's own noise is err(noise vs truth) / sqrt(5)
            (e^2 = s^2 (4/N + 1/N) for independent estimates)
  object    reference of the scene without the ground at 4 spp, --coverage: the object mask
  render    32 spheres (the default scene: overlap weights, ground occludes, exp calibrated);
            the switches: --no-shadows, overlap none, ground receiver, exp exact,
            16 / 64 / 128 spheres
  proxy     (unless --no-proxy) the scene whose mesh IS the union of the 32 fitted spheres
            (each sphere tessellated), with the same spheres as its proxy: the spheres are then
            an exact proxy, and what is left of render's error is the SH visibility model's
Spheres are fitted once per mesh and count with `penumbra fit-spheres -n N` (default settings,
the same as "spheres": {"fit": N}) into OUTDIR/spheres and used as files.

--self MODE writes "shadow": {"self": MODE} into every scene (transfer: the object's own mesh
ray traced per vertex, the default; spheres: its own spheres, the renderer before the transfer),
so that one binary measures both with --suffix. --quick renders only the default, --no-shadows and
ground receiver (no other switches, no other sphere counts).

--plain gives every object the constant albedo 0.7 instead of its texture (Spot's, and Bob's from
its material): the rasterizer samples a texture once per pixel, the reference box-filters it,
which shows as error along texture edges that is not visibility's.

Pose: each mesh is rotated 140 degrees about y as in examples/scenes/spot_city.json, scaled so
that its longest side is 1.7 units (Spot and Bob keep scale 1, as in the bundled scenes), centred
on the y axis and lifted so that its lowest point is at y = 0. The camera is spot_city's offset
from a target at 0.35 of the object's height. Map scale: chosen per map so that the unshadowed
ground is about 0.45 (rel. RMSE does not depend on it; the pictures do).

Per-pixel analysis on the object's pixels (default render): the truth's blocked fraction
b = (U - T) / U (U = render --no-shadows, which equals the reference's unoccluded irradiance to
1e-4), binned; per bin the share of pixels, the mean signed error (R - T) relative to the mean of
T, and the share of the squared error; the share of the squared error where R > T (too bright =
missing occlusion); and the captured shadow sum(U - R) / sum(U - T).

Writes OUTDIR/scenes, OUTDIR/img (EXR), OUTDIR/maps (PNG error maps: truth | render | signed
error, red = render too bright, blue = too dark, saturating at 30% of the object's mean),
OUTDIR/results.tsv and markdown tables on stdout. Existing images are reused (delete OUTDIR/img
to start over). --suffix S names the `render` images, maps and OUTDIR/resultsS.tsv with S, so that
a second run into the same OUTDIR with another binary (a candidate change of the renderer) reuses
the truths, masks and sphere fits and compares its renders with the same truths.
"""
import json
import math
import os
import struct
import subprocess
import sys
import zlib
from itertools import accumulate

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "..")
DATA = os.path.join(ROOT, "data")
MESHES = ["spot_triangulated", "bob_tri", "blub", "scorpion", "koala", "goathead"]
MAPS = ["city", "night", "courtyard", "interior", "forest", "sunset"]
COUNTS = [16, 32, 64, 128]
SIZE_TARGET = 1.7
SELF = None  # --self: the scenes' shadow.self, or None for the renderer's default
BINS = [0.05, 0.2, 0.4]  # upper edges of the truth's blocked-fraction bins; the last is open


# ---------------------------------------------------------------------------------------------
# Images: ZIP EXR in (as written by the library, or uncompressed), PNG out

def read_exr(path):
    """(width, height, channels, rows) of a scanline EXR with NONE/ZIPS/ZIP compression; rows
    is a list of per-channel float lists, channels in the file's (alphabetical) order."""
    with open(path, "rb") as f:
        data = f.read()
    if struct.unpack_from("<I", data, 0)[0] != 20000630:
        raise ValueError(path + ": not an EXR file")
    pos, chans, comp, win = 8, [], 0, None
    while data[pos] != 0:
        end = data.index(b"\0", pos)
        name = data[pos:end].decode()
        tend = data.index(b"\0", end + 1)
        size = struct.unpack_from("<i", data, tend + 1)[0]
        val = data[tend + 5:tend + 5 + size]
        if name == "channels":
            p = 0
            while val[p] != 0:
                e = val.index(b"\0", p)
                chans.append((val[p:e].decode(), struct.unpack_from("<i", val, e + 1)[0]))
                p = e + 17
        elif name == "compression":
            comp = val[0]
        elif name == "dataWindow":
            win = struct.unpack_from("<4i", val, 0)
        pos = tend + 5 + size
    pos += 1
    if comp not in (0, 2, 3):
        raise ValueError(path + ": compression %d not supported" % comp)
    w, h = win[2] - win[0] + 1, win[3] - win[1] + 1
    lines = 16 if comp == 3 else 1
    nchunks = (h + lines - 1) // lines
    offsets = struct.unpack_from("<%dQ" % nchunks, data, pos)
    bpp = sum(4 if t == 2 else 2 for _, t in chans)
    planes = [[0.0] * (w * h) for _ in chans]
    for off in offsets:
        y, size = struct.unpack_from("<ii", data, off)
        raw = data[off + 8:off + 8 + size]
        n = min(lines, win[3] + 1 - y)
        if size < n * w * bpp:
            t = bytes(accumulate(zlib.decompress(raw), lambda a, b: (a + b - 128) & 255))
            half = (len(t) + 1) // 2
            out = bytearray(len(t))
            out[0::2], out[1::2] = t[:half], t[half:]
            raw = bytes(out)
        p = 0
        for r in range(n):
            row = (y - win[1] + r) * w
            for c, (_, typ) in enumerate(chans):
                fmt, step = ("<%df" % w, 4) if typ == 2 else ("<%de" % w, 2)
                planes[c][row:row + w] = struct.unpack_from(fmt, raw, p)
                p += step * w
    return w, h, [c for c, _ in chans], planes


def rgb(path):
    """Per-pixel (r, g, b) lists of an EXR (a 1-channel image repeats its channel)."""
    w, h, names, planes = read_exr(path)
    if len(planes) == 1:
        return w, h, [planes[0]] * 3
    order = [names.index(c) for c in "RGB"]
    return w, h, [planes[i] for i in order]


def write_png(path, w, h, pixels):
    """8-bit RGB PNG from a row-major list of (r, g, b) in [0, 255]."""
    raw = bytearray()
    for y in range(h):
        raw.append(0)
        for r, g, b in pixels[y * w:(y + 1) * w]:
            raw += bytes((r, g, b))

    def chunk(tag, body):
        return (struct.pack(">I", len(body)) + tag + body +
                struct.pack(">I", zlib.crc32(tag + body) & 0xffffffff))
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
                + chunk(b"IDAT", zlib.compress(bytes(raw), 6)) + chunk(b"IEND", b""))


def srgb8(v):
    v = max(0.0, min(1.0, v))
    v = 12.92 * v if v <= 0.0031308 else 1.055 * v ** (1 / 2.4) - 0.055
    return int(v * 255 + 0.5)


# ---------------------------------------------------------------------------------------------
# Running penumbra

def parse_options(args, values, flags=()):
    """The options after the positional arguments: `--name VALUE` into a copy of `values` (its
    keys are the known names, its values the defaults), and each of `flags` (`--name`, no value)
    into the returned set. An unknown name or a missing value exits with the script's usage."""
    opts, seen, i = dict(values), set(), 0
    while i < len(args):
        if args[i] in flags:
            seen.add(args[i])
            i += 1
        elif args[i] in opts and i + 1 < len(args):
            opts[args[i]] = args[i + 1]
            i += 2
        else:
            sys.exit("unknown option or missing value: %s\n%s"
                     % (args[i], sys.modules["__main__"].__doc__))
    return opts, seen


def run(args):
    r = subprocess.run(["nice"] + args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    if r.returncode != 0:
        sys.exit("failed: %s\n%s" % (" ".join(args), r.stderr))
    return r.stdout


def compare(bin_, a, b, mask):
    j = json.loads(run([bin_, "compare", a, b, "--mask", mask]))
    return j["rel_rmse"], j["mask"]["rel_rmse"]


class Images:
    """The images of a run in OUTDIR/img, made once and reused: references with the given
    --lighting, and renders whose names carry the run's suffix (so that another binary's renders
    compare with the same truths). Two threads each."""

    def __init__(self, bin_, out, suffix, lighting):
        self.bin, self.out, self.suffix, self.lighting = bin_, out, suffix, lighting
        self.th = ["--threads", "2"]

    def img(self, name):
        return os.path.join(self.out, "img", name + ".exr")

    def ref(self, scene, name, n, seed, cov=None):
        if not os.path.exists(self.img(name)):
            run([self.bin, "reference", scene, "-o", self.img(name), "--spp", str(n), "--seed",
                 str(seed), "--lighting", self.lighting] + self.th +
                (["--coverage", cov] if cov else []))
        return self.img(name)

    def render(self, scene, name, flags=()):
        name += self.suffix
        if not os.path.exists(self.img(name)):
            run([self.bin, "render", scene, "-o", self.img(name), "-q"] + self.th + list(flags))
        return self.img(name)


def mesh_bounds(path):
    lo, hi = [math.inf] * 3, [-math.inf] * 3
    with open(path) as f:
        for line in f:
            if line.startswith("v "):
                p = [float(x) for x in line.split()[1:4]]
                lo = [min(a, b) for a, b in zip(lo, p)]
                hi = [max(a, b) for a, b in zip(hi, p)]
    return lo, hi


def pose_and_camera(mesh):
    """Pose (scale, translation) that stands the mesh on y = 0, centred on the y axis, and the
    camera (eye, target) with spot_city.json's offset."""
    lo, hi = mesh_bounds(os.path.join(DATA, "meshes", mesh + ".obj"))
    s = 1.0 if mesh in ("spot_triangulated", "bob_tri") else \
        SIZE_TARGET / max(b - a for a, b in zip(lo, hi))
    c = [(a + b) / 2 for a, b in zip(lo, hi)]
    th = math.radians(140)  # R_y: x' = x cos + z sin, z' = -x sin + z cos
    t = [-s * (c[0] * math.cos(th) + c[2] * math.sin(th)), -s * lo[1],
         -s * (-c[0] * math.sin(th) + c[2] * math.cos(th))]
    height = s * (hi[1] - lo[1])
    target = [0.0, 0.35 * height, 0.0]
    eye = [3.0, target[1] + 1.4, 3.3]
    return s, t, eye, target


def scene_json(path, size, mesh_path, spheres, pose, cam, env, scale, shadow=None, ground=True,
               background="envmap", albedo=None):
    """Writes a scene; albedo is a texture path, an [r, g, b] constant or None (the mesh's own
    material, else the default)."""
    s, t = pose
    eye, target = cam
    obj = {"mesh": mesh_path, "spheres": spheres,
           "pose": {"rotation_axis_angle_deg": [0, 140, 0], "translation": t, "scale": s}}
    if isinstance(albedo, str):
        obj["albedo_texture"] = albedo
    elif albedo:
        obj["albedo"] = albedo
    sc = {"camera": {"width": size, "height": size, "fov_y_deg": 35, "eye": eye,
                     "target": target, "up": [0, 1, 0]},
          "lighting": {"envmap": os.path.join(DATA, "envmaps", env + ".exr"), "scale": scale,
                       "rotation_y_deg": 0},
          "sh_bands": 4, "objects": [obj], "background": background}
    if SELF:
        shadow = dict(shadow or {}, self=SELF)
    if shadow:
        sc["shadow"] = shadow
    if ground:
        sc["ground"] = {"height": 0, "albedo": [0.8, 0.8, 0.8], "half_size": 4}
    with open(path, "w") as f:
        json.dump(sc, f, indent=1)
    return path


def sphere_union_obj(spheres_json, path, rings=16, segs=32):
    """An OBJ of the spheres' union: each sphere a separate UV sphere (the parts inside other
    spheres are hidden from the camera and from shadow rays alike)."""
    with open(spheres_json) as f:
        spheres = json.load(f)["spheres"]
    out, base = [], 1
    for sp in spheres:
        (cx, cy, cz), r = sp["center"], sp["radius"]
        for i in range(rings + 1):
            th = math.pi * i / rings
            for j in range(segs):
                ph = 2 * math.pi * j / segs
                out.append("v %.7g %.7g %.7g" % (cx + r * math.sin(th) * math.cos(ph),
                                                   cy + r * math.cos(th),
                                                   cz + r * math.sin(th) * math.sin(ph)))
        for i in range(rings):
            for j in range(segs):
                a, b = base + i * segs + j, base + i * segs + (j + 1) % segs
                c, d = a + segs, b + segs
                if i > 0:
                    out.append("f %d %d %d" % (a, b, c))
                if i < rings - 1:
                    out.append("f %d %d %d" % (b, d, c))
        base += (rings + 1) * segs
    with open(path, "w") as f:
        f.write("\n".join(out) + "\n")


# ---------------------------------------------------------------------------------------------
# Per-pixel analysis

def analyse(truth, render, unsh, mask, map_png=None):
    w, h, T = rgb(truth)
    _, _, R = rgb(render)
    _, _, U = rgb(unsh)
    _, _, M = rgb(mask)
    idx = [i for i in range(w * h) if M[0][i] > 0.5]
    lum = lambda P, i: (P[0][i] + P[1][i] + P[2][i]) / 3
    tmean = sum(lum(T, i) for i in idx) / max(1, len(idx))
    nb = len(BINS) + 1
    cnt, sig, sq = [0] * nb, [0.0] * nb, [0.0] * nb
    bright_sq = tot_sq = 0.0
    shadow_t = shadow_r = 0.0
    for i in idx:
        t, r, u = lum(T, i), lum(R, i), lum(U, i)
        b = (u - t) / u if u > 1e-6 else 0.0
        k = next((n for n, e in enumerate(BINS) if b < e), nb - 1)
        e2 = sum((R[c][i] - T[c][i]) ** 2 for c in range(3))
        cnt[k] += 1
        sig[k] += (r - t) / tmean
        sq[k] += e2
        tot_sq += e2
        if r > t:
            bright_sq += e2
        shadow_t += u - t
        shadow_r += u - r
    res = {"pixels": len(idx),
           "bins": [(cnt[k] / max(1, len(idx)), sig[k] / max(1, cnt[k]), sq[k] / max(tot_sq, 1e-30))
                    for k in range(nb)],
           "too_bright_share": bright_sq / max(tot_sq, 1e-30),
           "captured": shadow_r / shadow_t if shadow_t > 0 else float("nan")}
    if map_png:
        pix = [(0, 0, 0)] * (3 * w * h)
        for y in range(h):
            for x in range(w):
                i = y * w + x
                pix[y * 3 * w + x] = tuple(srgb8(T[c][i]) for c in range(3))
                pix[y * 3 * w + w + x] = tuple(srgb8(R[c][i]) for c in range(3))
                if M[0][i] > 0.5:
                    d = max(-1.0, min(1.0, (lum(R, i) - lum(T, i)) / (0.3 * tmean)))
                    v = int(255 * (1 - abs(d)))
                    col = (255, v, v) if d > 0 else (v, v, 255)
                else:
                    g = srgb8(lum(T, i)) // 3
                    col = (g, g, g)
                pix[y * 3 * w + 2 * w + x] = col
        write_png(map_png, 3 * w, h, pix)
    return res


# ---------------------------------------------------------------------------------------------

def main():
    args = sys.argv[1:]
    if len(args) < 2:
        sys.exit(__doc__)
    bin_, out = os.path.abspath(args[0]), os.path.abspath(args[1])
    global SELF
    opts, flags = parse_options(args[2:], {"--size": "160", "--spp": "1024",
                                           "--meshes": ",".join(MESHES),
                                           "--maps": ",".join(MAPS), "--suffix": "",
                                           "--self": ""},
                                ("--no-proxy", "--plain", "--quick"))
    SELF = opts["--self"] or None
    proxy, plain, quick = "--no-proxy" not in flags, "--plain" in flags, "--quick" in flags
    size, spp = int(opts["--size"]), int(opts["--spp"])
    meshes, maps = opts["--meshes"].split(","), opts["--maps"].split(",")
    suffix = opts["--suffix"]
    for d in ("scenes", "img", "maps", "spheres"):
        os.makedirs(os.path.join(out, d), exist_ok=True)
    images = Images(bin_, out, suffix, "sh")
    img, ref, render = images.img, images.ref, images.render

    # Map scales: the unshadowed ground under each map at ~0.45 (Spot's scene, black background).
    scales = {}
    for env in maps:
        pose = pose_and_camera("spot_triangulated")
        sc = scene_json(os.path.join(out, "scenes", "expo_%s.json" % env), 32,
                        os.path.join(DATA, "meshes", "spot_triangulated.obj"), {"fit": 16},
                        pose[:2], pose[2:], env, 1.0, background=[0, 0, 0])
        im = render(sc, "expo_" + env, ["--no-shadows"])
        _, _, P = rgb(im)
        vals = [sum(P[c][i] for c in range(3)) / 3 for i in range(len(P[0])) if P[0][i] > 0]
        scales[env] = float("%.3g" % (0.45 / (sum(vals) / len(vals))))

    rows = []
    tsv = open(os.path.join(out, "results%s.tsv" % suffix), "w")
    tsv.write("mesh\tmap\tkind\trel_image\trel_object\n")

    def row(m, e, kind, v):
        rows.append((m, e, kind, v))
        tsv.write("%s\t%s\t%s\t%.5f\t%.5f\n" % (m, e, kind, v[0], v[1]))
        tsv.flush()

    analysis = {}
    setup = {}
    for mesh in meshes:  # fits first, then the cells map by map (city, night, courtyard first)
        mpath = os.path.join(DATA, "meshes", mesh + ".obj")
        albedo = [0.7, 0.7, 0.7] if plain else os.path.join(DATA, "meshes", "spot_texture.png") \
            if mesh == "spot_triangulated" else None
        sph = {}
        for n in COUNTS:
            sph[n] = os.path.join(out, "spheres", "%s_%d.json" % (mesh, n))
            if not os.path.exists(sph[n]):
                run([bin_, "fit-spheres", mpath, "-n", str(n), "-o", sph[n]] + images.th)
        union = os.path.join(out, "spheres", "%s_union32.obj" % mesh)
        if proxy and not os.path.exists(union):
            sphere_union_obj(sph[32], union)
        setup[mesh] = (mpath, albedo, sph, union) + pose_and_camera(mesh)
    for env in maps:
        for mesh in meshes:
            mpath, albedo, sph, union, s, t, eye, target = setup[mesh]
            cell = "%s_%s" % (mesh, env)

            def sc(tag, spheres=sph[32], shadow=None, ground=True, mp=mpath, alb=albedo):
                return scene_json(os.path.join(out, "scenes", "%s_%s.json" % (cell, tag)), size,
                                  mp, spheres, (s, t), (eye, target), env, scales[env],
                                  shadow, ground, albedo=alb)
            base = sc("base")
            truth = ref(base, cell + "_truth", spp, 1)
            noise = ref(base, cell + "_noise", spp // 4, 2)
            objcov = os.path.join(out, "img", cell + "_object_mask.exr")
            ref(sc("noground", ground=False), cell + "_noground", 4, 3, objcov)
            nz = compare(bin_, noise, truth, objcov)
            row(mesh, env, "truth_noise", (nz[0] / math.sqrt(5), nz[1] / math.sqrt(5)))
            r32 = render(base, cell + "_render32")
            row(mesh, env, "render", compare(bin_, r32, truth, objcov))
            uns = render(base, cell + "_noshadows", ["--no-shadows"])
            row(mesh, env, "no_shadows", compare(bin_, uns, truth, objcov))
            for tag, shadow in (("overlap_none", {"overlap": "none"}),
                                ("ground_receiver", {"ground": "receiver"}),
                                ("exp_exact", {"exp": "exact"})):
                if quick and tag != "ground_receiver":
                    continue
                row(mesh, env, tag, compare(bin_, render(sc(tag, shadow=shadow), cell + "_" + tag),
                                            truth, objcov))
            for n in COUNTS:
                if n != 32 and not quick:
                    row(mesh, env, "spheres%d" % n,
                        compare(bin_, render(sc("n%d" % n, spheres=sph[n]),
                                             cell + "_render%d" % n), truth, objcov))
            analysis[(mesh, env)] = analyse(truth, r32, uns, objcov,
                                            os.path.join(out, "maps", cell + suffix + ".png"))
            a = analysis[(mesh, env)]
            tsv.write("%s\t%s\tanalysis\t%s\n" % (mesh, env, json.dumps(a)))
            if proxy:
                pb = sc("proxy", spheres=sph[32], mp=union, alb=None)
                ptruth = ref(pb, cell + "_proxy_truth", spp, 1)
                pcov = os.path.join(out, "img", cell + "_proxy_mask.exr")
                ref(sc("proxy_noground", ground=False, mp=union, alb=None),
                    cell + "_proxy_noground", 4, 3, pcov)
                row(mesh, env, "proxy_render",
                    compare(bin_, render(pb, cell + "_proxy_render"), ptruth, pcov))
                row(mesh, env, "proxy_no_shadows",
                    compare(bin_, render(pb, cell + "_proxy_noshadows", ["--no-shadows"]), ptruth,
                            pcov))
                row(mesh, env, "proxy_overlap_none",
                    compare(bin_, render(sc("proxy_none", spheres=sph[32], mp=union, alb=None,
                                            shadow={"overlap": "none"}),
                                         cell + "_proxy_overlap_none"), ptruth, pcov))
                pa = analyse(ptruth, img(cell + "_proxy_render" + suffix),
                             img(cell + "_proxy_noshadows" + suffix), pcov,
                             os.path.join(out, "maps", cell + "_proxy" + suffix + ".png"))
                analysis[(mesh, env, "proxy")] = pa
                tsv.write("%s\t%s\tproxy_analysis\t%s\n" % (mesh, env, json.dumps(pa)))
            print("done %s (%.3f / %.3f)" % (cell, *dict(((r[0], r[1], r[2]), r[3])
                                                          for r in rows)[(mesh, env, "render")]),
                  file=sys.stderr, flush=True)
    tsv.close()
    report(rows, analysis, meshes, maps, scales, spp, size, proxy, suffix)


def report(rows, analysis, meshes, maps, scales, spp, size, proxy, suffix):
    v = {(m, e, k): x for m, e, k, x in rows}
    print("Map scales: " + ", ".join("%s %g" % (e, scales[e]) for e in maps))
    print("\n## render%s (32 spheres) vs reference --lighting sh (%d spp, %dx%d): rel. RMSE, "
          "image / object\n" % (suffix, spp, size, size))
    print("| mesh | " + " | ".join(maps) + " | RMS over maps |")
    print("|---|" + "---|" * (len(maps) + 1))
    for m in meshes:
        cells = [v[(m, e, "render")] for e in maps]
        rms = [math.sqrt(sum(c[j] ** 2 for c in cells) / len(cells)) for j in (0, 1)]
        print("| %s | " % m + " | ".join("%.3f / %.3f" % c for c in cells) +
              " | %.3f / %.3f |" % tuple(rms))
    for kind, title in (("no_shadows", "--no-shadows (the whole shadow signal)"),
                        ("truth_noise", "the truth's own noise")):
        print("\n### %s, image / object\n" % title)
        print("| mesh | " + " | ".join(maps) + " |")
        print("|---|" + "---|" * len(maps))
        for m in meshes:
            print("| %s | " % m + " | ".join("%.3f / %.3f" % v[(m, e, kind)] for e in maps) + " |")
    kinds = ["render", "spheres16", "spheres64", "spheres128", "overlap_none", "ground_receiver",
             "exp_exact", "no_shadows"]
    if proxy:
        kinds += ["proxy_render", "proxy_overlap_none", "proxy_no_shadows"]
    print("\n## Switches: RMS over the maps of rel. RMSE, object pixels (image in brackets)\n")
    print("| mesh | " + " | ".join(kinds) + " |")
    print("|---|" + "---|" * len(kinds))
    for m in meshes:
        cells = []
        for k in kinds:
            xs = [v[(m, e, k)] for e in maps if (m, e, k) in v]
            if not xs:
                cells.append("-")
                continue
            cells.append("%.3f (%.3f)" % tuple(math.sqrt(sum(x[j] ** 2 for x in xs) / len(xs))
                                               for j in (1, 0)))
        print("| %s | " % m + " | ".join(cells) + " |")
    for tag, key in (("real mesh", ()), ("sphere-union mesh", ("proxy",))):
        if key and not proxy:
            continue
        print("\n## Where the object's error is (%s, mean over maps): by the truth's blocked "
              "fraction b, pixel share / mean signed error (rel. to the object's mean) / share of "
              "squared error\n" % tag)
        edges = ["b < %g" % BINS[0]] + ["%g-%g" % (a, b) for a, b in zip(BINS, BINS[1:])] + \
            ["b > %g" % BINS[-1]]
        print("| mesh | " + " | ".join(edges) + " | too-bright share of sq. error | captured "
              "shadow |")
        print("|---|" + "---|" * (len(edges) + 2))
        for m in meshes:
            an = [analysis[(m, e) + key] for e in maps]
            cells = []
            for k in range(len(edges)):
                cells.append("%.2f / %+.3f / %.2f" % tuple(sum(a["bins"][k][j] for a in an) /
                                                            len(an) for j in range(3)))
            print("| %s | " % m + " | ".join(cells) + " | %.2f | %.2f |" % (
                sum(a["too_bright_share"] for a in an) / len(an),
                sum(a["captured"] for a in an) / len(an)))


if __name__ == "__main__":
    main()
