"""Tests of the `voxcast` Python module (python/voxcast_module.cpp).

Run by ctest (python.test_voxcast) with PYTHONPATH set to the module's build
directory, VOXCAST_CLI to the `voxcast` executable and VOXCAST_TEST_DATA_DIR
to tests/data. The oracles are independent of the module: the CLI's own
files (scene files, PFM images read back here with a reader written from the
PFM format description), numpy geometry, and the scene file round trip.
"""

import os
import subprocess
import sys
import tempfile
import unittest

import numpy as np

import voxcast

CLI = os.environ.get("VOXCAST_CLI", "voxcast")
DATA = os.environ.get(
    "VOXCAST_TEST_DATA_DIR",
    os.path.join(os.path.dirname(__file__), "..", "data"))
MESH = os.path.join(DATA, "meshes", "spot.obj")
CAMEL = os.path.join(DATA, "meshes", "camel.off")
REPO = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")
SIZE = (96, 64)


def read_pfm(path):
    """PFM as written by any tool: header 'PF' (RGB) or 'Pf' (gray), 'W H',
    scale (negative = little-endian), then rows bottom to top."""
    with open(path, "rb") as f:
        data = f.read()
    fields, pos = [], 0
    while len(fields) < 4:
        while data[pos:pos + 1].isspace():
            pos += 1
        start = pos
        while not data[pos:pos + 1].isspace():
            pos += 1
        fields.append(data[start:pos].decode())
    pos += 1  # the one whitespace byte after the scale
    magic, w, h, scale = fields[0], int(fields[1]), int(fields[2]), float(fields[3])
    channels = 3 if magic == "PF" else 1
    dtype = "<f4" if scale < 0 else ">f4"
    a = np.frombuffer(data, dtype=dtype, count=w * h * channels, offset=pos)
    a = a.reshape(h, w, channels)[::-1]
    return a[:, :, 0] if channels == 1 else a


def cli(*args):
    subprocess.run([CLI, *args], check=True, stdout=subprocess.DEVNULL)


