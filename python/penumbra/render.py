"""penumbra.render: the differentiable soft-shadow renderer as a torch.autograd.Function.

The forward calls pen_flat_renderer_fwd, the backward pen_flat_renderer_bwd
(include/penumbra/flat.h): this module only checks the tensors and hands their memory to the C
library. Differentiable inputs (float32 CPU tensors): SH lighting, ground albedo, disk lights, and per
object the vertex positions, texture or constant albedo, proxy spheres and pose. Not
differentiated, and refused when given as tensors that require a gradient: faces, texture
coordinates, camera, ground geometry, background and environment map (as in the C renderer).

The model and the defaults are the scene JSON's and `penumbra render`'s (docs/design.md sec.
1.15): the objects' own shadows and their shadows on the ground come from the ray-traced transfer
of their meshes ("transfer"), textures are averaged over the pixel's footprint. Under "transfer"
the pose, vertex, sphere and disk-light gradients are not exact (the transfer is constant in
them): a render whose inputs ask for one raises PenumbraError at once, naming the group. A pose or
shape optimiser renders gradient_model(scene, ["pose"]) instead, the rule `penumbra optimize`
follows.

A Renderer owns one C renderer (its render state and caches) across calls; render_scene without
one makes a fresh one per call. A backward needs the state of its own forward: a Renderer
remembers which forward its state holds, and when a later forward has replaced it (two renders
in one graph), the backward renders its scene again first, which gives the same state bit for bit
(the renderer is deterministic), so the gradients are right at the cost of one forward.
"""

import ctypes
import dataclasses
import math
import threading
from typing import List, Optional, Sequence

import torch
from torch.autograd.function import once_differentiable

from . import _lib
from ._lib import PenumbraError

EXP_METHODS = {"calibrated": 0, "default": 0, "paper": 1, "exact": 2}
OVERLAP_MODES = {"weights": 0, "none": 1}
GROUND_MODES = {"occludes": 0, "receiver": 1}
# The same names and values as the scene JSON and the C enums (pen_shadow_self,
# pen_shadow_ground_shadow, pen_texture_filter): the first of each is the default.
SELF_SHADOW_MODES = {"transfer": 0, "spheres": 1}
GROUND_SHADOW_MODES = {"transfer": 0, "spheres": 1}
TEXTURE_FILTERS = {"footprint": 0, "point": 1}
# Gradient groups (PEN_GRAD_* in render.h).
GRAD_GROUPS = {"lighting": 1, "albedo": 2, "spheres": 4, "pose": 8, "vertices": 16, "lights": 32}
# A disk light as a row of floats (PEN_LIGHT_FLOATS, include/penumbra/scene.h): direction (3),
# angular radius in degrees, irradiance (3); the layout of pen_flat_scene.lights and
# pen_flat_grad.lights, and of Scene.lights' rows.
LIGHT_FLOATS = 7


@dataclasses.dataclass
class Camera:
    """Pinhole camera (Y up); the image is height x width, row 0 at the top.

    fx, fy, cx, cy: calibrated intrinsics in pixels (pixel centres at +0.5, as in COLMAP); all 0:
    the field of view fov_y_deg with square pixels and the principal point at the centre."""

    width: int = 64
    height: int = 64
    fov_y_deg: float = 40.0
    eye: Sequence[float] = (0.0, 1.0, 3.0)
    target: Sequence[float] = (0.0, 0.5, 0.0)
    up: Sequence[float] = (0.0, 1.0, 0.0)
    fx: float = 0.0
    fy: float = 0.0
    cx: float = 0.0
    cy: float = 0.0


@dataclasses.dataclass
class Object:
    """One mesh with its albedo, proxy spheres and pose.

    vertices (V, 3) float32, object space; faces (F, 3) int32/int64 into vertices, counter-clockwise
    seen from outside; uvs (U, 2) float32 with v up and uv_faces (F, 3) into uvs (None: one uv per
    vertex, U == V); texture (H, W, 3) float32 linear RGB, row 0 at the top, or else albedo (3,);
    spheres (S, 4) float32, x y z r in object space; pose (7,) float32: rotation axis * angle in
    degrees, translation, uniform scale (p_world = R (scale p) + t). sphere_weights (S,) float32:
    the spheres' overlap weights (overlap_weights(); not differentiated); None: computed from the
    current spheres at every render, so give them (e.g. those load_scene returns, or
    overlap_weights() of the initial spheres) to hold them fixed while optimising the spheres.
    texture_filter: "footprint" (the texture averaged over the pixel's footprint, the default, as
    in the JSON) or "point" (one bilinear lookup at the pixel's uv, continuous in the geometry).
    """

    vertices: torch.Tensor
    faces: torch.Tensor
    uvs: Optional[torch.Tensor] = None
    uv_faces: Optional[torch.Tensor] = None
    texture: Optional[torch.Tensor] = None
    albedo: Optional[torch.Tensor] = None
    spheres: Optional[torch.Tensor] = None
    pose: Optional[torch.Tensor] = None
    sphere_weights: Optional[torch.Tensor] = None
    texture_filter: str = "footprint"


