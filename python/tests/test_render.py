"""The binding's contract: the same image as `penumbra render` for the same scene JSON, the
loaders, argument errors (dtype, shape, device) and library errors, and autograd behaviour."""

import dataclasses
import os
import shutil
import subprocess
import sys
import tempfile
import unittest

import torch

import penumbra
import scenes

SRC = os.environ.get("PENUMBRA_SRC",
                     os.path.normpath(os.path.join(os.path.dirname(__file__), "..", "..")))
CLI = os.environ.get("PENUMBRA_CLI", os.path.join(SRC, "build", "penumbra"))
SPOT = os.path.join(SRC, "data", "meshes", "spot_triangulated.obj")
SPOT_TEXTURE = os.path.join(SRC, "data", "meshes", "spot_texture.png")
CITY = os.path.join(SRC, "data", "envmaps", "city.hdr")

# A textured Spot with three inline spheres on the ground (the scene of tests/cli_render.sh). Both
# scenes shade the objects' own shadows with their spheres ("self": "spheres") and look Spot's
# texture up at the pixel's uv ("texture_filter": "point"), the model in which every gradient is
# exact; test_transfer_and_footprint renders the JSON's defaults.
SCENE_SH = """{"camera": {"width": 48, "height": 40, "fov_y_deg": 40, "eye": [2.5, 1.8, 3.0],
            "target": [0, 0.5, 0]},
 "lighting": {"sh": [[1.5,1.5,1.5],[-1,-1,-1],[0.2,0.2,0.2],[-0.3,-0.3,-0.3],
                     [0,0,0],[0,0,0],[0,0,0],[0,0,0],[0,0,0],
                     [0,0,0],[0,0,0],[0,0,0],[0,0,0],[0,0,0],[0,0,0],[0,0,0]]},
 "objects": [{"mesh": "%(mesh)s", "albedo_texture": "%(texture)s", "texture_filter": "point",
              "spheres": [{"center": [0, -0.07, 0.3], "radius": 0.36},
                          {"center": [0, 0.45, -0.4], "radius": 0.28},
                          {"center": [0, -0.55, 0.35], "radius": 0.2}],
              "pose": {"rotation_axis_angle_deg": [0, 140, 0], "translation": [0, 0.737, 0]}}],
 "ground": {"albedo": [0.7, 0.7, 0.7]},
 "shadow": {"self": "spheres"},
 "background": [0.1, 0.2, 0.3]}"""

# The same object under the city map (rotated, scaled, 3 bands, paper exponential), the map as
# background, a second constant-albedo object that casts shadows on the first.
SCENE_ENVMAP = """{"camera": {"width": 40, "height": 32, "fov_y_deg": 45, "eye": [-2.0, 1.5, 3.2],
            "target": [0, 0.4, 0]},
 "lighting": {"envmap": "%(envmap)s", "scale": 0.3, "rotation_y_deg": 40},
 "sh_bands": 3, "shadow": {"exp": "paper", "epsilon": 3.0, "self": "spheres"},
 "objects": [{"mesh": "%(mesh)s", "albedo_texture": "%(texture)s", "texture_filter": "point",
              "spheres": [{"center": [0, -0.07, 0.3], "radius": 0.36}],
              "pose": {"translation": [0, 0.737, 0]}},
             {"mesh": "%(mesh)s", "albedo": [0.3, 0.6, 0.9],
              "spheres": [{"center": [0, 0, 0], "radius": 0.4}],
              "pose": {"translation": [0.9, 0.45, -0.8], "scale": 0.6}}],
 "ground": {"albedo": [0.6, 0.6, 0.6], "height": 0.01, "half_size": 3},
 "background": "envmap"}"""


# Disk lights over a bare ground (LIGHTS: the list's members).
SCENE_LIGHTS = """{"camera": {"width": 24, "height": 16, "fov_y_deg": 50, "eye": [0, 2, 3],
            "target": [0, 0, 0]},
 "lighting": {"sh": [[0.5, 0.5, 0.5]], "lights": [LIGHTS]}, "sh_bands": 1,
 "objects": [], "ground": {"albedo": [0.7, 0.7, 0.7]}}"""


def _cli_available():
    return os.access(CLI, os.X_OK)


