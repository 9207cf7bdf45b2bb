"""The Python examples (examples/python) as a user runs them: fit_pose's loop on a small scene,
and both scripts from the command line on their default scene, made small (--size, --iterations).
fit_lighting's loop itself is test_example.py's."""

import os
import re
import subprocess
import sys
import tempfile
import unittest

import torch

import scenes

SRC = os.environ.get("PENUMBRA_SRC",
                     os.path.normpath(os.path.join(os.path.dirname(__file__), "..", "..")))
EXAMPLES = os.path.join(SRC, "examples", "python")
sys.path.insert(0, EXAMPLES)
import fit_pose  # noqa: E402


class FitPoseTest(unittest.TestCase):
    def test_fit_pose(self):
        """From about 8 degrees and 0.07 units off, 60 Adam steps bring the ellipsoid back: the loss
        falls tenfold and both offsets by more than half."""
        scene = scenes.ball_scene(24)
        truth = scene.objects[0].pose.clone()
        start = truth + torch.tensor([0.0, 8.0, 0.0, 0.05, 0.0, -0.05, 0.0])
        target = fit_pose.penumbra.render_scene(scene)
        fitted, losses = fit_pose.fit_pose(scene, target, [start], iterations=60)
        self.assertTrue(torch.equal(scene.objects[0].pose, truth))  # the scene is unchanged
        self.assertEqual(len(losses), 60)
        self.assertLess(losses[-1], 0.1 * losses[0])
        r0, t0 = fit_pose.pose_error(start, truth)
        r1, t1 = fit_pose.pose_error(fitted[0], truth)
        self.assertGreater(r0, 7.0)  # (0, 8, 0) added to the axis-angle vector (10, 25, 0)
        self.assertLess(r1, 0.5 * r0)
        self.assertLess(t1, 0.5 * t0)
        self.assertEqual(float(fitted[0][6]), float(truth[6]))  # the scale is not fitted


class CommandLineTest(unittest.TestCase):
    """Each script on its default scene at 32x32 with a few iterations, writing its pictures."""

    def run_example(self, script, *args):
        with tempfile.TemporaryDirectory() as out:
            proc = subprocess.run([sys.executable, os.path.join(EXAMPLES, script), *args,
                                   "--size", "32", "--out", out],
                                  capture_output=True, text=True, timeout=300)
            self.assertEqual(proc.returncode, 0, proc.stdout + proc.stderr)
            for name in ("target.png", "initial.png", "fitted.png"):
                self.assertTrue(os.path.getsize(os.path.join(out, name)) > 0, name)
            return proc.stdout

    def test_fit_lighting_script(self):
        out = self.run_example("fit_lighting.py", "--iterations", "20")
        m = re.search(r"loss (\S+) -> (\S+);", out)
        self.assertIsNotNone(m, out)
        self.assertLess(float(m.group(2)), float(m.group(1)))

    def test_fit_pose_script(self):
        out = self.run_example("fit_pose.py", "--iterations", "10")
        m = re.search(r"loss (\S+) -> (\S+)\n", out)
        self.assertIsNotNone(m, out)
        self.assertLess(float(m.group(2)), float(m.group(1)))
        self.assertRegex(out, r"object 0: rotation off 10\.72 -> \S+ degrees, translation off "
                              r"0\.1000 -> \S+")


if __name__ == "__main__":
    unittest.main()
