"""ctypes view of libpenumbra.so: finding the library, the flat structs of penumbra/flat.h and the
few public structs (pen_image, pen_mesh, pen_spheres) the loaders use, and error handling.

The library is looked up, in order, at $PENUMBRA_LIB (the .so file or the folder holding it),
then in the repository's build/ folder next to this package (python/../build/libpenumbra.so).
"""

import ctypes
import os

c_float_p = ctypes.POINTER(ctypes.c_float)
c_uint32_p = ctypes.POINTER(ctypes.c_uint32)

LIB_NAME = "libpenumbra.so"


class PenumbraError(RuntimeError):
    """An error reported by the C library; the message is the library's one line (file, place,
    what is wrong)."""


# ---- Structs (field for field as in include/penumbra/*.h) --------------------------------------


# pen_flat_object and pen_mesh begin alike.
_GEOMETRY_FIELDS = [
    ("vertex_count", ctypes.c_int),
    ("triangle_count", ctypes.c_int),
    ("positions", c_float_p),
    ("indices", c_uint32_p),
    ("uv_count", ctypes.c_int),
    ("uvs", c_float_p),
    ("uv_indices", c_uint32_p),
]


class FlatObject(ctypes.Structure):
    _fields_ = _GEOMETRY_FIELDS + [
        ("texture_width", ctypes.c_int),
        ("texture_height", ctypes.c_int),
        ("texture", c_float_p),
        ("albedo", ctypes.c_float * 3),
        ("sphere_count", ctypes.c_int),
        ("spheres", c_float_p),
        ("pose", ctypes.c_float * 7),
        ("sphere_weights", c_float_p),
    ]


class FlatScene(ctypes.Structure):
    _fields_ = [
        ("width", ctypes.c_int),
        ("height", ctypes.c_int),
        ("fov_y_deg", ctypes.c_float),
        ("eye", ctypes.c_float * 3),
        ("target", ctypes.c_float * 3),
        ("up", ctypes.c_float * 3),
        ("sh_bands", ctypes.c_int),
        ("sh", c_float_p),
        ("epsilon", ctypes.c_float),
        ("exp_method", ctypes.c_int),
        ("ground_enabled", ctypes.c_int),
        ("ground_height", ctypes.c_float),
        ("ground_albedo", ctypes.c_float * 3),
        ("ground_half_size", ctypes.c_float),
        ("background_envmap", ctypes.c_int),
        ("background", ctypes.c_float * 3),
        ("envmap_width", ctypes.c_int),
        ("envmap_height", ctypes.c_int),
        ("envmap", c_float_p),
        ("envmap_rotation_y_deg", ctypes.c_float),
        ("envmap_scale", ctypes.c_float),
        ("shadows", ctypes.c_int),
        ("antialias", ctypes.c_int),
        ("object_count", ctypes.c_int),
        ("objects", ctypes.POINTER(FlatObject)),
        ("overlap", ctypes.c_int),
        ("ground_occlusion", ctypes.c_int),
    ]


class FlatObjectGrad(ctypes.Structure):
    _fields_ = [
        ("positions", c_float_p),
        ("texture", c_float_p),
        ("albedo", c_float_p),
        ("spheres", c_float_p),
        ("pose", c_float_p),
    ]


class FlatGrad(ctypes.Structure):
    _fields_ = [
        ("sh", c_float_p),
        ("ground_albedo", c_float_p),
        ("objects", ctypes.POINTER(FlatObjectGrad)),
    ]


class Image(ctypes.Structure):
    _fields_ = [
        ("width", ctypes.c_int),
        ("height", ctypes.c_int),
        ("channels", ctypes.c_int),
        ("data", c_float_p),
    ]


class Mesh(ctypes.Structure):
    _fields_ = _GEOMETRY_FIELDS + [
        ("normal_count", ctypes.c_int),
        ("normals", c_float_p),
        ("normal_indices", c_uint32_p),
        ("texture_path", ctypes.c_char_p),
    ]


class Spheres(ctypes.Structure):
    _fields_ = [("count", ctypes.c_int), ("data", c_float_p), ("weight", c_float_p)]


# ---- Loading ------------------------------------------------------------------------------------