class Temp(unittest.TestCase):
    def setUp(self):
        self.dir = tempfile.mkdtemp(prefix="penumbra_py_")

    def tearDown(self):
        shutil.rmtree(self.dir, ignore_errors=True)

    def write_scene(self, template, name="scene.json"):
        path = os.path.join(self.dir, name)
        with open(path, "w") as f:
            f.write(template % {"mesh": SPOT, "texture": SPOT_TEXTURE, "envmap": CITY})
        return path


@unittest.skipUnless(_cli_available(), "the penumbra CLI is not built (%s)" % CLI)
class CliEqualityTest(Temp):
    """load_scene + render_scene give the CLI's image bit for bit (EXR holds float32)."""

    def check(self, template, *flags):
        path = self.write_scene(template)
        out = os.path.join(self.dir, "cli.exr")
        subprocess.run([CLI, "render", path, "-o", out, "-q"] + list(flags), check=True)
        want = penumbra.load_image(out)
        scene = penumbra.load_scene(path)
        got = penumbra.render_scene(scene, shadows="--no-shadows" not in flags)
        self.assertEqual(got.shape, want.shape)
        self.assertTrue(torch.equal(got, want),
                        "max difference %g" % float((got - want).abs().max()))
        return scene, got

    def test_sh_lighting(self):
        scene, img = self.check(SCENE_SH)
        self.assertEqual(tuple(img.shape), (40, 48, 3))
        self.assertEqual(len(scene.objects[0].spheres), 3)

    def test_no_shadows(self):
        self.check(SCENE_SH, "--no-shadows")

    def test_light_layout(self):
        # Two disk lights of distinct fields: the rows load_scene reads from the library and the
        # rows render_scene hands it both follow penumbra.render's LIGHT_FLOATS, the library's
        # PEN_LIGHT_FLOATS (a stride of the one differing from the other's would shift the second
        # light's fields and change both the rows and the image).
        rows = [[0.6, 1.0, 0.3, 2.5, 3.0, 2.5, 2.0], [-0.4, 0.8, -0.5, 7.0, 0.5, 1.0, 1.5]]
        lights = ", ".join('{"direction": %s, "angular_radius_deg": %s, "irradiance": %s}'
                           % (r[:3], r[3], r[4:]) for r in rows)
        scene, _ = self.check(SCENE_LIGHTS.replace("LIGHTS", lights))
        want = torch.tensor(rows, dtype=torch.float32)
        want[:, :3] /= want[:, :3].norm(dim=1, keepdim=True)  # the loader keeps unit directions
        self.assertTrue(torch.allclose(scene.lights, want, rtol=0, atol=1e-6), str(scene.lights))

    def test_transfer_and_footprint(self):
        """The CLI's defaults (own shadows from the transfer, footprint texture filter) are the
        binding's: load_scene keeps the JSON's model and render_scene gives the CLI's image;
        lighting and texture gradients flow, a vertex gradient is refused at the render, naming
        the group, until gradient_model switches to the sphere model."""
        template = (SCENE_SH.replace('"shadow": {"self": "spheres"},', "")
                    .replace('"texture_filter": "point",', ""))
        path = self.write_scene(template)
        out = os.path.join(self.dir, "cli.exr")
        subprocess.run([CLI, "render", path, "-o", out, "-q"], check=True)
        want = penumbra.load_image(out)
        scene = penumbra.load_scene(path)
        self.assertEqual(scene.self_shadow, "transfer")
        self.assertEqual(scene.objects[0].texture_filter, "footprint")
        got = penumbra.render_scene(scene)
        self.assertTrue(torch.equal(got, want),
                        "max difference %g" % float((got - want).abs().max()))
        sh = scene.sh.clone().requires_grad_(True)
        penumbra.render_scene(dataclasses.replace(scene, sh=sh)).sum().backward()
        self.assertTrue(bool(torch.isfinite(sh.grad).all()) and float(sh.grad.abs().sum()) > 0)
        ob = scene.objects[0]
        v = ob.vertices.clone().requires_grad_(True)
        bent = dataclasses.replace(scene, objects=[dataclasses.replace(ob, vertices=v)])
        with self.assertRaisesRegex(penumbra.PenumbraError,
                                    'no vertex gradient under "shadow": {"self": "transfer"}'):
            penumbra.render_scene(bent)
        model = penumbra.gradient_model(bent, ["vertices"])
        self.assertEqual((model.self_shadow, model.ground_shadow), ("spheres", "spheres"))
        self.assertEqual(model.objects[0].texture_filter, "point")
        self.assertIs(model.objects[0].vertices, v)
        penumbra.render_scene(model).sum().backward()
        self.assertTrue(float(v.grad.abs().sum()) > 0)
        same = penumbra.gradient_model(scene, ["lighting", "albedo"])
        self.assertEqual((same.self_shadow, same.objects[0].texture_filter),
                         ("transfer", "footprint"))
        with self.assertRaisesRegex(ValueError, "self_shadow"):
            penumbra.render_scene(dataclasses.replace(scene, self_shadow="mesh"))
        # the ground's shadow keys travel from the JSON through load_scene
        path = self.write_scene(template.replace('"background"',
                                                 '"shadow": {"ground_grid": 48},\n "background"'),
                                "grid.json")
        subprocess.run([CLI, "render", path, "-o", out, "-q"], check=True)
        want = penumbra.load_image(out)
        scene = penumbra.load_scene(path)
        self.assertEqual((scene.ground_shadow, scene.ground_grid), ("transfer", 48))
        got = penumbra.render_scene(scene)
        self.assertTrue(torch.equal(got, want),
                        "max difference %g" % float((got - want).abs().max()))

    def test_envmap_two_objects(self):
        scene, img = self.check(SCENE_ENVMAP)
        self.assertEqual(scene.background, "envmap")
        self.assertEqual(scene.exp, "paper")
        self.assertEqual(tuple(scene.sh.shape), (9, 3))


