// GigaVoxels (gigavoxels.hpp): pools, the volume query, the LRU cache and
// requests through the frame loop, producers and INRIMAGE files.
//  * exact mode with a tiny pool renders the image of an unlimited pool;
//  * one-pass mode shows coarser data meanwhile and converges to it;
//  * validate() (no dangling pointer, no orphan, usage lists permutations)
//    holds after every pass (GigaOptions::check_after_pass);
//  * the usage list is an order-preserving partition (std::stable_partition
//    as the oracle) and recycling never takes what the pass used;
//  * producer bricks equal the producer's voxels, border included, and
//    finest-level samples equal trilinear interpolation of the producer's
//    global voxel grid computed here (seamless across bricks);
//  * quadrilinear filtering is continuous across LOD changes;
//  * INRIMAGE files: the shipped crop loads with the values written, every
//    corrupted or truncated variant is rejected with a one-line error.
#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <map>
#include <random>

#include "support/cli_runner.hpp"
#include "support/test_data.hpp"
#include "voxcast/error.hpp"
#include "voxcast/gigavoxels.hpp"
#include "voxcast/volume_integrator.hpp"

namespace voxcast::giga {
namespace {

/// A small view whose pixel cone asks for the levels these tests were
/// written for: the node levels 8-voxel bricks reach at one pixel (with
/// M = 16 a level's voxels are half as wide, so half a pixel).
FrameView view_of(int w, int h, uint32_t frame = 0) {
  FrameView v;
  v.width = w, v.height = h, v.frame = frame;
  v.lod_pixels = 8.f / float(kBrickSide);
  v.camera = Camera::orbit(Aabb{{0, 0, 0}, {1, 1, 1}}, w, h, 30.f, 20.f);
  return v;
}

GigaOptions unlimited() {
  GigaOptions o;
  o.tiles = 1 << 16, o.bricks = 1 << 14;
  o.check_after_pass = true;
  return o;
}

struct Rendered {
  Film film;
  FrameStats stats;
};

Rendered render(GigaVoxels& g, const FrameView& view, int max_passes, bool shading = false) {
  VolumeIntegratorOptions io;
  io.shading = shading;
  VolumeIntegrator integrator(io);
  FrameOptions fo;
  fo.max_passes = max_passes;
  fo.tile_size = 8;
  Rendered r;
  r.stats = render_frame(g, integrator, view, fo, &r.film);
  return r;
}

uint64_t total(const GigaVoxels& g, uint64_t GigaPassStats::*field) {
  uint64_t s = 0;
  for (const GigaPassStats& p : g.pass_stats()) s += p.*field;
  return s;
}

/// A camera circling the cloud, exact mode: the unlimited pool keeps every
/// view's bricks; the tiny one holds little more than one pass needs, so it
/// recycles as the camera moves. Every frame must be the same image, with
/// either voxel format (`bits` per channel).
void exact_mode_with_tiny_pool(int bits) {
  const auto cloud = make_procedural("cloud", 256);
  auto view = [](uint32_t f) {
    // Narrow views of different parts of the cloud.
    FrameView v = view_of(40, 32, f);
    v.camera = Camera::orbit(Aabb{{0, 0, 0}, {1, 1, 1}}, 40, 32, 60.f * float(f), 15.f, 1.0f);
    const Vec3 side = normalize(cross(v.camera.target - v.camera.eye, Vec3{0, 1, 0}));
    v.camera.target = v.camera.target + side * 0.22f + Vec3{0, 0.1f * float(f % 3) - 0.1f, 0};
    v.camera.fovy_degrees = 18.f;
    return v;
  };
  constexpr uint32_t kFrames = 6;
  GigaOptions all = unlimited();
  all.brick_bits = bits;
  GigaVoxels big(cloud, all);
  std::vector<Rendered> want;
  uint64_t peak = 0, pass_need = 0;
  for (uint32_t f = 0; f < kFrames; ++f) {
    want.push_back(render(big, view(f), 500));
    ASSERT_EQ(want.back().stats.passes.back().requests, 0u) << "exact mode must converge";
    for (const GigaPassStats& p : big.pass_stats()) {
      peak = std::max(peak, p.bricks_resident);
      pass_need = std::max(pass_need, p.bricks_used + p.bricks_uploaded);
    }
  }
  int covered = 0;
  for (float a : want[0].film.alpha.pixels) covered += a > 0.3f;
  EXPECT_GT(covered, 100) << "the cloud must cover the image";

  GigaOptions tiny = all;
  tiny.bricks = uint32_t(pass_need + 4), tiny.tiles = 200;
  ASSERT_LT(tiny.bricks * 2, peak) << "the tiny pool must be much smaller than what the views use";
  GigaVoxels small(cloud, tiny);
  uint64_t recycled = 0, recycled_tiles = 0;
  for (uint32_t f = 0; f < kFrames; ++f) {
    const Rendered got = render(small, view(f), 5000);
    recycled += total(small, &GigaPassStats::recycled_bricks);
    recycled_tiles += total(small, &GigaPassStats::recycled_tiles);
    EXPECT_EQ(got.stats.passes.back().requests, 0u) << "frame " << f;
    EXPECT_EQ(got.film.color.pixels, want[f].film.color.pixels) << "frame " << f;
    EXPECT_EQ(got.film.alpha.pixels, want[f].film.alpha.pixels) << "frame " << f;
    EXPECT_EQ(got.film.depth.pixels, want[f].film.depth.pixels) << "frame " << f;
  }
  std::printf(
      "bricks: unlimited pool peak %llu, tiny pool %u, recycled %llu; tiles recycled %llu\n",
      (unsigned long long)peak, tiny.bricks, (unsigned long long)recycled,
      (unsigned long long)recycled_tiles);
  EXPECT_GT(recycled, 0u) << "the tiny pool must recycle bricks";
  EXPECT_GT(recycled_tiles, 0u) << "...and node tiles (with their subtrees)";
}

TEST(Giga, ExactModeWithTinyPoolRendersTheUnlimitedImage) {
  exact_mode_with_tiny_pool(16);
}

TEST(Giga8, ExactModeWithTinyPoolRendersTheUnlimitedImage) {
  exact_mode_with_tiny_pool(8);
}

TEST(Giga, OnePassShowsCoarserDataThenConverges) {
  const auto menger = make_procedural("menger", 64);
  GigaVoxels exact(menger, unlimited());
  const Rendered want = render(exact, view_of(32, 32), 500, true);
  GigaVoxels g(menger, unlimited());
  std::vector<uint64_t> requests;
  Rendered r;
  for (uint32_t f = 0; f < 40; ++f) {
    r = render(g, view_of(32, 32, f), 1, true);
    ASSERT_EQ(r.stats.passes.size(), 1u);
    requests.push_back(r.stats.requests);
    if (f == 0) {
      // Nothing was resident: the first frame is empty.
      EXPECT_EQ(*std::max_element(r.film.alpha.pixels.begin(), r.film.alpha.pixels.end()), 0.f);
    }
    if (r.stats.requests == 0) break;
  }
  ASSERT_EQ(requests.back(), 0u) << "one-pass frames must converge";
  EXPECT_GT(requests.size(), 3u);  // top-down: one level per frame
  EXPECT_EQ(r.film.color.pixels, want.film.color.pixels);
}

/// Traces `view`'s rays through `g` as pass 0 of frame `view.frame` would
/// (begin_frame, then the rays), without serving; returns the requests,
/// sorted and deduplicated as the frame loop hands them to end_pass.
std::vector<Request> trace_pass(GigaVoxels& g, const FrameView& view) {
  g.begin_frame(view);
  const CameraRays cam = view.rays();
  TraceContext ctx;
  ctx.frame = view.frame, ctx.requests.reserve(1 << 20);
  const VolumeIntegrator integrator;
  for (int y = 0; y < view.height; ++y)
    for (int x = 0; x < view.width; ++x) integrator.integrate(g, cam.ray(x, y), view.lod(), ctx);
  std::vector<Request> r(ctx.requests.items().begin(), ctx.requests.items().end());
  std::sort(r.begin(), r.end(), [](const Request& a, const Request& b) {
    return a.kind != b.kind ? a.kind < b.kind : a.key < b.key;
  });
  r.erase(std::unique(r.begin(), r.end(),
                      [](const Request& a, const Request& b) {
                        return a.kind == b.kind && a.key == b.key;
                      }),
          r.end());
  return r;
}

TEST(Giga, UsageListIsAnOrderPreservingPartition) {
  const auto cloud = make_procedural("cloud", 64);
  GigaOptions o = unlimited();
  o.bricks = 400, o.tiles = 200;
  GigaVoxels g(cloud, o);
  render(g, view_of(24, 24), 500);
  ASSERT_EQ(g.validate(), "");
  // A frame whose rays touch only part of what is resident: a narrow view.
  FrameView v = view_of(6, 6, 7);
  v.camera.fovy_degrees = 8.f;
  trace_pass(g, v);
  const uint32_t now = GigaVoxels::stamp(7, 0);
  std::vector<uint32_t> bricks = g.brick_usage(), tiles = g.tile_usage();
  const auto unused_b = [&](uint32_t b) { return g.brick_stamp(b) != now; };
  const auto unused_t = [&](uint32_t t) { return g.tile_stamp(t) != now; };
  std::stable_partition(bricks.begin(), bricks.end(), unused_b);
  std::stable_partition(tiles.begin(), tiles.end(), unused_t);
  const size_t used =
      size_t(std::count_if(bricks.begin(), bricks.end(), [&](uint32_t b) { return !unused_b(b); }));
  ASSERT_GT(used, 0u);
  ASSERT_LT(used, bricks.size());
  g.end_pass({});  // no request: only the LRU update
  EXPECT_EQ(g.brick_usage(), bricks);
  EXPECT_EQ(g.tile_usage(), tiles);
  EXPECT_EQ(g.pass_stats().back().bricks_used, used);
  EXPECT_EQ(g.validate(), "");
}

TEST(Giga, RecyclingTakesTheFrontAndNeverWhatThePassUsed) {
  const auto cloud = make_procedural("cloud", 256);
  GigaOptions o = unlimited();
  o.bricks = 60, o.tiles = 400;
  GigaVoxels g(cloud, o);
  // One-pass frames from moving viewpoints: the pool fills, then recycles.
  uint64_t recycled = 0;
  for (uint32_t f = 0; f < 12; ++f) {
    FrameView v = view_of(24, 24, f);
    v.camera = Camera::orbit(Aabb{{0, 0, 0}, {1, 1, 1}}, 24, 24, 30.f * float(f), 10.f, 1.4f);
    const std::vector<Request> requests = trace_pass(g, v);
    const uint32_t now = GigaVoxels::stamp(f, 0);
    // What the pass used, and the LRU order recycling must follow.
    std::map<uint32_t, std::pair<uint32_t, std::vector<float>>> used;  // brick -> owner, densities
    for (const auto& rb : g.resident_bricks())
      if (g.brick_stamp(rb.brick) == now) {
        std::vector<float> d;
        for (const BrickVoxel& x : rb.voxels) d.push_back(x.density);
        used[rb.brick] = {rb.node, d};
      }
    std::vector<uint32_t> order = g.brick_usage();
    std::stable_partition(order.begin(), order.end(),
                          [&](uint32_t b) { return g.brick_stamp(b) != now; });
    g.end_pass(requests);
    ASSERT_EQ(g.validate(), "") << "frame " << f;
    const GigaPassStats& st = g.pass_stats().back();
    recycled += st.recycled_bricks;
    std::map<uint32_t, uint32_t> owner;
    for (const auto& rb : g.resident_bricks()) {
      owner[rb.brick] = rb.node;
      const auto it = used.find(rb.brick);
      if (it != used.end()) {
        EXPECT_EQ(rb.node, it->second.first) << "a brick the pass used changed owner";
        for (size_t i = 0; i < rb.voxels.size(); ++i)
          ASSERT_EQ(rb.voxels[i].density, it->second.second[i]);
      }
    }
    for (const auto& [b, what] : used) EXPECT_TRUE(owner.count(b)) << "a used brick was evicted";
    // The uploads went to the front of the old order and now sit at the back.
    const size_t n = size_t(st.bricks_uploaded);
    ASSERT_LE(n, order.size());
    const std::vector<uint32_t>& now_order = g.brick_usage();
    for (size_t i = 0; i < n; ++i) {
      EXPECT_EQ(now_order[now_order.size() - n + i], order[i]);
      EXPECT_TRUE(owner.count(order[i]));
    }
  }
  EXPECT_GT(recycled, 0u);
}

/// The brick of region r as the producer's voxels, read one by one (the
/// BrickVoxel layout: premultiplied, border included): the tests' oracle.
std::vector<BrickVoxel> producer_brick(const Producer& p, const NodeRegion& r) {
  std::vector<BrickVoxel> out(kBrickVoxels);
  for (int k = 0; k < kBrickStored; ++k)
    for (int j = 0; j < kBrickStored; ++j)
      for (int i = 0; i < kBrickStored; ++i) {
        const VolumeSample v =
            p.voxel(r.level, int64_t(r.x) * kBrickSide - 1 + i, int64_t(r.y) * kBrickSide - 1 + j,
                    int64_t(r.z) * kBrickSide - 1 + k);
        out[size_t(i + kBrickStored * (j + kBrickStored * k))] = {
            v.density, v.color.r * v.density, v.color.g * v.density, v.color.b * v.density};
      }
  return out;
}

TEST(Giga, ProducerBricksEqualDirectSampling) {
  for (const char* name : {"cloud", "menger", "mandelbulb"}) {
    const auto p = make_procedural(name, 128);
    GigaVoxels g(p, unlimited());
    render(g, view_of(24, 24), 500);
    const auto bricks = g.resident_bricks();
    ASSERT_GT(bricks.size(), 10u) << name;
    for (const auto& rb : bricks) {
      const NodeRegion& r = rb.region;
      const std::vector<BrickVoxel> want = producer_brick(*p, r);
      for (size_t i = 0; i < want.size(); ++i) {
        const BrickVoxel &b = rb.voxels[i], &v = want[i];
        // The pool holds halves (PoolVoxel): exactly the producer's
        // value through stored_value's rounding.
        ASSERT_EQ(b.density, stored_value(r.level, v.density)) << name << " level " << r.level;
        ASSERT_EQ(b.r, stored_value(r.level, v.r)) << name;
        ASSERT_EQ(b.b, stored_value(r.level, v.b)) << name;
      }
    }
  }
}

TEST(Giga8, ProducerBricksAreWithinHalfAStepOfTheirRange) {
  // PoolVoxel8: channel c of a voxel is q * step[c], step[c] = the brick's
  // largest value of c / 255 and q the nearest: within step[c] / 2 of the
  // producer's value, zero exactly zero, each brick's largest value kept
  // (to float rounding). The oracle: the producer's voxels, read here.
  for (const char* name : {"cloud", "menger", "mandelbulb"}) {
    const auto p = make_procedural(name, 128);
    GigaOptions o = unlimited();
    o.brick_bits = 8;
    GigaVoxels g(p, o);
    ASSERT_EQ(g.brick_bits(), 8);
    render(g, view_of(24, 24), 500);
    const auto bricks = g.resident_bricks();
    ASSERT_GT(bricks.size(), 10u) << name;
    int64_t inexact = 0;
    for (const auto& rb : bricks) {
      const NodeRegion& r = rb.region;
      const std::vector<BrickVoxel> want = producer_brick(*p, r);
      float top[4] = {0, 0, 0, 0};
      for (const BrickVoxel& w : want) {
        const float c[4] = {w.density, w.r, w.g, w.b};
        for (int ch = 0; ch < 4; ++ch) top[ch] = std::max(top[ch], c[ch]);
      }
      float got_top[4] = {0, 0, 0, 0};
      for (size_t i = 0; i < want.size(); ++i) {
        const BrickVoxel& b = rb.voxels[i];
        const float got[4] = {b.density, b.r, b.g, b.b};
        const float exact[4] = {want[i].density, want[i].r, want[i].g, want[i].b};
        for (int ch = 0; ch < 4; ++ch) {
          const float half_step = top[ch] / 510.f;
          ASSERT_LE(std::fabs(got[ch] - exact[ch]), half_step * 1.0001f)
              << name << " level " << r.level << " channel " << ch;
          if (exact[ch] == 0.f) {
            ASSERT_EQ(got[ch], 0.f) << name;
          }
          inexact += got[ch] != exact[ch];
          got_top[ch] = std::max(got_top[ch], got[ch]);
        }
      }
      for (int ch = 0; ch < 4; ++ch) ASSERT_NEAR(got_top[ch], top[ch], top[ch] * 1e-6f) << name;
    }
    EXPECT_GT(inexact, 0) << name << ": the 8-bit pool must actually round";
  }
}

TEST(Giga8, ImageIsCloseToTheSixteenBitImage) {
  // The same cloud view with both voxel formats: the 8-bit pool's rounding
  // (at most half a step of each brick's range) moves pixels by far less
  // than an 8-bit display step on average, and never by much.
  const auto p = make_procedural("cloud", 256);
  Rendered img[2];
  for (int i = 0; i < 2; ++i) {
    GigaOptions o = unlimited();
    o.brick_bits = i == 0 ? 16 : 8;
    GigaVoxels g(p, o);
    img[i] = render(g, view_of(64, 48), 500);
    ASSERT_EQ(img[i].stats.passes.back().requests, 0u);
  }
  const std::vector<float>&a = img[0].film.color.pixels, &b = img[1].film.color.pixels;
  ASSERT_EQ(a.size(), b.size());
  double sum = 0, worst = 0, signal = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    const double d = double(a[i]) - double(b[i]);
    sum += d * d, worst = std::max(worst, std::fabs(d)), signal = std::max(signal, double(a[i]));
  }
  const double rmse = std::sqrt(sum / double(a.size()));
  std::printf("8-bit vs 16-bit pool: RMSE %.5f, max %.5f (brightest %.3f)\n", rmse, worst, signal);
  EXPECT_GT(signal, 0.2) << "the view must show the cloud";
  EXPECT_GT(worst, 0.0) << "the formats must differ (the 8-bit pool in use)";
  EXPECT_LT(rmse, 1.0 / 512);
  EXPECT_LT(worst, 4.0 / 255);
}

// constant_below() is a proof: wherever the cloud's producer says a node is
// empty at its level and every finer one, every voxel its subtree's bricks
// store (the region with each level's one-voxel margin) is empty, level by
// level down to the finest. The interval bound over the noise lattice must
// also prove the shell around the sphere empty where the radius test alone
// cannot (else rays descend through it: docs/BENCHMARKS.md).
TEST(Giga, EmptyBelowSummariesAreKeptAndMatchARecursiveRecount) {
  // A converged cloud: empty constants not provable empty at their level
  // (the fringe around the sphere) have resident empty children down to
  // the cone's level, the summaries march jumps by. validate() recounts
  // every summary recursively after every pass (check_after_pass); here
  // some must exist (ExactModeWithTinyPoolRendersTheUnlimitedImage checks
  // that pools whose summaries differ render the same images).
  const auto cloud = make_procedural("cloud", 512);
  GigaVoxels g(cloud, unlimited());
  for (uint32_t f = 0; f < 3; ++f) {
    FrameView v = view_of(32, 24, f);
    v.camera = Camera::orbit(Aabb{{0, 0, 0}, {1, 1, 1}}, 32, 24, 40.f * float(f), 15.f, 1.3f);
    const Rendered r = render(g, v, 500);
    ASSERT_EQ(r.stats.passes.back().requests, 0u) << "exact mode must converge";
    ASSERT_EQ(g.validate(), "");
    EXPECT_GT(g.empty_below_nodes(), 0u) << "frame " << f;
  }
}

TEST(Giga, CloudEmptyBelowIsAProof) {
  const auto p = make_procedural("cloud", 128);  // levels 0..3 (M = 16)
  const int max_level = p->max_level();
  int proven = 0, beyond_radius_test = 0;
  for (int level = 0; level <= max_level; ++level) {
    const uint32_t n = 1u << level;
    for (uint32_t z = 0; z < n; ++z)
      for (uint32_t y = 0; y < n; ++y)
        for (uint32_t x = 0; x < n; ++x) {
          VolumeSample v{1.f, {1, 1, 1, 1}};
          if (!p->constant_below({level, x, y, z}, &v)) continue;
          ++proven;
          ASSERT_EQ(v.density, 0.f);
          // The sphere test of Cloud::constant_below (center 0.5, radius
          // 0.4 x 1.6, the region's half diagonal with its margin).
          const double side = std::ldexp(1.0, -level), margin = side / kBrickSide;
          const double cx = (x + 0.5) * side - 0.5, cy = (y + 0.5) * side - 0.5,
                       cz = (z + 0.5) * side - 0.5;
          if (std::sqrt(cx * cx + cy * cy + cz * cz) - std::sqrt(3.0) * (0.5 * side + margin) <=
              0.64)
            ++beyond_radius_test;
          for (int l = level; l <= max_level; ++l) {
            const int64_t scale = int64_t(1) << (l - level), m = kBrickSide * scale;
            for (int64_t k = int64_t(z) * m - 1; k <= int64_t(z + 1) * m; ++k)
              for (int64_t j = int64_t(y) * m - 1; j <= int64_t(y + 1) * m; ++j)
                for (int64_t i = int64_t(x) * m - 1; i <= int64_t(x + 1) * m; ++i)
                  ASSERT_EQ(p->voxel(l, i, j, k).density, 0.f)
                      << "node " << level << " (" << x << ", " << y << ", " << z << "), level " << l
                      << " voxel " << i << " " << j << " " << k;
          }
        }
  }
  EXPECT_GT(proven, 0);
  EXPECT_GT(beyond_radius_test, 0);
}

TEST(Giga, PoolVoxelsRoundToHalfPrecision) {
  // PoolVoxel: the value per voxel side (2^-L / M) as a binary16 rounded to
  // nearest even. Exact where a half holds it, within 2^-11 relative
  // elsewhere, saturated at 65504 per voxel, ties to even.
  constexpr float M = float(kBrickSide);
  const int log2_m = std::countr_zero(unsigned(kBrickSide));
  EXPECT_EQ(stored_value(0, 0.f), 0.f);
  EXPECT_EQ(stored_value(0, M), M);                            // 1 per voxel
  EXPECT_EQ(stored_value(5, 3.f * 32.f * M), 3.f * 32.f * M);  // 3 per voxel at level 5
  EXPECT_EQ(stored_value(0, M * 65504.f), M * 65504.f);
  EXPECT_EQ(stored_value(0, M * 1e6f), M * 65504.f);                          // saturated
  EXPECT_EQ(stored_value(0, M * (1.f + 0x1p-11f)), M);                        // tie: to even
  EXPECT_EQ(stored_value(0, M * (1.f + 3 * 0x1p-11f)), M * (1.f + 0x1p-9f));  // tie: up
  EXPECT_EQ(stored_value(0, M * 0x1p-24f), M * 0x1p-24f);                     // smallest subnormal
  EXPECT_EQ(stored_value(0, M * 0x1p-26f), 0.f);
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> mant(1.f, 2.f);
  std::uniform_int_distribution<int> ex(-14, 14), lv(0, kMaxLevel);
  for (int i = 0; i < 100000; ++i) {
    const int level = lv(rng);
    const float v = std::ldexp(mant(rng), ex(rng) + level + log2_m);
    const float s = stored_value(level, v);
    ASSERT_LE(std::fabs(s - v), std::ldexp(v, -11)) << v << " level " << level;
  }
}

/// Trilinear interpolation of the producer's level-L voxel grid at unit-cube
/// point q (voxel (x, y, z) centered at (x + 0.5) / (M 2^L)), written here
/// from the producer's voxels alone, each as the pool stores it
/// (stored_value: half precision, the same in every brick that holds it).
double trilinear_density(const Producer& p, int level, Vec3 q, bool rounded = true) {
  const double n = double(kBrickSide << level);
  double acc = 0;
  int64_t i0[3];
  double f[3];
  for (int a = 0; a < 3; ++a) {
    const double u = double(q[a]) * n - 0.5;
    i0[a] = int64_t(std::floor(u)), f[a] = u - std::floor(u);
  }
  for (int k = 0; k < 2; ++k)
    for (int j = 0; j < 2; ++j)
      for (int i = 0; i < 2; ++i)
        acc +=
            (i ? f[0] : 1 - f[0]) * (j ? f[1] : 1 - f[1]) * (k ? f[2] : 1 - f[2]) * [&](float d) {
              return rounded ? stored_value(level, d) : d;
            }(p.voxel(level, i0[0] + i, i0[1] + j, i0[2] + k).density);
  return acc;
}

/// Finest-level samples against trilinear interpolation of the producer's
/// global voxel grid: within `tolerance` (world density units).
void finest_samples_are_trilinear(int bits) {
  const auto p = make_procedural("cloud", 32);
  GigaOptions o = unlimited();
  o.size = 2.f, o.origin = {-1, -1, -1};  // world placement: densities scale by 1 / size
  o.brick_bits = bits;
  GigaVoxels g(p, o);
  // An orthographic view at the finest level everywhere (lod_pixels 0).
  FrameView v;
  v.width = v.height = 32, v.lod_pixels = 0.f;
  v.camera.projection = Projection::Orthographic;
  v.camera.eye = {0.1f, 0.2f, 4.f}, v.camera.target = {0.f, 0.f, 0.f}, v.camera.ortho_width = 2.2f;
  render(g, v, 500);
  // 16-bit: each voxel as the pool's halves hold it, the same in every
  // brick (seamless). 8-bit: the exact grid, within half a step of the
  // densest brick's range (so a border rounded differently in two bricks
  // leaves a seam of at most that much on either side).
  double tolerance = 1e-4;
  if (bits == 8) {
    double top = 0;
    for (const auto& rb : g.resident_bricks())
      for (const BrickVoxel& b : rb.voxels) top = std::max(top, double(b.density));
    tolerance = top / 510.0 / 2.0 * 1.001 + 1e-4;
  }
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> U(0.2f, 0.8f);
  TraceContext ctx;
  double worst = 0;
  int nonzero = 0;
  for (int i = 0; i < 4000; ++i) {
    const Vec3 q{U(rng), U(rng), U(rng)};
    const VolumeSample s = g.sample(q * 2.f - Vec3{1, 1, 1}, float(p->max_level()), ctx);
    const double want = trilinear_density(*p, p->max_level(), q, bits == 16) / 2.0;
    worst = std::max(worst, std::fabs(double(s.density) - want));
    nonzero += want > 1;
  }
  std::printf("%d-bit pool: worst finest-sample error %.3g (bound %.3g)\n", bits, worst, tolerance);
  EXPECT_GT(nonzero, 500);
  EXPECT_LT(worst, tolerance);
  EXPECT_TRUE(ctx.requests.empty()) << "all finest bricks the view needs are resident";
}

TEST(Giga, FinestSamplesAreSeamlessTrilinear) {
  finest_samples_are_trilinear(16);
}

TEST(Giga8, FinestSamplesAreTrilinearWithinHalfAStep) {
  finest_samples_are_trilinear(8);
}

TEST(Giga, QuadrilinearFilteringIsContinuousAcrossLod) {
  // Along a perspective ray the wanted level falls continuously with the
  // cone; blended samples change little per tiny step, while snapping to
  // whole levels jumps where the level changes.
  // (Voxel sizes as in view_of's, with a one-pixel cone: the levels where
  // the cloud's coarser octaves drop out, so snapping visibly jumps.)
  const auto p = make_procedural("cloud", 128);
  GigaVoxels g(p, unlimited());
  FrameView v = view_of(48, 48);
  v.lod_pixels = 1.f;
  v.camera = Camera::orbit(Aabb{{0, 0, 0}, {1, 1, 1}}, 48, 48, 0.f, 0.f, 0.9f);
  render(g, v, 500);
  const CameraRays cam = v.rays();
  const LodFootprint lod = v.lod();
  TraceContext ctx;
  ctx.requests.reserve(1 << 16);
  const Ray ray = cam.ray(24, 24);
  double jump_blend = 0, jump_snap = 0;
  int level_changes = 0;
  float prev_blend = -1, prev_snap = -1, prev_level = -1;
  for (float t = 0.45f; t < 1.35f; t += 1e-4f) {
    const float level =
        std::clamp(std::log2(1.f / (kBrickSide * (lod.size_at_origin + lod.size_per_t * t))), 0.f,
                   float(p->max_level()));
    const Vec3 x = ray.origin + ray.dir * t;
    const float blend = g.sample(x, level, ctx).density;
    const float snap = g.sample(x, std::floor(level), ctx).density;
    if (prev_blend >= 0) {
      jump_blend = std::max(jump_blend, double(std::fabs(blend - prev_blend)));
      jump_snap = std::max(jump_snap, double(std::fabs(snap - prev_snap)));
      level_changes += std::floor(level) != std::floor(prev_level);
    }
    prev_blend = blend, prev_snap = snap, prev_level = level;
  }
  ASSERT_GE(level_changes, 1) << "the ray must cross a LOD change";
  EXPECT_GT(jump_snap, 0.5) << "snapped levels must jump somewhere for the test to mean anything";
  EXPECT_LT(jump_blend, jump_snap / 4);
}

/// Images, the requests of every pass and the pool statistics are the same
/// with 1 and 2 threads (requests reach end_pass sorted and deduplicated,
/// and no buffer overflows: nothing depends on the schedule).
void render_does_not_depend_on_threads(int bits) {
  const auto p = make_procedural("mandelbulb", 64);
  std::vector<std::vector<float>> images;
  std::vector<std::vector<uint64_t>> requests;
  for (int threads : {1, 2}) {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, size_t(threads));
    GigaOptions o = unlimited();
    o.bricks = 300, o.tiles = 300, o.brick_bits = bits;
    GigaVoxels g(p, o);
    const Rendered r = render(g, view_of(64, 48), 2000, true);
    images.push_back(r.film.color.pixels);
    requests.emplace_back();
    for (const PassStats& ps : r.stats.passes) {
      EXPECT_EQ(ps.dropped, 0u);
      requests.back().push_back(ps.requests);
    }
    for (const GigaPassStats& gs : g.pass_stats()) requests.back().push_back(gs.bricks_resident);
  }
  EXPECT_EQ(images[0], images[1]);
  EXPECT_EQ(requests[0], requests[1]);
}

