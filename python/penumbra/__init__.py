"""penumbra: differentiable soft-shadow rendering (SH visibility from sphere proxies) for PyTorch.

A thin ctypes binding over the C library libpenumbra.so (the copy a wheel carries inside the
package, else where `cmake --install` put it, through $PENUMBRA_LIB, or in the repository's
build/ folder). See docs/python.md.

    import penumbra, torch
    scene = penumbra.load_scene("examples/scenes/spot_city.json")   # as `penumbra render` sees it
    scene.sh.requires_grad_()
    image = penumbra.render_scene(scene)        # (H, W, 3) float32, linear RGB: the CLI's image
    image.mean().backward()                     # scene.sh.grad from the C backward

A pose (vertex, sphere, disk-light) gradient needs the sphere model of the objects' own shadows:
scene = penumbra.gradient_model(scene, ["pose"]) first, or the render raises PenumbraError.

In a loop, render through one penumbra.Renderer: it keeps the C render state (and its caches)
from one step to the next. penumbra.render_batch renders a batch of cameras into one (B, H, W, 3)
tensor, a penumbra.BatchRenderer keeping one render state per camera.
"""

from . import _lib
from ._lib import PenumbraError
from .batch import BatchRenderer, render_batch
from .io import (Mesh, envmap_to_sh, fit_spheres, load_image, load_mesh, load_scene,
                 load_spheres, overlap_weights, save_image)
from .render import (GRAD_GROUPS, Camera, Object, RenderFunction, Renderer, Scene,
                     gradient_model, pose, render, render_aovs, render_scene)

# Load the library now when it is there, so that one whose struct layout differs from this
# package's is refused at import; a missing one is reported at first use (with where it looked).
try:
    _lib.lib()
except _lib.LibraryNotFound:
    pass


def version():
    """The C library's version string."""
    return _lib.lib().pen_version().decode()


__all__ = ["BatchRenderer", "Camera", "GRAD_GROUPS", "Mesh", "Object", "PenumbraError",
           "RenderFunction", "Renderer", "Scene", "envmap_to_sh", "fit_spheres", "gradient_model",
           "load_image", "load_mesh",
           "load_scene", "load_spheres", "overlap_weights", "pose", "render", "render_aovs",
           "render_batch",
           "render_scene", "save_image", "version"]