class LoaderTest(Temp):
    def test_scene_fields(self):
        scene = penumbra.load_scene(self.write_scene(SCENE_ENVMAP))
        cam = scene.camera
        self.assertEqual((cam.width, cam.height, cam.fov_y_deg), (40, 32, 45.0))
        self.assertEqual(cam.eye[:2], (-2.0, 1.5))
        self.assertAlmostEqual(cam.eye[2], 3.2, places=6)  # a float32 in C
        self.assertEqual(len(scene.objects), 2)
        spot, other = scene.objects
        self.assertIsNotNone(spot.texture)
        self.assertIsNone(other.texture)
        self.assertTrue(torch.allclose(other.albedo, torch.tensor([0.3, 0.6, 0.9])))
        self.assertTrue(torch.allclose(other.pose, penumbra.pose(translation=(0.9, 0.45, -0.8),
                                                                 scale=0.6)))
        self.assertAlmostEqual(scene.ground_height, 0.01, places=6)
        self.assertEqual(scene.epsilon, 3.0)
        self.assertEqual(scene.envmap_rotation_y_deg, 40.0)
        # The loaded lighting is the projection of the map less the sun found in it (lights
        # AUTO, docs/design.md sec. 1.14): below the whole map's DC by the sun's share (about a
        # quarter of city's light). The map itself is kept as loaded.
        sh = penumbra.envmap_to_sh(CITY, bands=3, rotation_y_deg=40, scale=0.3)
        self.assertTrue(bool((scene.sh[0] < 0.9 * sh[0]).all() and (scene.sh[0] > 0.6 * sh[0]).all()))
        self.assertTrue(torch.equal(penumbra.envmap_to_sh(scene.envmap, 3, 40, 0.3), sh))
        # ... and the sun is a disk light: (K, 7) rows of direction, radius, irradiance.
        self.assertIsNotNone(scene.lights)
        self.assertEqual(scene.lights.shape[1], 7)
        sun = scene.lights[0]
        self.assertGreater(float(sun[1]), 0.5 * float(sun[:3].norm()))  # about 48 degrees up
        self.assertTrue(0.01 <= float(sun[3]) <= 20.0)
        self.assertTrue(bool((sun[4:] > 0).all()))

    def test_mesh_and_texture(self):
        mesh = penumbra.load_mesh(SPOT)
        scene = penumbra.load_scene(self.write_scene(SCENE_SH))
        ob = scene.objects[0]
        self.assertEqual(mesh.vertices.dtype, torch.float32)
        self.assertEqual(mesh.faces.dtype, torch.int64)
        self.assertTrue(torch.equal(mesh.vertices, ob.vertices))
        self.assertTrue(torch.equal(mesh.faces, ob.faces))
        self.assertTrue(torch.equal(mesh.uvs, ob.uvs))
        self.assertTrue(torch.equal(mesh.uv_faces, ob.uv_faces))
        self.assertGreaterEqual(int(mesh.faces.min()), 0)
        self.assertLess(int(mesh.faces.max()), mesh.vertices.shape[0])
        tex = penumbra.load_image(SPOT_TEXTURE)
        self.assertTrue(torch.equal(tex, ob.texture))
        raw = penumbra.load_image(SPOT_TEXTURE, raw=True)
        self.assertFalse(torch.equal(tex, raw))  # sRGB decoding happened in one of them

    def test_image_and_spheres_round_trip(self):
        img = torch.rand(5, 7, 3)
        path = os.path.join(self.dir, "img.exr")
        penumbra.save_image(path, img)
        self.assertTrue(torch.equal(penumbra.load_image(path), img))
        spheres_path = os.path.join(self.dir, "s.json")
        with open(spheres_path, "w") as f:
            f.write('{"spheres": [{"center": [1, 2, 3], "radius": 0.5}]}')
        self.assertTrue(torch.equal(penumbra.load_spheres(spheres_path),
                                    torch.tensor([[1.0, 2.0, 3.0, 0.5]])))

    def test_file_errors(self):
        missing = os.path.join(self.dir, "nosuch.json")
        with self.assertRaisesRegex(penumbra.PenumbraError, "nosuch.json"):
            penumbra.load_scene(missing)
        with self.assertRaisesRegex(penumbra.PenumbraError, "nosuch.obj"):
            penumbra.load_mesh(os.path.join(self.dir, "nosuch.obj"))
        bad = self.write_scene(SCENE_SH.replace('"radius": 0.36', '"radius": -1'))
        with self.assertRaisesRegex(penumbra.PenumbraError, r"objects\[0\]\.spheres"):
            penumbra.load_scene(bad)
        with self.assertRaisesRegex(penumbra.PenumbraError, "fit"):
            v, f, _ = scenes.octasphere(1)
            penumbra.fit_spheres(v, f, 0)
        with self.assertRaises(penumbra.PenumbraError):
            penumbra.save_image(os.path.join(self.dir, "x.exr"),
                                torch.full((2, 2, 3), float("nan")))
        self.assertFalse(os.path.exists(os.path.join(self.dir, "x.exr")))

    def test_library_not_found(self):
        env = dict(os.environ, PENUMBRA_LIB=os.path.join(self.dir, "nosuch.so"),
                   PYTHONPATH=os.path.join(SRC, "python"))
        r = subprocess.run([sys.executable, "-c", "import penumbra; penumbra.version()"],
                           env=env, capture_output=True, text=True)
        self.assertNotEqual(r.returncode, 0)
        self.assertIn("libpenumbra.so not found", r.stderr)
        self.assertIn("PENUMBRA_LIB", r.stderr)