TEST(Giga, RenderDoesNotDependOnThreads) {
  render_does_not_depend_on_threads(16);
}

TEST(Giga8, RenderDoesNotDependOnThreads) {
  render_does_not_depend_on_threads(8);
}

TEST(Giga, PoolSizesFollowTheBudget) {
  const auto p = make_procedural("menger", 64);
  GigaOptions o;
  o.budget_bytes = uint64_t(64) << 20;
  GigaVoxels g(p, o);
  EXPECT_LE(g.pool_bytes(), o.budget_bytes);
  EXPECT_GT(g.pool_bytes(), o.budget_bytes * 99 / 100);
  EXPECT_EQ(g.tile_capacity(), g.brick_capacity());
  EXPECT_EQ(g.brick_bits(), 16);
  // 8 bits per channel: 4-byte voxels plus the brick's steps, nearly twice
  // the bricks in the same budget.
  GigaOptions o8 = o;
  o8.brick_bits = 8;
  GigaVoxels g8(p, o8);
  EXPECT_EQ(g8.brick_bits(), 8);
  EXPECT_LE(g8.pool_bytes(), o.budget_bytes);
  EXPECT_GT(g8.pool_bytes(), o.budget_bytes * 99 / 100);
  EXPECT_GT(g8.brick_capacity(), g.brick_capacity() * 19 / 10);
  EXPECT_LT(g8.brick_capacity(), g.brick_capacity() * 2);
  for (int bits : {0, 4, 12, 32}) {
    o8.brick_bits = bits;
    EXPECT_THROW(GigaVoxels(p, o8), Error) << bits;
  }
  o.budget_bytes = 1000;
  EXPECT_THROW(GigaVoxels(p, o), Error);
  EXPECT_THROW(make_procedural("cloud", 48), Error);
  EXPECT_THROW(make_procedural("smoke", 64), Error);
}

