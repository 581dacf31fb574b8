// Beam optimization (esvo §6.2): the coarse pass may only skip work. Every
// ray traced with its block's start region must return exactly the hit of
// the plain caster (hit flag, t bit for bit, voxel, child, level, position),
// on the shared meshes and on random octrees with random cameras (eye
// outside, inside the root cube, inside occupied space; partial blocks at
// the image borders; LOD on and off), for the ESVO octree and for the sparse
// voxel DAG of the same voxels (svdag §4: the same loop, the same beam).
#include <gtest/gtest.h>

#include <bit>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <functional>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "render/beam.hpp"
#include "support/cli_runner.hpp"
#include "support/esvo_testing.hpp"
#include "support/shared_meshes.hpp"
#include "support/test_data.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/render.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast {
namespace {

const std::filesystem::path kMeshes = std::filesystem::path(VOXCAST_TEST_DATA_DIR) / "meshes";

struct BeamDiff {
  size_t rays = 0, hits = 0, mismatches = 0, empty_blocks = 0;
  uint64_t iterations_plain = 0, iterations_beam = 0;
  std::string first;  // description of the first mismatch
};

bool same_hit(bool a_hit, const SurfaceHit& a, bool b_hit, const SurfaceHit& b) {
  if (a_hit != b_hit) return false;
  if (!a_hit) return true;
  return std::bit_cast<uint32_t>(a.t) == std::bit_cast<uint32_t>(b.t) &&
         a.voxel_ref == b.voxel_ref && a.child == b.child && a.level == b.level &&
         a.voxel_size == b.voxel_size &&
         std::bit_cast<uint32_t>(a.position.x) == std::bit_cast<uint32_t>(b.position.x) &&
         std::bit_cast<uint32_t>(a.position.y) == std::bit_cast<uint32_t>(b.position.y) &&
         std::bit_cast<uint32_t>(a.position.z) == std::bit_cast<uint32_t>(b.position.z);
}

// Traces every pixel of a W x H image plainly and with the start region of
// its K x K block (blocks on the K grid, partial at the right/bottom border).
// `tamper` may modify the coarse result (negative control).
BeamDiff compare_beam(const Structure& structure, const Camera& camera, int W, int H, int K,
                      float lod_pixels, const std::function<void(BeamStart&)>& tamper = {}) {
  const SurfaceQuery& s = *structure.surface();
  TraceContext plain_ctx, counted_a, counted_b;
  counted_a.counting = counted_b.counting = true;
  const CameraRays cam(camera, W, H);
  LodFootprint lod;  // as render() sets it: orthographic pixels have a constant footprint
  lod.size_at_origin = lod_pixels * cam.pixel_size();
  lod.size_per_t = lod_pixels * cam.pixel_angle();
  BeamDiff diff;
  for (int by = 0; by < H; by += K) {
    for (int bx = 0; bx < W; bx += K) {
      const int bx1 = std::min(bx + K, W), by1 = std::min(by + K, H);
      BeamStart start;
      s.beam_start(detail::block_beam(cam, bx, by, bx1, by1, lod), plain_ctx, &start);
      EXPECT_TRUE(start.valid);
      if (tamper) tamper(start);
      diff.empty_blocks += start.empty;
      for (int y = by; y < by1; ++y) {
        for (int x = bx; x < bx1; ++x) {
          const Ray ray = cam.ray(x, y);
          SurfaceHit a, b;
          const uint64_t ia = counted_a.counters.iterations, ib = counted_b.counters.iterations;
          const bool ha = s.trace(ray, lod, counted_a, &a);
          const bool hb = s.trace(ray, lod, counted_b, &b, &start);
          SurfaceHit plain;
          const bool hp = s.trace(ray, lod, plain_ctx, &plain);
          ++diff.rays;
          diff.hits += ha;
          diff.iterations_plain += counted_a.counters.iterations - ia;
          diff.iterations_beam += counted_b.counters.iterations - ib;
          if (!same_hit(ha, a, hp, plain) || !same_hit(ha, a, hb, b)) {
            if (diff.mismatches++ == 0) {
              char buf[256];
              std::snprintf(buf, sizeof buf,
                            "pixel (%d,%d): plain hit=%d t=%.9g ref=%llu child=%u, beam hit=%d "
                            "t=%.9g ref=%llu child=%u",
                            x, y, int(ha), double(a.t), (unsigned long long)a.voxel_ref, a.child,
                            int(hb), double(b.t), (unsigned long long)b.voxel_ref, b.child);
              diff.first = buf;
            }
          }
        }
      }
    }
  }
  return diff;
}

std::shared_ptr<const esvo::EsvoOctree> octree_of(const VoxelSet& set,
                                                  uint32_t max_block_slots = 1u << 20) {
  esvo::BuildOptions bo;
  bo.max_block_slots = max_block_slots;
  return std::make_shared<const esvo::EsvoOctree>(esvo::build_octree(set, bo));
}

std::shared_ptr<const dag::SparseVoxelDag> dag_of(const VoxelSet& set) {
  return std::make_shared<const dag::SparseVoxelDag>(dag::build_dag(set));
}

// The ESVO octree and the DAG of the same voxels (both Structures).
std::vector<std::unique_ptr<Structure>> structures_of(const VoxelSet& set,
                                                      uint32_t max_block_slots = 1u << 20) {
  std::vector<std::unique_ptr<Structure>> v;
  v.push_back(std::make_unique<esvo::EsvoStructure>(octree_of(set, max_block_slots)));
  v.push_back(std::make_unique<dag::DagStructure>(dag_of(set)));
  return v;
}

// ---------------------------------------------------------------------------

class SharedMeshBeam : public ::testing::TestWithParam<const char*> {};

TEST_P(SharedMeshBeam, HitsIdenticalWithAndWithoutBeam) {
  const Mesh mesh = load_mesh(testing::test_mesh(GetParam()));
  VoxelizeOptions vo;
  vo.mode = VoxelizationMode::Conservative;
  const VoxelSet voxels = voxelize(mesh, GridTransform::fit(mesh.bounds(), 1024), vo);
  const auto structures = structures_of(voxels);
  const int W = 320, H = 240;
  // Framed view; a view from inside the bounds (eye in the root cube); a
  // grazing view from far away with a narrow field of view.
  const Aabb b = mesh.bounds();
  std::vector<Camera> cams;
  cams.push_back(Camera::frame(b, W, H));
  Camera inside;
  inside.eye = b.center() + b.extent() * 0.05f;
  inside.target = b.center() + Vec3{b.extent().x, -0.2f * b.extent().y, 0.3f * b.extent().z};
  inside.fovy_degrees = 80.f;
  cams.push_back(inside);
  Camera far;
  far.eye = b.center() + Vec3{-3.f * b.extent().x, 0.1f * b.extent().y, 0.f};
  far.target = b.center();
  far.fovy_degrees = 15.f;
  cams.push_back(far);
  for (const auto& s : structures) {
    for (size_t ci = 0; ci < cams.size(); ++ci) {
      for (int K : {4, 8}) {
        for (float lod : {0.f, 1.f}) {
          const BeamDiff d = compare_beam(*s, cams[ci], W, H, K, lod);
          std::printf(
              "%s %s cam %zu K=%d lod=%g: %zu rays, %zu hits, iterations/ray %.2f -> %.2f\n",
              GetParam(), s->name().c_str(), ci, K, double(lod), d.rays, d.hits,
              double(d.iterations_plain) / double(d.rays),
              double(d.iterations_beam) / double(d.rays));
          EXPECT_EQ(d.mismatches, 0u)
              << s->name() << " cam " << ci << " K " << K << " lod " << lod << ": " << d.first;
          EXPECT_GT(d.hits, 0u);
          EXPECT_LE(d.iterations_beam, d.iterations_plain);
        }
      }
    }
  }
}

INSTANTIATE_TEST_SUITE_P(SharedMeshes, SharedMeshBeam, voxcast::testing::all_shared_meshes(),
                         voxcast::testing::mesh_test_name);

// The comparison above can fail: a start region that is too small (here the
// far half of the true one) changes hits.
TEST(Beam, ComparisonDetectsABadStartRegion) {
  for (const auto& sp : structures_of(testing::make_sphere_shell(6))) {
    SCOPED_TRACE(sp->name());
    const Structure& s = *sp;
    Camera cam;
    cam.eye = {0.5f, 0.6f, 2.5f};
    cam.target = {0.5f, 0.5f, 0.5f};
    const BeamDiff ok = compare_beam(s, cam, 256, 192, 8, 0.f);
    EXPECT_EQ(ok.mismatches, 0u) << ok.first;
    ASSERT_GT(ok.hits, 100u);
    const BeamDiff bad = compare_beam(s, cam, 256, 192, 8, 0.f, [](BeamStart& b) {
      if (!b.empty) b.region.hi.z = 0.5f * (b.region.lo.z + b.region.hi.z);  // drops the near side
    });
    EXPECT_GT(bad.mismatches, 0u);
    // Beam works: fewer iterations, and the sphere's corners are empty blocks.
    EXPECT_LT(ok.iterations_beam, ok.iterations_plain);
    EXPECT_GT(ok.empty_blocks, 0u);
  }
}

TEST(Beam, RandomOctreesAndCameras) {
  std::mt19937 rng(20240611);
  std::uniform_real_distribution<float> u01(0.f, 1.f);
  auto rnd = [&](float lo, float hi) { return lo + (hi - lo) * u01(rng); };
  // A solid ball (eye inside occupied space), random clouds at two depths,
  // a shell, and a multi-block layout with far pointers.
  // Each set as an ESVO octree and as a DAG (structure index oi / 2).
  std::vector<std::unique_ptr<Structure>> structures;
  auto add = [&](const VoxelSet& set, uint32_t max_block_slots = 1u << 20) {
    for (auto& s : structures_of(set, max_block_slots)) structures.push_back(std::move(s));
  };
  add(testing::make_dense_grid(5, [](uint32_t x, uint32_t y, uint32_t z) {
    const int dx = int(x) - 16, dy = int(y) - 16, dz = int(z) - 16;
    return dx * dx + dy * dy + dz * dz < 144;
  }));
  add(testing::make_random_voxels(4, 300, 1));
  add(testing::make_random_voxels(7, 3000, 2));
  add(testing::make_sphere_shell(7));
  add(testing::make_random_voxels(6, 5000, 3), 64);
  add(testing::make_random_voxels(2, 20, 4));  // the smallest DAG: the root is a 4^3 leaf mask
  size_t total_rays = 0, total_hits = 0, inside_eyes = 0, ortho_rays = 0, ortho_hits = 0;
  for (size_t si = 0; si < structures.size(); ++si) {
    const Structure& s = *structures[si];
    const size_t oi = si / 2;
    for (int trial = 0; trial < 48; ++trial) {
      Camera cam;
      if (trial % 3 == 0) {
        cam.eye = {rnd(0.05f, 0.95f), rnd(0.05f, 0.95f),
                   rnd(0.05f, 0.95f)};  // inside the root cube
      } else if (trial % 3 == 1 && oi == 0) {
        cam.eye = {rnd(0.45f, 0.55f), rnd(0.45f, 0.55f), rnd(0.45f, 0.55f)};  // inside the ball
      } else {
        cam.eye = {rnd(-1.5f, 2.5f), rnd(-1.5f, 2.5f), rnd(-1.5f, 2.5f)};
      }
      cam.target = {rnd(0.2f, 0.8f), rnd(0.2f, 0.8f), rnd(0.2f, 0.8f)};
      if (trial % 5 == 4) cam.target = cam.eye + Vec3{0.f, 0.f, 1.f};    // axis-aligned view
      if (trial % 7 == 6) cam.target = cam.eye + Vec3{1e-3f, 1.f, 0.f};  // nearly axis-aligned
      cam.up = normalize(Vec3{rnd(-0.3f, 0.3f), 1.f, rnd(-0.3f, 0.3f)});
      cam.fovy_degrees = rnd(10.f, 100.f);
      const bool inside = cam.eye.x > 0 && cam.eye.x < 1 && cam.eye.y > 0 && cam.eye.y < 1 &&
                          cam.eye.z > 0 && cam.eye.z < 1;
      inside_eyes += inside;
      const int K = (trial % 3 == 2) ? 3 : (trial % 2 ? 8 : 4);
      const int W = 37 + trial, H = 29 + (trial * 3) % 11;  // blocks cut by the borders
      const float lod = (trial % 4 == 3) ? 2.f : 0.f;
      const BeamDiff d = compare_beam(s, cam, W, H, K, lod);
      EXPECT_EQ(d.mismatches, 0u) << s.name() << " " << oi << " trial " << trial << " eye "
                                  << cam.to_string() << ": " << d.first;
      total_rays += d.rays;
      total_hits += d.hits;
      // The same view with parallel rays (the beam is then a prism), from
      // narrow to wider than the root cube.
      Camera ortho = cam;
      ortho.projection = Projection::Orthographic;
      ortho.ortho_width = 0.05f + 0.6f * float(trial % 5);
      const BeamDiff o = compare_beam(s, ortho, W, H, K, lod);
      EXPECT_EQ(o.mismatches, 0u) << s.name() << " " << oi << " trial " << trial << " ortho "
                                  << ortho.to_string() << ": " << o.first;
      ortho_rays += o.rays;
      ortho_hits += o.hits;
    }
  }
  EXPECT_GT(inside_eyes, 10u);
  EXPECT_GT(total_hits, total_rays / 10);
  EXPECT_LT(total_hits, total_rays);
  EXPECT_GT(ortho_hits, ortho_rays / 10);
  EXPECT_LT(ortho_hits, ortho_rays);
}

// The renderer with the beam produces the same images; the timed frame
// includes the coarse pass; tiles that do not divide by K work.
TEST(Beam, RenderImagesIdentical) {
  for (const auto& sp : structures_of(testing::make_sphere_shell(7))) {
    SCOPED_TRACE(sp->name());
    const Structure& s = *sp;
    RenderOptions ro;
    ro.width = 101;
    ro.height = 67;
    ro.camera.eye = {0.3f, 0.7f, 1.9f};
    ro.camera.target = {0.5f, 0.5f, 0.5f};
    ro.want_depth = ro.want_normal = true;
    ro.lod_pixels = 0.f;
    for (int tile : {16, 10}) {
      ro.tile_size = tile;
      ro.beam = 0;
      const RenderResult a = render(s, ro);
      for (int K : {4, 8}) {
        ro.beam = K;
        const RenderResult b = render(s, ro);
        EXPECT_EQ(a.hits, b.hits);
        EXPECT_GT(b.hits, 0u);
        EXPECT_TRUE(a.color.pixels == b.color.pixels) << "tile " << tile << " K " << K;
        EXPECT_TRUE(a.normal.pixels == b.normal.pixels);
        ASSERT_EQ(a.depth.pixels.size(), b.depth.pixels.size());
        EXPECT_EQ(
            std::memcmp(a.depth.pixels.data(), b.depth.pixels.data(), a.depth.pixels.size() * 4),
            0);
      }
    }
  }
}

TEST(Beam, BadBlockSizeIsAnError) {
  const esvo::EsvoStructure s(octree_of(testing::make_sphere_shell(4)));
  RenderOptions ro;
  ro.width = 8, ro.height = 8;
  for (int bad : {1, -4, 65}) {
    ro.beam = bad;
    EXPECT_THROW(render(s, ro), Error) << bad;
  }
  testing::TempDir dir;
  ASSERT_EQ(testing::run_cli("build " + (kMeshes / "teapot.obj").string() + " -o " +
                             dir.file("t.vxc") + " --resolution 64")
                .exit_code,
            0);
  const testing::CliResult r =
      testing::run_cli("render " + dir.file("t.vxc") + " -o " + dir.file("a.png") + " --beam 1");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("--beam"), std::string::npos) << r.output;
  const testing::CliResult ok = testing::run_cli("render " + dir.file("t.vxc") + " -o " +
                                                 dir.file("b.png") + " --size 64x48 --beam 8");
  EXPECT_EQ(ok.exit_code, 0) << ok.output;
}

}  // namespace
}  // namespace voxcast