class ArgumentErrorTest(unittest.TestCase):
    def setUp(self):
        self.scene = scenes.ball_scene(8)
        self.ob = self.scene.objects[0]

    def expect(self, exc, pattern):
        with self.assertRaisesRegex(exc, pattern):
            penumbra.render_scene(self.scene)

    def test_dtype(self):
        self.ob.vertices = self.ob.vertices.double()
        self.expect(TypeError, r"objects\[0\]\.vertices must be float32, got torch.float64")

    def test_sh_dtype(self):
        self.scene.sh = self.scene.sh.half()
        self.expect(TypeError, "sh must be float32")

    def test_faces_dtype(self):
        self.ob.faces = self.ob.faces.float()
        self.expect(TypeError, r"faces must be int32 or int64")

    def test_not_a_tensor(self):
        self.ob.spheres = [[0, 0, 0, 1]]
        self.expect(TypeError, r"spheres must be a torch tensor, got list")

    def test_device(self):
        self.scene.sh = torch.empty(16, 3, device="meta")
        self.expect(ValueError, "sh must be a CPU tensor, got device meta")

    def test_shapes(self):
        self.ob.vertices = self.ob.vertices[:, :2]
        self.expect(ValueError, r"vertices must have shape \(N, 3\), got \(18, 2\)")

    def test_sh_rows(self):
        self.scene.sh = self.scene.sh[:15]
        self.expect(ValueError, "bands\\^2 rows")

    def test_pose_shape(self):
        self.ob.pose = torch.zeros(6)
        self.expect(ValueError, r"pose must have shape \(7\)")

    def test_face_index_range(self):
        f = self.ob.faces.clone()
        f[3, 1] = 18
        self.ob.faces = f
        self.expect(ValueError, r"faces: index 18 out of range \[0, 18\)")

    def test_texture_needs_uvs(self):
        self.ob.texture = torch.ones(2, 2, 3)
        self.expect(ValueError, "texture needs uvs")

    def test_background(self):
        self.scene.background = "envmap"
        self.expect(ValueError, "needs scene.envmap")
        self.scene.background = "sky"
        self.expect(ValueError, "RGB triple")

    def test_exp(self):
        self.scene.exp = "fast"
        self.expect(ValueError, "exp must be one of")

    def test_library_errors(self):
        v = self.ob.vertices.clone()
        v[2, 1] = float("nan")
        self.ob.vertices = v
        self.expect(penumbra.PenumbraError, "not finite")
        self.ob.vertices = scenes.octasphere(1)[0]
        self.ob.sphere_weights = torch.tensor([1.0, 1.0, 1.0])
        self.expect(ValueError, r"objects\[0\]\.sphere_weights must have shape \(2\), got \(3,\)")
        self.ob.sphere_weights = torch.tensor([1.0, -1.0])
        self.expect(penumbra.PenumbraError, r"objects\[0\].*sphere 1: overlap weight -1 is not")
        self.ob.sphere_weights = None
        self.ob.spheres = torch.tensor([[0.0, 0.0, 0.0, -1.0]])
        self.expect(penumbra.PenumbraError, r"objects\[0\].*sphere 0.*radius > 0")
        self.ob.spheres = None
        self.scene.camera.fov_y_deg = 0.0
        self.expect(penumbra.PenumbraError, "fov")

    def test_camera(self):
        self.scene.camera.width = 0
        self.expect(ValueError, r"camera width must be an integer in \[1, 16384\], got 0")
        self.scene.camera.width = 8
        self.scene.camera.eye = (1, 2)
        self.expect(ValueError, "camera eye must have 3 coordinates")