// ---- INRIMAGE ----

std::vector<unsigned char> read_bytes(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

std::filesystem::path skull_path() {
  return testing::require_file(std::filesystem::path(VOXCAST_TEST_DATA_DIR) /
                               "volumes/skull32.inr");
}

/// `parse` must throw voxcast::Error with one line starting with `prefix`.
template <class Parse>
void expect_one_line_error(Parse&& parse, const std::string& prefix, const std::string& what) {
  try {
    parse();
    ADD_FAILURE() << what << ": accepted";
  } catch (const Error& e) {
    const std::string msg = e.what();
    EXPECT_EQ(msg.find('\n'), std::string::npos) << what << ": " << msg;
    EXPECT_EQ(msg.rfind(prefix, 0), 0u) << what << ": " << msg;
  }
}

TEST(GigaInrimage, ShippedSkullLoadsAndRoundTrips) {
  const ScalarVolume v = read_inrimage(skull_path().string());
  EXPECT_EQ(v.nx, 32);
  EXPECT_EQ(v.ny, 32);
  EXPECT_EQ(v.nz, 32);
  EXPECT_FLOAT_EQ(v.vz, 7.30158f);
  // The samples are the little-endian floats after the 256-byte header.
  const auto bytes = read_bytes(skull_path());
  ASSERT_EQ(bytes.size(), 256u + 4u * 32 * 32 * 32);
  for (size_t i : {size_t(0), size_t(12345), size_t(32767)}) {
    float x;
    std::memcpy(&x, &bytes[256 + 4 * i], 4);
    EXPECT_EQ(v.values[i], x);
  }
  const ScalarVolume again = parse_inrimage(write_inrimage(v));
  EXPECT_EQ(again.values, v.values);
  EXPECT_EQ(again.vx, v.vx);
}

TEST(GigaInrimage, VolumeProducerFinestLevelIsTheNormalizedData) {
  // A cubic volume of 2^L M voxels with equal voxel sizes maps voxel for
  // voxel onto the finest level.
  constexpr int n = 2 * kBrickSide;
  ScalarVolume v;
  v.nx = v.ny = v.nz = n;
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> U(-5.f, 20.f);
  for (int i = 0; i < n * n * n; ++i) v.values.push_back(U(rng));
  const auto [lo, hi] = std::minmax_element(v.values.begin(), v.values.end());
  const auto p = make_volume_producer(v);
  ASSERT_EQ(p->max_level(), 1);
  for (int z = 0; z < n; z += 3)
    for (int y = 0; y < n; y += 5)
      for (int x = 0; x < n; ++x)
        EXPECT_NEAR(p->voxel(1, x, y, z).density, (v.at(x, y, z) - *lo) / (*hi - *lo), 1e-6);
  // Level 0 averages 2x2x2.
  double sum = 0;
  for (int k = 0; k < 8; ++k)
    sum += p->voxel(1, 2 * 3 + (k & 1), 2 * 4 + ((k >> 1) & 1), 2 * 5 + (k >> 2)).density;
  EXPECT_NEAR(p->voxel(0, 3, 4, 5).density, sum / 8, 1e-6);
  // The skull renders through the structure with a transfer function.
  GigaVoxels g(make_volume_producer(read_inrimage(skull_path().string())), unlimited());
  VolumeIntegratorOptions io;
  io.transfer = TransferFunction::parse("0:0:0,0,0;0.3:0:1,0.8,0.6;1:120:1,1,1");
  VolumeIntegrator integrator(io);
  Film film;
  FrameOptions fo;
  fo.max_passes = 500;
  const FrameStats s = render_frame(g, integrator, view_of(24, 24), fo, &film);
  EXPECT_EQ(s.passes.back().requests, 0u);
  int opaque = 0;
  for (float a : film.alpha.pixels) opaque += a > 0.5f;
  EXPECT_GT(opaque, 50);
}

TEST(GigaInrimage, GzipVolumesLoadAndDamagedStreamsAreRejected) {
  // Compressed by the gzip tool, not by our code.
  testing::TempDir dir;
  const std::string gz = dir.file("skull.inr.gz");
  ASSERT_EQ(std::system(("gzip -c '" + skull_path().string() + "' > '" + gz + "'").c_str()), 0);
  const ScalarVolume plain = read_inrimage(skull_path().string());
  EXPECT_EQ(read_inrimage(gz).values, plain.values);
  const auto bytes = read_bytes(gz);
  auto expect_rejected = [&](const std::vector<unsigned char>& b, const std::string& what) {
    const std::string path = dir.file("damaged.inr.gz");
    std::ofstream(path, std::ios::binary)
        .write(reinterpret_cast<const char*>(b.data()), std::streamsize(b.size()));
    try {
      read_inrimage(path);
      ADD_FAILURE() << what << ": accepted";
    } catch (const Error& e) {
      EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos) << what;
    }
  };
  for (size_t len = 2; len < bytes.size(); len += 1 + len / 3)
    expect_rejected({bytes.begin(), bytes.begin() + std::ptrdiff_t(len)},
                    "cut at " + std::to_string(len));
  auto flipped = bytes;
  flipped[flipped.size() / 2] ^= 0x5a;
  expect_rejected(flipped, "a corrupted byte");
  auto trailing = bytes;
  trailing.push_back(7);
  expect_rejected(trailing, "a trailing byte");
}

