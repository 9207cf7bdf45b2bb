"""torch.autograd.gradcheck of penumbra.render_scene for every parameter kind.

The C pipeline is float32, so each check runs through a double wrapper: the double input is cast
to float32, rendered, and the image cast back to double and projected on three fixed random
images (out = image . Q, Q of shape (H*W*3, 3)), which keeps the number of backward passes at
three while every pixel still counts. gradcheck then compares the analytic Jacobian (the C
backward) with central differences of step eps, element by element:
|analytic - numeric| <= atol + rtol |numeric|.

Step and tolerances, per kind (the scene: tests/scenes.py ball_scene, 16 x 16), with the largest
|analytic - numeric| measured on this scene in brackets:
  lighting, albedos, texture   linear in the image: eps 1e-2, atol 1e-3, rtol 1e-3
  spheres                      eps 1e-3, atol 2e-2, rtol 2e-2 (0.006; largest derivative 8)
  pose                         eps 1e-4, atol 8e-2, rtol 2e-2 (0.027; largest derivative 16 to 23)
  vertices                     eps 1e-4, atol 3e-2, rtol 2e-2 (0.013; largest derivative 4 to 16)
  disk light                   eps 1e-3, atol 2e-2, rtol 2e-2 (direction, radius in degrees and
                               irradiance of one 8-degree light whose shadow falls on the ground)
Why these steps: the differences are of a float32 image, whose rounding (summed over the 768
weighted values) puts noise of about 1e-6 / eps on each quotient, which favours large steps; but
moving geometry makes the antialiased image continuous only up to isolated jumps at silhouette
corners (docs/rasterizer.md), which favours small ones: at eps 1e-3, two of the 54 vertex
coordinates of this scene straddle a jump (a difference quotient of 148 against an analytic 1.2);
at 1e-4 none does, and the noise stays under 0.5 % of the largest derivative.

Two checks run through one penumbra.Renderer kept across all of gradcheck's calls (the others
through a fresh render state per call).
"""

import unittest

import torch

import penumbra
import scenes

SIZE = 16


def _check(test, getter, setter, eps, atol, rtol, textured=False, **options):
    sc = scenes.ball_scene(SIZE, textured=textured)
    q = torch.randn(SIZE * SIZE * 3, 3, generator=torch.Generator().manual_seed(1),
                    dtype=torch.float64)
    x0 = getter(sc).detach().double().requires_grad_()

    def f(x):
        setter(sc, x.float())
        return penumbra.render_scene(sc, **options).double().reshape(-1) @ q

    test.assertTrue(torch.autograd.gradcheck(f, (x0,), eps=eps, atol=atol, rtol=rtol))
    # The check is not vacuous: the projected image depends on the parameter.
    x0.grad = None
    f(x0).sum().backward()
    test.assertGreater(float(x0.grad.abs().max()), 1e-3)


def _ob(sc):
    return sc.objects[0]


class GradcheckTest(unittest.TestCase):
    def test_lighting(self):
        _check(self, lambda s: s.sh, lambda s, x: setattr(s, "sh", x), 1e-2, 1e-3, 1e-3)

    def test_lighting_without_shadows(self):
        _check(self, lambda s: s.sh, lambda s, x: setattr(s, "sh", x), 1e-2, 1e-3, 1e-3,
               shadows=False)

    def test_albedo(self):
        _check(self, lambda s: _ob(s).albedo, lambda s, x: setattr(_ob(s), "albedo", x),
               1e-2, 1e-3, 1e-3)

    def test_ground_albedo(self):
        _check(self, lambda s: s.ground_albedo, lambda s, x: setattr(s, "ground_albedo", x),
               1e-2, 1e-3, 1e-3)

    def test_texture(self):
        _check(self, lambda s: _ob(s).texture, lambda s, x: setattr(_ob(s), "texture", x),
               1e-2, 1e-3, 1e-3, textured=True)

    def test_spheres(self):
        _check(self, lambda s: _ob(s).spheres, lambda s, x: setattr(_ob(s), "spheres", x),
               1e-3, 2e-2, 2e-2)

    def test_pose(self):
        _check(self, lambda s: _ob(s).pose, lambda s, x: setattr(_ob(s), "pose", x),
               1e-4, 8e-2, 2e-2)

    def test_pose_textured_without_shadows(self):
        _check(self, lambda s: _ob(s).pose, lambda s, x: setattr(_ob(s), "pose", x),
               1e-4, 8e-2, 2e-2, textured=True, shadows=False)

    def test_vertices(self):
        _check(self, lambda s: _ob(s).vertices, lambda s, x: setattr(_ob(s), "vertices", x),
               1e-4, 3e-2, 2e-2)

    def test_vertices_textured(self):
        _check(self, lambda s: _ob(s).vertices, lambda s, x: setattr(_ob(s), "vertices", x),
               1e-4, 3e-2, 2e-2, textured=True)

    def test_disk_light(self):
        def with_light(s):
            if s.lights is None:
                s.lights = torch.tensor([[0.5, 1.0, 0.3, 8.0, 2.0, 1.8, 1.5]])
            return s.lights

        _check(self, with_light, lambda s, x: setattr(s, "lights", x), 1e-3, 2e-2, 2e-2)

    # Through one kept Renderer: gradcheck's perturbed forwards replace the state between the
    # forward of the checked output and its backward, which then renders again first.
    def test_lighting_through_one_renderer(self):
        _check(self, lambda s: s.sh, lambda s, x: setattr(s, "sh", x), 1e-2, 1e-3, 1e-3,
               renderer=penumbra.Renderer())

    def test_vertices_through_one_renderer(self):
        _check(self, lambda s: _ob(s).vertices, lambda s, x: setattr(_ob(s), "vertices", x),
               1e-4, 3e-2, 2e-2, textured=True, renderer=penumbra.Renderer())


if __name__ == "__main__":
    unittest.main()