@dataclasses.dataclass
class Scene:
    """Everything pen_render draws. sh is (bands^2, 3) float32, coefficient i = l*l + l + m per
    row, one column per colour channel. background is an RGB triple or "envmap" (then envmap, an
    (H, W, 3) float32 equirectangular map, is drawn where nothing is hit, rotated and scaled).
    epsilon <= 0 takes the exponential model's; exp is "calibrated", "paper" or "exact"; overlap is
    "weights" (each sphere's log-visibility times its overlap weight) or "none" (the plain sum);
    ground_occlusion is "occludes" (the ground hides what lies below each object's horizon, as in
    the ray-traced reference) or "receiver" (it only receives shadows). lights is None or a
    (K, LIGHT_FLOATS = 7) float32 tensor of K <= 16 distant disk lights, one row each: the
    direction towards the light (3, any non-zero length), the angular radius in degrees and the
    irradiance (3) that an unoccluded surface facing it receives; load_scene fills it with the
    lights the scene gives or finds in its environment map. self_shadow is "transfer" (the default, as in the JSON: the
    objects' own shadows from their meshes, ray traced once per pose and cached: exact, but then
    only the lighting, albedo, texture and ground albedo have gradients; a render whose vertex,
    pose, sphere or light tensors require a gradient raises PenumbraError) or "spheres" (from
    their spheres: every gradient; gradient_model() picks it). With self_shadow "transfer",
    ground_shadow is "transfer" (those objects' ground shadows ray traced at a grid of ground_grid
    x ground_grid nodes, 0: 96) or "spheres". The texture lookup is each Object's
    texture_filter."""

    camera: Camera
    sh: torch.Tensor
    objects: List[Object] = dataclasses.field(default_factory=list)
    ground: bool = True
    ground_albedo: object = (0.8, 0.8, 0.8)
    ground_height: float = 0.0
    ground_half_size: float = 4.0
    background: object = (0.0, 0.0, 0.0)
    envmap: Optional[torch.Tensor] = None
    envmap_rotation_y_deg: float = 0.0
    envmap_scale: float = 1.0
    epsilon: float = 0.0
    exp: str = "calibrated"
    overlap: str = "weights"
    ground_occlusion: str = "occludes"
    lights: Optional[torch.Tensor] = None
    self_shadow: str = "transfer"
    ground_shadow: str = "transfer"
    ground_grid: int = 0


def pose(rotation_axis_angle_deg=(0.0, 0.0, 0.0), translation=(0.0, 0.0, 0.0), scale=1.0):
    """The (7,) float32 pose tensor of a rotation (axis * angle, degrees), translation, scale."""
    return torch.tensor(list(rotation_axis_angle_deg) + list(translation) + [scale],
                        dtype=torch.float32)


# ---- Argument checks ----------------------------------------------------------------------------


def _shape_text(shape):
    return "(" + ", ".join("N" if d is None else str(d) for d in shape) + ")"


def _float_tensor(name, x, shape, allow_list=False):
    """x as a float32 CPU tensor of the given shape (None = any size >= 1); lists are converted
    when allow_list, tensors must already be float32 on the CPU."""
    if not isinstance(x, torch.Tensor):
        if allow_list and isinstance(x, (list, tuple)):
            x = torch.tensor(x, dtype=torch.float32)
        else:
            raise TypeError("penumbra: %s must be a torch tensor, got %s"
                            % (name, type(x).__name__))
    if x.dtype != torch.float32:
        raise TypeError("penumbra: %s must be float32, got %s" % (name, x.dtype))
    if x.device.type != "cpu":
        raise ValueError("penumbra: %s must be a CPU tensor, got device %s" % (name, x.device))
    ok = x.dim() == len(shape) and all(
        (d is None and s >= 1) or s == d for s, d in zip(x.shape, shape))
    if not ok:
        raise ValueError("penumbra: %s must have shape %s, got %s"
                         % (name, _shape_text(shape), tuple(x.shape)))
    return x.contiguous()