TEST(GigaInrimage, CorruptedAndTruncatedFilesAreRejected) {
  const auto good = read_bytes(skull_path());
  ASSERT_NO_THROW(parse_inrimage(good));
  auto expect_rejected = [](const std::vector<unsigned char>& bytes, const std::string& what) {
    expect_one_line_error([&] { parse_inrimage(bytes); }, "INRIMAGE: ", what);
  };
  // Every truncation (a sample of lengths, all inside the header).
  for (size_t len = 0; len < good.size(); len += (len < 300 ? 1 : 997))
    expect_rejected({good.begin(), good.begin() + std::ptrdiff_t(len)},
                    "truncated at " + std::to_string(len));
  auto with_header = [&](const std::string& from, const std::string& to) {
    std::string h(good.begin(), good.begin() + 256);
    const size_t at = h.find(from);
    EXPECT_NE(at, std::string::npos) << from;
    h.replace(at, from.size(), to);
    // Keep the header 256 bytes: absorb the length change in the padding.
    const size_t end = h.find("##}\n");
    if (h.size() > 256) h.erase(end - (h.size() - 256), h.size() - 256);
    if (h.size() < 256) h.insert(end, 256 - h.size(), '\n');
    std::vector<unsigned char> out(h.begin(), h.end());
    out.insert(out.end(), good.begin() + 256, good.end());
    return out;
  };
  for (auto [from, to] :
       std::vector<std::pair<std::string, std::string>>{{"XDIM=32", "XDIM=0"},
                                                        {"XDIM=32", "XDIM=33"},
                                                        {"YDIM=32", "YDIM=-32"},
                                                        {"ZDIM=32", "ZDIM=3x"},
                                                        {"ZDIM=32\n", ""},
                                                        {"VDIM=1", "VDIM=3"},
                                                        {"TYPE=float", "TYPE=double"},
                                                        {"PIXSIZE=32 bits", "PIXSIZE=12 bits"},
                                                        {"PIXSIZE=32 bits", "PIXSIZE=32"},
                                                        {"PIXSIZE=32 bits", "PIXSIZE=64 bits"},
                                                        {"CPU=decm", "CPU=vax"},
                                                        {"VX=7.8861", "VX=-1"},
                                                        {"VY=7.8861", "VY=nan"},
                                                        {"VZ=7.30158", "VZ=7.3\nVZ=7.3"},
                                                        {"VDIM=1", "SCALE=3**2"},
                                                        {"VDIM=1", "no equals sign"},
                                                        {"#INRIMAGE-4#{", "#INRIMAGE-5#{"},
                                                        {"##}", "#}}"}})
    expect_rejected(with_header(from, to), from + " -> " + to);
  // A header that is not a multiple of 256 bytes; trailing bytes; a NaN sample.
  std::vector<unsigned char> odd(good.begin(), good.begin() + 252);
  const std::string end = "##}\n";
  odd.insert(odd.end() - 4, end.begin(), end.end());
  odd.resize(256 - 4 + 4 - 4);
  expect_rejected(odd, "short header");
  auto trailing = good;
  trailing.push_back(0);
  expect_rejected(trailing, "trailing byte");
  auto nan = good;
  const float q = NAN;
  std::memcpy(&nan[256 + 4 * 100], &q, 4);
  expect_rejected(nan, "NaN sample");
  EXPECT_THROW(read_inrimage("/nonexistent/volume.inr"), Error);
}

