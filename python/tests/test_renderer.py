"""penumbra.Renderer (a C render state kept across calls), the once-differentiable backward, the
layout check of the ctypes structs against the library, and where the package finds the library.

State reuse must not change a single bit: every comparison here is exact (torch.equal)."""

import os
import shutil
import subprocess
import sys
import tempfile
import threading
import unittest

import torch

import penumbra
from penumbra import _lib
import scenes
import test_render

SRC = test_render.SRC
PACKAGE = os.path.join(SRC, "python", "penumbra")


def _leaves(sc):
    """The scene's differentiable inputs (lighting, ground albedo, and per object vertices,
    texture or albedo, spheres, pose), made leaves that want a gradient."""
    ts = [sc.sh, sc.ground_albedo]
    for ob in sc.objects:
        ts += [ob.vertices, ob.texture if ob.texture is not None else ob.albedo, ob.spheres,
               ob.pose]
    for t in ts:
        t.requires_grad_()
    return ts


def _step(sc, renderer, weight):
    """(image, gradients of sum(image * weight)) of one render."""
    ts = _leaves(sc)
    for t in ts:
        t.grad = None
    image = penumbra.render_scene(sc, renderer=renderer)
    (image * weight).sum().backward()
    return image.detach(), [t.grad.clone() for t in ts]


def _move(sc, k):
    """Changes every differentiable input a little (step k of an imagined optimisation)."""
    with torch.no_grad():
        sc.sh[0] += 0.02 * k
        sc.ground_albedo[1] = 0.6 + 0.01 * k
        for ob in sc.objects:
            ob.vertices[0, 1] += 0.004 * k
            ob.spheres[:, 3] *= 1.0 + 0.01 * k
            ob.pose[4] += 0.01 * k
            if ob.texture is not None:
                ob.texture[0, 0, 0] = 0.3 + 0.05 * k
            else:
                ob.albedo[2] = 0.3 + 0.02 * k


def _fresh_copy(sc):
    """The same scene with its own tensors (so that two renderers see equal, separate inputs)."""
    import copy
    return copy.deepcopy(sc)