def _index_tensor(name, x, rows, limit, limit_name):
    """An (rows, 3) integer tensor with values in [0, limit), as contiguous int32."""
    if not isinstance(x, torch.Tensor):
        raise TypeError("penumbra: %s must be a torch tensor, got %s" % (name, type(x).__name__))
    if x.dtype not in (torch.int32, torch.int64):
        raise TypeError("penumbra: %s must be int32 or int64, got %s" % (name, x.dtype))
    if x.device.type != "cpu":
        raise ValueError("penumbra: %s must be a CPU tensor, got device %s" % (name, x.device))
    if (x.dim() != 2 or x.shape[1] != 3 or x.shape[0] < 1
            or (rows is not None and x.shape[0] != rows)):
        want = "(%s, 3)" % ("F" if rows is None else rows)
        raise ValueError("penumbra: %s must have shape %s, got %s" % (name, want, tuple(x.shape)))
    lo, hi = int(x.min()), int(x.max())
    if lo < 0 or hi >= limit:
        raise ValueError("penumbra: %s: index %d out of range [0, %d) (%s)"
                         % (name, lo if lo < 0 else hi, limit, limit_name))
    return x.to(torch.int32).contiguous()


def _sh_bands(sh):
    bands = int(round(math.sqrt(sh.shape[0])))
    if bands * bands != sh.shape[0] or not 1 <= bands <= 8:
        raise ValueError("penumbra: sh must have bands^2 rows for 1 to 8 bands, got %d rows"
                         % sh.shape[0])
    return bands


class _ObjectSpec:
    """The non-differentiable part of one object: int32 faces, uvs, uv faces, sphere weights."""

    def __init__(self, faces, uvs, uv_faces, sphere_weights=None, texture_filter=0):
        self.faces, self.uvs, self.uv_faces = faces, uvs, uv_faces
        self.sphere_weights = sphere_weights
        self.texture_filter = texture_filter


def _plain(name, value):
    """A number or sequence that the renderer takes as a constant: a tensor that requires a
    gradient is refused (it would get none); other tensors are read as their values."""
    if isinstance(value, torch.Tensor):
        if value.requires_grad:
            raise ValueError("penumbra: %s has no gradient in the renderer; pass it without "
                             "requires_grad (e.g. %s.detach())" % (name, name))
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return type(value)(_plain("%s[%d]" % (name, i), v) for i, v in enumerate(value))
    return value


def _choice(name, value, table):
    """table[value], or ValueError naming the field and the accepted names."""
    if value not in table:
        raise ValueError("penumbra: %s must be one of %s; got %r"
                         % (name, ", ".join('"%s"' % k for k in table), value))
    return table[value]


class _Spec:
    """Everything of a scene that is not a differentiable input of the Function."""

    def __init__(self, scene, shadows, antialias, threads):
        cam = scene.camera
        if not isinstance(cam, Camera):
            raise TypeError("penumbra: scene.camera must be a penumbra.Camera, got %s"
                            % type(cam).__name__)
        cam = dataclasses.replace(cam, **{f.name: _plain("camera." + f.name,
                                                         getattr(cam, f.name))
                                          for f in dataclasses.fields(Camera)})
        for name in ("width", "height"):
            value = getattr(cam, name)
            if not isinstance(value, int) or not 1 <= value <= 16384:
                raise ValueError("penumbra: camera %s must be an integer in [1, 16384], got %r"
                                 % (name, value))
        for name in ("eye", "target", "up"):
            if len(getattr(cam, name)) != 3:
                raise ValueError("penumbra: camera %s must have 3 coordinates" % name)
        self.camera = cam
        self.ground = bool(scene.ground)
        self.ground_height = float(_plain("ground_height", scene.ground_height))
        self.ground_half_size = float(_plain("ground_half_size", scene.ground_half_size))
        self.epsilon = float(_plain("epsilon", scene.epsilon))
        self.exp = _choice("exp", scene.exp, EXP_METHODS)
        self.overlap = _choice("overlap", scene.overlap, OVERLAP_MODES)
        self.ground_occlusion = _choice("ground_occlusion", scene.ground_occlusion, GROUND_MODES)
        self.self_shadow = _choice("self_shadow", scene.self_shadow, SELF_SHADOW_MODES)
        self.ground_shadow = _choice("ground_shadow", scene.ground_shadow, GROUND_SHADOW_MODES)
        self.ground_grid = int(scene.ground_grid)
        self.envmap = None
        if scene.envmap is not None:
            if isinstance(scene.envmap, torch.Tensor) and scene.envmap.requires_grad:
                _plain("envmap", scene.envmap)
            self.envmap = _float_tensor("envmap", scene.envmap, (None, None, 3)).detach()
        if isinstance(scene.background, str):
            if scene.background != "envmap":
                raise ValueError("penumbra: background must be an RGB triple or \"envmap\"")
            if self.envmap is None:
                raise ValueError("penumbra: background \"envmap\" needs scene.envmap")
            self.background_envmap, self.background = 1, (0.0, 0.0, 0.0)
        else:
            bg = _float_tensor("background", _plain("background", scene.background), (3,),
                               allow_list=True)
            self.background_envmap, self.background = 0, tuple(float(v) for v in bg)
        self.envmap_rotation_y_deg = float(_plain("envmap_rotation_y_deg",
                                                  scene.envmap_rotation_y_deg))
        self.envmap_scale = float(_plain("envmap_scale", scene.envmap_scale))
        self.shadows, self.antialias = int(bool(shadows)), int(bool(antialias))
        self.threads = threads
        self.renderer = None
        self.objects = []
        self.wrt = 0  # PEN_GRAD_* bits of the inputs that require a gradient