// ---- Span sampling (the integrator's fast path) ----

/// sample_span resolves a span's brick and its parent's once and samples
/// them by affine maps of t; sample() locates every point by descending from
/// the root. Both must give the same medium at the same points and levels,
/// blended or not, with either voxel format.
void span_sampling_equals_point_sampling(int bits) {
  const auto p = make_procedural("cloud", 128);
  GigaOptions o = unlimited();
  o.brick_bits = bits;
  GigaVoxels g(p, o);
  const FrameView v = view_of(40, 30);
  render(g, v, 500);
  const CameraRays cam = v.rays();
  const LodFootprint lod = v.lod();
  TraceContext ctx;
  ctx.requests.reserve(1 << 16);
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> unit(0.f, 1.f);
  int compared = 0, blended = 0;
  double worst = 0;
  for (int y = 0; y < 30; y += 3)
    for (int x = 0; x < 40; x += 3) {
      const Ray ray = cam.ray(x, y);
      VolumeSpan spans[64];
      const int n = g.march(ray, 0.f, lod, ctx, spans);
      for (int i = 0; i < n; ++i) {
        const VolumeSpan& s = spans[i];
        if (s.constant) continue;
        float t[8], level[8];
        for (int k = 0; k < 8; ++k) {
          t[k] = s.t0 + (s.t1 - s.t0) * unit(rng);
          // Whole levels and blends between the span's level and its parent's.
          level[k] = k == 0 ? float(s.level) : float(s.level) - (k == 1 ? 1.f : unit(rng));
        }
        VolumeSample got[8];
        g.sample_span(ray, s, t, level, 8, ctx, got);
        for (int k = 0; k < 8; ++k) {
          const VolumeSample want = g.sample(ray.origin + ray.dir * t[k], level[k], ctx, nullptr);
          const double err = std::fabs(double(got[k].density) - double(want.density));
          worst = std::max(worst, err / std::max(1.0, double(want.density)));
          if (want.density > 1e-3f) {
            for (float c : {got[k].color.r - want.color.r, got[k].color.g - want.color.g,
                            got[k].color.b - want.color.b})
              EXPECT_NEAR(c, 0.f, 1e-3f);
          }
          ++compared, blended += level[k] != std::floor(level[k]);
        }
      }
    }
  EXPECT_GT(compared, 1000);
  EXPECT_GT(blended, 500);
  EXPECT_LT(worst, 1e-4) << "relative density error";
}

