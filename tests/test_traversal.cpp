// ESVO ray caster (esvo §6.1 / Appendix A) against hand-built octrees with
// known answers and against a brute-force double-precision DDA oracle.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <memory>
#include <random>
#include <vector>

#include "support/dda_oracle.hpp"
#include "support/esvo_testing.hpp"
#include "support/octree_rays.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/render.hpp"

namespace voxcast {
namespace {

using esvo::cast_ray;
using esvo::CastResult;
using esvo::EsvoOctree;
using esvo::kMaxScale;
using testing::DdaHit;
using testing::DenseGrid;
using testing::desc;
using testing::DVec3;
using testing::hand_octree;

// ---------------------------------------------------------------------------
// Hand-built octrees (testing::hand_octree, laid out as esvo.hpp describes).

CastResult cast(const EsvoOctree& o, Vec3 p, Vec3 d, float tmax = INFINITY) {
  return cast_ray(o, p, normalize(d), tmax, 0.f, 0.f);
}

TEST(TraversalHand, SingleLeaf) {
  // Root with one leaf child at slot 0: the cube [1,1.5]^3.
  const EsvoOctree o = hand_octree(1, {desc(0, false, 0x01, 0x01)});
  CastResult r = cast(o, {0.5f, 1.25f, 1.25f}, {1, 0, 0});
  ASSERT_TRUE(r.hit);
  EXPECT_FLOAT_EQ(r.t, 0.5f);
  EXPECT_EQ(r.scale, kMaxScale - 1);
  EXPECT_EQ(r.child, 0);
  EXPECT_EQ(r.parent_slot, 1u);
  EXPECT_EQ(r.pos.x, 1.f);
  EXPECT_EQ(r.pos.y, 1.f);
  EXPECT_EQ(r.pos.z, 1.f);
  // From the other side: passes the empty child 1 first, enters at x = 1.5.
  r = cast(o, {2.5f, 1.25f, 1.25f}, {-1, 0, 0});
  ASSERT_TRUE(r.hit);
  EXPECT_FLOAT_EQ(r.t, 1.0f);
  // tmax before the voxel: no hit.
  EXPECT_FALSE(cast(o, {2.5f, 1.25f, 1.25f}, {-1, 0, 0}, 0.9f).hit);
  // Through the empty upper half: miss; and a ray that misses the cube.
  EXPECT_FALSE(cast(o, {0.5f, 1.75f, 1.25f}, {1, 0, 0}).hit);
  EXPECT_FALSE(cast(o, {0.5f, 2.5f, 1.25f}, {1, 0, 0}).hit);
  // Origin inside the voxel: t = 0.
  r = cast(o, {1.1f, 1.2f, 1.3f}, {0, 1, 0});
  ASSERT_TRUE(r.hit);
  EXPECT_EQ(r.t, 0.f);
}

TEST(TraversalHand, AllEightLeaves) {
  const EsvoOctree o = hand_octree(1, {desc(0, false, 0xFF, 0xFF)});
  // Down the z axis into child 7 (x=1, y=1, z=1).
  CastResult r = cast(o, {1.75f, 1.75f, 2.5f}, {0, 0, -1});
  ASSERT_TRUE(r.hit);
  EXPECT_FLOAT_EQ(r.t, 0.5f);
  EXPECT_EQ(r.child, 7);
  EXPECT_EQ(r.pos.x, 1.5f);
  EXPECT_EQ(r.pos.z, 1.5f);
  // Diagonal from below into child 0 through the cube corner.
  r = cast(o, {0.9f, 0.9f, 0.9f}, {1, 1, 1});
  ASSERT_TRUE(r.hit);
  EXPECT_NEAR(r.t, 0.1f * std::sqrt(3.f), 1e-6f);
  EXPECT_EQ(r.child, 0);
  // Each child from its own side along +-x.
  for (int c = 0; c < 8; ++c) {
    const float y = (c & 2) ? 1.75f : 1.25f, z = (c & 4) ? 1.75f : 1.25f;
    const bool from_high = c & 1;
    r = cast(o, {from_high ? 2.2f : 0.8f, y, z}, {from_high ? -1.f : 1.f, 0, 0});
    ASSERT_TRUE(r.hit) << c;
    EXPECT_EQ(r.child, c);
    EXPECT_NEAR(r.t, 0.2f, 1e-6f);
  }
}

TEST(TraversalHand, TwoLevelsNearAndFar) {
  // Root: child 0 subdivided; its descriptor holds one leaf in child 7, the
  // cube [1.25,1.5]^3. Near: child pointer 1 -> slot 2. Far: child pointer 1
  // -> far pointer slot 2 holding offset +2 -> descriptor at slot 3.
  const EsvoOctree near = hand_octree(2, {desc(1, false, 0x01, 0x00), desc(0, false, 0x80, 0x80)});
  const EsvoOctree far =
      hand_octree(2, {desc(1, true, 0x01, 0x00), 2u, desc(0, false, 0x80, 0x80)});
  for (const EsvoOctree* o : {&near, &far}) {
    CastResult r = cast(*o, {0.5f, 1.3f, 1.3f}, {1, 0, 0});
    ASSERT_TRUE(r.hit);
    EXPECT_FLOAT_EQ(r.t, 0.75f);
    EXPECT_EQ(r.scale, kMaxScale - 2);
    EXPECT_EQ(r.child, 7);
    EXPECT_EQ(r.parent_slot, o == &near ? 2u : 3u);
    EXPECT_EQ(r.pos.x, 1.25f);
    EXPECT_EQ(r.pos.y, 1.25f);
    EXPECT_EQ(r.pos.z, 1.25f);
    // Through child 0 of the root but past the leaf: miss.
    EXPECT_FALSE(cast(*o, {0.5f, 1.1f, 1.1f}, {1, 0, 0}).hit);
    // Negative direction from the far side.
    r = cast(*o, {1.3f, 1.3f, 2.7f}, {0, 0, -1});
    ASSERT_TRUE(r.hit);
    EXPECT_FLOAT_EQ(r.t, 1.2f);
    // LOD: a footprint of a quarter cube stops at the root's child 0 when it
    // is entered: a coarser voxel, entered earlier.
    r = cast_ray(*o, {0.5f, 1.1f, 1.1f}, {1, 0, 0}, INFINITY, 0.f, 0.5f);
    ASSERT_TRUE(r.hit);
    EXPECT_EQ(r.scale, kMaxScale - 1);
    EXPECT_FLOAT_EQ(r.t, 0.5f);
    EXPECT_EQ(r.parent_slot, 1u);
  }
}

// ---------------------------------------------------------------------------
// Oracle comparison.

using testing::kDeltaOct;
using Tally = testing::DdaTally;
using testing::grown_span;

// Checks one ray (octree space, unit direction) against the oracle.
// `grid` is the occupancy at the level the cast must stop at: the finest
// level without a footprint, a coarser one with a constant footprint `bias`.
void check_ray(const EsvoOctree& octree, const DenseGrid& grid, Vec3 p, Vec3 d, Tally* tally,
               float bias = 0.f) {
  const int L = grid.levels();
  const double n = grid.resolution();
  const CastResult r = cast_ray(octree, p, d, INFINITY, 0.f, bias);
  // Grid space: g = (p - 1) N; t is unchanged.
  const DVec3 go{(double(p.x) - 1) * n, (double(p.y) - 1) * n, (double(p.z) - 1) * n};
  const DVec3 gd{double(d.x) * n, double(d.y) * n, double(d.z) * n};
  testing::CasterHit h;
  if (r.hit) {
    ASSERT_EQ(r.scale, kMaxScale - L) << "must stop at the footprint's level";
    const double fx = (double(r.pos.x) - 1) * n, fy = (double(r.pos.y) - 1) * n,
                 fz = (double(r.pos.z) - 1) * n;
    h = {true, int(fx), int(fy), int(fz), double(r.t)};
    ASSERT_TRUE(fx == h.x && fy == h.y && fz == h.z) << "pos is not a voxel corner";
    // Parent slot and child index name this voxel (independent top-down query).
    if (L == octree.levels()) {
      uint32_t parent = 0;
      int child = -1;
      ASSERT_TRUE(testing::query_leaf(octree, uint32_t(h.x), uint32_t(h.y), uint32_t(h.z), &parent,
                                      &child));
      EXPECT_EQ(r.parent_slot, parent);
      EXPECT_EQ(r.child, child);
    }
  }
  testing::expect_first_hit_matches(grid, go, gd, h, kDeltaOct * n, tally, p, d);
}

// Random rays of several kinds, octree space, unit directions (dda_oracle.hpp).
using RayGen = testing::OctreeRayGen;

struct OracleCase {
  const char* name;
  int levels;
  size_t random_count;  // 0: sphere shell
};

void run_oracle(const VoxelSet& set, int rays, uint64_t seed, Tally* tally,
                const esvo::BuildOptions& opt = {}) {
  const EsvoOctree octree = esvo::build_octree(set, opt);
  const DenseGrid grid = DenseGrid::from_voxels(set);
  RayGen gen(seed, set.grid.levels);
  for (int i = 0; i < rays; ++i) {
    Vec3 p, d;
    gen.next(&p, &d);
    check_ray(octree, grid, p, d, tally);
    if (::testing::Test::HasFatalFailure()) return;
  }
}

TEST(TraversalOracle, RandomSetsAndShellsLevels4To9) {
  Tally tally;
  for (int L = 4; L <= 9; ++L) {
    const size_t counts[] = {0, 200, 1500, 3000, 20000, 40000, 60000};
    SCOPED_TRACE("levels " + std::to_string(L));
    run_oracle(testing::make_random_voxels(L, counts[L - 3], 1000 + L), 9000, 17 + L, &tally);
    if (HasFatalFailure()) return;
    run_oracle(testing::make_sphere_shell(L), 9000, 91 + L, &tally);
    if (HasFatalFailure()) return;
  }
  std::printf("oracle: %llu rays, %llu hits, %llu exact edge/corner ties, %llu float near-ties\n",
              (unsigned long long)tally.rays, (unsigned long long)tally.hits,
              (unsigned long long)tally.exact_ties, (unsigned long long)tally.near_ties);
  EXPECT_GE(tally.rays, 100000u);
  EXPECT_GE(tally.hits, tally.rays / 5) << "the ray mix should hit often";
  // Ties come only from the deliberately degenerate rays; bound them.
  EXPECT_LE(tally.exact_ties + tally.near_ties, tally.rays / 50);
}

TEST(TraversalOracle, MultiBlockFarPointersGiveSameHits) {
  const VoxelSet set = testing::make_sphere_shell(7);
  esvo::BuildOptions tiny;
  tiny.max_block_slots = 96;
  tiny.max_block_values = 128;
  const EsvoOctree a = esvo::build_octree(set);
  const EsvoOctree b = esvo::build_octree(set, tiny);
  ASSERT_GT(b.block_count, 2u);
  EXPECT_GT(b.memory_stats().far_pointer_bytes, 0u) << "small blocks should need far pointers";
  RayGen gen(5, 7);
  int hits = 0;
  for (int i = 0; i < 20000; ++i) {
    Vec3 p, d;
    gen.next(&p, &d);
    const CastResult ra = cast_ray(a, p, d, INFINITY, 0.f, 0.f);
    const CastResult rb = cast_ray(b, p, d, INFINITY, 0.f, 0.f);
    ASSERT_EQ(ra.hit, rb.hit);
    if (!ra.hit) continue;
    ++hits;
    // Same arithmetic on the same geometry: bit-identical results.
    ASSERT_EQ(ra.t, rb.t);
    ASSERT_EQ(ra.pos.x, rb.pos.x);
    ASSERT_EQ(ra.pos.y, rb.pos.y);
    ASSERT_EQ(ra.pos.z, rb.pos.z);
    ASSERT_EQ(ra.child, rb.child);
    ASSERT_EQ(ra.scale, rb.scale);
  }
  EXPECT_GT(hits, 2000);
  Tally tally;
  run_oracle(set, 10000, 77, &tally, tiny);
}

// Coarse occupancy: voxel at level l is occupied if any leaf below is.
DenseGrid coarsen(const VoxelSet& set, int level) {
  return DenseGrid::from_voxels(set, level);
}

TEST(TraversalLod, ConstantFootprintStopsAtThatLevel) {
  const int L = 8;
  const VoxelSet set = testing::make_sphere_shell(L);
  const EsvoOctree octree = esvo::build_octree(set);
  for (int level = 2; level < L; ++level) {
    // A footprint of exactly one level-`level` cube: every ray stops at the
    // first voxel of that level, i.e. the coarse grid's DDA answer.
    const float bias = std::ldexp(1.f, -level);
    const DenseGrid coarse = coarsen(set, level);
    RayGen gen(300 + level, level);
    Tally tally;
    for (int i = 0; i < 3000; ++i) {
      Vec3 p, d;
      gen.next(&p, &d);
      check_ray(octree, coarse, p, d, &tally, bias);
      if (HasFatalFailure()) return;
    }
    // Coarse grids have few grid lines, so the deliberately degenerate rays
    // (through edges and corners) meet them far more often than at level 9.
    EXPECT_LE(tally.exact_ties + tally.near_ties, tally.rays / 10);
    const uint64_t hits = tally.hits;
    EXPECT_GT(hits, 300u) << level;
  }
}

TEST(TraversalLod, PixelConeHitsCoarserAncestorEarlier) {
  const int L = 9;
  const VoxelSet set = testing::make_sphere_shell(L);
  const EsvoOctree octree = esvo::build_octree(set);
  std::vector<DenseGrid> coarse;
  for (int level = 0; level <= L; ++level) coarse.push_back(coarsen(set, level));
  RayGen gen(4242, L);
  int coarser = 0, hits = 0;
  for (int i = 0; i < 5000; ++i) {
    Vec3 p = Vec3{1.5f, 1.5f, 1.5f} + gen.sphere() * 3.f;
    const Vec3 d =
        normalize(Vec3{gen.uni(1.3f, 1.7f), gen.uni(1.3f, 1.7f), gen.uni(1.3f, 1.7f)} - p);
    const CastResult fine = cast_ray(octree, p, d, INFINITY, 0.f, 0.f);
    // ~8 finest voxels at the sphere's distance (t ~ 2.3).
    const float coef = 8.f / 512.f / 2.3f;
    const CastResult lod = cast_ray(octree, p, d, INFINITY, coef, 0.f);
    // The coarse cubes contain the fine ones; the converse does not hold (the
    // ray may cross a coarse cube and miss its leaves).
    if (fine.hit) {
      ASSERT_TRUE(lod.hit) << "a coarse voxel exists wherever a fine one does";
    }
    if (!fine.hit) continue;
    ++hits;
    ASSERT_GE(lod.scale, fine.scale);
    coarser += lod.scale > fine.scale;
    const float side = std::ldexp(1.f, lod.scale - kMaxScale);
    // The coarse voxel satisfies the footprint test and its parent would not.
    EXPECT_LE(side, coef * (lod.t + 2 * side) + 1e-6f);
    // Coarse cubes contain the fine ones: the coarse hit cannot be later.
    EXPECT_LE(lod.t, fine.t + 1e-5f);
    // When the coarse cube contains the fine hit voxel, it is its ancestor at
    // that level: same cube after rounding the fine position down.
    const int shift = lod.scale - fine.scale;
    const int n = 1 << L;
    const int fx = int((fine.pos.x - 1) * n) >> shift, fy = int((fine.pos.y - 1) * n) >> shift,
              fz = int((fine.pos.z - 1) * n) >> shift;
    const int cx = int((lod.pos.x - 1) * n) >> shift, cy = int((lod.pos.y - 1) * n) >> shift,
              cz = int((lod.pos.z - 1) * n) >> shift;
    if (fx == cx && fy == cy && fz == cz) continue;
    // Otherwise the ray met another occupied coarse cube first.
    const int level = kMaxScale - lod.scale;
    const DenseGrid& g = coarse[size_t(level)];
    EXPECT_TRUE(g.occupied(cx, cy, cz)) << level;
    const double m = g.resolution();
    double t0, t1;
    ASSERT_TRUE(grown_span({(p.x - 1) * m, (p.y - 1) * m, (p.z - 1) * m},
                           {d.x * m, d.y * m, d.z * m}, cx, cy, cz, kDeltaOct * m, &t0, &t1));
    EXPECT_LE(t0, fine.t + 1e-5);
  }
  EXPECT_GT(hits, 1000);
  EXPECT_GT(coarser, hits * 9 / 10) << "the footprint should select coarser levels";
}

TEST(TraversalStructure, WorldRaysMapToOctreeSpace) {
  TraceContext ctx;
  // World placement: origin (-3, 1, 2), side 4 (grid of 2^6 voxels of 1/16).
  VoxelSet set = testing::make_sphere_shell(6);
  set.grid.origin = {-3.f, 1.f, 2.f};
  set.grid.voxel_size = 4.0 / 64;
  auto octree = std::make_shared<EsvoOctree>(esvo::build_octree(set));
  const esvo::EsvoStructure s(octree);
  const Aabb b = s.bounds();
  EXPECT_FLOAT_EQ(b.lo.x, -3.f);
  EXPECT_FLOAT_EQ(b.hi.z, 6.f);
  // A ray from the +x side through the middle hits the shell at about
  // center + 0.4*side (+- one voxel).
  const Ray ray{{5.f, 3.02f, 4.01f}, {-1, 0, 0}, INFINITY};
  SurfaceHit hit;
  ASSERT_TRUE(s.trace(ray, {}, ctx, &hit));
  EXPECT_NEAR(hit.t, 5.f - (-1.f + 0.4f * 4.f), 2 * 4.0 / 64);
  EXPECT_EQ(hit.level, 6);
  EXPECT_FLOAT_EQ(hit.voxel_size, 4.f / 64);
  EXPECT_NEAR(hit.position.x, ray.origin.x - hit.t, 1e-4);
  EXPECT_NEAR(hit.position.y, 3.02f, 1e-4);
  // Clamped into the voxel.
  const float vx = std::floor((hit.position.x + 3.f) / (4.f / 64));
  EXPECT_GE(hit.position.x, -3.f + vx * 4.f / 64 - 1e-5f);
  // Same answer as the raw caster on the mapped ray.
  const CastResult r = cast_ray(*octree, (ray.origin - set.grid.origin) / 4.f + Vec3{1, 1, 1},
                                ray.dir / 4.f, INFINITY, 0.f, 0.f);
  ASSERT_TRUE(r.hit);
  EXPECT_EQ(hit.voxel_ref, r.parent_slot);
  EXPECT_EQ(int(hit.child), r.child);
  EXPECT_FLOAT_EQ(hit.t, r.t);
  // tmax before the surface: miss. A world footprint of 2 voxels: level 5.
  EXPECT_FALSE(s.trace({ray.origin, ray.dir, hit.t * 0.5f}, {}, ctx, &hit));
  ASSERT_TRUE(s.trace(ray, {2 * 4.f / 64, 0.f}, ctx, &hit));
  EXPECT_EQ(hit.level, 5);
  // Attributes are those of the hit voxel (radial normal of the shell: +x here).
  Color c;
  Vec3 n;
  ASSERT_TRUE(s.trace(ray, {}, ctx, &hit));
  s.attributes(hit, ctx, &c, &n);
  EXPECT_GT(n.x, 0.8f);
}

}  // namespace
}  // namespace voxcast