# Per object, the differentiable inputs in this order (pen_flat_object_grad's fields).
_OBJ_FIELDS = ("vertices", "texture", "albedo", "spheres", "pose")


def _check_object(i, ob):
    """(_ObjectSpec, [vertices, texture, albedo, spheres, pose]) of a checked object."""
    p = "objects[%d]." % i
    v = _float_tensor(p + "vertices", ob.vertices, (None, 3))
    faces = _index_tensor(p + "faces", ob.faces, None, v.shape[0], "vertices")
    uvs = uv_faces = None
    if ob.uvs is not None:
        uvs = _float_tensor(p + "uvs", ob.uvs, (None, 2)).detach()
        if ob.uv_faces is not None:
            uv_faces = _index_tensor(p + "uv_faces", ob.uv_faces, faces.shape[0], uvs.shape[0],
                                     "uvs")
        elif uvs.shape[0] != v.shape[0]:
            raise ValueError("penumbra: %suvs: %d uvs for %d vertices; per-vertex uvs need one "
                             "per vertex, or give uv_faces" % (p, uvs.shape[0], v.shape[0]))
    elif ob.uv_faces is not None:
        raise ValueError("penumbra: %suv_faces given without uvs" % p)
    tex = None
    if ob.texture is not None:
        tex = _float_tensor(p + "texture", ob.texture, (None, None, 3))
        if uvs is None:
            raise ValueError("penumbra: %stexture needs uvs" % p)
    albedo = _float_tensor(p + "albedo", (0.8, 0.8, 0.8) if ob.albedo is None else ob.albedo,
                           (3,), allow_list=True)
    spheres = weights = None
    if ob.spheres is not None and (not isinstance(ob.spheres, torch.Tensor) or ob.spheres.numel()):
        spheres = _float_tensor(p + "spheres", ob.spheres, (None, 4))
        if ob.sphere_weights is not None:
            weights = _float_tensor(p + "sphere_weights", ob.sphere_weights, (spheres.shape[0],),
                                    allow_list=True).detach()
    elif ob.sphere_weights is not None:
        raise ValueError("penumbra: %ssphere_weights given without spheres" % p)
    ps = _float_tensor(p + "pose", pose() if ob.pose is None else ob.pose, (7,), allow_list=True)
    filt = _choice(p + "texture_filter", ob.texture_filter, TEXTURE_FILTERS)
    return _ObjectSpec(faces, uvs, uv_faces, weights, filt), [v, tex, albedo, spheres, ps]


# ---- The Function -------------------------------------------------------------------------------