class AutogradTest(unittest.TestCase):
    def test_only_requested_gradients(self):
        scene = scenes.ball_scene(12)
        scene.sh.requires_grad_()
        img = penumbra.render_scene(scene)
        self.assertTrue(img.requires_grad)
        img.mean().backward()
        self.assertEqual(scene.sh.grad.shape, (16, 3))
        self.assertIsNone(scene.objects[0].vertices.grad)
        # Without any input requiring a gradient the image is a plain tensor.
        self.assertFalse(penumbra.render_scene(scenes.ball_scene(12)).requires_grad)

    def test_two_renders_one_backward(self):
        """Each forward keeps its own state: one backward through two renders (two views)
        gives the sum of the separate gradients."""
        a, b = scenes.ball_scene(12), scenes.ball_scene(12)
        b.camera.eye = (-1.0, 1.2, 2.0)
        sh = scenes.lighting().requires_grad_()
        a.sh = b.sh = sh
        (penumbra.render_scene(a).sum() + 2 * penumbra.render_scene(b).sum()).backward()
        both = sh.grad.clone()
        sh.grad = None
        penumbra.render_scene(a).sum().backward()
        ga = sh.grad.clone()
        sh.grad = None
        penumbra.render_scene(b).sum().backward()
        self.assertTrue(torch.allclose(both, ga + 2 * sh.grad, rtol=1e-5, atol=1e-5))
        self.assertFalse(torch.allclose(ga, sh.grad))

    def test_non_contiguous_and_lists(self):
        scene = scenes.ball_scene(12)
        ob = scene.objects[0]
        vt = ob.vertices.t().contiguous().requires_grad_()
        ob.vertices = vt.t()  # a non-contiguous view
        ob.albedo = [0.8, 0.5, 0.3]
        ref = penumbra.render_scene(scenes.ball_scene(12))
        img = penumbra.render_scene(scene)
        self.assertTrue(torch.equal(img, ref))
        img.sum().backward()
        self.assertEqual(vt.grad.shape, (3, 18))
        self.assertGreater(float(vt.grad.abs().sum()), 0.0)

    def test_modified_input_is_refused(self):
        scene = scenes.ball_scene(12)
        sh = scene.sh.requires_grad_()
        img = penumbra.render_scene(scene)
        with torch.no_grad():
            sh.mul_(2.0)  # the backward would differentiate another scene
        with self.assertRaisesRegex(RuntimeError, "modified by an inplace operation"):
            img.sum().backward()

    def test_threads_do_not_change_results(self):
        scene = scenes.ball_scene(80, textured=True)  # above the one-thread size
        scene.sh.requires_grad_()
        out = []
        for threads in (1, 3):
            scene.sh.grad = None
            img = penumbra.render_scene(scene, threads=threads)
            img.square().sum().backward()
            out.append((img, scene.sh.grad.clone()))
        self.assertTrue(torch.equal(out[0][0], out[1][0]))
        self.assertTrue(torch.equal(out[0][1], out[1][1]))

    def test_render_one_object(self):
        """penumbra.render (one object, keyword arguments) is render_scene of that scene."""
        scene = scenes.ball_scene(12, textured=True)
        ob = scene.objects[0]
        img = penumbra.render(ob.vertices, ob.faces, scene.sh, scene.camera, uvs=ob.uvs,
                              texture=ob.texture, spheres=ob.spheres, pose=ob.pose,
                              ground_albedo=scene.ground_albedo, ground_half_size=3.0,
                              background=(0.2, 0.3, 0.4), self_shadow="spheres",
                              texture_filter="point")
        self.assertTrue(torch.equal(img, penumbra.render_scene(scene)))


