"""Loading helpers over the C library's readers: scene JSON, meshes (OBJ, PLY), images (PNG, HDR,
EXR), sphere sets, and the SH projection of an environment map. Everything is returned as new
float32 / int64 CPU tensors that own their memory."""

import ctypes
import dataclasses
import os
from typing import Optional

import numpy as np
import torch

from . import _lib
from .render import LIGHT_FLOATS, Camera, Object, Scene


def _copy(ptr, shape):
    """A float32 tensor copied from the C floats at ptr (zeros for a NULL pointer)."""
    n = int(np.prod(shape))
    if n == 0 or not ptr:
        return torch.zeros(shape, dtype=torch.float32)
    arr = np.ctypeslib.as_array(ptr, shape=(n,)).astype(np.float32, copy=True)
    return torch.from_numpy(arr.reshape(shape))


def _indices(ptr, rows):
    """(rows, 3) int64 from uint32 indices (torch has no uint32)."""
    n = 3 * rows
    if n == 0 or not ptr:
        return torch.zeros(rows, 3, dtype=torch.int64)
    arr = np.ctypeslib.as_array(ptr, shape=(n,)).astype(np.int64)
    return torch.from_numpy(arr.reshape(rows, 3))


def _path(path):
    return os.fsencode(os.fspath(path))


# ---- Scenes -------------------------------------------------------------------------------------


def load_scene(path, fit_spheres=True, threads=0):
    """Loads a scene JSON (docs/file-formats.md) into a Scene of tensors, made ready as `penumbra
    render` makes it (pen_scene_prepare), so that render_scene() gives its image: the lighting is
    the map's SH projection (or the "sh" given) with the lights given or found in the map, objects
    keep their texture (or constant albedo), texture filter, spheres with their overlap weights
    and pose, and the shadow model keys are kept. With fit_spheres, objects whose spheres are
    {"fit": N} get the fitted set (cached in $XDG_CACHE_HOME/penumbra, shared with the CLI; the
    same fit on any thread count); otherwise they have none (spheres None: render them without
    shadows). threads: the fit's threads (0: all cores, as the CLI)."""
    L = _lib.lib()
    with _lib.Context(threads) as c:
        handle = ctypes.c_void_p()
        c.check(L.pen_flat_scene_load(c.ptr, _path(path), int(bool(fit_spheres)),
                                      ctypes.byref(handle)))
        try:
            return _scene_from_flat(L.pen_flat_loaded_scene(handle).contents)
        finally:
            L.pen_flat_loaded_free(handle)


def _scene_from_flat(f):
    camera = Camera(f.width, f.height, f.fov_y_deg, tuple(f.eye), tuple(f.target), tuple(f.up),
                    f.fx, f.fy, f.cx, f.cy)
    objects = []
    for i in range(f.object_count):
        o = f.objects[i]
        ob = Object(vertices=_copy(o.positions, (o.vertex_count, 3)),
                    faces=_indices(o.indices, o.triangle_count),
                    albedo=torch.tensor(list(o.albedo), dtype=torch.float32),
                    pose=torch.tensor(list(o.pose), dtype=torch.float32))
        if o.uv_count > 0:
            ob.uvs = _copy(o.uvs, (o.uv_count, 2))
            ob.uv_faces = _indices(o.uv_indices, o.triangle_count)
        if o.texture_width > 0:
            ob.texture = _copy(o.texture, (o.texture_height, o.texture_width, 3))
        if o.sphere_count > 0:
            ob.spheres = _copy(o.spheres, (o.sphere_count, 4))
            if o.sphere_weights:
                ob.sphere_weights = _copy(o.sphere_weights, (o.sphere_count,))
        ob.texture_filter = {0: "footprint", 1: "point"}[o.texture_filter]
        objects.append(ob)
    envmap = None
    if f.envmap_width > 0:
        envmap = _copy(f.envmap, (f.envmap_height, f.envmap_width, 3))
    exp = {0: "calibrated", 1: "paper", 2: "exact"}[f.exp_method]
    return Scene(camera=camera, sh=_copy(f.sh, (f.sh_bands * f.sh_bands, 3)), objects=objects,
                 ground=bool(f.ground_enabled),
                 ground_albedo=torch.tensor(list(f.ground_albedo), dtype=torch.float32),
                 ground_height=f.ground_height, ground_half_size=f.ground_half_size,
                 background="envmap" if f.background_envmap else tuple(f.background),
                 envmap=envmap, envmap_rotation_y_deg=f.envmap_rotation_y_deg,
                 envmap_scale=f.envmap_scale, epsilon=f.epsilon, exp=exp,
                 overlap={0: "weights", 1: "none"}[f.overlap],
                 ground_occlusion={0: "occludes", 1: "receiver"}[f.ground_occlusion],
                 lights=(_copy(f.lights, (f.light_count, LIGHT_FLOATS))
                         if f.light_count > 0 else None),
                 self_shadow={0: "transfer", 1: "spheres"}[f.self_shadow],
                 ground_shadow={0: "transfer", 1: "spheres"}[f.ground_shadow],
                 ground_grid=f.ground_grid)


# ---- Meshes, images, spheres --------------------------------------------------------------------


@dataclasses.dataclass
class Mesh:
    """A loaded mesh: vertices (V, 3) float32, faces (F, 3) int64; uvs (U, 2) and uv_faces
    (F, 3) when the file has texture coordinates; texture_path from an OBJ's material, if any."""

    vertices: torch.Tensor
    faces: torch.Tensor
    uvs: Optional[torch.Tensor] = None
    uv_faces: Optional[torch.Tensor] = None
    texture_path: Optional[str] = None


