// The tile caster (SurfacePackets::trace_tile, core/octree_tile_caster.hpp)
// against the scalar caster it must reproduce bit for bit: every SurfaceHit
// field of every pixel equals trace() of that pixel's camera ray, for the
// ESVO (plain, with far pointers, with contours) and the DAG, at LOD 0 and
// at pixel footprints, from outside the root cube, from inside it (the eye
// among the voxels), orthographic, on image sizes that cut tiles, with
// whole-image and odd-sized tile rectangles, at the pixel center and at an
// antialiasing sample, for every kernel ISA this CPU runs (render --caster
// tile: tests/test_surface_integrator.cpp, tests/test_cli.cpp).
#include <gtest/gtest.h>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "support/octree_scenes.hpp"
#include "support/packet_testing.hpp"
#include "support/test_data.hpp"
#include "voxcast/camera.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/packet_caster.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast {
namespace {

using testing::same_hit;

using Scenes = testing::OctreeScenes;
const Scenes& scenes() {
  return testing::spot_octree_scenes();
}

// Every pixel of `rect` (x0, y0, x1, y1) of the w x h image of `camera`:
// trace_tile == trace(). Returns the hits.
template <class S>
size_t expect_same(const S& s, const Camera& camera, int w, int h, const LodFootprint& lod,
                   const int rect[4], const std::string& what, Vec2 sample = {0.5f, 0.5f}) {
  const CameraRays cam(camera, w, h, sample);
  const int x0 = rect[0], y0 = rect[1], x1 = rect[2], y1 = rect[3];
  const size_t n = size_t(x1 - x0) * size_t(y1 - y0);
  std::vector<SurfaceHit> want(n);
  std::vector<uint8_t> want_found(n);
  TraceContext ctx;
  for (int y = y0; y < y1; ++y)
    for (int x = x0; x < x1; ++x) {
      const size_t k = size_t(y - y0) * size_t(x1 - x0) + size_t(x - x0);
      want_found[k] = s.trace(cam.ray(x, y), lod, ctx, &want[k]);
    }
  size_t hits = 0;
  for (uint8_t f : want_found) hits += f;
  for (const Isa isa : testing::packet_isas()) {
    std::vector<SurfaceHit> got(n);
    std::vector<uint8_t> found(n, 7);
    const bool tiled =
        s.packets()->trace_tile(cam, x0, y0, x1, y1, lod, ctx, got.data(), found.data(), isa);
    EXPECT_TRUE(tiled) << what;
    size_t bad = 0;
    for (size_t k = 0; k < n; ++k) {
      const bool ok = found[k] == want_found[k] && (!found[k] || same_hit(got[k], want[k]));
      if (!ok && ++bad <= 5)
        ADD_FAILURE() << what << " " << isa_name(isa) << " pixel " << x0 + int(k) % (x1 - x0) << ","
                      << y0 + int(k) / (x1 - x0) << ": found " << int(found[k]) << " want "
                      << int(want_found[k]) << ", t " << got[k].t << " want " << want[k].t
                      << ", ref " << got[k].voxel_ref << " want " << want[k].voxel_ref << ", child "
                      << got[k].child << " want " << want[k].child << ", level " << got[k].level
                      << " want " << want[k].level;
    }
    EXPECT_EQ(bad, 0u) << what << " " << isa_name(isa);
  }
  return hits;
}

template <class S>
void check_structure(const S& s, const char* name) {
  const Aabb b = s.bounds();
  const Vec3 c = (b.lo + b.hi) * 0.5f, e = b.hi - b.lo;
  const int w = 101, h = 77;  // tiles cut on both axes
  struct View {
    const char* what;
    Camera camera;
  };
  Camera inside;  // the eye among the voxels, looking across the model
  inside.eye = c + Vec3{0.05f * e.x, 0.02f * e.y, 0.1f * e.z};
  inside.target = c + Vec3{-0.4f * e.x, -0.1f * e.y, -0.3f * e.z};
  inside.fovy_degrees = 70.f;
  Camera axis;  // looking down an axis through the center: rays in grid planes
  axis.eye = c + Vec3{0.f, 0.f, 1.5f * e.z};
  axis.target = c;
  const View views[] = {
      {"frame", Camera::frame(b, w, h)},
      {"orbit", Camera::orbit(b, w, h, 200.f, -30.f)},
      {"close", Camera::orbit(b, w, h, 40.f, 20.f, 0.45f * e.x)},
      {"ortho", Camera::orbit(b, w, h, 90.f, 0.f, 0.f, Projection::Orthographic)},
      {"inside", inside},
      {"axis", axis},
  };
  const int whole[4] = {0, 0, w, h};
  const int odd[4] = {13, 5, 50, 70};  // a rectangle that is not a tile
  for (const View& v : views) {
    const CameraRays cr(v.camera, w, h);
    for (const float px : {0.f, 1.f, 4.f}) {
      LodFootprint lod;
      lod.size_per_t = px * cr.pixel_angle();
      lod.size_at_origin = px * cr.pixel_size();
      const std::string what = std::string(name) + " " + v.what + " lod " + std::to_string(px);
      const size_t hits = expect_same(s, v.camera, w, h, lod, whole, what);
      if (std::string(v.what) != "inside") {
        EXPECT_GT(hits, size_t(w * h / 20)) << what;
      }
      expect_same(s, v.camera, w, h, lod, odd, what + " rect");
      // An antialiasing sample away from the pixel center.
      expect_same(s, v.camera, w, h, lod, odd, what + " sample", {0.125f, 0.8125f});
    }
  }
}

TEST(TileCaster, EsvoHitsEqualTheScalarCaster) {
  check_structure(*scenes().esvo, "esvo");
}
TEST(TileCaster, EsvoFarPointersHitsEqualTheScalarCaster) {
  check_structure(*scenes().esvo_far, "esvo far");
}
TEST(TileCaster, EsvoContoursHitsEqualTheScalarCaster) {
  check_structure(*scenes().esvo_contours, "esvo contours");
}
TEST(TileCaster, DagHitsEqualTheScalarCaster) {
  check_structure(*scenes().dag, "dag");
}

}  // namespace
}  // namespace voxcast
