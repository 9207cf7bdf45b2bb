"""One scene, one image and one contract through every door (docs/design.md sec. 1.15).

- Images: each bundled scene, and one of our own with textures, an OBJ's materials, a disk light
  and two objects, rendered by `penumbra render` (EXR, float) and by load_scene + render_scene
  with the thread count pinned, agree within 1e-6 relative RMSE (tests/test_doors.c holds the C
  API and the flat API to the same command images).
- Gradients: for each model (the objects' own shadows from the transfer or the spheres; texture
  lookups over the footprint or at a point) and each gradient group, the binding either returns
  the flat API's gradient bit for bit (itself pen_render_bwd's bit for bit, tests/test_flat_api.c,
  and checked against finite differences in tests/test_render_grad.c and test_gradcheck.py) or
  refuses with the C library's one line naming the group; never a partial gradient with success.
"""

import ctypes
import dataclasses
import importlib
import os
import shutil
import subprocess
import tempfile
import unittest

import torch

import penumbra
from penumbra import _lib
prender = importlib.import_module("penumbra.render")  # the module, not the function

import scenes

SRC = os.environ.get("PENUMBRA_SRC",
                     os.path.normpath(os.path.join(os.path.dirname(__file__), "..", "..")))
CLI = os.environ.get("PENUMBRA_CLI", os.path.join(SRC, "build", "penumbra"))
THREADS = 2
QUICK = os.environ.get("PEN_TEST_QUICK", "0") not in ("", "0")

OWN_SCENE = """{"camera": {"width": 96, "height": 72, "fov_y_deg": 40,
            "eye": [2.6, 1.6, 3.0], "target": [0.2, 0.45, 0]},
 "lighting": {"envmap": "%(src)s/data/envmaps/interior.hdr", "scale": 0.5,
              "lights": [{"direction": [0.6, 1.0, 0.3], "angular_radius_deg": 2.5,
                          "irradiance": [2.0, 1.9, 1.7]}]},
 "objects": [{"mesh": "%(src)s/data/meshes/spot_triangulated.obj",
              "albedo_texture": "%(src)s/data/meshes/spot_texture.png",
              "spheres": {"fit": 12},
              "pose": {"rotation_axis_angle_deg": [0, 140, 0], "translation": [0, 0.737, 0]}},
             {"mesh": "%(src)s/data/meshes/bob_tri.obj", "spheres": {"fit": 8},
              "pose": {"translation": [1.0, 0.3, -0.6], "scale": 0.6}}],
 "ground": {"albedo": [0.7, 0.7, 0.7]},
 "background": "envmap"}"""


def rel_rmse(a, b):
    a, b = a.double(), b.double()
    den = float(b.square().sum())
    return (float((a - b).square().sum()) / (den if den > 0 else 1.0)) ** 0.5


@unittest.skipUnless(os.access(CLI, os.X_OK), "the penumbra CLI is not built (%s)" % CLI)
class ImageDoorsTest(unittest.TestCase):
    def setUp(self):
        self.dir = tempfile.mkdtemp(prefix="penumbra_doors_")

    def tearDown(self):
        shutil.rmtree(self.dir, ignore_errors=True)

    def check(self, path):
        out = os.path.join(self.dir, "cli.exr")
        subprocess.run([CLI, "render", path, "-o", out, "-q", "--threads", str(THREADS)],
                       check=True)
        want = penumbra.load_image(out)
        scene = penumbra.load_scene(path, threads=THREADS)
        got = penumbra.render_scene(scene, threads=THREADS)
        self.assertEqual(got.shape, want.shape)
        self.assertLessEqual(rel_rmse(got, want), 1e-6)
        return scene

    def test_own_scene(self):
        path = os.path.join(self.dir, "own.json")
        with open(path, "w") as f:
            f.write(OWN_SCENE % {"src": SRC})
        scene = self.check(path)
        # every key of the file kept: the model, each object's filter, the lights
        self.assertEqual((scene.self_shadow, scene.ground_shadow), ("transfer", "transfer"))
        self.assertEqual([o.texture_filter for o in scene.objects], ["footprint", "footprint"])
        self.assertEqual(tuple(scene.lights.shape), (1, 7))

    def test_aovs(self):
        """render_aovs gives the command's --mask, --depth and --normals of the same frame."""
        path = os.path.join(self.dir, "own.json")
        with open(path, "w") as f:
            f.write(OWN_SCENE % {"src": SRC})
        names = ("mask", "depth", "normals")
        outs = {n: os.path.join(self.dir, n + ".exr") for n in names}
        subprocess.run([CLI, "render", path, "-o", os.path.join(self.dir, "i.exr"), "-q",
                        "--threads", str(THREADS)] +
                       [a for n in names for a in ("--" + n, outs[n])], check=True)
        got = penumbra.render_aovs(penumbra.load_scene(path, threads=THREADS), threads=THREADS)
        for n in names:
            want = penumbra.load_image(outs[n])  # loading gives 3 channels (grey replicated)
            g = got[n] if got[n].dim() == 3 else got[n][..., None].expand(-1, -1, 3)
            self.assertTrue(torch.equal(g, want), n)
        self.assertTrue(0 < float(got["mask"].mean()) < 1)
        self.assertEqual(got["image"].shape, (72, 96, 3))

    @unittest.skipIf(QUICK, "512 x 512 with fits: left to the full build")
    def test_bundled_scenes(self):
        for name in ("spot_city", "spot_interior"):
            with self.subTest(scene=name):
                scene = self.check(os.path.join(SRC, "examples", "scenes", name + ".json"))
                self.assertIsNotNone(scene.lights)  # the sun or lamps found in the map


