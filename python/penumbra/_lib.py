"""ctypes view of libpenumbra.so: finding the library, the flat structs of penumbra/flat.h and the
few public structs (pen_image, pen_mesh, pen_spheres) the loaders use, the check of those mirrors
against the library's own layout, and error handling.

The library is looked up, in order: beside this file (penumbra/libpenumbra.so, the copy a wheel
carries: `pip install .` builds it into the package, setup.py; the package and its library come
as one, so nothing overrides it), at penumbra._libpath.LIBRARY when that module exists (an
installed package: `cmake --install` writes it with the installed library's absolute path), at
$PENUMBRA_LIB (the .so file or the folder holding it), then in the repository's build/ folder next
to this package (python/../build/libpenumbra.so). When it is loaded, the layout table the library
reports (pen_flat_abi) is compared with the ctypes structs below, and a library that differs is
refused with the struct and field named: a mismatch would otherwise corrupt memory silently.
"""

import ctypes
import os

c_float_p = ctypes.POINTER(ctypes.c_float)
c_uint32_p = ctypes.POINTER(ctypes.c_uint32)

LIB_NAME = "libpenumbra.so"


class PenumbraError(RuntimeError):
    """An error reported by the C library; the message is the library's one line (file, place,
    what is wrong)."""


class LibraryNotFound(PenumbraError):
    """No libpenumbra.so where the package looks (the message lists the places)."""


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
        ("texture_filter", ctypes.c_int),
    ]


class FlatScene(ctypes.Structure):
    _fields_ = [
        ("width", ctypes.c_int),
        ("height", ctypes.c_int),
        ("fov_y_deg", ctypes.c_float),
        ("eye", ctypes.c_float * 3),
        ("target", ctypes.c_float * 3),
        ("up", ctypes.c_float * 3),
        ("fx", ctypes.c_float),
        ("fy", ctypes.c_float),
        ("cx", ctypes.c_float),
        ("cy", ctypes.c_float),
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
        ("light_count", ctypes.c_int),
        ("lights", c_float_p),
        ("self_shadow", ctypes.c_int),
        ("ground_shadow", ctypes.c_int),
        ("ground_grid", ctypes.c_int),
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
        ("lights", c_float_p),
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
        ("material_count", ctypes.c_int),
        ("materials", ctypes.c_void_p),  # pen_mesh_material *: not read by the package
        ("triangle_materials", ctypes.POINTER(ctypes.c_int32)),
        ("colors", c_float_p),
    ]


class Spheres(ctypes.Structure):
    _fields_ = [("count", ctypes.c_int), ("data", c_float_p), ("weight", c_float_p)]


# ---- Layout check -------------------------------------------------------------------------------

# The layout version this package's structs are written for (PEN_FLAT_ABI_VERSION in flat.h).
ABI_VERSION = 4

# The C structs the package mirrors, by their C names.
MIRRORS = {
    "pen_flat_object": FlatObject,
    "pen_flat_scene": FlatScene,
    "pen_flat_object_grad": FlatObjectGrad,
    "pen_flat_grad": FlatGrad,
    "pen_image": Image,
    "pen_mesh": Mesh,
    "pen_spheres": Spheres,
}


class AbiField(ctypes.Structure):
    """One row of pen_flat_abi's table (pen_flat_abi_field)."""

    _fields_ = [
        ("type", ctypes.c_char_p),
        ("field", ctypes.c_char_p),
        ("offset", ctypes.c_size_t),
        ("size", ctypes.c_size_t),
    ]


def abi_table(handle):
    """(version, {struct name: (size, [(field, offset, size), ...])}) as the library reports
    them."""
    rows, count = ctypes.POINTER(AbiField)(), ctypes.c_int()
    fn = handle.pen_flat_abi
    fn.restype = ctypes.c_int
    fn.argtypes = [ctypes.POINTER(ctypes.POINTER(AbiField)), ctypes.POINTER(ctypes.c_int)]
    version = fn(ctypes.byref(rows), ctypes.byref(count))
    table = {}
    for i in range(count.value):
        r = rows[i]
        name = r.type.decode()
        if r.field is None:
            table[name] = (r.size, [])
        else:
            table[name][1].append((r.field.decode(), r.offset, r.size))
    return version, table


def check_abi(version, table, mirrors=None):
    """Raises PenumbraError unless the layout table (abi_table) matches the ctypes structs
    (MIRRORS: C name -> ctypes class) field for field: names in order, offsets, sizes, and each
    struct's size."""
    if version != ABI_VERSION:
        raise PenumbraError("flat struct layout version %d, this package is written for %d"
                            % (version, ABI_VERSION))
    for cname, cls in (MIRRORS if mirrors is None else mirrors).items():
        where = "struct %s (penumbra._lib.%s)" % (cname, cls.__name__)
        if cname not in table:
            raise PenumbraError("%s: not in the library's layout table" % where)
        size, lib_fields = table[cname]
        ours = [(name, getattr(cls, name).offset, getattr(cls, name).size)
                for name, _ in cls._fields_]
        for k in range(max(len(ours), len(lib_fields))):
            theirs = lib_fields[k] if k < len(lib_fields) else None
            mine = ours[k] if k < len(ours) else None
            if theirs == mine:
                continue
            if mine is None or (theirs is not None and theirs[0] != mine[0]):
                raise PenumbraError(
                    "%s, field %s: the library has it at offset %d (%d bytes), the package %s"
                    % (where, theirs[0], theirs[1], theirs[2],
                       "has %s there" % mine[0] if mine else "does not have it"))
            if theirs is None:
                raise PenumbraError("%s, field %s: the package has it, the library does not"
                                    % (where, mine[0]))
            raise PenumbraError(
                "%s, field %s: offset %d and size %d in the library, %d and %d in the package"
                % (where, mine[0], theirs[1], theirs[2], mine[1], mine[2]))
        if ctypes.sizeof(cls) != size:
            raise PenumbraError("%s: %d bytes in the library, %d in the package"
                                % (where, size, ctypes.sizeof(cls)))