class VoxcastModule(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.TemporaryDirectory()
        cls.dir = cls.tmp.name
        # The same scene built by the CLI and by the module.
        cls.cli_scene = os.path.join(cls.dir, "cli.vxc")
        cli("build", MESH, "-o", cls.cli_scene, "--resolution", "64")
        cls.scene = voxcast.build(MESH, resolution=64)

    @classmethod
    def tearDownClass(cls):
        cls.tmp.cleanup()

    def path(self, name):
        return os.path.join(self.dir, name)

    def test_build_matches_cli_scene_file(self):
        # The module's build saved is byte-identical to `voxcast build`'s.
        out = self.path("py.vxc")
        self.scene.save(out)
        with open(out, "rb") as a, open(self.cli_scene, "rb") as b:
            self.assertEqual(a.read(), b.read())

    def test_info(self):
        info = self.scene.info()
        self.assertEqual(info["format"], "esvo")
        self.assertEqual(info["resolution"], 64)
        self.assertEqual(info["source"], "spot.obj")
        self.assertGreater(info["voxels"], 1000)
        mem = info["memory"]
        parts = sum(v for k, v in mem.items() if k not in ("total", "colors", "normals"))
        # colors + normals are the split of the attribute values: the other
        # components add up to the total.
        self.assertEqual(parts + mem["colors"] + mem["normals"], mem["total"])
        lo, hi = info["occupied_bounds"]
        self.assertTrue(all(a < b for a, b in zip(lo, hi)))

    def render_both(self, scene_path, scene, camera_args, camera):
        color = self.path("c.pfm")
        depth = self.path("d.pfm")
        cli("render", scene_path, "-o", color, "--depth", depth, "--size",
            "%dx%d" % SIZE, *camera_args)
        r = voxcast.render(scene, size=SIZE, camera=camera, depth=True)
        return r, read_pfm(color), read_pfm(depth)

    def test_render_equals_cli(self):
        cases = [
            ([], None),
            (["--orbit", "30,20"], {"orbit": "30,20"}),
            (["--orbit", "120,-10"], {"orbit": (120, -10)}),
            (["--camera", "ortho"], "ortho"),
            (["--camera", "2,1,3,0,0.5,0,0,1,0,35"], "2,1,3,0,0.5,0,0,1,0,35"),
        ]
        for args, cam in cases:
            with self.subTest(camera=cam):
                r, color, depth = self.render_both(self.cli_scene, self.scene, args, cam)
                self.assertEqual(r["color"].shape, (SIZE[1], SIZE[0], 3))
                self.assertEqual(r["color"].dtype, np.float32)
                self.assertGreater(r["hits"], 0)
                np.testing.assert_array_equal(r["color"], color)
                np.testing.assert_array_equal(r["depth"], depth)

    def test_render_options(self):
        plain = voxcast.render(self.scene, size=SIZE, normal=True)
        self.assertEqual(plain["normal"].shape, (SIZE[1], SIZE[0], 3))
        self.assertNotIn("depth", plain)
        shadow = voxcast.render(self.scene, size=SIZE, shadows="hard")
        ao = voxcast.render(self.scene, size=SIZE, ao=4)
        for r in (shadow, ao):
            self.assertFalse(np.array_equal(r["color"], plain["color"]))
        # AO only darkens: never brighter than the unoccluded image.
        self.assertTrue(np.all(ao["color"] <= plain["color"] + 1e-6))
        coarse = voxcast.render(self.scene, size=SIZE, lod=8)
        self.assertFalse(np.array_equal(coarse["color"], plain["color"]))

    def test_gi_and_spp_equal_cli(self):
        # gi=, bounces=, env=, sun=, seed= mean what `voxcast render --gi`'s
        # flags mean (the same bytes), and spp= what --spp means.
        sky = os.path.join(REPO, "scenes", "sky.hdr")
        out = self.path("gi.pfm")
        depth = self.path("gi_depth.pfm")
        cli("render", self.cli_scene, "-o", out, "--depth", depth, "--size", "%dx%d" % SIZE,
            "--gi", "6", "--bounces", "3", "--env", sky, "--env-scale", "0.8",
            "--sun", "-0.4,-1,-0.6", "--sun-intensity", "2", "--seed", "3")
        r = voxcast.render(self.scene, size=SIZE, gi=6, bounces=3, env=sky, env_scale=0.8,
                           sun=(-0.4, -1, -0.6), sun_intensity=2, seed=3, depth=True)
        self.assertEqual(r["samples"], 6 * SIZE[0] * SIZE[1])
        np.testing.assert_array_equal(r["color"], read_pfm(out))
        np.testing.assert_array_equal(r["depth"], read_pfm(depth))
        # Without environment sampling: other samples, the same CLI bytes.
        cli("render", self.cli_scene, "-o", out, "--size", "%dx%d" % SIZE, "--gi", "6",
            "--env", sky, "--no-env-sampling")
        cosine = voxcast.render(self.scene, size=SIZE, gi=6, env=sky, env_sampling=False)
        np.testing.assert_array_equal(cosine["color"], read_pfm(out))
        self.assertFalse(np.array_equal(cosine["color"],
                                        voxcast.render(self.scene, size=SIZE, gi=6, env=sky)["color"]))
        cli("render", self.cli_scene, "-o", out, "--size", "%dx%d" % SIZE, "--spp", "4")
        aa = voxcast.render(self.scene, size=SIZE, spp=4)
        np.testing.assert_array_equal(aa["color"], read_pfm(out))
        self.assertFalse(np.array_equal(aa["color"], voxcast.render(self.scene, size=SIZE)["color"]))
        with self.assertRaisesRegex(voxcast.Error, "surface shading"):
            voxcast.render(self.scene, size=SIZE, gi=2, ao=4)
        with self.assertRaisesRegex(voxcast.Error, "option of gi|options of gi"):
            voxcast.render(self.scene, size=SIZE, env=sky)
        with self.assertRaisesRegex(voxcast.Error, "bounces"):
            voxcast.render(self.scene, size=SIZE, gi=2, bounces=-1)
        with self.assertRaisesRegex(voxcast.Error, "no-such.hdr"):
            voxcast.render(self.scene, size=SIZE, gi=2, env=self.path("no-such.hdr"))

    def test_trace_equals_render_depth(self):
        for cam in (None, "ortho"):
            with self.subTest(camera=cam):
                r = voxcast.render(self.scene, size=SIZE, camera=cam, depth=True, lod=1)
                o, d, pixel_size, pixel_angle = voxcast.camera_rays(self.scene, SIZE, cam)
                t = voxcast.trace(self.scene, o.reshape(-1, 3), d.reshape(-1, 3),
                                  lod_size=pixel_size, lod_angle=pixel_angle)
                depth = r["depth"].reshape(-1)
                np.testing.assert_array_equal(t["hit"], np.isfinite(depth))
                np.testing.assert_array_equal(t["t"], depth)
                hit = t["hit"]
                self.assertGreater(hit.sum(), 100)
                # Positions lie on the rays, inside the occupied bounds.
                p = t["position"][hit]
                expect = o.reshape(-1, 3)[hit] + d.reshape(-1, 3)[hit] * t["t"][hit, None]
                voxel = self.scene.info()["voxel_size"]
                self.assertLess(np.abs(p - expect).max(), 2 * voxel)
                n = np.linalg.norm(t["normal"][hit], axis=1)
                np.testing.assert_allclose(n, 1, atol=1e-2)
                self.assertTrue(np.all(np.isnan(t["position"][~hit])))

    def test_trace_misses_and_unnormalized(self):
        lo, hi = self.scene.info()["occupied_bounds"]
        center = (np.array(lo) + np.array(hi)) / 2
        o = np.array([center + [0, 0, 10], center + [0, 0, 10], center + [0, 0, 10]],
                     dtype=np.float32)
        d = np.array([[0, 0, -1], [0, 0, -7], [0, 0, 1]], dtype=np.float32)
        t = voxcast.trace(self.scene, o, d)
        self.assertEqual(list(t["hit"]), [True, True, False])
        # t is a world distance whatever the direction's length.
        self.assertEqual(t["t"][0], t["t"][1])
        self.assertTrue(np.isinf(t["t"][2]))

    def test_load_slice_file(self):
        # A slice file (`build --slices`, esvo section 7) through the format
        # registry: the in-core scene's images, and it is not saved as a .vxc.
        vxs = self.path("cli.vxs")
        cli("build", MESH, "-o", vxs, "--resolution", "64", "--slices",
            "--slice-size", "4K")
        s = voxcast.load(vxs)
        info = s.info()
        self.assertEqual(info["format"], "esvo-sliced")
        self.assertEqual(info["resolution"], 64)
        in_core = voxcast.load(self.cli_scene)
        self.assertEqual(info["occupied_bounds"], in_core.info()["occupied_bounds"])
        a = voxcast.render(s, size=SIZE, depth=True)
        b = voxcast.render(in_core, size=SIZE, depth=True)
        np.testing.assert_array_equal(a["color"], b["color"])
        np.testing.assert_array_equal(a["depth"], b["depth"])
        with self.assertRaises(Exception):
            s.save(self.path("never.vxc"))

    def test_save_load_round_trip(self):
        for fmt in ("esvo", "dag"):
            with self.subTest(format=fmt):
                s = voxcast.build(CAMEL, resolution=32, format=fmt)
                out = self.path("rt_%s.vxc" % fmt)
                s.save(out)
                back = voxcast.load(out)
                self.assertEqual(back.info(), s.info())
                a = voxcast.render(s, size=SIZE, depth=True)
                b = voxcast.render(back, size=SIZE, depth=True)
                np.testing.assert_array_equal(a["color"], b["color"])
                np.testing.assert_array_equal(a["depth"], b["depth"])
                again = self.path("rt2_%s.vxc" % fmt)
                back.save(again)
                with open(out, "rb") as x, open(again, "rb") as y:
                    self.assertEqual(x.read(), y.read())

    def test_numpy_mesh_equals_file(self):
        m = voxcast.load_mesh(CAMEL)
        self.assertEqual(m["vertices"].shape[1], 3)
        self.assertEqual(m["faces"].shape[1], 3)
        for fmt in ("esvo", "dag"):
            with self.subTest(format=fmt):
                from_file = voxcast.build(CAMEL, resolution=32, format=fmt)
                from_arrays = voxcast.build(vertices=m["vertices"], faces=m["faces"],
                                            normals=m["normals"], color=m.get("color"),
                                            resolution=32, format=fmt)
                a, b = from_file.info(), from_arrays.info()
                self.assertEqual(b["source"], "numpy arrays")
                for k in ("source",):
                    a.pop(k), b.pop(k)
                self.assertEqual(a, b)
                ra = voxcast.render(from_file, size=SIZE, depth=True)
                rb = voxcast.render(from_arrays, size=SIZE, depth=True)
                np.testing.assert_array_equal(ra["color"], rb["color"])
                np.testing.assert_array_equal(ra["depth"], rb["depth"])

    def test_numpy_cube_voxels(self):
        # An axis-aligned box of 12 triangles: its surface voxels, from numpy
        # geometry alone, are the box's shell in the 16^3 grid.
        v = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)],
                     dtype=np.float32)
        f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
        s = voxcast.build(vertices=v, faces=f, resolution=16, format="dag",
                          color=(1.0, 0.0, 0.0))
        vox = s.voxels()
        xyz = vox["coords"]
        self.assertEqual(xyz.dtype, np.int32)
        info = s.info()
        self.assertEqual(len(xyz), info["voxels"])
        # Expected shell: grid cells whose box touches the unit cube's faces.
        origin = np.array(info["grid_origin"])
        size = info["voxel_size"]
        g = np.indices((16, 16, 16)).reshape(3, -1).T
        lo = origin + g * size
        hi = lo + size
        inside = np.all((hi >= 0) & (lo <= 1), axis=1)
        strictly = np.all((lo > 0) & (hi < 1), axis=1)
        expect = {tuple(p) for p in g[inside & ~strictly]}
        self.assertEqual({tuple(p) for p in xyz}, expect)
        self.assertTrue(np.all(vox["colors"] == [255, 0, 0]))

    def test_voxels_of_mesh(self):
        s = voxcast.build(CAMEL, resolution=32, format="dag")
        vox = s.voxels()
        self.assertEqual(vox["coords"].shape, (s.info()["voxels"], 3))
        self.assertEqual(vox["colors"].dtype, np.uint8)
        self.assertTrue(np.all((vox["coords"] >= 0) & (vox["coords"] < 32)))
        self.assertEqual(len({tuple(p) for p in vox["coords"]}), len(vox["coords"]))

    def test_errors(self):
        with self.assertRaisesRegex(voxcast.Error, "no-such.vxc"):
            voxcast.load(self.path("no-such.vxc"))
        bad = self.path("bad.vxc")
        with open(bad, "wb") as f:
            f.write(b"not a scene")
        with self.assertRaises(voxcast.Error) as e:
            voxcast.load(bad)
        self.assertNotIn("\n", str(e.exception))
        self.assertTrue(issubclass(voxcast.Error, RuntimeError))
        with self.assertRaisesRegex(voxcast.Error, "power of two"):
            voxcast.build(MESH, resolution=100)
        with self.assertRaisesRegex(voxcast.Error, "octree"):
            voxcast.build(MESH, resolution=16, format="octree")
        with self.assertRaisesRegex(voxcast.Error, "camera"):
            voxcast.render(self.scene, size=SIZE, camera="1,2,3")
        with self.assertRaises(ValueError):
            voxcast.build(vertices=np.zeros((3, 2), np.float32), faces=np.zeros((1, 3), int))
        with self.assertRaises(ValueError):
            voxcast.build(vertices=np.zeros((3, 3), np.float32), faces=np.array([[0, 1, 5]]))
        with self.assertRaisesRegex(voxcast.Error, "dag"):
            self.scene.voxels()


if __name__ == "__main__":
    unittest.main(argv=sys.argv[:1], verbosity=2)