def _flat_gradient(scene, group, d_image):
    """The gradient of `group` straight from the flat API (pen_flat_render_fwd / _bwd on the flat
    scene the binding builds), as a tensor shaped like the binding's."""
    spec = prender._Spec(scene, True, True, THREADS)
    sh = scene.sh.detach().contiguous()
    ground = prender._float_tensor("ground_albedo", scene.ground_albedo, (3,),
                                   allow_list=True).detach()
    lights = None if scene.lights is None else scene.lights.detach().contiguous()
    obj = []
    for i, ob in enumerate(scene.objects):
        os_, ts = prender._check_object(i, ob)
        spec.objects.append(os_)
        obj += [None if t is None else t.detach().contiguous() for t in ts]
    flat = prender._flat(spec, sh, ground, lights, obj)
    L = _lib.lib()
    with _lib.Context(THREADS) as c:
        st = ctypes.c_void_p()
        c.check(L.pen_render_state_create(c.ptr, ctypes.byref(st)))
        try:
            image = torch.empty(flat.height, flat.width, 3)
            c.check(L.pen_flat_render_fwd(c.ptr, ctypes.byref(flat), st, _lib.fptr(image)))
            ob = obj[0:5]
            out = {"lighting": torch.zeros_like(sh), "albedo": torch.zeros_like(ob[1]),
                   "lights": None if lights is None else torch.zeros_like(lights),
                   "vertices": torch.zeros_like(ob[0]), "spheres": torch.zeros_like(ob[3]),
                   "pose": torch.zeros(7)}[group]
            og = (_lib.FlatObjectGrad * 1)()
            g = _lib.FlatGrad()
            g.objects = og
            if group == "lighting":
                g.sh = _lib.fptr(out)
            elif group == "lights":
                g.lights = _lib.fptr(out)
            else:
                setattr(og[0], {"albedo": "texture", "vertices": "positions", "spheres": "spheres",
                                "pose": "pose"}[group], _lib.fptr(out))
            status = L.pen_flat_render_bwd(c.ptr, ctypes.byref(flat), st,
                                           _lib.fptr(d_image.contiguous()), ctypes.byref(g))
            if status != 0:
                raise penumbra.PenumbraError(L.pen_context_error(c.ptr).decode())
        finally:
            L.pen_render_state_free(st)
    return out


class GradientMatrixTest(unittest.TestCase):
    """model x gradient group x entry point (the C entry is tests/test_render_grad.c's
    test_grad_model_rule and tests/test_flat_api.c)."""

    def scene(self, self_shadow, texture_filter):
        sc = scenes.ball_scene(16, textured=True)
        light = torch.tensor([[0.4, 1.0, 0.5, 3.0, 1.5, 1.5, 1.5]])
        objs = [dataclasses.replace(o, texture_filter=texture_filter) for o in sc.objects]
        return dataclasses.replace(sc, self_shadow=self_shadow, ground_shadow=self_shadow,
                                   lights=light, objects=objs)

    def leaf(self, sc, group):
        """sc with the tensor of `group` made a leaf that requires a gradient, and that leaf."""
        ob = sc.objects[0]
        if group == "lighting":
            t = sc.sh.clone().requires_grad_()
            return dataclasses.replace(sc, sh=t), t
        if group == "lights":
            t = sc.lights.clone().requires_grad_()
            return dataclasses.replace(sc, lights=t), t
        name = {"albedo": "texture", "vertices": "vertices", "spheres": "spheres",
                "pose": "pose"}[group]
        t = getattr(ob, name).clone().requires_grad_()
        return dataclasses.replace(sc, objects=[dataclasses.replace(ob, **{name: t})]), t

    def test_matrix(self):
        d_image = torch.randn(16, 16, 3, generator=torch.Generator().manual_seed(3))
        exact_under_transfer = {"lighting", "albedo"}
        for model in ("transfer", "spheres"):
            for filt in ("footprint", "point"):
                for group in penumbra.GRAD_GROUPS:
                    with self.subTest(model=model, texture_filter=filt, group=group):
                        sc, t = self.leaf(self.scene(model, filt), group)
                        if model == "transfer" and group not in exact_under_transfer:
                            words = {"spheres": "sphere", "vertices": "vertex",
                                     "lights": "disk-light"}.get(group, group)
                            with self.assertRaisesRegex(penumbra.PenumbraError,
                                                        "no %s gradient" % words):
                                penumbra.render_scene(sc, threads=THREADS)
                            with self.assertRaisesRegex(penumbra.PenumbraError,
                                                        "no %s gradient" % words):
                                _flat_gradient(sc, group, d_image)
                            continue
                        img = penumbra.render_scene(sc, threads=THREADS)
                        (img * d_image).sum().backward()
                        want = _flat_gradient(sc, group, d_image)
                        self.assertTrue(torch.equal(t.grad, want.reshape(t.grad.shape)),
                                        "binding and flat API differ")
                        self.assertGreater(float(t.grad.abs().max()), 0.0)

    def test_constants_refused(self):
        sc = scenes.ball_scene(12)
        eye = torch.tensor([0.3, 1.5, 2.4], requires_grad=True)
        cam = dataclasses.replace(sc.camera, eye=eye)
        with self.assertRaisesRegex(ValueError, "camera.eye has no gradient"):
            penumbra.render_scene(dataclasses.replace(sc, camera=cam))
        h = torch.tensor(0.0, requires_grad=True)
        with self.assertRaisesRegex(ValueError, "ground_height has no gradient"):
            penumbra.render_scene(dataclasses.replace(sc, ground_height=h))
        # a tensor without requires_grad is a plain value
        img = penumbra.render_scene(dataclasses.replace(sc, ground_height=torch.tensor(0.0)))
        self.assertTrue(torch.equal(img, penumbra.render_scene(sc)))


if __name__ == "__main__":
    unittest.main()
