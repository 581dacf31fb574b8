// Profiling counters of the ray caster (esvo §8.5, Table 6), the per-pixel
// iteration image and its heat map (Figure 32): exact counts on hand-built
// octrees, loop invariants on random rays, and counters on == counters off.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <memory>
#include <random>
#include <string>

#include "support/cli_runner.hpp"
#include "support/esvo_testing.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/render.hpp"

namespace voxcast {
namespace {

using esvo::CastResult;
using esvo::EsvoOctree;
using testing::desc;
using testing::hand_octree;

// World ray of the unit grid -> octree space ([1,2]^3; t unchanged).
CastResult counted(const EsvoOctree& o, Vec3 world_origin, Vec3 dir, RayCounters* c) {
  return esvo::cast_ray(o, world_origin + Vec3{1, 1, 1}, normalize(dir), INFINITY, 0.f, 0.f,
                        nullptr, c);
}

TEST(RenderStats, ExactCountsOneLevel) {
  // Root with one leaf in child slot 0: the world cube [0, 0.5]^3.
  const EsvoOctree o = hand_octree(1, {desc(0, false, 0x01, 0x01)});
  {
    // Straight into the leaf: one iteration that INTERSECTs and hits.
    RayCounters c;
    const CastResult r = counted(o, {0.25f, 0.25f, -1.f}, {0, 0, 1}, &c);
    ASSERT_TRUE(r.hit);
    EXPECT_EQ(r.t, 1.f);
    EXPECT_EQ(c.iterations, 1u);
    EXPECT_EQ(c.intersects, 1u);
    EXPECT_EQ(c.pushes, 0u);
    EXPECT_EQ(c.stores, 0u);
    EXPECT_EQ(c.advances, 0u);
    EXPECT_EQ(c.pops, 0u);
    EXPECT_EQ(c.descriptor_fetches, 1u);
    EXPECT_EQ(c.far_reads, 0u);
    EXPECT_EQ(c.bytes(), 8u);
  }
  {
    // Through the two empty children at x, y in [0.5, 1]: two ADVANCEs, the
    // second leaves the root (one POP), nothing is intersected.
    RayCounters c;
    const CastResult r = counted(o, {0.75f, 0.75f, -1.f}, {0, 0, 1}, &c);
    EXPECT_FALSE(r.hit);
    EXPECT_EQ(c.iterations, 2u);
    EXPECT_EQ(c.intersects, 0u);
    EXPECT_EQ(c.pushes, 0u);
    EXPECT_EQ(c.advances, 2u);
    EXPECT_EQ(c.pops, 1u);
    EXPECT_EQ(c.descriptor_fetches, 1u);
  }
  {
    // Missing the root cube: no iteration at all, counters untouched.
    RayCounters c;
    c.iterations = 5;  // accumulates, never resets
    EXPECT_FALSE(counted(o, {2.f, 2.f, -1.f}, {0, 0, 1}, &c).hit);
    EXPECT_EQ(c.iterations, 5u);
    EXPECT_EQ(c.bytes(), 0u);
  }
}

TEST(RenderStats, ExactCountsTwoLevels) {
  // Root: non-leaf child 0 (world [0,0.5]^3) whose descriptor (slot 2) has a
  // single leaf in child slot 7 (world [0.25,0.5]^3).
  const EsvoOctree o = hand_octree(2, {desc(1, false, 0x01, 0x00), desc(0, false, 0x80, 0x80)});
  RayCounters c;
  const CastResult r = counted(o, {0.375f, 0.375f, -1.f}, {0, 0, 1}, &c);
  ASSERT_TRUE(r.hit);
  EXPECT_EQ(r.t, 1.25f);
  EXPECT_EQ(r.parent_slot, 2u);
  EXPECT_EQ(r.child, 7);
  // 1: INTERSECT child 0 of the root, PUSH (its exit t 1.5 < root exit 2:
  //    stored); 2: empty child 3, ADVANCE; 3: INTERSECT leaf 7, hit.
  EXPECT_EQ(c.iterations, 3u);
  EXPECT_EQ(c.intersects, 2u);
  EXPECT_EQ(c.pushes, 1u);
  EXPECT_EQ(c.stores, 1u);
  EXPECT_EQ(c.advances, 1u);
  EXPECT_EQ(c.pops, 0u);
  EXPECT_EQ(c.descriptor_fetches, 2u);
  EXPECT_EQ(c.bytes(), 16u);

  // Same octree, along -x at y = z = 0.375: the empty child 1 (ADVANCE),
  // then child 0, which the ray leaves through the root's own exit face
  // (x = 0): its tc_max equals h, so the PUSH is not stored (§6.1 "h").
  RayCounters c2;
  const CastResult r2 = counted(o, {2.f, 0.375f, 0.375f}, {-1, 0, 0}, &c2);
  ASSERT_TRUE(r2.hit);
  EXPECT_EQ(r2.t, 1.5f);
  EXPECT_EQ(c2.iterations, 3u);
  EXPECT_EQ(c2.advances, 1u);
  EXPECT_EQ(c2.pushes, 1u);
  EXPECT_EQ(c2.stores, 0u);
  EXPECT_EQ(c2.pops, 0u);
}

// Loop invariants (Figure 15 / Appendix A): every iteration ends in exactly
// one of PUSH, ADVANCE or a terminating hit; POP follows an ADVANCE; a store
// follows a PUSH; a descriptor is fetched at the start, after every PUSH and
// after every POP that stays inside the root.
TEST(RenderStats, LoopInvariantsOnRandomRays) {
  TraceContext ctx;
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(-0.5f, 1.5f);
  esvo::BuildOptions bo;
  bo.max_block_slots = 32;  // many blocks: far pointers get read
  const auto octree = std::make_shared<const EsvoOctree>(
      esvo::build_octree(testing::make_random_voxels(6, 6000, 11), bo));
  const esvo::EsvoStructure s(octree);
  RayCounters total;
  uint64_t hits = 0, rays = 0;
  for (int i = 0; i < 20000; ++i) {
    const Vec3 o{u(rng), u(rng), u(rng)};
    const Vec3 target{u(rng) * 0.5f + 0.25f, u(rng) * 0.5f + 0.25f, u(rng) * 0.5f + 0.25f};
    LodFootprint lod;
    if (i % 4 == 0) lod.size_per_t = 0.02f;  // LOD stops are hits too
    TraceContext counted;
    counted.counting = true;
    SurfaceHit h;
    const bool hit = s.trace({o, normalize(target - o), INFINITY}, lod, counted, &h);
    const RayCounters& c = counted.counters;
    SurfaceHit plain;
    ASSERT_EQ(hit, s.trace({o, normalize(target - o), INFINITY}, lod, ctx, &plain));
    if (hit) {
      ASSERT_EQ(std::memcmp(&h.t, &plain.t, sizeof h.t), 0);
    }
    ++rays;
    hits += hit;
    if (c.iterations == 0) {
      EXPECT_FALSE(hit);
      EXPECT_EQ(c.bytes(), 0u);
      continue;
    }
    ASSERT_EQ(c.iterations, c.pushes + c.advances + (hit ? 1 : 0)) << i;
    ASSERT_LE(c.stores, c.pushes);
    ASSERT_LE(c.pops, c.advances);
    ASSERT_LE(c.intersects, c.iterations);
    ASSERT_GE(c.intersects, c.pushes);
    ASSERT_EQ(c.descriptor_fetches, 1 + c.pushes + c.pops - (hit ? 0 : 1)) << i;
    ASSERT_LE(c.far_reads, c.pushes);
    if (!hit) {
      ASSERT_GE(c.pops, 1u);  // a miss ends by popping out of the root
    }
    total += c;
  }
  EXPECT_GT(hits, rays / 10);
  EXPECT_LT(hits, rays);
  EXPECT_GT(total.far_reads, 0u);
  EXPECT_EQ(total.bytes(), total.descriptor_fetches * 8 + total.far_reads * 4);
}

RenderOptions sphere_view() {
  RenderOptions ro;
  ro.width = 96;
  ro.height = 64;
  ro.camera.eye = {0.2f, 0.8f, 2.f};
  ro.camera.target = {0.5f, 0.5f, 0.5f};
  ro.want_depth = ro.want_normal = true;
  ro.lod_pixels = 0.f;
  return ro;
}

TEST(RenderStats, CountersDoNotChangeTheImageAndAddUp) {
  const esvo::EsvoStructure s(
      std::make_shared<const EsvoOctree>(esvo::build_octree(testing::make_sphere_shell(7))));
  RenderOptions ro = sphere_view();
  for (int beam : {0, 8}) {
    ro.beam = beam;
    ro.collect_stats = false;
    const RenderResult off = render(s, ro);
    ro.collect_stats = true;
    const RenderResult on = render(s, ro);
    EXPECT_TRUE(off.color.pixels == on.color.pixels);
    EXPECT_EQ(
        std::memcmp(off.depth.pixels.data(), on.depth.pixels.data(), off.depth.pixels.size() * 4),
        0);
    EXPECT_TRUE(off.normal.pixels == on.normal.pixels);
    EXPECT_EQ(off.counters.iterations, 0u);  // off = not collected
    EXPECT_TRUE(off.iterations.pixels.empty());
    ASSERT_EQ(on.iterations.width, ro.width);
    ASSERT_EQ(on.iterations.channels, 1);
    // The image sums to the frame total; misses of the root cube are 0.
    double sum = 0;
    size_t zero = 0;
    for (float v : on.iterations.pixels) sum += v, zero += v == 0.f;
    EXPECT_EQ(uint64_t(sum), on.counters.iterations);
    EXPECT_GT(zero, 0u);
    const RayCounters& c = on.counters;
    EXPECT_EQ(c.attribute_bytes, 12 * on.hits);  // raw attachment: lookup entry + value
    EXPECT_EQ(c.iterations, c.pushes + c.advances + on.hits);
    EXPECT_LE(c.pops, c.advances);
    EXPECT_GT(on.per_ray(c.iterations), 1.0);
    if (beam) {
      EXPECT_EQ(on.beams, uint64_t((96 / 8) * (64 / 8)));
      EXPECT_GT(on.coarse_counters.iterations, 0u);
    } else {
      EXPECT_EQ(on.beams, 0u);
      EXPECT_EQ(on.coarse_counters.iterations, 0u);
    }
  }
  // The beam takes iterations off the full-resolution rays.
  ro.collect_stats = true;
  ro.beam = 0;
  const RenderResult plain = render(s, ro);
  ro.beam = 8;
  const RenderResult beamed = render(s, ro);
  EXPECT_LT(beamed.counters.iterations, plain.counters.iterations);
}

TEST(RenderStats, HeatmapRamp) {
  Image it(11, 1, 1);
  for (int x = 0; x < 11; ++x) *it.at(x, 0) = float(x) * 6.4f;
  const Image h = iteration_heatmap(it, 64.f);
  ASSERT_EQ(h.channels, 3);
  // Black at 0, pale yellow at the maximum, lightness increasing in between.
  EXPECT_LT(h.at(0, 0)[0] + h.at(0, 0)[1] + h.at(0, 0)[2], 0.01f);
  EXPECT_GT(h.at(10, 0)[0], 0.9f);
  EXPECT_GT(h.at(10, 0)[1], 0.9f);
  auto luma = [&](int x) {
    return 0.2126f * h.at(x, 0)[0] + 0.7152f * h.at(x, 0)[1] + 0.0722f * h.at(x, 0)[2];
  };
  for (int x = 1; x < 11; ++x) EXPECT_GT(luma(x), luma(x - 1)) << x;
  *it.at(3, 0) = 1000.f;  // clamped
  EXPECT_EQ(iteration_heatmap(it, 64.f).at(3, 0)[1], h.at(10, 0)[1]);
  EXPECT_THROW(iteration_heatmap(it, 0.f), Error);
}

TEST(RenderStats, CliStatsAndHeatmap) {
  testing::TempDir dir;
  const std::string mesh =
      (std::filesystem::path(VOXCAST_TEST_DATA_DIR) / "meshes" / "stanford-bunny.obj").string();
  ASSERT_EQ(testing::run_cli("build " + mesh + " -o " + dir.file("b.vxc") + " --resolution 128")
                .exit_code,
            0);
  const testing::CliResult r =
      testing::run_cli("render " + dir.file("b.vxc") + " -o " + dir.file("a.png") +
                       " --size 80x60 --stats --beam 4 --heatmap " + dir.file("h.png"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  for (const char* row : {"iterations", "intersect", "push", "store", "advance", "pop", "bytes",
                          "coarse pass", "heatmap:", "= 64 iterations"})
    EXPECT_NE(r.output.find(row), std::string::npos) << row << "\n" << r.output;
  const Image h = read_png(dir.file("h.png"));
  EXPECT_EQ(h.width, 80);
  EXPECT_EQ(h.height, 60);
  float brightest = 0;
  for (float v : h.pixels) brightest = std::max(brightest, v);
  EXPECT_GT(brightest, 0.2f);  // not all black
  // --heatmap alone works, a non-png heat map is a one-line error.
  EXPECT_EQ(testing::run_cli("render " + dir.file("b.vxc") + " -o " + dir.file("a.png") +
                             " --size 40x30 --heatmap " + dir.file("h2.png"))
                .exit_code,
            0);
  EXPECT_TRUE(std::filesystem::exists(dir.file("h2.png")));
  const testing::CliResult bad =
      testing::run_cli("render " + dir.file("b.vxc") + " -o " + dir.file("a.png") + " --heatmap " +
                       dir.file("h.pfm"));
  EXPECT_NE(bad.exit_code, 0);
  EXPECT_NE(bad.output.find("--heatmap"), std::string::npos) << bad.output;
}

}  // namespace
}  // namespace voxcast