def _candidates():
    env = os.environ.get("PENUMBRA_LIB")
    if env:
        yield os.path.join(env, LIB_NAME) if os.path.isdir(env) else env
        return
    here = os.path.dirname(os.path.abspath(__file__))
    yield os.path.join(here, "..", "..", "build", LIB_NAME)


def _declare(lib):
    P = ctypes.c_void_p
    I = ctypes.c_int
    F = ctypes.c_float
    S = ctypes.c_char_p
    sigs = {
        "pen_context_create": (P, []),
        "pen_context_destroy": (None, [P]),
        "pen_context_error": (S, [P]),
        "pen_context_set_threads": (None, [P, I]),
        "pen_version": (S, []),
        "pen_render_state_create": (I, [P, ctypes.POINTER(P)]),
        "pen_render_state_free": (None, [P]),
        "pen_flat_render_fwd": (I, [P, ctypes.POINTER(FlatScene), P, c_float_p]),
        "pen_flat_render_bwd": (
            I,
            [P, ctypes.POINTER(FlatScene), P, c_float_p, ctypes.POINTER(FlatGrad)],
        ),
        "pen_flat_scene_load": (I, [P, S, I, ctypes.POINTER(P)]),
        "pen_flat_loaded_scene": (ctypes.POINTER(FlatScene), [P]),
        "pen_flat_loaded_fit_request": (I, [P, I]),
        "pen_flat_loaded_free": (None, [P]),
        "pen_image_load_ex": (I, [P, S, ctypes.c_uint, ctypes.POINTER(Image)]),
        "pen_image_save": (I, [P, S, ctypes.POINTER(Image)]),
        "pen_image_free": (None, [ctypes.POINTER(Image)]),
        "pen_envmap_to_sh": (I, [P, ctypes.POINTER(Image), I, F, F, c_float_p]),
        "pen_mesh_load": (I, [P, S, ctypes.POINTER(Mesh)]),
        "pen_mesh_free": (None, [ctypes.POINTER(Mesh)]),
        "pen_spheres_load": (I, [P, S, ctypes.POINTER(Spheres)]),
        "pen_spheres_free": (None, [ctypes.POINTER(Spheres)]),
        "pen_spheres_fit": (I, [P, ctypes.POINTER(Mesh), I, P, ctypes.POINTER(Spheres), P]),
        "pen_spheres_overlap_weights": (I, [P, ctypes.POINTER(Spheres), c_float_p]),
        "pen_sh_exp_method_parse": (I, [S]),
    }
    for name, (res, args) in sigs.items():
        fn = getattr(lib, name)
        fn.restype = res
        fn.argtypes = args


_lib = None


def lib():
    """The loaded library (loaded on first use)."""
    global _lib
    if _lib is None:
        tried = []
        for path in _candidates():
            path = os.path.normpath(path)
            if os.path.exists(path):
                try:
                    handle = ctypes.CDLL(path)
                except OSError as e:
                    raise PenumbraError("cannot load %s: %s" % (path, e)) from None
                _declare(handle)
                _lib = handle
                break
            tried.append(path)
        else:
            raise PenumbraError(
                "libpenumbra.so not found (looked at %s); build it (make build) or set "
                "PENUMBRA_LIB to the library or its folder" % ", ".join(tried)
            )
    return _lib


class Context:
    """A pen_context for one call:
    `with Context(threads) as c: c.check(lib().pen_x(c.ptr, ...))`."""

    def __init__(self, threads=0):
        self.ptr = lib().pen_context_create()
        if not self.ptr:
            raise MemoryError("pen_context_create")
        lib().pen_context_set_threads(self.ptr, int(threads))

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        lib().pen_context_destroy(self.ptr)
        self.ptr = None

    def check(self, status, what=""):
        if status != 0:
            msg = lib().pen_context_error(self.ptr).decode("utf-8", "replace")
            raise PenumbraError((what + ": " if what else "") + msg)


def fptr(t):
    """float* to a contiguous float32 tensor's data (None for None)."""
    return None if t is None else ctypes.cast(t.data_ptr(), c_float_p)


def uptr(t):
    """uint32* to a contiguous int32 tensor's data (None for None)."""
    return None if t is None else ctypes.cast(t.data_ptr(), c_uint32_p)
