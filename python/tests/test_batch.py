"""penumbra.render_batch and penumbra.BatchRenderer: a batch of cameras gives the images of the
single renders bit for bit, the scene's gradients are the sum of the single renders' gradients,
the per-camera states survive between steps without changing a bit, and bad batches are refused.
"""

import dataclasses
import unittest

import torch

import penumbra
import scenes
import test_renderer


def _cameras(size):
    """Three cameras on a circle around the ball scene's object, one size."""
    eyes = [(0.3, 1.5, 2.4), (2.2, 1.3, 0.9), (-1.8, 1.7, -1.4)]
    return [penumbra.Camera(size, size, 40.0, eye, (0.0, 0.35, 0.0)) for eye in eyes]


def _leaves(sc):
    """test_renderer's leaves, their gradients cleared."""
    ts = test_renderer._leaves(sc)
    for t in ts:
        t.grad = None
    return ts


def _weights(shape):
    g = torch.Generator().manual_seed(11)
    return torch.rand(*shape, generator=g)


class RenderBatch(unittest.TestCase):
    def test_equals_single_renders(self):
        sc = scenes.ball_scene(size=16, textured=True)
        cams = _cameras(16)
        ts = _leaves(sc)
        images = penumbra.render_batch(sc, cams)
        self.assertEqual(tuple(images.shape), (3, 16, 16, 3))
        w = _weights(images.shape)
        (images * w).sum().backward()
        batch_grads = [t.grad.clone() for t in ts]
        summed = [torch.zeros_like(t) for t in ts]
        for b, cam in enumerate(cams):
            for t in ts:
                t.grad = None
            single = penumbra.render_scene(dataclasses.replace(sc, camera=cam))
            self.assertTrue(torch.equal(single.detach(), images[b].detach()), "camera %d" % b)
            (single * w[b]).sum().backward()
            for s, t in zip(summed, ts):
                s += t.grad
        for k, (a, s) in enumerate(zip(batch_grads, summed)):
            # autograd adds the cameras' gradients in its own order: equal up to rounding
            self.assertTrue(torch.allclose(a, s, rtol=1e-5, atol=1e-6 * float(s.abs().max())),
                            "input %d: max difference %g" % (k, float((a - s).abs().max())))

    def test_transfer_shared_between_cameras(self):
        """Under the default model (the transfer, ray traced), a BatchRenderer's renderers share
        their traces (pen_render_state_share) and render each camera as a render alone does, and
        the lighting gradient flows."""
        sc = dataclasses.replace(scenes.ball_scene(size=16, textured=True),
                                 self_shadow="transfer", ground_shadow="transfer")
        sc = dataclasses.replace(sc, objects=[dataclasses.replace(o, texture_filter="footprint")
                                              for o in sc.objects])
        cams = _cameras(16)
        sh = sc.sh.clone().requires_grad_()
        with penumbra.BatchRenderer() as batch:
            for step in range(2):  # the second step reads the shared traces
                images = batch.render_batch(dataclasses.replace(sc, sh=sh), cams)
                images.sum().backward()
                for b, cam in enumerate(cams):
                    alone = penumbra.render_scene(dataclasses.replace(sc, camera=cam))
                    self.assertTrue(torch.equal(alone, images[b].detach()), "camera %d" % b)
        self.assertGreater(float(sh.grad.abs().max()), 0.0)

    def test_renderer_kept_between_steps(self):
        sc = scenes.ball_scene(size=16)
        cams = _cameras(16)
        with penumbra.BatchRenderer(threads=1) as batch:
            for step in range(3):
                with torch.no_grad():
                    sc.sh[0] += 0.05
                ts = _leaves(sc)
                images = batch.render_batch(sc, cams)
                images.sum().backward()
                kept = [t.grad.clone() for t in ts]
                self.assertEqual(len(batch), 3)
                for t in ts:
                    t.grad = None
                fresh = penumbra.render_batch(sc, cams, threads=1)
                fresh.sum().backward()
                self.assertTrue(torch.equal(images.detach(), fresh.detach()), "step %d" % step)
                for a, b in zip(kept, ts):
                    self.assertTrue(torch.equal(a, b.grad), "step %d" % step)
            first = batch.renderers(3)
            self.assertIs(first[0], batch.renderers(2)[0])

    def test_errors(self):
        sc = scenes.ball_scene(size=16)
        with self.assertRaisesRegex(ValueError, "at least one camera"):
            penumbra.render_batch(sc, [])
        with self.assertRaisesRegex(TypeError, r"cameras\[1\] must be a penumbra.Camera"):
            penumbra.render_batch(sc, [sc.camera, "front"])
        with self.assertRaisesRegex(TypeError, "sequence of penumbra.Camera"):
            penumbra.render_batch(sc, sc.camera)
        with self.assertRaisesRegex(ValueError, r"cameras\[1\] is 8x8 but cameras\[0\] is 16x16"):
            penumbra.render_batch(sc, [sc.camera, penumbra.Camera(8, 8)])
        with self.assertRaisesRegex(TypeError, "BatchRenderer"):
            penumbra.render_batch(sc, [sc.camera], renderer=penumbra.Renderer())


if __name__ == "__main__":
    unittest.main()
