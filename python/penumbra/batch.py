"""penumbra.batch: one scene seen by a batch of cameras, as one (B, H, W, 3) tensor.

Each camera renders through its own penumbra.Renderer (a C render state and its caches), so that
in an optimisation loop camera b finds the state of its own previous step: the mesh adjacency,
the per-pixel buffers and the environment-map background of that view, which a single shared
state would rebuild at every camera. The images are those of render_scene with the scene's camera
replaced, bit for bit (each is one call of the same autograd Function), and the backward of the
stacked tensor sends each image's gradient through its own C backward; autograd adds them into
the scene's tensors, so a scene tensor's gradient is the sum over the cameras.

The cameras render one after the other (each render uses the threads it is given); several
views in parallel is the C optimiser's business (docs/optimize.md, "Several views").
"""

import dataclasses

import torch

from .render import Camera, Renderer, Scene, render_scene


class BatchRenderer:
    """One Renderer per camera of a batch, kept across calls: camera b of every call renders
    through renderer b (the list grows to the largest batch seen). threads: each renderer's
    default thread count (0: all cores). close() frees them now.

        batch = penumbra.BatchRenderer()
        for step in range(200):
            images = batch.render_batch(scene, cameras)        # (B, H, W, 3)
            loss = (images - targets).square().mean()
            ...
    """

    def __init__(self, threads=0):
        self.threads = int(threads)
        self._renderers = []

    def renderers(self, count):
        """The renderers of cameras 0 .. count - 1 (made as needed)."""
        while len(self._renderers) < count:
            r = Renderer(self.threads)
            if self._renderers:  # one trace of the transfers per pose for every camera
                r._share(self._renderers[0])
            self._renderers.append(r)
        return self._renderers[:count]

    def render_batch(self, scene, cameras, shadows=True, antialias=True, threads=None):
        """render_batch() through these renderers."""
        return render_batch(scene, cameras, shadows=shadows, antialias=antialias,
                            threads=threads, renderer=self)

    def close(self):
        for r in self._renderers:
            r.close()
        self._renderers = []

    def __len__(self):
        return len(self._renderers)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _check_cameras(cameras):
    if isinstance(cameras, Camera) or not hasattr(cameras, "__len__"):
        raise TypeError("penumbra: cameras must be a sequence of penumbra.Camera, got %s"
                        % type(cameras).__name__)
    if len(cameras) < 1:
        raise ValueError("penumbra: render_batch needs at least one camera")
    for b, cam in enumerate(cameras):
        if not isinstance(cam, Camera):
            raise TypeError("penumbra: cameras[%d] must be a penumbra.Camera, got %s"
                            % (b, type(cam).__name__))
        if (cam.width, cam.height) != (cameras[0].width, cameras[0].height):
            raise ValueError("penumbra: cameras[%d] is %dx%d but cameras[0] is %dx%d: a batch "
                             "has one image size" % (b, cam.width, cam.height, cameras[0].width,
                                                     cameras[0].height))
    return list(cameras)


def render_batch(scene, cameras, shadows=True, antialias=True, threads=None, renderer=None):
    """Renders the Scene from every camera (a sequence of B penumbra.Camera of one size; the
    scene's own camera is not used); returns the (B, height, width, 3) float32 linear RGB images,
    differentiable in the same scene tensors as render_scene, their gradients summed over the
    cameras. renderer: a BatchRenderer (camera b through its renderer b, kept for the next call);
    None: fresh renderers for this call. threads: None takes the renderer's (0 without one)."""
    if not isinstance(scene, Scene):
        raise TypeError("penumbra: render_batch takes a penumbra.Scene, got %s"
                        % type(scene).__name__)
    if renderer is not None and not isinstance(renderer, BatchRenderer):
        raise TypeError("penumbra: renderer must be a penumbra.BatchRenderer, got %s"
                        % type(renderer).__name__)
    cameras = _check_cameras(cameras)
    if threads is None:
        threads = renderer.threads if renderer is not None else 0
    # Without one, fresh renderers for this call (each kept alive by its image's graph), still
    # sharing their ray-traced transfers.
    states = (renderer if renderer is not None else BatchRenderer(threads)).renderers(len(cameras))
    images = [render_scene(dataclasses.replace(scene, camera=cam), shadows=shadows,
                           antialias=antialias, threads=threads, renderer=r)
              for cam, r in zip(cameras, states)]
    return torch.stack(images)


__all__ = ["BatchRenderer", "render_batch"]