namespace voxcast {
namespace {

TEST(Render, ImagesCountsAndLod) {
  TraceContext ctx;
  auto octree =
      std::make_shared<esvo::EsvoOctree>(esvo::build_octree(testing::make_sphere_shell(7)));
  const esvo::EsvoStructure s(octree);
  RenderOptions ro;
  ro.width = 67;  // not a multiple of the tile size
  ro.height = 41;
  ro.tile_size = 16;
  ro.camera = Camera::frame(s.bounds(), ro.width, ro.height);
  ro.lod_pixels = 0.f;
  ro.want_depth = true;
  ro.want_normal = true;
  const RenderResult r = render(s, ro);
  ASSERT_EQ(r.color.width, 67);
  ASSERT_EQ(r.depth.channels, 1);
  ASSERT_EQ(r.normal.channels, 3);
  EXPECT_EQ(r.rays, 67u * 41u);
  uint64_t finite = 0;
  const CameraRays rays(ro.camera, ro.width, ro.height);
  for (int y = 0; y < ro.height; ++y)
    for (int x = 0; x < ro.width; ++x) {
      const float d = *r.depth.at(x, y);
      const float* c = r.color.at(x, y);
      SurfaceHit hit;
      const bool h = s.trace(rays.ray(x, y), {}, ctx, &hit);
      ASSERT_EQ(h, std::isfinite(d)) << x << "," << y;
      if (!h) {
        EXPECT_EQ(c[0], ro.background.r);
        EXPECT_EQ(c[2], ro.background.b);
        continue;
      }
      ++finite;
      EXPECT_EQ(d, hit.t);
      for (int k = 0; k < 3; ++k) {
        EXPECT_GE(c[k], 0.f);
        EXPECT_LE(c[k], 1.5f);
        EXPECT_GE(r.normal.at(x, y)[k], 0.f);
        EXPECT_LE(r.normal.at(x, y)[k], 1.f);
      }
      // The shaded normal faces the viewer.
      const float* n = r.normal.at(x, y);
      EXPECT_LE(dot(Vec3{n[0] * 2 - 1, n[1] * 2 - 1, n[2] * 2 - 1}, rays.direction(x, y)), 1e-4f);
    }
  EXPECT_EQ(r.hits, finite);
  EXPECT_GT(finite, r.rays / 20);  // the automatic camera keeps the whole root cube in view
  // A footprint of many pixels stops at coarser voxels, entered earlier.
  ro.lod_pixels = 16.f;
  const RenderResult coarse = render(s, ro);
  EXPECT_GE(coarse.hits, r.hits);
  size_t earlier = 0, both = 0;
  for (size_t i = 0; i < r.depth.pixels.size(); ++i)
    if (std::isfinite(r.depth.pixels[i]) && std::isfinite(coarse.depth.pixels[i])) {
      ++both;
      EXPECT_LE(coarse.depth.pixels[i], r.depth.pixels[i] + 1e-5f);
      earlier += coarse.depth.pixels[i] < r.depth.pixels[i] - 1e-4f;
    }
  EXPECT_GT(earlier, both / 4);
  ro.width = 0;
  EXPECT_THROW(render(s, ro), Error);
  ro.width = 10;
  ro.lod_pixels = -1.f;
  EXPECT_THROW(render(s, ro), Error);
}

}  // namespace
}  // namespace voxcast