class Renderer:
    """A C renderer (pen_flat_renderer) kept across calls: its render state and caches (per-pixel
    buffers, mesh adjacency, environment-map background, overlap weights of unchanged spheres)
    survive from one step to the next. Images and gradients are those of a fresh render, bit for
    bit. threads: the default thread count of its renders (0: all cores). Safe to share between
    Python threads (calls take turns). close() frees it now; otherwise it is freed with the last
    reference (graphs that still need its backward hold one).

        renderer = penumbra.Renderer()
        for step in range(200):
            loss = (renderer.render_scene(scene) - target).square().mean()
            ...
    """

    def __init__(self, threads=0):
        self.threads = int(threads)
        self._lock = threading.Lock()
        self._ctx = _lib.Context(self.threads)
        self._ptr = ctypes.c_void_p()
        self._last = None  # the token of the forward whose buffers the state holds
        self._ctx.check(_lib.lib().pen_flat_renderer_create(self._ctx.ptr,
                                                            ctypes.byref(self._ptr)))

    def render_scene(self, scene, shadows=True, antialias=True, threads=None):
        """render_scene() through this renderer."""
        return render_scene(scene, shadows=shadows, antialias=antialias, threads=threads,
                            renderer=self)

    def render(self, vertices, faces, sh, camera=None, **kwargs):
        """render() through this renderer."""
        return render(vertices, faces, sh, camera, renderer=self, **kwargs)

    def close(self):
        """Frees the C renderer; rendering or a backward through it afterwards is an error."""
        with self._lock:
            if self._ptr and _lib._lib is not None:
                _lib.lib().pen_flat_renderer_free(self._ptr)
            self._ptr = ctypes.c_void_p()
            if self._ctx.ptr and _lib._lib is not None:
                self._ctx.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __del__(self):
        if getattr(self, "_ctx", None) is not None:
            try:
                self.close()
            except Exception:  # interpreter shutdown: the modules may already be gone
                pass

    def _call(self, threads, fn, *args):
        if not self._ptr:
            raise PenumbraError("penumbra: the Renderer is closed")
        self._ctx.set_threads(threads)
        self._ctx.check(fn(self._ctx.ptr, self._ptr, *args))

    def _call_ctx(self, threads, fn, *args):
        """fn(context, *args), a call that takes no renderer."""
        if not self._ptr:
            raise PenumbraError("penumbra: the Renderer is closed")
        self._ctx.set_threads(threads)
        self._ctx.check(fn(self._ctx.ptr, *args))

    def _share(self, other):
        """Shares the ray-traced transfers with another Renderer's (pen_render_state_share):
        cameras of one scene then trace them once per pose."""
        L = _lib.lib()
        with self._lock:
            self._ctx.check(L.pen_render_state_share(self._ctx.ptr,
                                                     L.pen_flat_renderer_state(self._ptr),
                                                     L.pen_flat_renderer_state(other._ptr)))

    def aovs(self):
        """The object mask (H, W), view depth (H, W) and world normals (H, W, 3) of this
        renderer's last forward, sampled at the pixel centres (pen_render_state_aovs): mask 1
        where an object is visible, 0 for ground and background; depth along the camera's axis,
        0 for the background; unit normals facing the camera, 0 for the background. Float32
        tensors, not differentiable: what targets and loss weights are made from."""
        with self._lock:
            if not self._ptr or self._last is None:
                raise PenumbraError("penumbra: aovs() needs a render through this Renderer first")
            L = _lib.lib()
            st = L.pen_flat_renderer_state(self._ptr)
            out = {}
            imgs = []
            # The forward's size, from the G-buffer: ask for an allocated mask first.
            probe = _lib.Image()
            self._ctx.check(L.pen_render_state_aovs(self._ctx.ptr, st, ctypes.byref(probe), None,
                                                    None))
            h, w = probe.height, probe.width
            L.pen_image_free(ctypes.byref(probe))
            for name, ch in (("mask", 1), ("depth", 1), ("normals", 3)):
                t = torch.empty(h, w, ch, dtype=torch.float32)
                out[name] = t
                imgs.append(_lib.Image(w, h, ch, _lib.fptr(t)))
            self._ctx.check(L.pen_render_state_aovs(self._ctx.ptr, st, *(ctypes.byref(i)
                                                                           for i in imgs)))
            out["mask"], out["depth"] = out["mask"][..., 0], out["depth"][..., 0]
            return out

    def _forward(self, threads, flat, image, wrt=0):
        """Renders flat into image; returns the token its backward passes to _backward. wrt: the
        gradient groups the inputs will ask for, checked first against the model (the C
        refusal, pen_flat_grad_check, raised before anything is rendered)."""
        with self._lock:
            if wrt:
                self._call_ctx(threads, _lib.lib().pen_flat_grad_check, ctypes.byref(flat), wrt)
            self._last = None
            self._call(threads, _lib.lib().pen_flat_renderer_fwd, ctypes.byref(flat),
                       _lib.fptr(image))
            self._last = object()
            return self._last

    def _backward(self, token, threads, flat, d_image, grad):
        with self._lock:
            if self._last is not token:  # a later forward replaced this one's state
                image = torch.empty(flat.height, flat.width, 3, dtype=torch.float32)
                self._last = None
                self._call(threads, _lib.lib().pen_flat_renderer_fwd, ctypes.byref(flat),
                           _lib.fptr(image))
                self._last = token
            self._call(threads, _lib.lib().pen_flat_renderer_bwd, ctypes.byref(flat),
                       _lib.fptr(d_image), ctypes.byref(grad))