def _owned(kind, free, make, read, threads=0):
    """Fills a new C struct of type `kind` with make(ctx, out) (a pen_* call returning a status;
    its failure raises PenumbraError), returns read(struct) and frees the struct with free."""
    out = kind()
    with _lib.Context(threads) as c:
        c.check(make(c.ptr, ctypes.byref(out)))
        try:
            return read(out)
        finally:
            free(ctypes.byref(out))


def _mesh_from_c(m):
    out = Mesh(_copy(m.positions, (m.vertex_count, 3)), _indices(m.indices, m.triangle_count))
    if m.uv_count > 0:
        out.uvs = _copy(m.uvs, (m.uv_count, 2))
        out.uv_faces = _indices(m.uv_indices, m.triangle_count)
    if m.texture_path:
        out.texture_path = os.fsdecode(m.texture_path)
    return out


def load_mesh(path):
    """Loads an OBJ or PLY mesh (polygons triangulated as fans)."""
    L = _lib.lib()
    return _owned(_lib.Mesh, L.pen_mesh_free,
                  lambda c, out: L.pen_mesh_load(c, _path(path), out), _mesh_from_c)


def _c_mesh(vertices, faces):
    """A pen_mesh borrowing the tensors (returned with the tensors that keep it alive)."""
    v = vertices.detach().to("cpu", torch.float32).contiguous()
    f = faces.detach().to("cpu", torch.int32).contiguous()
    m = _lib.Mesh()
    m.vertex_count, m.triangle_count = v.shape[0], f.shape[0]
    m.positions, m.indices = _lib.fptr(v), _lib.uptr(f)
    return m, (v, f)


def load_image(path, raw=False):
    """Loads PNG (decoded from sRGB to linear unless raw), HDR or EXR as an (H, W, 3) tensor."""
    L = _lib.lib()
    return _owned(_lib.Image, L.pen_image_free,
                  lambda c, out: L.pen_image_load_ex(c, _path(path), 1 if raw else 0, out),
                  lambda img: _copy(img.data, (img.height, img.width, img.channels)))


def _c_image(image):
    t = image.detach().to("cpu", torch.float32).contiguous()
    if t.dim() != 3 or not 1 <= t.shape[2] <= 4:
        raise ValueError("penumbra: an image must have shape (H, W, C) with C in 1..4, got %s"
                         % (tuple(t.shape),))
    return _lib.Image(t.shape[1], t.shape[0], t.shape[2], _lib.fptr(t)), t


def save_image(path, image):
    """Saves an (H, W, C) tensor by extension: .png (clamped, sRGB 8-bit), .hdr, .exr (linear);
    atomically (no partial file on failure)."""
    img, keep = _c_image(image)  # keep: the tensor behind the borrowed pen_image
    with _lib.Context() as c:
        c.check(_lib.lib().pen_image_save(c.ptr, _path(path), ctypes.byref(img)))


def envmap_to_sh(envmap, bands=4, rotation_y_deg=0.0, scale=1.0):
    """SH projection (bands^2, 3) of an equirectangular map (a path or an (H, W, 3) tensor),
    rotated about +Y and scaled as in the scene JSON's lighting."""
    if not isinstance(envmap, torch.Tensor):
        envmap = load_image(envmap)
    img, keep = _c_image(envmap)  # keep: the tensor behind the borrowed pen_image
    if not 1 <= int(bands) <= 8:
        raise ValueError("penumbra: bands must be in 1..8, got %r" % (bands,))
    sh = torch.zeros(int(bands) * int(bands), 3, dtype=torch.float32)
    with _lib.Context() as c:
        c.check(_lib.lib().pen_envmap_to_sh(c.ptr, ctypes.byref(img), int(bands),
                                            float(rotation_y_deg), float(scale), _lib.fptr(sh)))
    return sh


def overlap_weights(spheres):
    """The overlap weights of an (S, 4) sphere set (pen_spheres_overlap_weights): an (S,) float32
    tensor, deterministic, that Object.sphere_weights takes. Not differentiable."""
    # Copied to the CPU (C reads the pointer), float64 input accepted.
    if isinstance(spheres, torch.Tensor):
        s = spheres.detach().to("cpu", torch.float32).contiguous()
    else:
        s = torch.tensor(spheres, dtype=torch.float32)
    if s.dim() != 2 or s.shape[1] != 4:
        raise ValueError("penumbra: spheres must have shape (N, 4), got %s" % (tuple(s.shape),))
    out = torch.zeros(s.shape[0], dtype=torch.float32)
    c = _lib.Spheres(int(s.shape[0]), _lib.fptr(s), None)
    with _lib.Context() as ctx:
        ctx.check(_lib.lib().pen_spheres_overlap_weights(ctx.ptr, ctypes.byref(c), _lib.fptr(out)))
    return out


def load_spheres(path):
    """Loads a sphere set JSON as an (S, 4) tensor: x, y, z, r per sphere (overlap_weights()
    gives their weights; a file's own "weight" entries are what load_scene uses)."""
    L = _lib.lib()
    return _owned(_lib.Spheres, L.pen_spheres_free,
                  lambda c, out: L.pen_spheres_load(c, _path(path), out),
                  lambda s: _copy(s.data, (s.count, 4)))


def fit_spheres(vertices, faces, count, threads=0):
    """Fits `count` proxy spheres to a closed mesh (pen_spheres_fit, default settings); returns
    a (count, 4) tensor. Not cached: use load_scene with {"fit": N} for the cached fit."""
    m, keep = _c_mesh(vertices, faces)  # keep: the tensors behind the borrowed pen_mesh
    L = _lib.lib()
    return _owned(_lib.Spheres, L.pen_spheres_free,
                  lambda c, out: L.pen_spheres_fit(c, ctypes.byref(m), int(count), None, out, None),
                  lambda s: _copy(s.data, (s.count, 4)), threads)