# ---- Loading ------------------------------------------------------------------------------------


def _candidates():
    """(path, how it was found) in the order they are tried."""
    here = os.path.dirname(os.path.abspath(__file__))
    yield os.path.join(here, LIB_NAME), "the package's own copy (pip install)"
    try:
        from . import _libpath
    except ImportError:
        _libpath = None
    if _libpath is not None:
        yield _libpath.LIBRARY, "penumbra._libpath.LIBRARY"
    env = os.environ.get("PENUMBRA_LIB")
    if env:
        yield (os.path.join(env, LIB_NAME) if os.path.isdir(env) else env), "PENUMBRA_LIB"
        return  # an explicit setting that is wrong is an error, not a reason to look elsewhere
    yield os.path.join(here, "..", "..", "build", LIB_NAME), "the build tree"


def _declare(lib):
    P = ctypes.c_void_p
    I = ctypes.c_int
    F = ctypes.c_float
    S = ctypes.c_char_p
    FSP = ctypes.POINTER(FlatScene)
    FGP = ctypes.POINTER(FlatGrad)
    sigs = {
        "pen_context_create": (P, []),
        "pen_context_destroy": (None, [P]),
        "pen_context_error": (S, [P]),
        "pen_context_set_threads": (None, [P, I]),
        "pen_version": (S, []),
        "pen_render_state_create": (I, [P, ctypes.POINTER(P)]),
        "pen_render_state_free": (None, [P]),
        "pen_flat_render_fwd": (I, [P, FSP, P, c_float_p]),
        "pen_flat_render_bwd": (I, [P, FSP, P, c_float_p, FGP]),
        "pen_flat_renderer_create": (I, [P, ctypes.POINTER(P)]),
        "pen_flat_renderer_free": (None, [P]),
        "pen_flat_renderer_fwd": (I, [P, P, FSP, c_float_p]),
        "pen_flat_renderer_bwd": (I, [P, P, FSP, c_float_p, FGP]),
        "pen_flat_grad_check": (I, [P, FSP, ctypes.c_uint]),
        "pen_flat_renderer_state": (P, [P]),
        "pen_render_state_share": (I, [P, P, P]),
        "pen_render_state_aovs": (I, [P, P, ctypes.POINTER(Image), ctypes.POINTER(Image),
                                      ctypes.POINTER(Image)]),
        "pen_flat_grad_model": (ctypes.c_uint, [FSP, ctypes.POINTER(FlatObject), ctypes.c_uint]),
        "pen_flat_scene_load": (I, [P, S, I, ctypes.POINTER(P)]),
        "pen_flat_loaded_scene": (FSP, [P]),
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


def _open(path):
    """The library at path, its layout checked and its functions declared."""
    try:
        handle = ctypes.CDLL(path)
    except OSError as e:
        raise PenumbraError("cannot load %s: %s" % (path, e)) from None
    try:
        check_abi(*abi_table(handle))
        _declare(handle)
    except AttributeError as e:  # a symbol missing: a library older than the package
        raise PenumbraError("%s does not match this package (rebuild or reinstall it): %s"
                            % (path, e)) from None
    except PenumbraError as e:
        raise PenumbraError("%s does not match this package (rebuild or reinstall it): %s"
                            % (path, e)) from None
    return handle


_lib = None


def lib():
    """The loaded library (loaded on first use; `import penumbra` tries once, so that a library
    that does not match is refused at import)."""
    global _lib
    if _lib is None:
        tried = []
        for path, how in _candidates():
            path = os.path.normpath(path)
            if os.path.exists(path):
                _lib = _open(path)
                break
            tried.append("%s (%s)" % (path, how))
        else:
            raise LibraryNotFound(
                "libpenumbra.so not found (looked at %s); build it (make build), install it "
                "(cmake --install), or set PENUMBRA_LIB to the library or its folder"
                % ", ".join(tried)
            )
    return _lib


class Context:
    """A pen_context, for one call (`with Context(threads) as c: c.check(lib().pen_x(c.ptr,
    ...))`) or kept by an object that calls the library many times (then close() it)."""

    def __init__(self, threads=0):
        self.ptr = lib().pen_context_create()
        if not self.ptr:
            raise MemoryError("pen_context_create")
        self.set_threads(threads)

    def set_threads(self, threads):
        lib().pen_context_set_threads(self.ptr, int(threads))

    def close(self):
        if self.ptr:
            lib().pen_context_destroy(self.ptr)
            self.ptr = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

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