TEST(Giga, SpanSamplingEqualsPointSampling) {
  span_sampling_equals_point_sampling(16);
}

TEST(Giga8, SpanSamplingEqualsPointSampling) {
  span_sampling_equals_point_sampling(8);
}

// ---- MetaImage files ----

TEST(GigaMetaImage, LocalAndExternalDataLoad) {
  // .mha: the shipped skull written as MetaImage reads back exactly.
  const ScalarVolume skull = read_inrimage(skull_path().string());
  const auto mha = write_metaimage(skull);
  const ScalarVolume back = parse_metaimage(mha);
  EXPECT_EQ(back.nx, 32);
  EXPECT_EQ(back.values, skull.values);
  EXPECT_EQ(back.vz, skull.vz);
  // .mhd + .raw: big-endian 16-bit samples written here byte by byte,
  // with a 3-byte HeaderSize prefix in the data file.
  testing::TempDir dir;
  const std::string header =
      "ObjectType = Image\nNDims = 3\nDimSize = 3 2 2\nElementSpacing = 1 1 2.5\n"
      "Offset = 0 0 0\nElementType = MET_SHORT\nBinaryDataByteOrderMSB = True\n"
      "HeaderSize = 3\nElementDataFile = data.raw\n";
  std::ofstream(dir.file("v.mhd"), std::ios::binary) << header;
  std::string raw = "abc";
  for (int i = 0; i < 12; ++i) {
    const int16_t x = int16_t(i * 100 - 300);
    raw += char(uint16_t(x) >> 8), raw += char(uint16_t(x) & 0xFF);
  }
  std::ofstream(dir.file("data.raw"), std::ios::binary) << raw;
  const ScalarVolume v = read_metaimage(dir.file("v.mhd"));
  ASSERT_EQ(v.values.size(), 12u);
  for (int i = 0; i < 12; ++i) EXPECT_EQ(v.values[size_t(i)], float(i * 100 - 300));
  EXPECT_EQ(v.nx, 3);
  EXPECT_EQ(v.nz, 2);
  EXPECT_EQ(v.vz, 2.5f);
  EXPECT_EQ(read_volume_file(dir.file("v.mhd")).values, v.values);
  EXPECT_THROW(read_volume_file(dir.file("data.raw")), Error);
}

