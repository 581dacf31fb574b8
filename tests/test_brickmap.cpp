// Brickmap worlds (include/voxcast/brickmap.hpp, van Wingerden 2015): the
// cell and brick layouts, the brick pool and the size-class color allocator
// (§3.1.4, §4.3), the builder from the voxelizer's VoxelSet (§4.1 color
// order, LOD colors), the surface query (§3.3) against the dense-grid DDA
// oracle (tests/support/dda_oracle) and against the ESVO render of the same
// voxels, LOD and not-resident answers, and the scene file (§4.5).
#include <gtest/gtest.h>
#include <tbb/task_arena.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <random>
#include <string>
#include <vector>

#include "brickmap/brick_skip.hpp"
#include "render/beam.hpp"
#include "support/cli_runner.hpp"
#include "support/dda_oracle.hpp"
#include "support/esvo_testing.hpp"
#include "support/packet_testing.hpp"
#include "support/test_data.hpp"
#include "voxcast/brickmap.hpp"
#include "voxcast/brickmap_file.hpp"
#include "voxcast/brickmap_stream.hpp"
#include "voxcast/camera.hpp"
#include "voxcast/effects.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/render.hpp"
#include "voxcast/scene_file.hpp"

namespace voxcast {
namespace {

using namespace brickmap;
using testing::CasterHit;
using testing::DdaTally;
using testing::DenseGrid;
using testing::DVec3;

// ---------------------------------------------------------------------------
// Layouts.

TEST(BrickmapLayout, CellFieldsRoundTrip) {
  EXPECT_EQ(resident_cell(0x123456), 0x40123456u);
  EXPECT_EQ(cell_state(resident_cell(0xFFFFFF)), kStateResident);
  EXPECT_EQ(cell_brick(resident_cell(0xABCDEF, kFlagEdited)), 0xABCDEFu);
  EXPECT_EQ(CellFlags::get(resident_cell(5, kFlagEdited)), kFlagEdited);
  // Figure 11: the first three bytes carry the LOD color, the last the flags.
  const uint32_t nr = not_resident_cell(0xFF332211u);
  EXPECT_EQ(nr, 0x80332211u);
  EXPECT_EQ(cell_state(nr), kStateNotResident);
  EXPECT_EQ(cell_lod_abgr(nr), 0xFF332211u);
  EXPECT_EQ(cell_state(0), kStateEmpty);
}

TEST(BrickmapLayout, RankBelowCountsTheLowerBitsOfTheMask) {
  std::mt19937_64 rng(7);
  for (int trial = 0; trial < 50; ++trial) {
    Brick b;
    for (uint64_t& w : b.mask) w = rng() & rng();  // ~25 % dense
    int naive = 0;
    for (uint32_t bit = 0; bit < 512; ++bit) {
      ASSERT_EQ(rank_below(b, bit), naive) << "bit " << bit;
      naive += (b.mask[bit / 64] >> (bit % 64)) & 1;
    }
    EXPECT_EQ(brick_popcount(b), naive);
  }
  // Bit x + 8y + 64z is voxel (x, y, z).
  EXPECT_EQ(voxel_bit(1, 0, 0), 1u);
  EXPECT_EQ(voxel_bit(0, 1, 0), 8u);
  EXPECT_EQ(voxel_bit(0, 0, 1), 64u);
  EXPECT_EQ(voxel_bit(7, 7, 7), 511u);
}

// ---------------------------------------------------------------------------
// Memory management (§3.1.4, §4.3).

TEST(BrickmapMemory, BrickPoolReusesReleasedSlots) {
  BrickPool pool;
  for (uint32_t i = 0; i < 10; ++i) EXPECT_EQ(pool.allocate(), i);
  pool.release(3);
  pool.release(7);
  EXPECT_EQ(pool.live(), 8u);
  const uint32_t a = pool.allocate(), b = pool.allocate();
  EXPECT_EQ(std::min(a, b), 3u);
  EXPECT_EQ(std::max(a, b), 7u);
  EXPECT_EQ(pool.extent(), 10u);  // no growth while slots are free
  EXPECT_EQ(pool.allocate(), 10u);
}

// Random allocate/release against an independent record of the live runs:
// runs never overlap, lie inside the extent, have the class size of their
// request; freeing everything lets the merges rebuild large nodes, so a new
// wave of large runs reuses the pool instead of growing it.
TEST(BrickmapMemory, ColorRunsNeverOverlapAndFreedSpaceIsReused) {
  EXPECT_EQ(ColorAllocator::class_size(1), 16u);
  EXPECT_EQ(ColorAllocator::class_size(16), 16u);
  EXPECT_EQ(ColorAllocator::class_size(17), 32u);
  EXPECT_EQ(ColorAllocator::class_size(512), 512u);
  ColorAllocator alloc;
  std::map<uint32_t, uint32_t> live;  // first -> node size
  std::mt19937 rng(11);
  const auto check_disjoint = [&] {
    uint32_t end = 0;
    for (const auto& [first, size] : live) {
      ASSERT_GE(first, end) << "overlapping color runs";
      ASSERT_EQ(first % size, 0u) << "a node not aligned to its size";
      end = first + size;
    }
    ASSERT_LE(end, alloc.extent());
  };
  std::vector<std::pair<uint32_t, uint32_t>> runs;  // (first, count)
  for (int step = 0; step < 20000; ++step) {
    if (runs.empty() || rng() % 3 != 0) {
      const uint32_t count = 1 + rng() % (rng() % 4 == 0 ? 512 : 64);
      const uint32_t first = alloc.allocate(count);
      ASSERT_EQ(live.count(first), 0u);
      live[first] = ColorAllocator::class_size(count);
      runs.push_back({first, count});
    } else {
      const size_t k = rng() % runs.size();
      alloc.release(runs[k].first, runs[k].second);
      live.erase(runs[k].first);
      runs[k] = runs.back();
      runs.pop_back();
    }
    if (step % 1000 == 0) check_disjoint();
    if (HasFatalFailure()) return;
  }
  check_disjoint();
  uint64_t live_entries = 0;
  for (const auto& r : live) live_entries += r.second;
  EXPECT_EQ(live_entries + alloc.free_entries(), alloc.extent());
  for (const auto& r : runs) alloc.release(r.first, r.second);
  live.clear();
  EXPECT_EQ(alloc.free_entries(), alloc.extent());
  const uint32_t extent = alloc.extent();
  // Half the pool again in 512-entry runs: the merged free nodes serve them
  // (only classes above the merge threshold merge, so allow some growth).
  for (uint32_t i = 0; i < extent / 1024; ++i) live[alloc.allocate(512)] = 512;
  check_disjoint();
  EXPECT_LE(alloc.extent(), extent + extent / 4) << "freed space was not merged and reused";
}

// ---------------------------------------------------------------------------
// Builder (§4.1).

// The color and normal words the world stores for voxel (x, y, z), looked up
// by the documented rule (brick color pointer + popcount below).
bool world_voxel(const World& w, uint32_t x, uint32_t y, uint32_t z, uint32_t* color,
                 uint32_t* normal) {
  const uint32_t c = w.cell(w.cell_index(x / 8, y / 8, z / 8));
  if (cell_state(c) != kStateResident) return false;
  const Brick& b = w.brick(cell_brick(c));
  const uint32_t bit = (x % 8) + 8 * (y % 8) + 64 * (z % 8);
  if (!((b.mask[bit / 64] >> (bit % 64)) & 1)) return false;
  uint32_t below = 0;
  for (uint32_t i = 0; i < bit; ++i) below += (b.mask[i / 64] >> (i % 64)) & 1;
  *color = w.colors()[b.color + below];
  *normal = w.has_normals() ? w.normals()[b.color + below] : 0;
  return true;
}

TEST(BrickmapBuild, VoxelsColorsNormalsAndLodColorsAreTheSets) {
  for (int levels : {2, 4, 6}) {
    const VoxelSet set =
        testing::make_random_voxels(levels, size_t(3) << (2 * levels), 40 + levels);
    const World w = build_world(set);
    SCOPED_TRACE("levels " + std::to_string(levels));
    EXPECT_EQ(w.decode_voxels(), set.codes);
    EXPECT_EQ(w.stats().voxels, set.size());
    std::map<uint64_t, std::vector<size_t>> by_brick;
    for (size_t i = 0; i < set.size(); ++i) {
      const MortonCoord c = morton_decode(set.codes[i]);
      uint32_t color = 0, normal = 0;
      ASSERT_TRUE(world_voxel(w, c.x, c.y, c.z, &color, &normal));
      EXPECT_EQ(color, esvo::encode_color_abgr(set.colors[i]));
      EXPECT_EQ(normal, esvo::encode_normal_cube(set.normals[i]));
      by_brick[w.cell_index(c.x / 8, c.y / 8, c.z / 8)].push_back(i);
    }
    EXPECT_EQ(w.stats().bricks, by_brick.size());
    for (const auto& [cell, members] : by_brick) {
      // LOD color: mean of the voxels' stored (decoded) linear colors.
      double m[3] = {0, 0, 0};
      for (size_t i : members) {
        const Color c = esvo::decode_color_abgr(esvo::encode_color_abgr(set.colors[i]));
        m[0] += c.r, m[1] += c.g, m[2] += c.b;
      }
      const Color lod = esvo::decode_color_abgr(w.brick(cell_brick(w.cell(cell))).lod);
      const float got[3] = {lod.r, lod.g, lod.b};
      for (int k = 0; k < 3; ++k)
        EXPECT_NEAR(linear_to_srgb(got[k]), linear_to_srgb(float(m[k] / double(members.size()))),
                    0.5 / 255 + 1e-4);
    }
  }
}

TEST(BrickmapBuild, EditingABrickReleasesAndReusesItsStorage) {
  World w(testing::unit_grid(5));
  uint64_t full[8];
  std::fill(full, full + 8, ~uint64_t(0));
  std::vector<uint32_t> colors(512, 0xFF0000FFu), normals(512, 0);
  w.set_brick(w.cell_index(1, 2, 3), full, colors.data(), normals.data());
  EXPECT_TRUE(w.occupied(0, 0, 0));
  EXPECT_TRUE(w.voxel(8 + 7, 16, 24 + 5));
  const WorldStats before = w.stats();
  uint64_t one[8] = {1, 0, 0, 0, 0, 0, 0, 0};
  w.set_brick(w.cell_index(1, 2, 3), one, colors.data(), normals.data(), kFlagEdited);
  EXPECT_EQ(w.stats().voxels, 1u);
  EXPECT_EQ(CellFlags::get(w.cell(w.cell_index(1, 2, 3))), kFlagEdited);
  EXPECT_FALSE(w.voxel(9, 16, 24));
  EXPECT_TRUE(w.voxel(8, 16, 24));
  const uint64_t none[8] = {};
  w.set_brick(w.cell_index(1, 2, 3), none, colors.data(), normals.data());
  EXPECT_EQ(w.cell(w.cell_index(1, 2, 3)), 0u);
  EXPECT_FALSE(w.occupied(0, 0, 0)) << "the occupancy bit outlived the last brick";
  w.set_brick(w.cell_index(0, 0, 0), full, colors.data(), normals.data());
  EXPECT_EQ(w.stats().brick_bytes, before.brick_bytes) << "the pool slot was not reused";
  EXPECT_EQ(w.stats().color_bytes, before.color_bytes) << "the color run was not reused";
}

// The brickgrid's clearances against a brute force: the Chebyshev distance
// to the nearest filled cell, capped.
void expect_clearances_and_cell_boxes_are_exact(const World& w, const std::string& when) {
  SCOPED_TRACE(when);
  const std::array<uint32_t, 3> d = w.dims();
  std::vector<std::array<int, 3>> filled;
  for (int k = 0; k < int(d[2]); ++k)
    for (int j = 0; j < int(d[1]); ++j)
      for (int i = 0; i < int(d[0]); ++i)
        if (w.cell(w.cell_index(uint32_t(i), uint32_t(j), uint32_t(k))) != 0)
          filled.push_back({i, j, k});
  int wrong = 0;
  for (int k = 0; k < int(d[2]); ++k)
    for (int j = 0; j < int(d[1]); ++j)
      for (int i = 0; i < int(d[0]); ++i) {
        int want = kMaxClearance;
        for (const auto& f : filled)
          want = std::min(want,
                          std::max({std::abs(f[0] - i), std::abs(f[1] - j), std::abs(f[2] - k)}));
        const int got = w.clearance(w.cell_index(uint32_t(i), uint32_t(j), uint32_t(k)));
        if (got != want && ++wrong <= 3)
          ADD_FAILURE() << "cell " << i << "," << j << "," << k << ": clearance " << got
                        << ", brute force " << want;
      }
  // The box of each level-kCellBoxLevel node's non-empty cells (the walk
  // skips a node whose box the ray misses), from the filled cells.
  const int q = World::kCellBoxLevel;
  ASSERT_GE(w.pyramid_levels(), q);
  const int side = 1 << q;
  for (uint32_t k = 0; k < w.pyramid_dim(q); ++k)
    for (uint32_t j = 0; j < w.pyramid_dim_y(q); ++j)
      for (uint32_t i = 0; i < w.pyramid_dim(q); ++i) {
        const int node[3] = {int(i), int(j), int(k)};
        uint32_t lo[3] = {7, 7, 7}, hi[3] = {0, 0, 0};
        bool any = false;
        for (const auto& f : filled) {
          if (f[0] / side != node[0] || f[1] / side != node[1] || f[2] / side != node[2]) continue;
          any = true;
          for (int a = 0; a < 3; ++a)
            lo[a] = std::min(lo[a], uint32_t(f[a] % side)),
            hi[a] = std::max(hi[a], uint32_t(f[a] % side));
        }
        uint32_t want = 0;
        if (any)
          for (int a = 0; a < 3; ++a) want |= lo[a] << (3 * a) | hi[a] << (9 + 3 * a);
        const uint32_t got = w.cell_box(w.pyramid_index(q, i, j, k));
        if (got != want && ++wrong <= 3)
          ADD_FAILURE() << "node " << i << "," << j << "," << k << ": cell box " << std::hex << got
                        << ", brute force " << want << std::dec;
      }
  // The node clearances (the lane walk's jumps over empty nodes): per ray
  // octant, the side of the largest cube of empty nodes with its corner at
  // the node reaching into that octant (nodes outside the grid are empty).
  const int nd[3] = {int(w.pyramid_dim(q)), int(w.pyramid_dim_y(q)), int(w.pyramid_dim(q))};
  std::vector<uint8_t> node_full(size_t(nd[0]) * size_t(nd[1]) * size_t(nd[2]), 0);
  for (const auto& f : filled)
    node_full[size_t(f[0] / side + nd[0] * (f[1] / side + nd[1] * (f[2] / side)))] = 1;
  const auto full = [&](int x, int y, int z) {
    return x >= 0 && y >= 0 && z >= 0 && x < nd[0] && y < nd[1] && z < nd[2] &&
           node_full[size_t(x + nd[0] * (y + nd[1] * z))] != 0;
  };
  for (int k = 0; k < nd[2]; ++k)
    for (int j = 0; j < nd[1]; ++j)
      for (int i = 0; i < nd[0]; ++i)
        for (int oct = 0; oct < 8; ++oct) {
          const int s[3] = {(oct & 1) ? 1 : -1, (oct & 2) ? 1 : -1, (oct & 4) ? 1 : -1};
          int want = 0;  // grow the cube while it stays empty
          for (bool empty = true; empty && want < kMaxClearance;) {
            for (int dz = 0; dz <= want && empty; ++dz)
              for (int dy = 0; dy <= want && empty; ++dy)
                for (int dx = 0; dx <= want && empty; ++dx)
                  empty = !full(i + s[0] * dx, j + s[1] * dy, k + s[2] * dz);
            want += empty;
          }
          const int got =
              w.node_clearance(w.pyramid_index(q, uint32_t(i), uint32_t(j), uint32_t(k)), oct);
          if (got != want && ++wrong <= 3)
            ADD_FAILURE() << "node " << i << "," << j << "," << k << " octant " << oct
                          << ": node clearance " << got << ", brute force " << want;
        }
}

TEST(BrickmapBuild, ClearancesAndCellBoxesFollowBuildsEditsAndEvictions) {
  // A 256^3 grid (32^3 cells) with a brickgrid cut off at 20 cells in y:
  // sparse bricks, then single and batched edits that fill and empty cells.
  World w(testing::unit_grid(8), false, 20);
  std::mt19937_64 rng(7);
  uint64_t one[8] = {1, 0, 0, 0, 0, 0, 0, 0};
  const uint64_t none[8] = {};
  std::vector<uint32_t> colors(512, 0xFF808080u);
  const auto random_cell = [&] {
    return w.cell_index(uint32_t(rng() % w.dims()[0]), uint32_t(rng() % w.dims()[1]),
                        uint32_t(rng() % w.dims()[2]));
  };
  for (int n = 0; n < 12; ++n) w.set_brick(random_cell(), one, colors.data(), nullptr);
  expect_clearances_and_cell_boxes_are_exact(w, "single adds");
  std::vector<uint64_t> batch;
  for (int n = 0; n < 40; ++n) {
    batch.push_back(random_cell());
    w.set_brick(batch.back(), one, colors.data(), nullptr, 0, nullptr, false);
  }
  w.update_occupancy(batch);
  expect_clearances_and_cell_boxes_are_exact(w, "batched adds");
  std::vector<uint64_t> filled;
  for (uint64_t c = 0; c < w.cells().size(); ++c)
    if (w.cell(c) != 0) filled.push_back(c);
  w.set_brick(filled[0], none, nullptr, nullptr);
  w.set_not_resident(filled[1], 0xFF00FF00u);  // not resident is not empty
  expect_clearances_and_cell_boxes_are_exact(w, "a single removal and an eviction");
  batch.clear();
  for (size_t n = 2; n < filled.size(); n += 2) {
    w.set_brick(filled[n], none, nullptr, nullptr, 0, nullptr, false);
    batch.push_back(filled[n]);
  }
  for (int n = 0; n < 5; ++n) {
    batch.push_back(random_cell());
    w.set_brick(batch.back(), one, colors.data(), nullptr, 0, nullptr, false);
  }
  w.update_occupancy(batch);
  expect_clearances_and_cell_boxes_are_exact(w, "batched removals and adds");
  // A dense block, then emptied again: every cell back to the cap.
  batch.clear();
  for (uint32_t k = 4; k < 20; ++k)
    for (uint32_t j = 2; j < 18; ++j)
      for (uint32_t i = 3; i < 19; ++i) {
        batch.push_back(w.cell_index(i, j, k));
        w.set_brick(batch.back(), one, colors.data(), nullptr, 0, nullptr, false);
      }
  w.update_occupancy(batch);
  expect_clearances_and_cell_boxes_are_exact(w, "a dense block");
  for (uint64_t c = 0; c < w.cells().size(); ++c)
    if (w.cell(c) != 0)
      w.set_brick(c, none, nullptr, nullptr, 0, nullptr, false), batch.push_back(c);
  w.update_occupancy(batch);
  expect_clearances_and_cell_boxes_are_exact(w, "all emptied");
  EXPECT_EQ(w.clearance(0), kMaxClearance);
}

TEST(BrickmapBuild, RefusesGridsBeyondTheBrickgridLimit) {
  GridTransform g = testing::unit_grid(13);  // 1024^3 cells > 2^28
  VoxelSet set;
  set.grid = g;
  EXPECT_THROW(build_world(set), Error);
}

// ---------------------------------------------------------------------------
// Surface query against the dense-grid DDA oracle.

struct Traced {
  bool hit = false;
  SurfaceHit h;
};

Traced trace(const BrickmapStructure& s, const Ray& ray, const LodFootprint& lod = {}) {
  TraceContext ctx;
  Traced t;
  t.hit = s.trace(ray, lod, ctx, &t.h);
  return t;
}

// The hit as the voxel (of its level) that holds its position; the
// position, level and size are checked against that voxel's box.
CasterHit as_caster_hit(const GridTransform& g, const Traced& t, int want_level) {
  CasterHit out;
  if (!t.hit) return out;
  EXPECT_EQ(t.h.level, want_level);
  const int up = g.levels - t.h.level;
  const double side = g.voxel_size * double(1 << up);
  EXPECT_NEAR(t.h.voxel_size, side, 1e-6 * side);
  int c[3];
  for (int a = 0; a < 3; ++a)
    c[a] = int(std::floor((double(t.h.position[a]) - double(g.origin[a])) / side));
  out = {true, c[0], c[1], c[2], double(t.h.t)};
  return out;
}

struct OracleCounts {
  DdaTally first;
};

// `rays` rays of the oracle's mix (OctreeRayGen, octree space [1,2]^3 mapped
// to the set's world cube), one in eight starting inside an occupied voxel.
void run_oracle(const VoxelSet& set, int rays, uint64_t seed, OracleCounts* counts) {
  const BrickmapStructure s(std::make_shared<World>(build_world(set)));
  const DenseGrid grid = DenseGrid::from_voxels(set);
  const GridTransform& g = set.grid;
  const double vs = g.voxel_size;
  testing::OctreeRayGen gen(seed, g.levels);
  for (int i = 0; i < rays; ++i) {
    Vec3 p, d;
    gen.next(&p, &d);
    if (i % 8 == 7 && !set.codes.empty()) {
      const MortonCoord c = morton_decode(set.codes[size_t(gen.pick(int(set.codes.size())))]);
      p = Vec3{1, 1, 1} +
          Vec3{float(c.x) + gen.uni(0, 1), float(c.y) + gen.uni(0, 1), float(c.z) + gen.uni(0, 1)} *
              float(1.0 / g.resolution);
    }
    const Vec3 wo = g.origin + (p - Vec3{1, 1, 1}) * float(g.side());
    const DVec3 go{(double(wo.x) - g.origin.x) / vs, (double(wo.y) - g.origin.y) / vs,
                   (double(wo.z) - g.origin.z) / vs};
    const DVec3 gd{double(d.x) / vs, double(d.y) / vs, double(d.z) / vs};
    const CasterHit hit = as_caster_hit(g, trace(s, Ray{wo, d, INFINITY}), g.levels);
    testing::expect_first_hit_matches(grid, go, gd, hit, testing::kDeltaOct * g.resolution,
                                      &counts->first, wo, d);
    if (::testing::Test::HasFailure()) return;
  }
}

TEST(BrickmapOracle, FirstHitsMatchTheDenseGridDda) {
  struct Case {
    int levels;
    size_t count;  // 0: sphere shell; SIZE_MAX: full grid
  };
  const Case cases[] = {{2, 20}, {3, SIZE_MAX}, {4, 300},   {5, 0}, {5, 6000},
                        {6, 0},  {6, 200},      {7, 30000}, {7, 0}, {8, 0}};
  OracleCounts counts;
  int k = 0;
  for (const Case& c : cases) {
    const VoxelSet set = testing::make_placed_case(c.levels, c.count, 90 + k, k);
    SCOPED_TRACE("levels " + std::to_string(c.levels) + " count " + std::to_string(c.count));
    run_oracle(set, 6000, 17 + k, &counts);
    if (HasFailure()) return;
    ++k;
  }
  std::printf("brickmap vs DDA: %llu rays, %llu hits, %llu exact ties, %llu near ties\n",
              (unsigned long long)counts.first.rays, (unsigned long long)counts.first.hits,
              (unsigned long long)counts.first.exact_ties,
              (unsigned long long)counts.first.near_ties);
  EXPECT_GE(counts.first.hits, counts.first.rays / 5);
  EXPECT_LE(counts.first.hits, counts.first.rays * 19 / 20);
  EXPECT_LE(counts.first.exact_ties + counts.first.near_ties, counts.first.rays / 50);
}

TEST(BrickmapOracle, VoxelizedMeshFirstHitsMatchTheDenseGridDda) {
  const Mesh mesh = load_mesh(testing::test_mesh("spot.obj"));
  const VoxelSet set = voxelize(mesh, GridTransform::fit(mesh.bounds(), 128), {});
  OracleCounts counts;
  run_oracle(set, 20000, 5, &counts);
  EXPECT_GE(counts.first.hits, counts.first.rays / 5);
}

// The beam optimization only skips work: images with beams of 4x4 and 8x8
// equal the image without, byte for byte, on a mesh world at 256^3 (grid
// units far from the origin, so plane ties are inexact), with LOD, with a
// camera inside the grid, an orthographic one (parallel beams), and with
// not-resident bricks (LOD colors).
// The spot at 256^3 as a resident world and as a copy with every third
// non-empty cell not resident (the beam start tests' two worlds).
struct SpotWorlds {
  Mesh mesh;
  std::unique_ptr<BrickmapStructure> full, partial;
  uint64_t evicted = 0;
};
SpotWorlds spot_worlds() {
  SpotWorlds s;
  s.mesh = load_mesh(testing::test_mesh("spot.obj"));
  const VoxelSet set = voxelize(s.mesh, GridTransform::fit(s.mesh.bounds(), 256), {});
  auto world = std::make_shared<World>(build_world(set));
  s.full = std::make_unique<BrickmapStructure>(world);
  auto partial_world = std::make_shared<World>(*world);
  for (uint64_t c = 0; c < partial_world->cells().size(); ++c)
    if (partial_world->cell(c) != 0 && c % 3 == 0)
      partial_world->set_not_resident(c, 0xFF2040F0u), ++s.evicted;
  s.partial = std::make_unique<BrickmapStructure>(partial_world);
  return s;
}

TEST(BrickmapOracle, BeamStartGivesTheSameImages) {
  const SpotWorlds spot = spot_worlds();
  ASSERT_GT(spot.evicted, 0u);
  const BrickmapStructure* full = spot.full.get();
  const BrickmapStructure* partial = spot.partial.get();
  const Aabb b = spot.mesh.bounds();
  RenderOptions o;
  o.width = 93, o.height = 71;  // partial beam blocks at the borders
  o.want_depth = o.want_normal = true;
  Camera inside;
  inside.eye = b.lo + b.extent() * 0.5f;
  inside.target = b.hi;
  inside.fovy_degrees = 70.f;
  std::vector<Camera> cameras = {
      Camera::orbit(b, o.width, o.height, 20.f, 25.f),
      Camera::orbit(b, o.width, o.height, 200.f, -10.f),
      Camera::orbit(b, o.width, o.height, 90.f, 0.f), inside,
      Camera::orbit(b, o.width, o.height, 35.f, 30.f).orthographic(b, o.width, o.height)};
  uint64_t hits = 0;
  for (const BrickmapStructure* s : {full, partial})
    for (const Camera& cam : cameras)
      for (float lod : {0.f, 1.f, 4.f}) {
        o.camera = cam;
        o.lod_pixels = lod;
        o.beam = 0;
        const RenderResult off = render(*s, o);
        hits += off.hits;
        for (int beam : {4, 8}) {
          o.beam = beam;
          const RenderResult on = render(*s, o);
          const std::string what = std::string(s == full ? "resident" : "partial") + " beam " +
                                   std::to_string(beam) + " lod " + std::to_string(lod) +
                                   " camera " + cam.to_string();
          EXPECT_EQ(on.hits, off.hits) << what;
          for (const auto& [a, c] :
               {std::pair{&on.color, &off.color}, std::pair{&on.depth, &off.depth},
                std::pair{&on.normal, &off.normal}})
            EXPECT_TRUE(a->pixels.size() == c->pixels.size() &&
                        std::memcmp(a->pixels.data(), c->pixels.data(),
                                    a->pixels.size() * sizeof(float)) == 0)
                << what;
        }
      }
  EXPECT_GT(hits, 0u);
}

// frustum_start() within a tile's start (the tile's cubes instead of the
// root): the images of render --frustum equal the scalar path's without a
// pass, on every ISA, LOD 0, 1 and 4, resident and partly not resident; a
// tile's pass lists its cubes, a block's box lies inside its tile's, and a
// block is empty exactly when the pass from the root finds it empty.
TEST(BrickmapOracle, FrustumStartWithinTheTileGivesTheSameImages) {
  const SpotWorlds spot = spot_worlds();
  const BrickmapStructure* full = spot.full.get();
  const BrickmapStructure* partial = spot.partial.get();
  const Aabb b = spot.mesh.bounds();
  RenderOptions o;
  o.width = 93, o.height = 71;  // partial tiles and blocks at the borders
  o.want_depth = o.want_normal = true;
  const Camera cameras[] = {Camera::orbit(b, o.width, o.height, 20.f, 25.f),
                            Camera::orbit(b, o.width, o.height, 200.f, -10.f)};
  uint64_t hits = 0, listed = 0;
  for (const auto& [s, name] : {std::pair{full, "resident"}, std::pair{partial, "partial"}})
    for (const Camera& cam : cameras)
      for (float lod : {0.f, 1.f, 4.f}) {
        o.frustum = 0;
        o.camera = cam, o.lod_pixels = lod;
        o.caster = Caster::Scalar;
        const RenderResult off = render(*s, o);
        hits += off.hits;
        o.caster = Caster::Packet;
        for (const Isa isa : testing::packet_isas()) {
          o.isa = isa;
          for (int k : {4, 8, 16}) {  // 16: the whole tile's list
            o.frustum = k;
            const RenderResult on = render(*s, o);
            const std::string what = std::string(s == full ? "resident" : "partial") + " frustum " +
                                     std::to_string(k) + " lod " + std::to_string(lod) + " " +
                                     isa_name(isa);
            EXPECT_EQ(on.hits, off.hits) << what;
            EXPECT_TRUE(on.color.pixels == off.color.pixels) << what;
            EXPECT_TRUE(on.depth.pixels == off.depth.pixels) << what;
            EXPECT_TRUE(on.normal.pixels == off.normal.pixels) << what;
          }
        }
        // The starts themselves: a 16x16 tile's list, its 8x8 blocks from it.
        const CameraRays cr(cam, o.width, o.height);
        LodFootprint fp;
        fp.size_per_t = lod * cr.pixel_angle();
        TraceContext ctx;
        BeamStart tile, block, root;
        s->frustum_start(voxcast::detail::block_beam(cr, 32, 16, 48, 32, fp), 0, ctx, &tile);
        ASSERT_TRUE(tile.valid);
        if (tile.empty) continue;
        EXPECT_EQ(tile.octant, -1);
        ASSERT_FALSE(tile.nodes.empty());
        listed += tile.nodes.size();
        for (const auto& [x0, y0] : {std::pair{32, 16}, std::pair{40, 24}}) {
          const BeamFrustum beam = voxcast::detail::block_beam(cr, x0, y0, x0 + 8, y0 + 8, fp);
          s->frustum_start(beam, 0, ctx, &block, &tile);
          s->beam_start(beam, ctx, &root);
          ASSERT_TRUE(block.valid && root.valid);
          EXPECT_TRUE(block.nodes.empty());  // only a tile's pass lists
          EXPECT_EQ(block.empty, root.empty);
          if (block.empty) continue;
          for (int a = 0; a < 3; ++a) {
            EXPECT_GE(block.region.lo[a], tile.region.lo[a]);
            EXPECT_LE(block.region.hi[a], tile.region.hi[a]);
          }
        }
      }
  EXPECT_GT(hits, 0u);
  EXPECT_GT(listed, 0u);
}

// The brick test before a brick's voxel DDA (traverse.cpp, brick_slices)
// only skips DDAs that find nothing: the SIMD test, its scalar reference and
// no test at all give bit-identical hits (t, position, face, level, voxel) on
// the oracle's ray mix (grid-plane origins, axis-parallel rays with signed
// zeros, near-axis rays, origins inside voxels), on placed cases and on a
// mesh world far from the origin, with and without an LOD footprint; and the
// test does skip (fewer DDA steps).
TEST(BrickmapSkip, TheSameHitsWithAndWithoutTheBrickTest) {
  struct Restore {
    ~Restore() { brickmap::detail::brick_skip_mode = brickmap::detail::BrickSkip::Simd; }
  } restore;
  std::vector<VoxelSet> sets;
  const std::pair<int, size_t> placed[] = {{5, 6000}, {6, 0}, {7, 30000}, {8, 0}, {8, 60000}};
  int k = 0;
  for (const auto& [levels, count] : placed)
    sets.push_back(testing::make_placed_case(levels, count, 300 + k, k)), ++k;
  const Mesh mesh = load_mesh(testing::test_mesh("spot.obj"));
  sets.push_back(voxelize(mesh, GridTransform::fit(mesh.bounds(), 256), {}));
  uint64_t rays = 0, hits = 0, steps_off = 0, steps_on = 0;
  for (size_t i = 0; i < sets.size(); ++i) {
    const VoxelSet& set = sets[i];
    const BrickmapStructure s(std::make_shared<World>(build_world(set)));
    const GridTransform& g = set.grid;
    testing::OctreeRayGen gen(77 + i, g.levels);
    for (int n = 0; n < 20000; ++n) {
      Vec3 p, d;
      gen.next(&p, &d);
      if (n % 8 == 7 && !set.codes.empty()) {
        const MortonCoord c = morton_decode(set.codes[size_t(gen.pick(int(set.codes.size())))]);
        p = Vec3{1, 1, 1} + Vec3{float(c.x) + gen.uni(0, 1), float(c.y) + gen.uni(0, 1),
                                 float(c.z) + gen.uni(0, 1)} *
                                float(1.0 / g.resolution);
      }
      const Ray ray{g.origin + (p - Vec3{1, 1, 1}) * float(g.side()), d, INFINITY};
      const LodFootprint lod =
          n % 3 == 0 ? LodFootprint{0.f, float(g.voxel_size) * 0.01f} : LodFootprint{};
      SurfaceHit want{}, got{};
      TraceContext ctx;
      ctx.counting = true;
      brickmap::detail::brick_skip_mode = brickmap::detail::BrickSkip::Off;
      const bool hit = s.trace(ray, lod, ctx, &want);
      steps_off += ctx.counters.iterations;
      ctx.counters = {};
      for (const brickmap::detail::BrickSkip mode :
           {brickmap::detail::BrickSkip::Scalar, brickmap::detail::BrickSkip::Simd}) {
        brickmap::detail::brick_skip_mode = mode;
        TraceContext c2;
        c2.counting = true;
        ASSERT_EQ(s.trace(ray, lod, c2, &got), hit) << "set " << i << " ray " << n;
        if (mode == brickmap::detail::BrickSkip::Simd) steps_on += c2.counters.iterations;
        if (!hit) continue;
        ASSERT_EQ(std::memcmp(&got.t, &want.t, sizeof(float)), 0)
            << "set " << i << " ray " << n << " t " << got.t << " want " << want.t << " face "
            << got.child << " want " << want.child << " ref " << got.voxel_ref << " want "
            << want.voxel_ref;
        ASSERT_EQ(std::memcmp(&got.position, &want.position, sizeof(Vec3)), 0)
            << "set " << i << " ray " << n;
        ASSERT_EQ(got.child, want.child);
        ASSERT_EQ(got.level, want.level);
        ASSERT_EQ(got.voxel_ref, want.voxel_ref) << "set " << i << " ray " << n;
      }
      ++rays, hits += hit;
    }
  }
  std::printf("brick test: %llu rays, %llu hits, %llu steps without, %llu with\n",
              (unsigned long long)rays, (unsigned long long)hits, (unsigned long long)steps_off,
              (unsigned long long)steps_on);
  EXPECT_GE(hits, rays / 5);
  EXPECT_LT(steps_on, steps_off);
}

// The cubes inside a brick an LOD footprint may stop at, tested from the
// brick's folded mask against the reference (the general loop's per-cube
// occupancy test): the same hits bit for bit, with footprints that stop in
// the pyramid, at bricks and at 2^3 and 4^3 blocks inside them.
TEST(BrickmapSkip, TheSameLodHitsWithAndWithoutTheBlockMasks) {
  struct Restore {
    ~Restore() { brickmap::detail::brick_block_masks = true; }
  } restore;
  std::vector<VoxelSet> sets;
  const std::pair<int, size_t> placed[] = {{5, 6000}, {7, 30000}, {8, 0}, {8, 60000}};
  int k = 0;
  for (const auto& [levels, count] : placed)
    sets.push_back(testing::make_placed_case(levels, count, 500 + k, k)), ++k;
  const Mesh mesh = load_mesh(testing::test_mesh("spot.obj"));
  sets.push_back(voxelize(mesh, GridTransform::fit(mesh.bounds(), 256), {}));
  uint64_t rays = 0, hits = 0, coarse = 0, steps_ref = 0, steps_fast = 0;
  for (size_t i = 0; i < sets.size(); ++i) {
    const VoxelSet& set = sets[i];
    const BrickmapStructure s(std::make_shared<World>(build_world(set)));
    const GridTransform& g = set.grid;
    const float vs = float(g.voxel_size);
    const LodFootprint lods[] = {{0.f, vs * 0.01f},
                                 {vs * 2.5f, vs * 0.004f},
                                 {vs * 5.f, 0.f},
                                 {0.f, vs * 0.05f},
                                 {vs * 1.2f, vs * 0.02f}};
    testing::OctreeRayGen gen(91 + i, g.levels);
    for (int n = 0; n < 15000; ++n) {
      Vec3 p, d;
      gen.next(&p, &d);
      const Ray ray{g.origin + (p - Vec3{1, 1, 1}) * float(g.side()), d, INFINITY};
      const LodFootprint& lod = lods[n % 5];
      SurfaceHit want{}, got{};
      TraceContext c1, c2;
      c1.counting = c2.counting = true;
      brickmap::detail::brick_block_masks = false;
      const bool hit = s.trace(ray, lod, c1, &want);
      brickmap::detail::brick_block_masks = true;
      ASSERT_EQ(s.trace(ray, lod, c2, &got), hit) << "set " << i << " ray " << n;
      steps_ref += c1.counters.iterations, steps_fast += c2.counters.iterations;
      ++rays;
      if (!hit) continue;
      ++hits, coarse += want.level < int(g.levels);
      ASSERT_EQ(std::memcmp(&got.t, &want.t, sizeof(float)), 0)
          << "set " << i << " ray " << n << " t " << got.t << " want " << want.t;
      ASSERT_EQ(std::memcmp(&got.position, &want.position, sizeof(Vec3)), 0)
          << "set " << i << " ray " << n;
      ASSERT_EQ(got.child, want.child) << "set " << i << " ray " << n;
      ASSERT_EQ(got.level, want.level) << "set " << i << " ray " << n;
      ASSERT_EQ(got.voxel_ref, want.voxel_ref) << "set " << i << " ray " << n;
    }
  }
  std::printf("block masks: %llu rays, %llu hits (%llu above the voxels), %llu steps\n",
              (unsigned long long)rays, (unsigned long long)hits, (unsigned long long)coarse,
              (unsigned long long)steps_fast);
  EXPECT_GE(hits, rays / 5);
  EXPECT_GE(coarse, hits / 4);
  // The same DDA steps but for the 2^3 blocks of visit_pairs, whose brick
  // test and slab entry skip some.
  EXPECT_LT(steps_fast, steps_ref);
}

// ---------------------------------------------------------------------------
// The same voxels as ESVO sees them: render both with one camera.

TEST(BrickmapOracle, RenderEqualsTheEsvoRenderOfTheSameVoxels) {
  const Mesh mesh = load_mesh(testing::test_mesh("spot.obj"));
  const VoxelSet set = voxelize(mesh, GridTransform::fit(mesh.bounds(), 128), {});
  const auto esvo_s = std::make_unique<esvo::EsvoStructure>(
      std::make_shared<esvo::EsvoOctree>(esvo::build_octree(set)));
  const auto brick_s =
      std::make_unique<BrickmapStructure>(std::make_shared<World>(build_world(set)));
  RenderOptions o;
  o.width = 160, o.height = 120;
  o.lod_pixels = 0;
  o.want_depth = o.want_normal = true;
  const Aabb b = mesh.bounds();
  const float r = length(b.extent());
  const float views[3][2] = {{20.f, 25.f}, {200.f, -10.f}, {95.f, 60.f}};
  for (const auto& view : views) {
    o.camera = Camera::orbit(b, o.width, o.height, view[0], view[1]);
    const RenderResult e = render(*esvo_s, o), m = render(*brick_s, o);
    size_t same_hit = 0, hits = 0, depth_ok = 0, color_ok = 0;
    const size_t px = size_t(o.width) * size_t(o.height);
    for (size_t i = 0; i < px; ++i) {
      const float de = e.depth.pixels[i], dm = m.depth.pixels[i];
      const bool he = std::isfinite(de), hm = std::isfinite(dm);
      same_hit += he == hm;
      if (!(he && hm)) continue;
      ++hits;
      depth_ok += std::fabs(de - dm) <= 1e-4f * r;
      bool close = true;
      for (int ch = 0; ch < 3; ++ch)
        close = close && std::fabs(e.color.pixels[3 * i + size_t(ch)] -
                                   m.color.pixels[3 * i + size_t(ch)]) <= 1e-5f;
      color_ok += close;
    }
    std::printf("orbit %g,%g: %zu px, %zu hits, same hit/miss %zu, depth %zu, color %zu\n", view[0],
                view[1], px, hits, same_hit, depth_ok, color_ok);
    EXPECT_GE(hits, px / 10);
    // Only float ties at voxel edges may differ between the two casters.
    EXPECT_GE(double(same_hit), 0.999 * double(px));
    EXPECT_GE(double(depth_ok), 0.999 * double(hits));
    EXPECT_GE(double(color_ok), 0.995 * double(hits));
  }
}

// ---------------------------------------------------------------------------
// LOD and residency.

TEST(BrickmapLod, ABrickFootprintStopsAtTheCoarsenedGridsFirstHitWithTheLodColor) {
  for (int levels : {5, 7}) {
    const VoxelSet set =
        levels == 5 ? testing::make_random_voxels(5, 400, 3) : testing::make_sphere_shell(7);
    const auto world = std::make_shared<World>(build_world(set));
    const BrickmapStructure s(world);
    const GridTransform& g = set.grid;
    const DenseGrid coarse = DenseGrid::from_voxels(set, g.levels - 3);
    const double bs = g.voxel_size * 8;
    testing::OctreeRayGen gen(99, g.levels - 3);
    DdaTally tally;
    for (int i = 0; i < 4000; ++i) {
      Vec3 p, d;
      gen.next(&p, &d);
      const Vec3 wo = g.origin + (p - Vec3{1, 1, 1}) * float(g.side());
      const LodFootprint lod{float(bs), 0.f};
      const Traced t = trace(s, Ray{wo, d, INFINITY}, lod);
      const CasterHit hit = as_caster_hit(g, t, g.levels - 3);
      const DVec3 go{(wo.x - g.origin.x) / bs, (wo.y - g.origin.y) / bs, (wo.z - g.origin.z) / bs};
      const DVec3 gd{d.x / bs, d.y / bs, d.z / bs};
      testing::expect_first_hit_matches(coarse, go, gd, hit,
                                        testing::kDeltaOct * (g.resolution / 8), &tally, wo, d);
      if (HasFailure()) return;
      if (t.hit) {
        TraceContext ctx;
        Color col;
        Vec3 n;
        s.attributes(t.h, ctx, &col, &n);
        const uint32_t cell =
            world->cell(world->cell_index(uint32_t(hit.x), uint32_t(hit.y), uint32_t(hit.z)));
        EXPECT_EQ(esvo::encode_color_abgr(col), world->brick(cell_brick(cell)).lod);
        EXPECT_FLOAT_EQ(length(n), 1.f);
      }
    }
    EXPECT_GE(tally.hits, tally.rays / 10);
  }
}

TEST(BrickmapLod, NotResidentBricksAnswerWithTheirLodColorAndAskOnce) {
  const VoxelSet set = testing::make_sphere_shell(6);
  auto world = std::make_shared<World>(build_world(set));
  const GridTransform& g = set.grid;
  // A ray along +z through the middle of the grid: its first brick.
  const Ray ray{{float(g.side() * 0.5 + 1e-3), float(g.side() * 0.5 + 1e-3), -1.f}, {0, 0, 1}};
  const Traced before = trace(BrickmapStructure(world), ray);
  ASSERT_TRUE(before.hit);
  const uint32_t bx = uint32_t(before.h.position.x / (g.voxel_size * 8));
  const uint32_t by = uint32_t(before.h.position.y / (g.voxel_size * 8));
  const uint32_t bz = uint32_t(before.h.position.z / (g.voxel_size * 8));
  const uint64_t ci = world->cell_index(bx, by, bz);
  const uint32_t lod = world->brick(cell_brick(world->cell(ci))).lod;
  world->set_not_resident(ci, lod);
  const BrickmapStructure s(world);
  TraceContext ctx;
  ctx.requests.reserve(8);
  SurfaceHit h;
  ASSERT_TRUE(s.trace(ray, {}, ctx, &h));
  EXPECT_EQ(h.level, g.levels - 3);
  EXPECT_LE(h.t, before.h.t);
  Color col;
  Vec3 n;
  s.attributes(h, ctx, &col, &n);
  EXPECT_EQ(esvo::encode_color_abgr(col), lod);
  EXPECT_EQ(n.z, -1.f) << "the face the ray entered";
  ASSERT_EQ(ctx.requests.size(), 1u);
  EXPECT_EQ(ctx.requests.items()[0].kind, BrickmapStructure::kRequestBrick);
  EXPECT_EQ(ctx.requests.items()[0].key, ci);
  // A footprint that wants the LOD color anyway asks for nothing.
  ctx.requests.clear();
  ASSERT_TRUE(s.trace(ray, LodFootprint{float(g.voxel_size * 8), 0.f}, ctx, &h));
  EXPECT_TRUE(ctx.requests.empty());
  // A 4^3 grid is one brick clipped to the grid: its LOD hit is the root cube.
  auto tiny = std::make_shared<World>(build_world(testing::make_random_voxels(2, 20, 4)));
  tiny->set_not_resident(0, 0xFF112233u);
  const Traced th = trace(BrickmapStructure(tiny), Ray{{0.3f, 0.6f, -1.f}, {0, 0, 1}});
  ASSERT_TRUE(th.hit);
  EXPECT_EQ(th.h.level, 0);
  EXPECT_FLOAT_EQ(th.h.voxel_size, 1.f);
  EXPECT_FLOAT_EQ(th.h.t, 1.f);
  for (int a = 0; a < 3; ++a) EXPECT_TRUE(th.h.position[a] >= 0.f && th.h.position[a] < 1.f);
}

// ---------------------------------------------------------------------------
// Scene files (§4.5).

std::filesystem::path temp_path(const std::string& name) {
  return std::filesystem::temp_directory_path() /
         ("voxcast_brickmap_" + std::to_string(::getpid()) + "_" + name);
}

TEST(BrickmapFile, SaveLoadRoundTripsExactly) {
  for (int levels : {3, 6, 8}) {
    const VoxelSet set =
        levels == 8 ? testing::make_sphere_shell(8) : testing::make_random_voxels(levels, 3000, 8);
    const World w = build_world(set);
    const SceneInfo info{"test", "conservative", 12, set.size()};
    const Container c = save_world(w, info);
    const std::vector<uint8_t> bytes = c.serialize();
    SceneInfo got;
    const World back = load_world(Container::parse(bytes.data(), bytes.size()), &got);
    EXPECT_EQ(got.source, "test");
    EXPECT_EQ(got.leaf_voxels, set.size());
    EXPECT_EQ(back.decode_voxels(), set.codes);
    for (size_t i = 0; i < set.size(); i += 7) {
      const MortonCoord m = morton_decode(set.codes[i]);
      uint32_t c0, n0, c1, n1;
      ASSERT_TRUE(world_voxel(w, m.x, m.y, m.z, &c0, &n0));
      ASSERT_TRUE(world_voxel(back, m.x, m.y, m.z, &c1, &n1));
      EXPECT_EQ(c0, c1);
      EXPECT_EQ(n0, n1);
    }
    EXPECT_EQ(save_world(back, info).serialize(), bytes) << "save(load(file)) != file";
    // The chunks are LZ4 blocks, smaller than the raw bricks for a shell.
    if (levels == 8) {
      EXPECT_LT(c.get(fourcc("BMCK")).size(), w.stats().voxels * 8 + w.stats().bricks * 64);
    }
  }
}

// Every section damaged (bytes flipped, truncated, grown) with the container
// hashes recomputed, so only the brickmap validators stand between the bytes
// and the world: each load either succeeds and yields a traceable world or
// throws voxcast::Error, never crashes.
TEST(BrickmapFile, DamagedSectionsAreRefusedWithOneLineErrors) {
  const VoxelSet set = testing::make_sphere_shell(6);
  const Container good = save_world(build_world(set), SceneInfo{"t", "conservative", 0, 0});
  std::mt19937 rng(5);
  size_t refused = 0, loaded = 0;
  for (uint32_t id : good.section_ids()) {
    const std::vector<uint8_t>& orig = good.get(id);
    for (int trial = 0; trial < 120; ++trial) {
      std::vector<uint8_t> bytes = orig;
      switch (trial % 4) {
        case 0:
          if (!bytes.empty()) bytes[rng() % bytes.size()] ^= uint8_t(1 + rng() % 255);
          break;
        case 1:
          bytes.resize(bytes.empty() ? 0 : rng() % bytes.size());
          break;
        case 2:
          bytes.resize(bytes.size() + 1 + rng() % 32, uint8_t(rng()));
          break;
        default:
          for (int k = 0; k < 4 && bytes.size() >= 4; ++k) {
            const size_t at = (rng() % (bytes.size() / 4)) * 4;
            const uint32_t v = rng() % 2 ? 0xFFFFFFFFu : rng();
            std::memcpy(&bytes[at], &v, 4);
          }
      }
      Container c = good;
      c.add(id, bytes);
      try {
        const auto w = std::make_shared<World>(load_world(c));
        const BrickmapStructure s(w);
        (void)trace(s, Ray{{0.5f, 0.5f, -1.f}, {0, 0, 1}});
        ++loaded;
      } catch (const Error& e) {
        ++refused;
        const std::string what = e.what();
        EXPECT_EQ(what.find('\n'), std::string::npos) << what;
      }
    }
  }
  std::printf("damaged sections: %zu refused, %zu loaded\n", refused, loaded);
  EXPECT_GT(refused, 300u);
}

TEST(BrickmapFile, AChunkWithABadChecksumIsNamed) {
  const VoxelSet set = testing::make_sphere_shell(8);  // 256^3: 2^3 chunks
  Container c = save_world(build_world(set), SceneInfo{"t", "conservative", 0, 0});
  std::vector<uint8_t> chunks = c.get(fourcc("BMCK"));
  chunks[chunks.size() / 2] ^= 0x40;
  c.add(fourcc("BMCK"), chunks);
  try {
    load_world(c);
    FAIL() << "a corrupted chunk loaded";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("checksum mismatch"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("BMCK chunk ("), std::string::npos) << e.what();
  }
}

TEST(BrickmapFile, LoadSceneRendersABrickmapFile) {
  const VoxelSet set = testing::make_sphere_shell(6);
  const std::filesystem::path path = temp_path("scene.vxc");
  save_scene(path, build_world(set), SceneInfo{"t", "conservative", 0, set.size()});
  const LoadedScene scene = load_scene(path);
  std::filesystem::remove(path);
  EXPECT_EQ(scene.format, "brickmap");
  EXPECT_EQ(scene.info.leaf_voxels, set.size());
  EXPECT_EQ(scene.structure->name(), "brickmap");
  RenderOptions o;
  o.width = o.height = 32;
  o.camera = Camera::frame(scene.structure->bounds(), o.width, o.height);
  const RenderResult r = render(*scene.structure, o);
  EXPECT_GT(r.hits, 100u);
}

// ---------------------------------------------------------------------------
// Editing (§3.2.2, §4.4) against a dense-grid oracle applying the same edits.

struct OracleEdit {
  bool sphere;
  double p[6];  // sphere: center, radius; box: lo, hi
  EditOp op;
  Color color;
};

// The rule of brickmap.hpp, written out: a voxel is in the brush when its
// center is (closed ball / closed box).
bool oracle_inside(const OracleEdit& e, double x, double y, double z) {
  if (e.sphere) {
    const double dx = x - e.p[0], dy = y - e.p[1], dz = z - e.p[2];
    return dx * dx + dy * dy + dz * dz <= e.p[3] * e.p[3];
  }
  return x >= e.p[0] && x <= e.p[3] && y >= e.p[1] && y <= e.p[4] && z >= e.p[2] && z <= e.p[5];
}

TEST(BrickmapEdit, EditsThenReloadGiveExactlyTheEditedVoxelSet) {
  VoxelSet set = testing::make_placed_case(6, 0, 0, 1);  // sphere shell, origin (-3,1,2), side 2
  const GridTransform& g = set.grid;
  World w = build_world(set);
  // Oracle: voxel (x, y, z) -> ABGR color, from the set directly.
  std::map<std::array<uint32_t, 3>, uint32_t> dense;
  for (size_t i = 0; i < set.size(); ++i) {
    const MortonCoord c = morton_decode(set.codes[i]);
    dense[{c.x, c.y, c.z}] = esvo::encode_color_abgr(set.colors[i]);
  }
  const auto at = [&](double f, int a) { return double(g.origin[a]) + f * g.side(); };
  const std::vector<OracleEdit> edits = {
      {true, {at(0.5, 0), at(0.5, 1), at(0.9, 2), 0.3, 0, 0}, EditOp::Remove, {}},
      {false,
       {at(0.1, 0), at(0.4, 1), at(0.1, 2), at(0.35, 0), at(0.6, 1), at(0.5, 2)},
       EditOp::Add,
       {0.9f, 0.2f, 0.1f, 1}},
      {true,
       {at(0.3, 0), at(0.5, 1), at(0.5, 2), 0.45, 0, 0},
       EditOp::Paint,
       {0.1f, 0.8f, 0.3f, 1}},
      {false,
       {at(0.6, 0), at(-0.2, 1), at(0.6, 2), at(1.3, 0), at(0.3, 1), at(0.7, 2)},
       EditOp::Add,
       {0.2f, 0.2f, 0.9f, 1}},
      {true, {at(2.0, 0), at(2.0, 1), at(2.0, 2), 0.1, 0, 0}, EditOp::Remove, {}},  // outside
  };
  for (const OracleEdit& e : edits) {
    const Brush brush = e.sphere ? Brush::sphere({e.p[0], e.p[1], e.p[2]}, e.p[3])
                                 : Brush::box({e.p[0], e.p[1], e.p[2]}, {e.p[3], e.p[4], e.p[5]});
    const EditResult r = edit(w, brush, e.op, e.color);
    const uint32_t abgr = esvo::encode_color_abgr(e.color);
    uint64_t changed = 0;
    for (uint32_t z = 0; z < g.resolution; ++z)
      for (uint32_t y = 0; y < g.resolution; ++y)
        for (uint32_t x = 0; x < g.resolution; ++x) {
          const double vs = g.voxel_size;
          if (!oracle_inside(e, g.origin.x + (x + 0.5) * vs, g.origin.y + (y + 0.5) * vs,
                             g.origin.z + (z + 0.5) * vs))
            continue;
          const auto it = dense.find({x, y, z});
          if (e.op == EditOp::Remove && it != dense.end()) dense.erase(it), ++changed;
          if (e.op == EditOp::Paint && it != dense.end() && it->second != abgr)
            it->second = abgr, ++changed;
          if (e.op == EditOp::Add) dense[{x, y, z}] = abgr, ++changed;
        }
    // Add counts only voxels whose state, color or normal changed.
    if (e.op == EditOp::Add) {
      EXPECT_LE(r.voxels, changed);
    } else {
      EXPECT_EQ(r.voxels, changed);
    }
    for (uint64_t cell : r.cells) {
      if (w.cell(cell) != 0) {
        EXPECT_EQ(CellFlags::get(w.cell(cell)), kFlagEdited);
      }
    }
  }
  const auto expect_equal = [&](const World& world, const char* what) {
    std::vector<uint64_t> want;
    for (const auto& [c, color] : dense) want.push_back(morton_encode(c[0], c[1], c[2]));
    std::sort(want.begin(), want.end());
    ASSERT_EQ(world.decode_voxels(), want) << what;
    for (const auto& [c, color] : dense) {
      uint32_t got = 0, normal = 0;
      ASSERT_TRUE(world_voxel(world, c[0], c[1], c[2], &got, &normal));
      ASSERT_EQ(got, color) << what << " voxel " << c[0] << "," << c[1] << "," << c[2];
    }
  };
  expect_equal(w, "after the edits");
  const std::vector<uint8_t> bytes = save_world(w, SceneInfo{}).serialize();
  const World back = load_world(Container::parse(bytes.data(), bytes.size()));
  expect_equal(back, "after save and reload");
  // The rendered world shows the edit: a ray into the removed cap misses
  // the shell there and hits the far side.
  const BrickmapStructure s(std::make_shared<World>(build_world(set)));
  const BrickmapStructure e(std::make_shared<World>(back));
  const Ray down{{float(at(0.5, 0)) + 1e-4f, float(at(0.5, 1)) + 1e-4f, float(at(1.2, 2))},
                 {0, 0, -1}};
  const Traced t0 = trace(s, down), t1 = trace(e, down);
  ASSERT_TRUE(t0.hit && t1.hit);
  EXPECT_GT(t1.h.t, t0.h.t + 0.5f * float(g.side()));
}

// The bookkeeping an edit defers and shortcuts (in-place color runs, one
// pyramid update per edit) against a world rebuilt brick by brick from the
// edited one with the plain set_brick: the same occupancy bits, pyramid
// nodes (brick counts and LOD colors), voxels and colors.
TEST(BrickmapEdit, InPlaceRunsAndTheBatchedPyramidEqualARebuiltWorld) {
  const VoxelSet set = testing::make_sphere_shell(7);
  World w = build_world(set);
  const GridTransform& g = set.grid;
  const auto at = [&](double f, int a) { return double(g.origin[a]) + f * g.side(); };
  const Vec3d c{at(0.5, 0), at(0.5, 1), at(0.95, 2)};
  // A full brick edited by one voxel keeps its color run.
  uint64_t full[8];
  std::fill(full, full + 8, ~uint64_t(0));
  std::vector<uint32_t> colors(512, 0xFF00FF00u), normals(512, 0);
  const uint64_t solid_cell = w.cell_index(0, 0, 0);
  w.set_brick(solid_cell, full, colors.data(), normals.data());
  const uint32_t run = w.brick(cell_brick(w.cell(solid_cell))).color;
  const EditResult one =
      edit(w,
           Brush::sphere({g.origin.x + 0.5 * g.voxel_size, g.origin.y + 0.5 * g.voxel_size,
                          g.origin.z + 0.5 * g.voxel_size},
                         0.1 * g.voxel_size),
           EditOp::Remove);
  ASSERT_EQ(one.voxels, 1u);
  EXPECT_EQ(w.brick(cell_brick(w.cell(solid_cell))).color, run) << "the run was reallocated";
  EXPECT_EQ(brick_popcount(w.brick(cell_brick(w.cell(solid_cell)))), 511);
  EXPECT_EQ(w.color_of(w.brick(cell_brick(w.cell(solid_cell))), 510), 0xFF00FF00u);
  // Edits that empty, fill and recolor many bricks.
  EXPECT_GT(edit(w, Brush::sphere(c, 0.2 * g.side()), EditOp::Remove).voxels, 0u);
  EXPECT_GT(edit(w, Brush::sphere(c, 0.1 * g.side()), EditOp::Add, {0.9f, 0.1f, 0.1f, 1}).voxels,
            0u);
  EXPECT_GT(
      edit(w,
           Brush::box({at(0.2, 0), at(0.2, 1), at(0.2, 2)}, {at(0.6, 0), at(0.7, 1), at(0.4, 2)}),
           EditOp::Paint, {0.1f, 0.2f, 0.9f, 1})
          .voxels,
      0u);
  World rebuilt(g);
  for (uint64_t i = 0; i < w.cells().size(); ++i) {
    const uint32_t cell = w.cell(i);
    if (cell_state(cell) != kStateResident) continue;
    const Brick& b = w.brick(cell_brick(cell));
    const int n = brick_popcount(b);
    std::vector<uint32_t> cs(static_cast<size_t>(n)), ns(static_cast<size_t>(n));
    for (int k = 0; k < n; ++k) {
      cs[size_t(k)] = w.color_of(b, uint32_t(k));
      ns[size_t(k)] = w.normals()[b.color + uint32_t(k)];
    }
    rebuilt.set_brick(i, b.mask, cs.data(), ns.data());
    const Brick& r = rebuilt.brick(cell_brick(rebuilt.cell(i)));
    ASSERT_EQ(r.lod, b.lod) << "cell " << i;
  }
  EXPECT_EQ(rebuilt.occupancy_words(), w.occupancy_words());
  ASSERT_EQ(rebuilt.pyramid_levels(), w.pyramid_levels());
  for (int k = 1; k <= w.pyramid_levels(); ++k) {
    const uint64_t nodes = uint64_t(w.pyramid_dim(k)) * w.pyramid_dim_y(k) * w.pyramid_dim(k);
    for (uint64_t i = 0; i < nodes; ++i) {
      ASSERT_EQ(rebuilt.pyramid_node(k, i).bricks, w.pyramid_node(k, i).bricks) << k << " " << i;
      ASSERT_EQ(rebuilt.pyramid_node(k, i).abgr, w.pyramid_node(k, i).abgr) << k << " " << i;
    }
  }
  EXPECT_EQ(rebuilt.decode_voxels(), w.decode_voxels());
}

// Brushes run over bricks in parallel: one thread and two give the same
// world, pool slots and color runs included.
TEST(BrickmapEdit, TheSameWorldWhateverTheThreads) {
  const VoxelSet set = testing::make_sphere_shell(7);
  const GridTransform& g = set.grid;
  const auto at = [&](double f, int a) { return double(g.origin[a]) + f * g.side(); };
  auto run = [&](int threads) {
    World w = build_world(set);
    tbb::task_arena arena(threads);
    arena.execute([&] {
      edit(w, Brush::sphere({at(0.5, 0), at(0.5, 1), at(0.95, 2)}, 0.3 * g.side()), EditOp::Remove);
      edit(w, Brush::sphere({at(0.3, 0), at(0.6, 1), at(0.5, 2)}, 0.2 * g.side()), EditOp::Add,
           {0.9f, 0.2f, 0.1f, 1});
      // The stamp and the snowfall batch their bricks the same way.
      VoxelSet s = testing::make_random_voxels(7, 20000, 3);
      testing::fill_random_attributes(s, 4);
      s.grid = w.grid();
      stamp(w, s, EditOp::Add);
      for (uint32_t step = 0; step < 3; ++step) snow_step(w, step);
    });
    return w;
  };
  const World one = run(1), two = run(2);
  EXPECT_EQ(one.cells(), two.cells());
  EXPECT_EQ(one.colors(), two.colors());
  EXPECT_EQ(one.normals(), two.normals());
  EXPECT_EQ(one.decode_voxels(), two.decode_voxels());
}

TEST(BrickmapEdit, RefusesBadBrushesAndNotResidentBricks) {
  World w = build_world(testing::make_sphere_shell(5));
  EXPECT_THROW(edit(w, Brush::sphere({0, 0, NAN}, 1), EditOp::Add), Error);
  EXPECT_THROW(edit(w, Brush::sphere({0, 0, 0}, -1), EditOp::Add), Error);
  EXPECT_THROW(edit(w, Brush::box({1, 0, 0}, {0, 1, 1}), EditOp::Add), Error);
  uint64_t cell = 0;
  while (w.cell(cell) == 0) ++cell;
  w.set_not_resident(cell, 0xFF808080u);
  EXPECT_THROW(edit(w, Brush::box({0, 0, 0}, {1, 1, 1}), EditOp::Paint), Error);
}

TEST(BrickmapCli, EditRemovesWhatTheLibraryRemoves) {
  testing::TempDir dir;
  const std::string world = dir.file("w.vxc"), edited = dir.file("e.vxc");
  save_scene(world, build_world(testing::make_sphere_shell(6)), SceneInfo{"t", "c", 0, 0});
  const testing::CliResult r = testing::run_cli("edit '" + world +
                                                "' --sphere 0.5,0.5,0.9,0.3 "
                                                "--remove -o '" +
                                                edited + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  World want = load_world(Container::read(world));
  const EditResult er = edit(want, Brush::sphere({0.5f, 0.5f, 0.9f}, 0.3f), EditOp::Remove);
  EXPECT_GT(er.voxels, 100u);
  EXPECT_NE(r.output.find(std::to_string(er.voxels) + " voxels changed"), std::string::npos)
      << r.output;
  EXPECT_EQ(load_world(Container::read(edited)).decode_voxels(), want.decode_voxels());
  // In place, then a paint: saved through the edit journal
  // (brickmap_file.hpp), which every reader replays; --checkpoint folds it
  // into the scene file.
  World painted = load_world(Container::read(world));
  edit(painted, Brush::box({0, 0, 0}, {1, 1, 0.5}), EditOp::Paint, Color{1, 0, 0, 1});
  const auto chunks = [](const World& w) { return save_world(w, SceneInfo{}).get(fourcc("BMCK")); };
  const testing::CliResult p =
      testing::run_cli("edit '" + world + "' --box 0,0,0,1,1,0.5 --paint 1,0,0");
  ASSERT_EQ(p.exit_code, 0) << p.output;
  EXPECT_NE(p.output.find("(journal "), std::string::npos) << p.output;
  EXPECT_TRUE(std::filesystem::exists(journal_path(world)));
  EXPECT_EQ(chunks(open_world(world)), chunks(painted));
  EXPECT_EQ(chunks(dynamic_cast<const BrickmapStructure&>(*load_scene(world).structure).world()),
            chunks(painted));
  edit(painted, Brush::sphere({0.5, 0.5, 0.5}, 0.2), EditOp::Add, Color{0, 1, 0, 1});
  const testing::CliResult q = testing::run_cli(
      "edit '" + world + "' --sphere 0.5,0.5,0.5,0.2 --add --color 0,1,0 --checkpoint");
  ASSERT_EQ(q.exit_code, 0) << q.output;
  EXPECT_NE(q.output.find("(checkpointed)"), std::string::npos) << q.output;
  EXPECT_FALSE(std::filesystem::exists(journal_path(world)));
  EXPECT_EQ(chunks(load_world(Container::read(world))), chunks(painted));
  // Usage errors exit 2 with one line.
  EXPECT_EQ(testing::run_cli("edit '" + world + "' --sphere 1,2,3 --remove").exit_code, 2);
  EXPECT_EQ(testing::run_cli("edit '" + world + "' --sphere 1,2,3,1").exit_code, 2);
}

TEST(BrickmapEdit, StampAddsRemovesAndPaintsExactlyTheVoxelSet) {
  World w = build_world(testing::make_sphere_shell(6));
  const std::vector<uint64_t> before = w.decode_voxels();
  VoxelSet s = testing::make_random_voxels(6, 3000, 8);
  testing::fill_random_attributes(s, 2);
  s.grid = w.grid();
  // Add: every stamp voxel solid with its own color, the others unchanged.
  const EditResult a = stamp(w, s, EditOp::Add);
  EXPECT_GT(a.voxels, 2000u);
  std::vector<uint64_t> want = before;
  want.insert(want.end(), s.codes.begin(), s.codes.end());
  std::sort(want.begin(), want.end());
  want.erase(std::unique(want.begin(), want.end()), want.end());
  EXPECT_EQ(w.decode_voxels(), want);
  const BrickmapStructure q(std::make_shared<World>(w));
  for (size_t i = 0; i < s.size(); i += 97) {
    const MortonCoord c = morton_decode(s.codes[i]);
    const float n = float(w.grid().resolution);
    TraceContext ctx;
    SurfaceHit h;
    ASSERT_TRUE(q.trace(Ray{{(c.x + 0.5f) / n, (c.y + 0.5f) / n, (c.z + 0.5f) / n}, {1, 0, 0}}, {},
                        ctx, &h));
    Color col;
    Vec3 nrm;
    q.attributes(h, ctx, &col, &nrm);
    EXPECT_EQ(esvo::encode_color_abgr(col), esvo::encode_color_abgr(s.colors[i]));
  }
  // Remove: exactly the stamp's voxels go.
  stamp(w, s, EditOp::Remove);
  std::vector<uint64_t> rest;
  std::set_difference(before.begin(), before.end(), s.codes.begin(), s.codes.end(),
                      std::back_inserter(rest));
  EXPECT_EQ(w.decode_voxels(), rest);
  // Another grid is refused.
  VoxelSet other = s;
  other.grid.voxel_size *= 2;
  EXPECT_THROW(stamp(w, other, EditOp::Add), Error);
  // A stamp touching a brick that is not resident changes nothing.
  stamp(w, s, EditOp::Add);
  const MortonCoord last = morton_decode(s.codes.back());
  w.set_not_resident(w.cell_index(last.x >> 3, last.y >> 3, last.z >> 3), 0xFF808080u);
  const std::vector<uint32_t> cells = w.cells();
  const std::vector<uint64_t> voxels = w.decode_voxels();
  EXPECT_THROW(stamp(w, s, EditOp::Remove), Error);
  EXPECT_EQ(w.cells(), cells);
  EXPECT_EQ(w.decode_voxels(), voxels);
}

TEST(BrickmapCli, BatchFileAndMeshStampEditAsTheLibraryDoes) {
  testing::TempDir dir;
  const std::string world = dir.file("w.vxc"), batch = dir.file("edits.txt");
  const std::string spot = testing::test_mesh("spot.obj").string();
  save_scene(world, build_world(testing::make_sphere_shell(6)), SceneInfo{"t", "c", 0, 0});
  testing::write_text(batch,
                      "# two brushes and a mesh stamp\n"
                      "sphere 0.5,0.5,0.9,0.2 remove\n"
                      "\n"
                      "box 0,0,0,1,1,0.3 paint 1,0,0  # the bottom red\n"
                      "mesh " +
                          spot + " 0.5,0.5,0.5 0.5 add 0,1,0\n");
  World want = load_world(Container::read(world));
  edit(want, Brush::sphere({0.5, 0.5, 0.9}, 0.2), EditOp::Remove);
  edit(want, Brush::box({0, 0, 0}, {1, 1, 0.3}), EditOp::Paint, Color{1, 0, 0, 1});
  // The stamp: spot's box centered at (0.5, 0.5, 0.5), its largest side 0.5.
  Mesh m = load_mesh(testing::test_mesh("spot.obj"));
  const Aabb b = m.bounds();
  const Vec3 e = b.extent();
  const float k = 0.5f / std::max({e.x, e.y, e.z});
  for (Vec3& p : m.positions) p = Vec3{0.5f, 0.5f, 0.5f} + (p - (b.lo + b.hi) * 0.5f) * k;
  const VoxelSet sv = voxelize(m, want.grid(), {});
  ASSERT_GT(sv.size(), 500u);
  stamp(want, sv, EditOp::Add);
  const testing::CliResult r = testing::run_cli("edit '" + world + "' --batch '" + batch + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("3 edits in"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("voxels/s"), std::string::npos) << r.output;
  const auto chunks = [](const World& w) { return save_world(w, SceneInfo{}).get(fourcc("BMCK")); };
  EXPECT_EQ(chunks(open_world(world)), chunks(want));
  OpenReport rep;
  (void)open_world(world, nullptr, &rep);
  EXPECT_EQ(rep.transactions, 1u) << "a batch is one transaction";
  // The single mesh brush, and batch errors name the line.
  const testing::CliResult one = testing::run_cli("edit '" + world + "' --mesh '" + spot +
                                                  "' --at 0.3,0.3,0.3 --size 0.2 --remove");
  EXPECT_EQ(one.exit_code, 0) << one.output;
  testing::write_text(batch, "sphere 0.5,0.5,0.5,0.1 add\ncube 1,2,3 add\n");
  const testing::CliResult bad = testing::run_cli("edit '" + world + "' --batch '" + batch + "'");
  EXPECT_EQ(bad.exit_code, 2);
  EXPECT_NE(bad.output.find("line 2"), std::string::npos) << bad.output;
}

// ---------------------------------------------------------------------------
// CLI: build --format brickmap, info, render.

TEST(BrickmapCli, BuildInfoRender) {
  testing::TempDir dir;
  const std::string mesh = testing::test_mesh("spot.obj").string();
  const std::string out = dir.file("spot.vxc");
  const testing::CliResult b =
      testing::run_cli("build '" + mesh + "' -o '" + out + "' --resolution 64 --format brickmap");
  ASSERT_EQ(b.exit_code, 0) << b.output;
  const testing::CliResult i = testing::run_cli("info '" + out + "'");
  ASSERT_EQ(i.exit_code, 0) << i.output;
  EXPECT_NE(i.output.find("brickmap"), std::string::npos) << i.output;
  EXPECT_NE(i.output.find("bricks"), std::string::npos) << i.output;
  const testing::CliResult r =
      testing::run_cli("render '" + out + "' -o '" + dir.file("a.png") + "' --size 64x48");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_TRUE(std::filesystem::exists(dir.file("a.png")));
}

// `voxcast bench --brickmap` reports edit throughput (issue 11): paint,
// remove and add of one sphere on the surface. Paint recolors the ball's
// solid voxels and remove then empties exactly those; add fills the ball.
TEST(BrickmapCli, BenchPrintsEditThroughputRows) {
  const std::string mesh = testing::test_mesh("spot.obj").string();
  const testing::CliResult b = testing::run_cli(
      "bench '" + mesh +
      "' --resolution 64 --size 32x24 --repeat 1 --brickmap --beam 0 --threads 1 -q");
  ASSERT_EQ(b.exit_code, 0) << b.output;
  const size_t at = b.output.find("brickmap edits");
  ASSERT_NE(at, std::string::npos) << b.output;
  unsigned long long voxels[3] = {}, bricks[3] = {};
  const char* names[3] = {"paint", "remove", "add"};
  size_t from = at;
  for (int i = 0; i < 3; ++i) {
    from = b.output.find(std::string("  ") + names[i] + " ", from);
    ASSERT_NE(from, std::string::npos) << b.output;
    char name[16];
    ASSERT_EQ(std::sscanf(b.output.c_str() + from, "%15s %llu voxels %llu bricks", name, &voxels[i],
                          &bricks[i]),
              3)
        << b.output.substr(from, 100);
  }
  EXPECT_GT(voxels[0], 0u);
  EXPECT_EQ(voxels[1], voxels[0]);
  EXPECT_EQ(bricks[1], bricks[0]);
  EXPECT_GT(voxels[2], voxels[1]) << "the added ball is solid, the surface it replaced is not";
  // The chunk decode row: a positive rate, every source brick decoded.
  const size_t row = b.output.find("brickmap chunk decode");
  ASSERT_NE(row, std::string::npos) << b.output;
  const size_t ms = b.output.find(" ms ", row);
  ASSERT_NE(ms, std::string::npos) << b.output.substr(row, 300);
  double gbs = 0;
  unsigned long long decoded = 0, source = 0;
  ASSERT_EQ(std::sscanf(b.output.c_str() + ms, " ms %lf GB/s, %llu bricks decoded of %llu", &gbs,
                        &decoded, &source),
            3)
      << b.output.substr(row, 300);
  EXPECT_GT(gbs, 0.0);
  EXPECT_GT(source, 10u);
  EXPECT_EQ(decoded, source);
  EXPECT_NE(b.output.find("(masks equal the source's)", ms), std::string::npos)
      << b.output.substr(row, 300);
}

TEST(BrickmapCli, BenchJsonHoldsTheChunkDecodeRate) {
  testing::TempDir dir;
  const std::string mesh = testing::test_mesh("spot.obj").string();
  const testing::CliResult b = testing::run_cli(
      "bench '" + mesh +
      "' --resolution 64 --size 16x12 --repeat 1 --brickmap --beam 0 --threads 1 -q --json '" +
      dir.file("b.json") + "'");
  ASSERT_EQ(b.exit_code, 0) << b.output;
  const nlohmann::json j = nlohmann::json::parse(testing::read_text(dir.file("b.json")));
  bool found = false;
  for (const nlohmann::json& run : j.at("runs")) {
    if (!run.contains("brickmap_chunk_decode")) continue;
    const nlohmann::json& d = run.at("brickmap_chunk_decode");
    found = true;
    EXPECT_GT(d.at("gb_per_s").get<double>(), 0.0);
    EXPECT_GT(d.at("raw_bytes").get<uint64_t>(), d.at("compressed_bytes").get<uint64_t>());
    EXPECT_GT(d.at("source_bricks").get<uint64_t>(), 10u);
    EXPECT_EQ(d.at("decoded_bricks"), d.at("source_bricks"));
    EXPECT_TRUE(d.at("bricks_equal").get<bool>());
  }
  EXPECT_TRUE(found) << b.output;
}

TEST(Brickmap, ChunkDecodeMeasuresEveryBrick) {
  const World w = build_world(testing::make_sphere_shell(6));
  uint64_t bricks = 0;
  for (uint64_t c = 0; c < w.cells().size(); ++c) bricks += w.cell(c) != 0;
  ASSERT_GT(bricks, 0u);
  const ChunkDecodeRate d = measure_chunk_decode(w, 2);
  EXPECT_EQ(d.source_bricks, bricks);
  EXPECT_EQ(d.decoded_bricks, bricks);
  EXPECT_EQ(d.decoded_hash, d.source_hash);
  EXPECT_GT(d.chunks, 0u);
  EXPECT_GT(d.raw_bytes, bricks * 64);
  EXPECT_GT(d.seconds, 0.0);
  EXPECT_GT(d.bytes_per_second(), 0.0);
}

// ---- The any-hit path of occlusion rays (BrickmapStructure::transmittance) ----

// The brickmap world answering occlusion through SurfaceQuery's default
// transmittance() (trace()): the reference of the any-hit path.
class TraceOccluder final : public Structure, public SurfaceQuery {
 public:
  explicit TraceOccluder(const BrickmapStructure& s) : s_(s) {}
  std::string name() const override { return "brickmap trace"; }
  Aabb bounds() const override { return s_.bounds(); }
  const SurfaceQuery* surface() const override { return this; }
  bool trace(const Ray& ray, const LodFootprint& lod, TraceContext& ctx, SurfaceHit* hit,
             const BeamStart* beam = nullptr) const override {
    return s_.trace(ray, lod, ctx, hit, beam);
  }
  void attributes(const SurfaceHit& hit, TraceContext& ctx, Color* color,
                  Vec3* normal) const override {
    s_.attributes(hit, ctx, color, normal);
  }

 private:
  const BrickmapStructure& s_;
};

TEST(BrickmapAnyHit, OcclusionEqualsTraceOnRandomRays) {
  const Mesh mesh = load_mesh(testing::test_mesh("spot.obj"));
  const VoxelSet set = voxelize(mesh, GridTransform::fit(mesh.bounds(), 64), {});
  const BrickmapStructure s(std::make_shared<World>(build_world(set)));
  const Aabb b = s.bounds();
  const Vec3 ext = b.extent();
  const float voxel = float(s.world().grid().voxel_size);
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  const auto unit = [&] {
    Vec3 d;
    do d = Vec3{u(rng) * 2 - 1, u(rng) * 2 - 1, u(rng) * 2 - 1};
    while (length(d) < 0.1f);
    return normalize(d);
  };
  // Solid voxel centers: rays that start inside solid.
  std::vector<Vec3> solid;
  {
    TraceContext ctx;
    for (int i = 0; i < 4000 && solid.size() < 500; ++i) {
      Ray r{b.lo + Vec3{u(rng) * ext.x, u(rng) * ext.y, u(rng) * ext.z}, unit()};
      SurfaceHit h;
      if (s.trace(r, {}, ctx, &h)) solid.push_back(h.position);
    }
  }
  ASSERT_GT(solid.size(), 100u);
  TraceContext ctx;
  size_t occluded = 0, open = 0, kinds[5] = {};
  for (int i = 0; i < 40000; ++i) {
    const int kind = i % 5;
    Ray r;
    r.origin = b.lo + Vec3{u(rng) * ext.x, u(rng) * ext.y, u(rng) * ext.z} * 1.4f - ext * 0.2f;
    r.dir = unit();
    r.tmax = INFINITY;
    if (kind == 1) {
      r.origin = solid[size_t(i) % solid.size()];  // inside a solid voxel
      r.tmax = u(rng) < 0.5f ? voxel * u(rng) : INFINITY;
    } else if (kind == 2) {
      // Grazing: along an axis, on a voxel plane of the grid.
      const int a = i % 3;
      r.dir = Vec3{0, 0, 0};
      r.dir[a] = u(rng) < 0.5f ? 1.f : -1.f;
      const int other = (a + 1) % 3;
      r.origin = solid[size_t(i) % solid.size()] - r.dir * (ext[a] * 2);
      const float g0 = float(s.world().grid().origin[other]);
      r.origin[other] = g0 + std::round((r.origin[other] - g0) / voxel) * voxel;
    } else if (kind == 3) {
      // tmax ending inside a brick near the first hit.
      SurfaceHit h;
      if (s.trace(r, {}, ctx, &h)) r.tmax = h.t + voxel * (u(rng) * 16 - 8);
    } else if (kind == 4) {
      r.tmax = length(ext) * u(rng) * 0.3f;  // short AO-like rays
    }
    SurfaceHit h;
    const bool want = s.trace(r, {}, ctx, &h);
    const bool got = s.occluded(r, {}, ctx);
    ASSERT_EQ(got, want) << "ray " << i << " kind " << kind;
    // With an LOD footprint the walk may stop early the same way.
    const LodFootprint lod{voxel * 0.5f, 0.004f};
    ASSERT_EQ(s.occluded(r, lod, ctx), s.trace(r, lod, ctx, &h)) << "ray " << i;
    (want ? occluded : open) += 1;
    kinds[kind] += want;
  }
  EXPECT_GT(occluded, 4000u);
  EXPECT_GT(open, 4000u);
  for (size_t k : kinds) EXPECT_GT(k, 0u);
}

TEST(BrickmapAnyHit, ShadowAndAoRendersAreByteIdentical) {
  const Mesh mesh = load_mesh(testing::test_mesh("spot.obj"));
  const VoxelSet set = voxelize(mesh, GridTransform::fit(mesh.bounds(), 128), {});
  const BrickmapStructure s(std::make_shared<World>(build_world(set)));
  const TraceOccluder reference(s);
  RenderOptions o;
  o.width = 96, o.height = 72;
  o.lod_pixels = 0;
  o.camera = Camera::orbit(mesh.bounds(), o.width, o.height, 30.f, 35.f);
  for (const bool packets : {true, false}) {
    o.effects.shadows = ShadowMode::Hard;
    o.effects.ao_rays = 16;
    o.effects.packets = packets;
    const RenderResult got = render(s, o), want = render(reference, o);
    ASSERT_EQ(got.shadow.pixels.size(), want.shadow.pixels.size());
    EXPECT_EQ(std::memcmp(got.shadow.pixels.data(), want.shadow.pixels.data(),
                          got.shadow.pixels.size() * sizeof(float)),
              0);
    EXPECT_EQ(std::memcmp(got.ao.pixels.data(), want.ao.pixels.data(),
                          got.ao.pixels.size() * sizeof(float)),
              0);
    EXPECT_EQ(std::memcmp(got.color.pixels.data(), want.color.pixels.data(),
                          got.color.pixels.size() * sizeof(float)),
              0);
    float lit = 0, occ = 0;
    for (float v : got.shadow.pixels) lit += v < 1.f;
    for (float v : got.ao.pixels) occ += v < 1.f;
    EXPECT_GT(lit, 10.f) << "some pixels in shadow";
    EXPECT_GT(occ, 50.f) << "some pixels occluded";
  }
}

}  // namespace
}  // namespace voxcast