class RendererTest(unittest.TestCase):
    def assert_same(self, a, b):
        self.assertTrue(torch.equal(a[0], b[0]), "images differ")
        for k, (x, y) in enumerate(zip(a[1], b[1])):
            self.assertTrue(torch.equal(x, y), "gradient %d differs" % k)

    def check_steps(self, make, steps=4):
        """Steps through one Renderer equal fresh renders, bit for bit, as the inputs change."""
        fresh_scene, kept_scene = make(), make()
        renderer = penumbra.Renderer()
        g = torch.Generator().manual_seed(3)
        for k in range(steps):
            _move(fresh_scene, k)
            _move(kept_scene, k)
            cam = fresh_scene.camera
            weight = torch.rand(cam.height, cam.width, 3, generator=g) - 0.5
            self.assert_same(_step(fresh_scene, None, weight), _step(kept_scene, renderer, weight))
        renderer.close()

    def test_ball_textured(self):
        self.check_steps(lambda: scenes.ball_scene(24, textured=True))

    def test_envmap_two_objects(self):
        # The city map as background (the renderer's background cache), two objects, their
        # overlap weights computed by the renderer from the spheres (its overlap-weight cache).
        tmp = tempfile.mkdtemp(prefix="penumbra_py_")
        try:
            path = os.path.join(tmp, "scene.json")
            with open(path, "w") as f:
                f.write(test_render.SCENE_ENVMAP % {"mesh": test_render.SPOT,
                                                    "texture": test_render.SPOT_TEXTURE,
                                                    "envmap": test_render.CITY})
            base = penumbra.load_scene(path)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        for ob in base.objects:
            ob.sphere_weights = None

        self.check_steps(lambda: _fresh_copy(base), steps=3)

    def test_frame_size_and_scene_change(self):
        # One renderer for scenes of different sizes and object counts, in turn.
        renderer = penumbra.Renderer()
        for size, textured in ((16, True), (24, False), (12, True), (24, False)):
            a, b = scenes.ball_scene(size, textured), scenes.ball_scene(size, textured)
            w = torch.linspace(-1, 1, size * size * 3).reshape(size, size, 3)
            self.assert_same(_step(a, None, w), _step(b, renderer, w))

    def test_two_renders_one_backward(self):
        # The second forward replaces the first one's state; the first backward renders again.
        a, b = scenes.ball_scene(16), scenes.ball_scene(20, textured=True)
        wa, wb = torch.rand(16, 16, 3), torch.rand(20, 20, 3)
        want_a, want_b = _step(_fresh_copy(a), None, wa), _step(_fresh_copy(b), None, wb)
        renderer = penumbra.Renderer()
        ta, tb = _leaves(a), _leaves(b)
        ia = penumbra.render_scene(a, renderer=renderer)
        ib = renderer.render_scene(b)
        ((ia * wa).sum() + (ib * wb).sum()).backward()
        self.assert_same(want_a, (ia.detach(), [t.grad for t in ta]))
        self.assert_same(want_b, (ib.detach(), [t.grad for t in tb]))

    def test_threads_share_a_renderer(self):
        renderer = penumbra.Renderer()
        sizes = (16, 20)
        want = [_step(scenes.ball_scene(s), None, torch.ones(s, s, 3)) for s in sizes]
        got = [[] for _ in sizes]

        def work(i):
            for _ in range(3):
                got[i].append(_step(scenes.ball_scene(sizes[i]), renderer,
                                    torch.ones(sizes[i], sizes[i], 3)))

        threads = [threading.Thread(target=work, args=(i,)) for i in range(len(sizes))]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        for i in range(len(sizes)):
            self.assertEqual(len(got[i]), 3)
            for r in got[i]:
                self.assert_same(want[i], r)

    def test_render_and_threads(self):
        sc = scenes.ball_scene(12)
        ob = sc.objects[0]
        with penumbra.Renderer(threads=1) as r:
            self.assertEqual(r.threads, 1)
            a = r.render(ob.vertices, ob.faces, sc.sh, sc.camera, albedo=ob.albedo,
                         spheres=ob.spheres, pose=ob.pose, ground_albedo=sc.ground_albedo,
                         ground_half_size=3.0, background=(0.2, 0.3, 0.4),
                         sphere_weights=ob.sphere_weights, self_shadow=sc.self_shadow,
                         texture_filter=ob.texture_filter)
            b = r.render_scene(sc, threads=2)
        self.assertTrue(torch.equal(a, b))
        self.assertTrue(torch.equal(a, penumbra.render_scene(sc)))

    def test_closed_and_wrong_type(self):
        sc = scenes.ball_scene(8)
        r = penumbra.Renderer()
        r.close()
        r.close()
        with self.assertRaisesRegex(penumbra.PenumbraError, "closed"):
            r.render_scene(sc)
        with self.assertRaisesRegex(TypeError, "renderer must be a penumbra.Renderer"):
            penumbra.render_scene(sc, renderer=object())

    def test_library_errors_keep_the_renderer_usable(self):
        sc = scenes.ball_scene(8)
        r = penumbra.Renderer()
        good = r.render_scene(sc)
        bad = scenes.ball_scene(8)
        bad.objects[0].spheres = torch.tensor([[0.0, 0.0, 0.0, -1.0]])
        bad.objects[0].sphere_weights = None
        with self.assertRaisesRegex(penumbra.PenumbraError, "radius"):
            r.render_scene(bad)
        self.assertTrue(torch.equal(good, r.render_scene(sc)))


class OnceDifferentiableTest(unittest.TestCase):
    def test_double_backward_refused(self):
        sc = scenes.ball_scene(8)
        sc.sh.requires_grad_()
        image = penumbra.render_scene(sc)
        (g,) = torch.autograd.grad(image.square().sum(), sc.sh, create_graph=True)
        with self.assertRaisesRegex(RuntimeError, "once_differentiable|twice"):
            g.sum().backward()