def _flat(spec, sh, ground_albedo, lights, obj):
    """The pen_flat_scene over the tensors' memory (the tensors must outlive its use)."""
    s = _lib.FlatScene()
    if lights is not None:
        s.light_count, s.lights = lights.shape[0], _lib.fptr(lights)
    cam = spec.camera
    s.width, s.height, s.fov_y_deg = int(cam.width), int(cam.height), float(cam.fov_y_deg)
    s.eye[:], s.target[:], s.up[:] = (tuple(float(x) for x in v)
                                      for v in (cam.eye, cam.target, cam.up))
    s.fx, s.fy, s.cx, s.cy = (float(v) for v in (cam.fx, cam.fy, cam.cx, cam.cy))
    s.sh_bands = _sh_bands(sh)
    s.sh = _lib.fptr(sh)
    s.epsilon, s.exp_method = spec.epsilon, spec.exp
    s.ground_enabled = int(spec.ground)
    s.ground_height, s.ground_half_size = spec.ground_height, spec.ground_half_size
    s.ground_albedo[:] = tuple(float(x) for x in ground_albedo)
    s.background_envmap, s.background[:] = spec.background_envmap, spec.background
    if spec.envmap is not None:
        s.envmap_height, s.envmap_width = spec.envmap.shape[0], spec.envmap.shape[1]
        s.envmap = _lib.fptr(spec.envmap)
    s.envmap_rotation_y_deg, s.envmap_scale = spec.envmap_rotation_y_deg, spec.envmap_scale
    s.shadows, s.antialias = spec.shadows, spec.antialias
    s.overlap = spec.overlap
    s.ground_occlusion = spec.ground_occlusion
    s.self_shadow = spec.self_shadow
    s.ground_shadow, s.ground_grid = spec.ground_shadow, spec.ground_grid
    n = len(spec.objects)
    objs = (_lib.FlatObject * max(n, 1))()
    for i, os_ in enumerate(spec.objects):
        v, tex, albedo, spheres, ps = obj[5 * i:5 * i + 5]
        o = objs[i]
        o.vertex_count, o.triangle_count = v.shape[0], os_.faces.shape[0]
        o.positions, o.indices = _lib.fptr(v), _lib.uptr(os_.faces)
        if os_.uvs is not None:
            o.uv_count, o.uvs = os_.uvs.shape[0], _lib.fptr(os_.uvs)
            o.uv_indices = _lib.uptr(os_.uv_faces)
        if tex is not None:
            o.texture_height, o.texture_width = tex.shape[0], tex.shape[1]
            o.texture = _lib.fptr(tex)
        o.albedo[:] = tuple(float(x) for x in albedo)
        if spheres is not None:
            o.sphere_count, o.spheres = spheres.shape[0], _lib.fptr(spheres)
            o.sphere_weights = _lib.fptr(os_.sphere_weights)
        o.pose[:] = tuple(float(x) for x in ps)
        o.texture_filter = os_.texture_filter
    s.object_count = n
    s.objects = objs
    return s


def _wanted_groups(sh, ground_albedo, lights, obj):
    """The PEN_GRAD_* bits of the inputs that require a gradient."""
    def req(t):
        return t is not None and t.requires_grad
    g = GRAD_GROUPS
    wrt = (g["lighting"] if req(sh) else 0) | (g["albedo"] if req(ground_albedo) else 0)
    wrt |= g["lights"] if req(lights) else 0
    for i in range(0, len(obj), 5):
        v, tex, albedo, spheres, ps = obj[i:i + 5]
        wrt |= (g["vertices"] if req(v) else 0) | (g["spheres"] if req(spheres) else 0)
        wrt |= (g["albedo"] if req(tex) or req(albedo) else 0) | (g["pose"] if req(ps) else 0)
    return wrt


