"""penumbra: differentiable soft-shadow rendering (SH visibility from sphere proxies) for PyTorch.

A thin ctypes binding over the C library libpenumbra.so (found through $PENUMBRA_LIB, or in the
repository's build/ folder). See docs/python.md.

    import penumbra, torch
    scene = penumbra.load_scene("examples/scenes/spot_city.json")
    scene.sh.requires_grad_()
    image = penumbra.render_scene(scene)        # (H, W, 3) float32, linear RGB
    image.mean().backward()                     # scene.sh.grad from the C backward
"""

from ._lib import PenumbraError
from .io import (Mesh, envmap_to_sh, fit_spheres, load_image, load_mesh, load_scene,
                 load_spheres, overlap_weights, save_image)
from .render import Camera, Object, RenderFunction, Scene, pose, render, render_scene


def version():
    """The C library's version string."""
    from . import _lib
    return _lib.lib().pen_version().decode()


__all__ = ["Camera", "Mesh", "Object", "PenumbraError", "RenderFunction", "Scene",
           "envmap_to_sh", "fit_spheres", "load_image", "load_mesh", "load_scene",
           "load_spheres", "overlap_weights", "pose", "render", "render_scene", "save_image",
           "version"]