TEST(GigaMetaImage, CorruptedAndTruncatedFilesAreRejected) {
  ScalarVolume small;
  small.nx = 4, small.ny = 3, small.nz = 2;
  for (int i = 0; i < 24; ++i) small.values.push_back(float(i));
  const auto good = write_metaimage(small);
  ASSERT_EQ(parse_metaimage(good).values, small.values);
  auto expect_rejected = [](const std::vector<unsigned char>& bytes, const std::string& what) {
    expect_one_line_error([&] { parse_metaimage(bytes); }, "MetaImage: ", what);
  };
  for (size_t len = 0; len < good.size(); ++len)
    expect_rejected({good.begin(), good.begin() + std::ptrdiff_t(len)},
                    "truncated at " + std::to_string(len));
  const std::string text(good.begin(), good.end());
  auto edited = [&](const std::string& from, const std::string& to) {
    std::string t = text;
    const size_t at = t.find(from);
    EXPECT_NE(at, std::string::npos) << from;
    t.replace(at, from.size(), to);
    return std::vector<unsigned char>(t.begin(), t.end());
  };
  for (auto [from, to] : std::vector<std::pair<std::string, std::string>>{
           {"NDims = 3", "NDims = 2"},
           {"DimSize = 4 3 2", "DimSize = 4 3"},
           {"DimSize = 4 3 2", "DimSize = 4 3 0"},
           {"DimSize = 4 3 2", "DimSize = 4 3 x"},
           {"DimSize = 4 3 2", "DimSize = 4 3 3"},
           {"DimSize = 4 3 2", "DimSize = 4 3 1"},
           {"MET_FLOAT", "MET_HALF"},
           {"MET_FLOAT", "MET_DOUBLE"},
           {"ElementSpacing = 1 1 1", "ElementSpacing = 1 -1 1"},
           {"ElementSpacing = 1 1 1", "ElementSpacing = 1 1"},
           {"BinaryDataByteOrderMSB = False", "BinaryDataByteOrderMSB = Maybe"},
           {"ObjectType = Image", "ObjectType = Mesh"},
           {"ObjectType = Image", "ObjectType = Image\nCompressedData = True"},
           {"ObjectType = Image", "ObjectType = Image\nElementNumberOfChannels = 3"},
           {"ObjectType = Image", "ObjectType = Image\nHeaderSize = -7"},
           {"ObjectType = Image", "ObjectType = Image\nNDims = 3"},
           {"ObjectType = Image", "ObjectTpye = Image"},
           {"ObjectType = Image", "no equals sign"},
           {"ElementDataFile = LOCAL", "ElementDataFile = ../secret.raw"},
           {"ElementDataFile = LOCAL", "ElementDataFile = other.raw"},
           {"ElementDataFile = LOCAL", "ElementDataFil = LOCAL"}})
    expect_rejected(edited(from, to), from + " -> " + to);
  auto trailing = good;
  trailing.push_back(0);
  expect_rejected(trailing, "trailing byte");
  auto nan = good;
  const float q = NAN;
  ASSERT_GT(nan.size(), 96u);
  std::memcpy(nan.data() + (nan.size() - 8), &q, 4);
  expect_rejected(nan, "NaN sample");
  EXPECT_THROW(read_metaimage("/nonexistent/volume.mhd"), Error);
}

// ---- Effects (§3.9) ----

double edge_energy(const Film& f) {
  // Second differences between horizontal neighbours (red channel), over
  // the image's brightness: detail, not brightness or smooth gradients.
  double e = 0, sum = 0;
  for (int y = 0; y < f.color.height; ++y)
    for (int x = 1; x + 1 < f.color.width; ++x) {
      const float c = f.color.at(x, y)[0];
      e += std::fabs(f.color.at(x + 1, y)[0] - 2.f * c + f.color.at(x - 1, y)[0]);
      sum += c;
    }
  return e / std::max(sum, 1e-9);
}

TEST(Giga, DepthOfFieldBlursOutOfFocusAndKeepsTheFocusPlane) {
  // The shaded sponge has edges everywhere (its holes); the lens cone reads
  // coarser levels away from the focus plane, which softens them.
  const auto p = make_procedural("menger", 128);
  const FrameView v = view_of(64, 48);
  auto draw = [&](float aperture, float focus) {
    GigaVoxels g(p, unlimited());
    VolumeIntegratorOptions io;
    io.shading = true;
    io.dof_aperture = aperture, io.dof_focus = focus;
    VolumeIntegrator integrator(io);
    FrameOptions fo;
    fo.max_passes = 500, fo.tile_size = 8;
    Film film;
    render_frame(g, integrator, v, fo, &film);
    return film;
  };
  const Film pinhole = draw(0.f, 1.f);
  const float distance = length(v.camera.eye - Vec3{0.5f, 0.5f, 0.5f});
  const double sharp = edge_energy(pinhole);
  // The lens cone in the units of the view's pixel cone (view_of).
  const float aperture = 0.25f * v.lod_pixels;
  // Focused in front of the sponge: all of it blurs.
  const double front = edge_energy(draw(aperture, 0.5f * distance));
  EXPECT_LT(front, 0.6 * sharp);
  // Focused on its center: only its front and back blur, it keeps more detail.
  const double center = edge_energy(draw(aperture, distance));
  EXPECT_GT(center, 1.3 * front) << sharp;
  // A lens too small to widen the cone beyond the pixel's renders the pinhole image.
  const Film tiny = draw(1e-7f, distance);
  double diff = 0;
  for (size_t i = 0; i < tiny.color.pixels.size(); ++i)
    diff = std::max(diff, double(std::fabs(tiny.color.pixels[i] - pinhole.color.pixels[i])));
  EXPECT_LT(diff, 0.02);
  EXPECT_THROW(VolumeIntegrator([] {
                 VolumeIntegratorOptions o;
                 o.dof_aperture = 0.1f, o.dof_focus = 0.f;
                 return o;
               }()),
               Error);
}