def gradient_model(scene, groups):
    """The scene in the model in which the gradients of `groups` (names of GRAD_GROUPS:
    "lighting", "albedo", "spheres", "pose", "vertices", "lights") are exact: a copy with
    self_shadow and ground_shadow "spheres" for pose, vertices, spheres or lights, and textured
    objects' texture_filter "point" for pose or vertices; the rule `penumbra optimize` follows
    (pen_render_grad_model). The tensors are shared, not copied.

        scene = penumbra.gradient_model(penumbra.load_scene("scene.json"), ["pose"])
    """
    if not isinstance(scene, Scene):
        raise TypeError("penumbra: gradient_model takes a penumbra.Scene, got %s"
                        % type(scene).__name__)
    if isinstance(groups, str):
        groups = [groups]
    wrt = 0
    for name in groups:
        wrt |= _choice("gradient group", name, GRAD_GROUPS)
    f = _lib.FlatScene()
    f.self_shadow = _choice("self_shadow", scene.self_shadow, SELF_SHADOW_MODES)
    f.ground_shadow = _choice("ground_shadow", scene.ground_shadow, GROUND_SHADOW_MODES)
    n = len(scene.objects)
    objs = (_lib.FlatObject * max(n, 1))()
    texels = ctypes.c_float(0.0)  # stands for a texture: the rule only asks whether there is one
    for i, ob in enumerate(scene.objects):
        objs[i].texture_filter = _choice("objects[%d].texture_filter" % i, ob.texture_filter,
                                         TEXTURE_FILTERS)
        if ob.texture is not None:
            objs[i].texture = ctypes.pointer(texels)
    f.object_count, f.objects = n, objs
    _lib.lib().pen_flat_grad_model(ctypes.byref(f), objs, wrt)
    names = {v: k for k, v in SELF_SHADOW_MODES.items()}
    filters = {v: k for k, v in TEXTURE_FILTERS.items()}
    objects = [dataclasses.replace(ob, texture_filter=filters[objs[i].texture_filter])
               for i, ob in enumerate(scene.objects)]
    return dataclasses.replace(scene, self_shadow=names[f.self_shadow],
                               ground_shadow=names[f.ground_shadow], objects=objects)


class RenderFunction(torch.autograd.Function):
    """apply(spec, sh, ground_albedo, lights, *per-object (vertices, texture, albedo, spheres,
    pose)); lights may be None;
    use render() or render_scene(), which check the arguments and build spec. The backward is
    the C backward, itself not differentiable (once_differentiable)."""

    @staticmethod
    def forward(ctx, spec, sh, ground_albedo, lights, *obj):
        renderer = spec.renderer if spec.renderer is not None else Renderer(spec.threads)
        flat = _flat(spec, sh, ground_albedo, lights, obj)
        image = torch.empty(flat.height, flat.width, 3, dtype=torch.float32)
        ctx.token = renderer._forward(spec.threads, flat, image, spec.wrt)
        ctx.spec, ctx.renderer = spec, renderer
        ctx.save_for_backward(sh, ground_albedo, lights, *obj)
        return image

    @staticmethod
    @once_differentiable
    def backward(ctx, d_image):
        spec, need = ctx.spec, ctx.needs_input_grad
        sh, ground_albedo, lights, *obj = ctx.saved_tensors
        flat = _flat(spec, sh, ground_albedo, lights, obj)
        d_image = d_image.to(torch.float32).contiguous()

        def zeros_if(k, t):
            return torch.zeros_like(t) if need[k] and t is not None else None

        d_sh, d_ground, d_lights = zeros_if(1, sh), zeros_if(2, ground_albedo), zeros_if(3, lights)
        d_obj = [zeros_if(4 + k, t) for k, t in enumerate(obj)]
        grads = (_lib.FlatObjectGrad * max(len(spec.objects), 1))()
        for i in range(len(spec.objects)):
            for name, t in zip(("positions",) + _OBJ_FIELDS[1:], d_obj[5 * i:5 * i + 5]):
                setattr(grads[i], name, _lib.fptr(t))
        g = _lib.FlatGrad(_lib.fptr(d_sh), _lib.fptr(d_ground), grads, _lib.fptr(d_lights))
        ctx.renderer._backward(ctx.token, spec.threads, flat, d_image, g)
        return (None, d_sh, d_ground, d_lights, *d_obj)


