"""Voxelize the Stanford bunny, render it from three sides with shadows and
save the images as 8-bit PNG-ready arrays (here: a binary PPM, no extra
Python packages needed) plus the scene file.

    PYTHONPATH=build/python python3 examples/python/render_bunny.py [OUT_DIR]

Run by ctest as python.render_bunny (README "Python").
"""

import os
import sys

import numpy as np

import voxcast

here = os.path.dirname(os.path.abspath(__file__))
data = os.environ.get("VOXCAST_TEST_DATA_DIR", os.path.join(here, "..", "..", "tests", "data"))
out = sys.argv[1] if len(sys.argv) > 1 else os.environ.get("VOXCAST_OUT_DIR", "bunny-out")
os.makedirs(out, exist_ok=True)

scene = voxcast.build(os.path.join(data, "meshes", "stanford-bunny.obj"), resolution=128)
info = scene.info()
print("%s: %d voxels, %d bytes" % (info["format"], info["voxels"], info["memory"]["total"]))
scene.save(os.path.join(out, "bunny.vxc"))


def to_srgb8(linear):
    """Linear color -> 8-bit sRGB, as the CLI encodes PNGs."""
    c = np.clip(linear, 0, 1)
    s = np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1 / 2.4) - 0.055)
    return np.round(s * 255).astype(np.uint8)


for azimuth in (0, 90, 200):
    r = voxcast.render(scene, size=(160, 120), camera={"orbit": (azimuth, 15)},
                       shadows="hard", depth=True)
    hit = np.isfinite(r["depth"])
    path = os.path.join(out, "bunny_%03d.ppm" % azimuth)
    img = to_srgb8(r["color"])
    with open(path, "wb") as f:
        f.write(b"P6\n%d %d\n255\n" % (img.shape[1], img.shape[0]))
        f.write(img.tobytes())
    print("%s: %.1f%% of pixels hit, camera %s" % (path, 100 * hit.mean(), r["camera"]))
    # The bunny fills a good part of every view (the example fails otherwise).
    assert 0.1 < hit.mean() < 0.9, hit.mean()

# A reloaded scene renders the same picture.
again = voxcast.load(os.path.join(out, "bunny.vxc"))
a = voxcast.render(scene, size=(64, 48))["color"]
b = voxcast.render(again, size=(64, 48))["color"]
assert np.array_equal(a, b)
print("ok")