TEST(Giga, SoftShadowsCostFewerSamplesThanHardOnes) {
  // The light cone widens with the light's size, so a soft shadow reads
  // coarser levels with longer steps: fewer brick samples per light cone
  // than a hard one; both darken the image.
  const auto p = make_procedural("cloud", 128);
  const FrameView v = view_of(32, 24);
  auto draw = [&](bool shadows, float radius, VolumeIntegratorStats* st) {
    GigaVoxels g(p, unlimited());
    VolumeIntegratorOptions io;
    io.shadows = shadows, io.light_radius = radius;
    VolumeIntegrator integrator(io);
    FrameOptions fo;
    fo.max_passes = 500, fo.tile_size = 8;
    Film film;
    // The second frame finds everything resident: its statistics count one pass.
    render_frame(g, integrator, v, fo, &film);
    FrameView again = v;
    again.frame = 1;
    render_frame(g, integrator, again, fo, &film);
    *st = integrator.stats();
    double sum = 0;
    for (float c : film.color.pixels) sum += c;
    return sum;
  };
  VolumeIntegratorStats none, hard, soft;
  const double lit = draw(false, 0.f, &none);
  const double hard_sum = draw(true, 0.f, &hard);
  const double soft_sum = draw(true, 0.2f, &soft);
  EXPECT_EQ(none.shadow_rays, 0u);
  ASSERT_GT(hard.shadow_rays, 1000u);
  EXPECT_EQ(soft.shadow_rays, hard.shadow_rays) << "one light cone per lit sample";
  const double hard_per = double(hard.shadow_samples) / double(hard.shadow_rays);
  const double soft_per = double(soft.shadow_samples) / double(soft.shadow_rays);
  EXPECT_LT(soft_per, 0.7 * hard_per) << hard_per << " vs " << soft_per;
  EXPECT_LT(hard_sum, 0.95 * lit);
  EXPECT_LT(soft_sum, 0.95 * lit);
}

// ---- Synthesis: recursive node graphs (§3.7-3.8) ----

/// Oracle: a point of the unit cube is in the Menger sponge of depth D when
/// none of its first D base-3 digit triples has two or more 1s.
bool in_sponge(const double p[3], int depth) {
  double q[3] = {p[0], p[1], p[2]};
  for (int k = 0; k < depth; ++k) {
    int ones = 0;
    for (double& c : q) {
      const int digit = std::min(2, int(c * 3));
      ones += digit == 1;
      c = c * 3 - digit;
    }
    if (ones >= 2) return false;
  }
  return true;
}

TEST(Giga, RecursiveSpongeIsBoundedAndMatchesDigitOracle) {
  EXPECT_THROW(RecursiveVolume::menger(0, 1.f), Error);
  EXPECT_THROW(RecursiveVolume::menger(kMaxRecursionDepth + 1, 1.f), Error);
  GraphNode bad;
  bad.child.fill(3);  // names no node
  EXPECT_THROW(RecursiveVolume({bad}, 2, 1.f), Error);
  for (int depth : {1, 3}) {
    const RecursiveVolume sponge = RecursiveVolume::menger(depth, 1.f);
    EXPECT_NEAR(sponge.coverage(0, 0), std::pow(20.0 / 27.0, depth), 1e-6);
    std::mt19937 rng(depth);
    std::uniform_real_distribution<float> u(0.f, 1.f);
    TraceContext ctx;
    double worst = 0;
    for (int i = 0; i < 60; ++i) {
      const Vec3 from{-0.5f, u(rng), u(rng)}, to{1.5f, u(rng), u(rng)};
      const Ray ray{from, normalize(to - from), INFINITY};
      // Optical depth from the spans: every one is a whole cell no finer
      // than the bound (3^-depth), constant 1 inside the sponge.
      VolumeSpan spans[4096];
      const int n = sponge.march(ray, 0.f, {}, ctx, spans);
      ASSERT_LT(n, 4096) << "the march must end";
      double tau = 0;
      for (int k = 0; k < n; ++k) {
        EXPECT_LE(spans[k].level, depth);
        EXPECT_GE(spans[k].voxel_size, std::pow(3.f, -float(depth)) * 0.999f);
        tau += double(spans[k].value.density) * (spans[k].t1 - spans[k].t0);
      }
      // The digit oracle by fine steps along the chord.
      double oracle = 0;
      const double dt = 1e-4;
      for (double t = dt / 2; t < 3; t += dt) {
        const double p[3] = {from.x + ray.dir.x * t, from.y + ray.dir.y * t,
                             from.z + ray.dir.z * t};
        if (p[0] < 0 || p[0] >= 1 || p[1] < 0 || p[1] >= 1 || p[2] < 0 || p[2] >= 1) continue;
        oracle += in_sponge(p, depth) ? dt : 0;
      }
      worst = std::max(worst, std::fabs(tau - oracle));
      // The integrator over the same spans: transmittance e^-tau.
      VolumeIntegratorOptions o;
      o.opacity_cutoff = 1.f;
      const VolumeRayResult r = VolumeIntegrator(o).integrate(sponge, ray, {}, ctx);
      EXPECT_NEAR(r.transmittance, std::exp(-tau), 1e-4);
    }
    EXPECT_LT(worst, 0.01) << "depth " << depth;
  }
  // A wide pixel cone stops at the root's children: their spans hold the
  // prefiltered mean of the cut recursion.
  const RecursiveVolume deep = RecursiveVolume::menger(kMaxRecursionDepth, 2.f);
  TraceContext ctx;
  VolumeSpan spans[64];
  const Ray ray{{-1.f, 0.2f, 0.2f}, {1.f, 0.f, 0.f}, INFINITY};
  const int n = deep.march(ray, 0.f, LodFootprint{0.4f, 0.f}, ctx, spans);
  ASSERT_GT(n, 0);
  for (int k = 0; k < n; ++k) {
    EXPECT_EQ(spans[k].level, 1);
    EXPECT_NEAR(spans[k].value.density, 2.f * deep.coverage(0, 1), 1e-6f);
  }
}

// procedural:menger-recursive (make_recursive_menger) is the voxel sponge
// procedural:menger as a node graph: at every finest voxel center of the
// voxel sponge, solid (coverage >= 1/2) exactly where the graph is solid,
// but for centers within a voxel of a hole's face; a graph one recursion
// level short disagrees far more.
TEST(Giga, RecursiveMengerMatchesTheVoxelSponge) {
  const int n = 64;
  const auto voxels = make_procedural("menger", n);
  const RecursiveVolume graph = make_recursive_menger(n), shallow = make_recursive_menger(n / 4);
  ASSERT_EQ(graph.max_depth(), shallow.max_depth() + 1);
  TraceContext ctx;
  int same = 0, same_shallow = 0, solid = 0;
  for (int z = 0; z < n; ++z)
    for (int y = 0; y < n; ++y)
      for (int x = 0; x < n; ++x) {
        const bool v = voxels->voxel(voxels->max_level(), x, y, z).density >= 200.f;
        const Vec3 p{(x + 0.5f) / n, (y + 0.5f) / n, (z + 0.5f) / n};
        same += v == (graph.sample(p, 0.f, ctx).density > 0.f);
        same_shallow += v == (shallow.sample(p, 0.f, ctx).density > 0.f);
        solid += v;
      }
  const double total = double(n) * n * n;
  EXPECT_GT(solid, total / 10);
  EXPECT_GT(same / total, 0.97) << "shallow: " << same_shallow / total;
  EXPECT_LT(same_shallow, same - int(total / 50));
}

}  // namespace
}  // namespace voxcast::giga
