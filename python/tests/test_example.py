"""The lighting-fit example (examples/python/fit_lighting.py) on a small scene: Adam through
penumbra.render_scene brings the image loss down by orders of magnitude from black lighting."""

import os
import sys
import unittest

import torch

import scenes

SRC = os.environ.get("PENUMBRA_SRC",
                     os.path.normpath(os.path.join(os.path.dirname(__file__), "..", "..")))
sys.path.insert(0, os.path.join(SRC, "examples", "python"))
import fit_lighting  # noqa: E402


class ExampleTest(unittest.TestCase):
    def test_fit_lighting(self):
        scene = scenes.ball_scene(24, textured=True)
        target = fit_lighting.penumbra.render_scene(scene)
        truth = scene.sh.clone()
        sh, losses = fit_lighting.fit_lighting(scene, target, iterations=80, lr=0.05)
        self.assertTrue(torch.equal(scene.sh, truth))  # the scene is given back unchanged
        self.assertEqual(len(losses), 80)
        self.assertLess(losses[-1], 1e-2 * losses[0])
        self.assertLess(losses[-1], 1e-3)
        self.assertGreater(float(sh.abs().sum()), 0.0)


if __name__ == "__main__":
    unittest.main()