def render_scene(scene, shadows=True, antialias=True, threads=None, renderer=None):
    """Renders a Scene; returns the (height, width, 3) float32 linear RGB image, differentiable in
    scene.sh, scene.ground_albedo, scene.lights and each object's vertices, texture, albedo,
    spheres and pose
    (whichever are tensors with requires_grad). renderer: a Renderer to render through (its state
    and caches kept for the next call); None: a fresh one for this call. threads: None takes the
    renderer's (0 without one: all cores)."""
    if not isinstance(scene, Scene):
        raise TypeError("penumbra: render_scene takes a penumbra.Scene, got %s"
                        % type(scene).__name__)
    if renderer is not None and not isinstance(renderer, Renderer):
        raise TypeError("penumbra: renderer must be a penumbra.Renderer, got %s"
                        % type(renderer).__name__)
    if threads is None:
        threads = renderer.threads if renderer is not None else 0
    spec = _Spec(scene, shadows, antialias, int(threads))
    spec.renderer = renderer
    sh = _float_tensor("sh", scene.sh, (None, 3))
    _sh_bands(sh)
    ground_albedo = _float_tensor("ground_albedo", scene.ground_albedo, (3,), allow_list=True)
    lights, row = None, LIGHT_FLOATS
    if scene.lights is not None and not (isinstance(scene.lights, torch.Tensor)
                                         and tuple(scene.lights.shape) == (0, row)):
        lights = _float_tensor("lights", scene.lights, (None, row))
        if lights.shape[0] > 16:
            raise ValueError("penumbra: at most 16 lights, got %d" % lights.shape[0])
    tensors = []
    for i, ob in enumerate(scene.objects):
        os_, ts = _check_object(i, ob)
        spec.objects.append(os_)
        tensors += ts
    # The groups whose tensors will ask for a gradient (grad mode is off inside the Function's
    # forward, so it is read here), refused at once when the model has no exact gradient of them.
    if torch.is_grad_enabled():
        spec.wrt = _wanted_groups(sh, ground_albedo, lights, tensors)
    return RenderFunction.apply(spec, sh, ground_albedo, lights, *tensors)


def render_aovs(scene, shadows=True, antialias=True, threads=None):
    """Renders a Scene without gradients and returns a dict of its image (H, W, 3) and, for the
    same frame, the object mask (H, W), view depth (H, W) and world normals (H, W, 3)
    (Renderer.aovs; `penumbra render --mask --depth --normals` writes the same)."""
    with Renderer(0 if threads is None else threads) as r, torch.no_grad():
        image = r.render_scene(scene, shadows=shadows, antialias=antialias, threads=threads)
        out = r.aovs()
    out["image"] = image
    return out


def render(vertices, faces, sh, camera=None, *, uvs=None, uv_faces=None, texture=None,
           albedo=None, spheres=None, pose=None, ground=True, ground_albedo=(0.8, 0.8, 0.8),
           ground_height=0.0, ground_half_size=4.0, background=(0.0, 0.0, 0.0), envmap=None,
           envmap_rotation_y_deg=0.0, envmap_scale=1.0, epsilon=0.0, exp="calibrated",
           shadows=True, antialias=True, threads=None, sphere_weights=None, overlap="weights",
           ground_occlusion="occludes", renderer=None, self_shadow="transfer",
           texture_filter="footprint"):
    """Renders one object (see Object and Scene for the arguments, whose defaults these are);
    returns the (height, width, 3) float32 image. camera: a Camera (None: the default 64 x 64
    one). threads, renderer: as render_scene."""
    scene = Scene(camera=camera or Camera(), sh=sh,
                  objects=[Object(vertices, faces, uvs, uv_faces, texture, albedo, spheres, pose,
                                  sphere_weights, texture_filter)],
                  ground=ground, ground_albedo=ground_albedo, ground_height=ground_height,
                  ground_half_size=ground_half_size, background=background, envmap=envmap,
                  envmap_rotation_y_deg=envmap_rotation_y_deg, envmap_scale=envmap_scale,
                  epsilon=epsilon, exp=exp, overlap=overlap, ground_occlusion=ground_occlusion,
                  self_shadow=self_shadow)
    return render_scene(scene, shadows=shadows, antialias=antialias, threads=threads,
                        renderer=renderer)


__all__ = ["Camera", "Object", "Renderer", "Scene", "pose", "render", "render_aovs",
           "render_scene", "gradient_model", "RenderFunction", "PenumbraError", "GRAD_GROUPS"]