class AbiTest(unittest.TestCase):
    def test_mirrors_match(self):
        version, table = _lib.abi_table(_lib.lib())
        self.assertEqual(version, _lib.ABI_VERSION)
        _lib.check_abi(version, table)
        self.assertEqual(set(table), set(_lib.MIRRORS))

    def test_wrong_struct_refused(self):
        version, table = _lib.abi_table(_lib.lib())
        fields = list(_lib.FlatScene._fields_)

        def struct(fs):
            return type("FlatScene", (__import__("ctypes").Structure,), {"_fields_": fs})

        c_int = __import__("ctypes").c_int
        cases = [
            (fields[:-1], "ground_grid.*does not have it"),             # a field missing
            (fields + [("extra", c_int)], "extra.*the library does not"),  # one too many
            (fields[:3] + fields[4:], "eye.*has target there"),          # one left out inside
            ([(n, c_int) if n == "sh" else (n, t) for n, t in fields], "field sh: offset"),
        ]
        for fs, pattern in cases:
            with self.assertRaisesRegex(penumbra.PenumbraError,
                                        r"struct pen_flat_scene \(penumbra._lib.FlatScene\)"):
                _lib.check_abi(version, table, {"pen_flat_scene": struct(fs)})
            with self.assertRaisesRegex(penumbra.PenumbraError, pattern):
                _lib.check_abi(version, table, {"pen_flat_scene": struct(fs)})
        with self.assertRaisesRegex(penumbra.PenumbraError, "version 4, .* written for 5"):
            old, _lib.ABI_VERSION = _lib.ABI_VERSION, 5
            try:
                _lib.check_abi(version, table)
            finally:
                _lib.ABI_VERSION = old
        with self.assertRaisesRegex(penumbra.PenumbraError, "pen_nothing.*not in the library"):
            _lib.check_abi(version, table, {"pen_nothing": _lib.Image})


class PackageCopy(unittest.TestCase):
    """A copy of the package in a temporary folder (no build tree beside it), imported by a
    fresh interpreter."""

    def setUp(self):
        self.dir = tempfile.mkdtemp(prefix="penumbra_pkg_")
        self.pkg = os.path.join(self.dir, "penumbra")
        shutil.copytree(PACKAGE, self.pkg, ignore=shutil.ignore_patterns("__pycache__"))
        self.library = os.path.normpath(_lib.lib()._name)

    def tearDown(self):
        shutil.rmtree(self.dir, ignore_errors=True)

    def run_python(self, code, **env_changes):
        env = dict(os.environ, PYTHONPATH=self.dir)
        for k, v in env_changes.items():
            if v is None:
                env.pop(k, None)
            else:
                env[k] = v
        return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                              text=True)

    def write_libpath(self, path):
        with open(os.path.join(self.pkg, "_libpath.py"), "w") as f:
            f.write("LIBRARY = %r\n" % path)

    def test_libpath_first(self):
        # Installed: _libpath names the library; no environment variable is needed.
        self.write_libpath(self.library)
        r = self.run_python("import penumbra, scenes; print(penumbra._lib.lib()._name); "
                            "print(float(penumbra.render_scene(scenes.ball_scene(8)).sum()) > 0)",
                            PENUMBRA_LIB=None,
                            PYTHONPATH=self.dir + os.pathsep + os.path.dirname(__file__))
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertEqual(r.stdout.split(), [self.library, "True"])
        # _libpath comes before PENUMBRA_LIB.
        r = self.run_python("import penumbra; print(penumbra._lib.lib()._name)",
                            PENUMBRA_LIB=os.path.join(self.dir, "nosuch.so"))
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertEqual(r.stdout.strip(), self.library)

    def test_libpath_missing_falls_through(self):
        self.write_libpath(os.path.join(self.dir, "gone", "libpenumbra.so.0"))
        r = self.run_python("import penumbra; print(penumbra._lib.lib()._name)",
                            PENUMBRA_LIB=self.library)
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertEqual(r.stdout.strip(), self.library)
        r = self.run_python("import penumbra; penumbra.version()", PENUMBRA_LIB=None)
        self.assertNotEqual(r.returncode, 0)
        self.assertIn("libpenumbra.so not found", r.stderr)
        self.assertIn("penumbra._libpath.LIBRARY", r.stderr)

    def test_mismatch_refused_at_import(self):
        # The package's FlatScene loses its last field: importing it against this library fails
        # with the struct and the field named.
        path = os.path.join(self.pkg, "_lib.py")
        with open(path) as f:
            text = f.read()
        line = '        ("ground_occlusion", ctypes.c_int),\n'
        self.assertIn(line, text)
        with open(path, "w") as f:
            f.write(text.replace(line, ""))
        r = self.run_python("import penumbra", PENUMBRA_LIB=self.library)
        self.assertNotEqual(r.returncode, 0)
        self.assertIn("does not match this package", r.stderr)
        self.assertIn("struct pen_flat_scene", r.stderr)
        self.assertIn("field ground_occlusion", r.stderr)


if __name__ == "__main__":
    unittest.main()