class OverlapTest(unittest.TestCase):
    def test_weights(self):
        one = penumbra.overlap_weights(torch.tensor([[0.0, 1.0, 0.0, 0.5]]))
        self.assertEqual(one.tolist(), [2.0])  # a lone sphere gets the target
        two = penumbra.overlap_weights([[0.0, 1.0, 0.0, 0.5], [0.0, 1.0, 0.0, 0.5]])
        self.assertTrue(torch.allclose(two, torch.tensor([1.0, 1.0]), rtol=1e-3))
        with self.assertRaisesRegex(penumbra.PenumbraError, "radius > 0"):
            penumbra.overlap_weights([[0.0, 0.0, 0.0, -1.0]])

    def test_none_is_weights_of_one(self):
        """overlap "none" renders bitwise as weights of 1; the fixture's weights differ."""
        scene = scenes.ball_scene(12)
        weighted = penumbra.render_scene(scene)
        scene.overlap = "none"
        plain = penumbra.render_scene(scene)
        scene.overlap = "weights"
        scene.objects[0].sphere_weights = torch.ones(2)
        self.assertTrue(torch.equal(plain, penumbra.render_scene(scene)))
        self.assertFalse(torch.equal(plain, weighted))
        scene.overlap = "half"
        with self.assertRaisesRegex(ValueError, "overlap must be"):
            penumbra.render_scene(scene)

    def test_ground_occlusion(self):
        """The ground hides the lower horizon from the objects by default; "receiver" renders the
        ball differently and the ground itself the same; without shadows the mode changes
        nothing."""
        scene = scenes.ball_scene(12)
        occluded = penumbra.render_scene(scene)
        scene.ground_occlusion = "receiver"
        received = penumbra.render_scene(scene)
        self.assertFalse(torch.equal(occluded, received))
        self.assertTrue(torch.equal(penumbra.render_scene(scene, shadows=False),
                                    penumbra.render_scene(dataclasses.replace(
                                        scene, ground_occlusion="occludes"), shadows=False)))
        scene.ground_occlusion = "floor"
        with self.assertRaisesRegex(ValueError, "ground_occlusion must be"):
            penumbra.render_scene(scene)


if __name__ == "__main__":
    unittest.main()
