// The DAG's voxel index (Hitchhiker's guide, "Dynamic voxel indexing"): 64-bit
// ranks and the voxel ranges of coarse (LOD) hits.
//
// 64-bit voxel indices (dag.hpp "64-bit voxel indices"): DAGs of 2^32 voxels
// and more, built directly as words because such a voxel set is far too big
// to hold. The shape is a solid box [0,wx) x [0,wy) x [0,wz) in the grid's
// corner: every node's content depends only on how far the box reaches into
// its cube along each axis, so the DAG has a handful of nodes per level while
// holding ~10^10 voxels, and every count and Morton rank has a closed form.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cstring>
#include <map>
#include <memory>
#include <random>
#include <vector>

#include "dag/octree_nodes.hpp"
#include "support/cli_runner.hpp"
#include "support/esvo_testing.hpp"
#include "support/packet_testing.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/dag_format.hpp"
#include "voxcast/error.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/scene_file.hpp"

namespace voxcast {
namespace {

using dag::SparseVoxelDag;

struct Box {
  int levels;
  uint32_t w[3];  // extent along x, y, z from the grid's corner

  uint64_t side(int level) const { return uint64_t(1) << (levels - level); }
  uint64_t reach(int axis, uint64_t lo, uint64_t s) const {
    return std::min<uint64_t>(s, w[axis] > lo ? w[axis] - lo : 0);
  }
  // Voxels of the box inside the cube of side s at (x, y, z): closed form.
  uint64_t count(uint64_t x, uint64_t y, uint64_t z, uint64_t s) const {
    return reach(0, x, s) * reach(1, y, s) * reach(2, z, s);
  }
  bool occupied(uint64_t x, uint64_t y, uint64_t z) const {
    return x < w[0] && y < w[1] && z < w[2];
  }
  uint64_t voxels() const { return uint64_t(w[0]) * w[1] * w[2]; }
  // Voxels with a Morton code below that of voxel (x, y, z): at every level
  // of its path, the counts of the sibling cubes in earlier child slots.
  uint64_t rank(uint64_t x, uint64_t y, uint64_t z) const {
    uint64_t r = 0;
    for (int l = 1; l <= levels; ++l) {
      const uint64_t s = side(l);
      const uint64_t px = x / (2 * s) * (2 * s), py = y / (2 * s) * (2 * s),
                     pz = z / (2 * s) * (2 * s);
      const int slot = int((x / s) & 1) | int((y / s) & 1) << 1 | int((z / s) & 1) << 2;
      for (int c = 0; c < slot; ++c)
        r += count(px + (c & 1) * s, py + ((c >> 1) & 1) * s, pz + ((c >> 2) & 1) * s, s);
    }
    return r;
  }
};

// The box's DAG in the dag.hpp layout: depth-first in Morton order with the
// distinct nodes of each level numbered at first visit (= first occurrence
// in Morton order, as build_dag numbers them), then laid out level by level.
SparseVoxelDag box_dag(const Box& box) {
  const int L = box.levels;
  std::vector<std::vector<std::vector<uint32_t>>> nodes(size_t(L - 1));  // [level][id] = words
  std::map<std::array<uint64_t, 4>, uint32_t> ids;                       // (level, reach) -> id
  auto visit = [&](auto&& self, int level, uint64_t x, uint64_t y, uint64_t z) -> uint32_t {
    const uint64_t s = box.side(level);
    const std::array<uint64_t, 4> key = {uint64_t(level), box.reach(0, x, s), box.reach(1, y, s),
                                         box.reach(2, z, s)};
    if (auto it = ids.find(key); it != ids.end()) return it->second;
    std::vector<uint32_t> words;
    if (level == L - 2) {
      uint64_t m = 0;
      for (uint32_t b = 0; b < 64; ++b) {
        const MortonCoord v = morton_decode(b);
        if (box.occupied(x + v.x, y + v.y, z + v.z)) m |= 1ull << b;
      }
      words = {uint32_t(m), uint32_t(m >> 32)};
    } else {
      words = {0};
      const uint64_t h = s / 2;
      for (int c = 0; c < 8; ++c) {
        const uint64_t cx = x + (c & 1) * h, cy = y + ((c >> 1) & 1) * h, cz = z + (c >> 2) * h;
        if (box.count(cx, cy, cz, h) == 0) continue;
        words[0] |= 1u << c;
        words.push_back(self(self, level + 1, cx, cy, cz));  // child id for now
      }
    }
    const uint32_t id = uint32_t(nodes[size_t(level)].size());
    nodes[size_t(level)].push_back(std::move(words));
    ids[key] = id;
    return id;
  };
  visit(visit, 0, 0, 0, 0);
  SparseVoxelDag d;
  d.grid = testing::unit_grid(L);
  std::vector<std::vector<uint32_t>> offset(size_t(L - 1));
  uint32_t total = 0;
  for (int l = 0; l <= L - 2; ++l)
    for (const auto& n : nodes[size_t(l)]) {
      offset[size_t(l)].push_back(total);
      total += uint32_t(n.size());
    }
  for (int l = 0; l <= L - 2; ++l)
    for (const auto& n : nodes[size_t(l)]) {
      d.words.push_back(n[0]);
      for (size_t j = 1; j < n.size(); ++j)
        d.words.push_back(l == L - 2 ? n[j] : offset[size_t(l + 1)][n[j]]);
    }
  d.finalize();
  return d;
}

// Box of ~3.3e10 voxels at 4096^3: the root and level 1 (2048^3 octants of
// up to 8.6e9 voxels) need 64-bit entries, level 2 (1024^3, <= 2^30) not.
const Box kBig{12, {4000, 3001, 2777}};

TEST(DagIndex64, GeneratorMatchesBuildDag) {
  // The word generator against the real builder on a box small enough to
  // voxelize, so the big-box tests below test the DAG, not the generator.
  const Box small{6, {50, 37, 21}};
  VoxelSet set;
  set.grid = testing::unit_grid(small.levels);
  for (uint32_t z = 0; z < 64; ++z)
    for (uint32_t y = 0; y < 64; ++y)
      for (uint32_t x = 0; x < 64; ++x)
        if (small.occupied(x, y, z)) set.codes.push_back(morton_encode(x, y, z));
  std::sort(set.codes.begin(), set.codes.end());
  const SparseVoxelDag built = dag::build_dag(set);
  const SparseVoxelDag generated = box_dag(small);
  EXPECT_TRUE(built.words == generated.words);
  EXPECT_EQ(generated.leaf_voxels, small.voxels());
  EXPECT_EQ(generated.wide_words, 0u);  // < 2^32 voxels: no 64-bit entries
}

TEST(DagIndex64, CountsPastTwoToThe32) {
  const SparseVoxelDag d = box_dag(kBig);
  ASSERT_GT(kBig.voxels(), uint64_t(1) << 32);
  EXPECT_EQ(d.leaf_voxels, kBig.voxels());
  EXPECT_EQ(d.stats().leaf_voxels, kBig.voxels());
  // Levels 0 and 1 are wide, level 2 (nodes of <= 1024^3 voxels) is not.
  EXPECT_EQ(d.wide_words, d.level_start[2]);
  EXPECT_EQ(d.voxel_prefix_wide.size(), d.wide_words);
  EXPECT_EQ(d.stats().index_bytes, d.words.size() * 4 + uint64_t(d.wide_words) * 8);
  // Node counts: the root's header entry and the octant (1,1,1), which
  // starts after 7 octants' worth of voxels.
  EXPECT_EQ(d.prefix_entry(0), kBig.voxels());
  EXPECT_EQ(d.voxel_rank(morton_encode(2048, 2048, 2048)), kBig.rank(2048, 2048, 2048));
  EXPECT_GT(kBig.rank(2048, 2048, 2048), uint64_t(1) << 32);
}

TEST(DagIndex64, DecodesSubRegionsAndRanks) {
  const SparseVoxelDag d = box_dag(kBig);
  std::mt19937_64 rng(7);
  // 8^3 cubes (level L-3) straddling the box's faces and corner, and random ones.
  std::vector<std::array<uint32_t, 3>> cubes = {
      {3992, 2992, 2768}, {3992, 0, 0}, {0, 2992, 2776}, {4000, 8, 8}, {2040, 2040, 2040}};
  for (int i = 0; i < 40; ++i)
    cubes.push_back(
        {uint32_t(rng() % 4096) & ~7u, uint32_t(rng() % 4096) & ~7u, uint32_t(rng() % 4096) & ~7u});
  for (const auto& c : cubes) {
    SCOPED_TRACE(::testing::Message() << "cube at " << c[0] << "," << c[1] << "," << c[2]);
    std::vector<uint64_t> expected;
    for (uint32_t z = c[2]; z < c[2] + 8; ++z)
      for (uint32_t y = c[1]; y < c[1] + 8; ++y)
        for (uint32_t x = c[0]; x < c[0] + 8; ++x)
          if (kBig.occupied(x, y, z)) expected.push_back(morton_encode(x, y, z));
    std::sort(expected.begin(), expected.end());
    const uint64_t cube_code = morton_encode(c[0], c[1], c[2]) >> 9;
    EXPECT_TRUE(d.decode_cube(kBig.levels - 3, cube_code) == expected);
    const uint64_t first = kBig.rank(c[0], c[1], c[2]);
    EXPECT_EQ(d.voxel_rank(morton_encode(c[0], c[1], c[2])), first);
    if (!expected.empty()) {
      const dag::VoxelRange r = d.cube_range(first, kBig.levels - 3);
      EXPECT_EQ(r.first, first);
      EXPECT_EQ(r.count, expected.size());
    }
  }
  // Single voxels on both sides of the box's far corner.
  EXPECT_EQ(d.decode_cube(12, morton_encode(3999, 3000, 2776)).size(), 1u);
  EXPECT_EQ(d.decode_cube(12, morton_encode(4000, 3000, 2776)).size(), 0u);
  EXPECT_EQ(d.voxel_rank(morton_encode(4095, 4095, 4095)), kBig.voxels());
  EXPECT_THROW(d.decode_cube(13, 0), Error);
  EXPECT_THROW(d.cube_range(kBig.voxels(), 12), Error);
}

// Rays from outside the box at random points of it: the hit voxel's index
// must be its Morton rank, most of them beyond 2^32.
TEST(DagIndex64, RayHitsReportSixtyFourBitRanks) {
  const SparseVoxelDag d = box_dag(kBig);
  const double n = 4096;
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(0, 1);
  int hits = 0, beyond = 0;
  for (int i = 0; i < 2000; ++i) {
    const Vec3 target{float(1 + u(rng) * kBig.w[0] / n), float(1 + u(rng) * kBig.w[1] / n),
                      float(1 + u(rng) * kBig.w[2] / n)};
    Vec3 from{float(1 + 2.5 * u(rng) - 0.25), float(1 + 2.5 * u(rng) - 0.25), float(2.2 + u(rng))};
    if (i % 3 == 1) std::swap(from.x, from.z);
    if (i % 3 == 2) std::swap(from.y, from.z);
    const dag::CastResult r = dag::cast_ray(d, from, target - from, 1e30f, 0, 0);
    ASSERT_TRUE(r.hit) << "ray " << i;
    ASSERT_EQ(r.scale, esvo::kMaxScale - kBig.levels);
    const uint64_t x = uint64_t((double(r.pos.x) - 1) * n), y = uint64_t((double(r.pos.y) - 1) * n),
                   z = uint64_t((double(r.pos.z) - 1) * n);
    ASSERT_TRUE(kBig.occupied(x, y, z));
    ASSERT_EQ(r.voxel_index, kBig.rank(x, y, z)) << "ray " << i;
    ++hits;
    beyond += r.voxel_index >= (uint64_t(1) << 32);
  }
  EXPECT_EQ(hits, 2000);
  EXPECT_GT(beyond, 500);
  // LOD hits (coarse cubes): index of the cube's first voxel, range = its voxels.
  int lod_hits = 0;
  for (int i = 0; i < 300; ++i) {
    const Vec3 target{float(1 + u(rng) * kBig.w[0] / n), float(1 + u(rng) * kBig.w[1] / n),
                      float(1 + u(rng) * kBig.w[2] / n)};
    const Vec3 from{float(1 + u(rng)), float(1 + u(rng)), 2.5f};
    const float bias = float(std::ldexp(1.0, -int(2 + rng() % 8)));  // cube of 2^-k
    const dag::CastResult r = dag::cast_ray(d, from, target - from, 1e30f, 0, bias);
    ASSERT_TRUE(r.hit);
    const int level = esvo::kMaxScale - r.scale;
    if (level >= kBig.levels) continue;
    ++lod_hits;
    const uint64_t s = kBig.side(level);
    const uint64_t x = uint64_t((double(r.pos.x) - 1) * n), y = uint64_t((double(r.pos.y) - 1) * n),
                   z = uint64_t((double(r.pos.z) - 1) * n);
    ASSERT_EQ(x % s + y % s + z % s, 0u);
    ASSERT_EQ(r.voxel_index, kBig.rank(x, y, z));
    const dag::VoxelRange range = d.cube_range(r.voxel_index, level);
    EXPECT_EQ(range.first, r.voxel_index);
    EXPECT_EQ(range.count, kBig.count(x, y, z, s));
  }
  EXPECT_GT(lod_hits, 100);
}

TEST(DagIndex64, SceneFileRoundTrip) {
  TraceContext ctx;
  const SparseVoxelDag d = box_dag(kBig);
  testing::TempDir dir;
  const std::string path = dir.file("box.vxc");
  SceneInfo info;
  info.source = "box";
  info.voxelization = "conservative";
  info.leaf_voxels = d.leaf_voxels;
  save_dag_scene(path, d, info);
  SceneInfo loaded_info;
  const SparseVoxelDag loaded = load_dag_scene(path, &loaded_info);
  EXPECT_EQ(loaded_info.leaf_voxels, kBig.voxels());
  EXPECT_EQ(loaded.leaf_voxels, kBig.voxels());
  EXPECT_TRUE(loaded.words == d.words);
  EXPECT_TRUE(loaded.voxel_prefix_wide == d.voxel_prefix_wide);
  // Through the renderer's interface: voxel_ref is the 64-bit rank.
  const LoadedScene scene = load_scene(std::filesystem::path(path));
  Ray ray;
  const GridTransform& g = loaded.grid;
  const double v = g.voxel_size;
  ray.origin = g.origin + Vec3{float(3000.5 * v), float(2900.5 * v), float(5000 * v)};
  ray.dir = {0, 0, -1};
  ray.tmax = 1e30f;
  SurfaceHit hit;
  ASSERT_TRUE(scene.structure->surface()->trace(ray, {}, ctx, &hit));
  EXPECT_EQ(hit.voxel_ref, kBig.rank(3000, 2900, 2776));
  EXPECT_GT(hit.voxel_ref, uint64_t(1) << 32);
}

// ---------------------------------------------------------------------------
// LOD attributes: a coarse hit shows the mean of the leaf voxels under it.

TEST(DagLodAttributes, CoarseHitsShowTheMeanOfTheirVoxels) {
  TraceContext ctx;
  for (int L : {2, 5, 7}) {
    SCOPED_TRACE("levels " + std::to_string(L));
    const VoxelSet set = L == 7 ? testing::make_sphere_shell(L)
                                : testing::make_random_voxels(L, L == 2 ? 40 : 9000, 5 + L);
    auto d = std::make_shared<SparseVoxelDag>(dag::build_dag(set));
    const dag::DagStructure structure(d);
    const int n = 1 << L;
    std::mt19937_64 rng(3 + L);
    std::uniform_real_distribution<double> u(0, 1);
    int lod_hits = 0, wide_ranges = 0;
    for (int i = 0; i < 3000; ++i) {
      // Rays into the grid from a random outside point; the footprint grows
      // with distance so hits land on every level.
      Ray ray;
      const GridTransform& g = d->grid;
      const float side = float(g.side());
      const Vec3 target = g.origin + Vec3{float(u(rng)), float(u(rng)), float(u(rng))} * side;
      ray.origin = g.origin + Vec3{float(3 * u(rng) - 1), float(3 * u(rng) - 1), 2.5f} * side;
      if (i % 3 == 1) std::swap(ray.origin.x, ray.origin.z);
      ray.dir = normalize(target - ray.origin);
      LodFootprint lod;
      lod.size_per_t = float(side / n * std::ldexp(1.0, int(rng() % (L + 1))) * u(rng));
      SurfaceHit hit;
      if (!structure.trace(ray, lod, ctx, &hit) || hit.level == L) continue;
      ++lod_hits;
      // The hit cube's voxels, brute force from the set: cube of side
      // 2^(L - level) voxels at the voxel containing the clamped position.
      const int shift = L - hit.level;
      const Vec3 q = (hit.position - g.origin) * float(n / side);
      const uint64_t cube =
          morton_encode(uint32_t(q.x), uint32_t(q.y), uint32_t(q.z)) >> (3 * shift);
      const auto lo = std::lower_bound(set.codes.begin(), set.codes.end(), cube << (3 * shift));
      const auto hi =
          std::lower_bound(set.codes.begin(), set.codes.end(), (cube + 1) << (3 * shift));
      ASSERT_GT(hi - lo, 0);
      const uint64_t first = uint64_t(lo - set.codes.begin()), count = uint64_t(hi - lo);
      ASSERT_EQ(hit.voxel_ref, first);
      const dag::VoxelRange range = d->cube_range(hit.voxel_ref, hit.level);
      ASSERT_EQ(range.first, first);
      ASSERT_EQ(range.count, count);
      wide_ranges += count > 2 * SparseVoxelDag::kAttributeBlock;
      // Mean of the stored (encoded) attributes over the range, in double.
      double c[4] = {0, 0, 0, 0}, nm[3] = {0, 0, 0};
      for (uint64_t v = first; v < first + count; ++v) {
        Color cv;
        Vec3 nv;
        d->voxel_attributes(v, &cv, &nv);
        c[0] += cv.r, c[1] += cv.g, c[2] += cv.b, c[3] += cv.a;
        nm[0] += nv.x, nm[1] += nv.y, nm[2] += nv.z;
      }
      Color got;
      Vec3 got_n;
      structure.attributes(hit, ctx, &got, &got_n);
      const double tol = 1e-6;
      EXPECT_NEAR(got.r, c[0] / double(count), tol);
      EXPECT_NEAR(got.g, c[1] / double(count), tol);
      EXPECT_NEAR(got.b, c[2] / double(count), tol);
      EXPECT_NEAR(got.a, c[3] / double(count), tol);
      const double len = std::sqrt(nm[0] * nm[0] + nm[1] * nm[1] + nm[2] * nm[2]);
      if (len > 1e-3 * double(count)) {
        EXPECT_NEAR(got_n.x, nm[0] / len, 1e-5);
        EXPECT_NEAR(got_n.y, nm[1] / len, 1e-5);
        EXPECT_NEAR(got_n.z, nm[2] / len, 1e-5);
      }
    }
    EXPECT_GT(lod_hits, 200);
    if (L >= 5) {
      EXPECT_GT(wide_ranges, 20);  // ranges that use the prefix table
    }
  }
}

// The voxel count a hit names (DagNodes::name_hit: SurfaceHit::child above
// the entered face, from the prefix entries next to the hit's pointer) is
// cube_range's at every level, on the scalar and the packet paths, and the
// attributes shown from it are cube_range's means (or the mean table's), the
// same floats, raw and compressed.
TEST(DagLodAttributes, HitCountsAreCubeRangeCounts) {
  using Nodes = ::voxcast::detail::DagNodes;
  TraceContext ctx;
  for (int L : {5, 7}) {
    for (const bool compressed : {false, true}) {
      SCOPED_TRACE("levels " + std::to_string(L) + (compressed ? " compressed" : " raw"));
      const VoxelSet set =
          L == 7 ? testing::make_sphere_shell(L) : testing::make_random_voxels(L, 9000, 5 + L);
      auto d = std::make_shared<SparseVoxelDag>(dag::build_dag(set));
      if (compressed) d->compress_attributes();
      const dag::DagStructure structure(d);
      const GridTransform& g = d->grid;
      const float side = float(g.side());
      std::mt19937_64 rng(17 + L);
      std::uniform_real_distribution<double> u(0, 1);
      std::vector<int> per_level(size_t(L + 1), 0);
      for (int k = 0; k <= L; ++k) {
        std::vector<Ray> rays(400);
        for (size_t i = 0; i < rays.size(); ++i) {
          const Vec3 target = g.origin + Vec3{float(u(rng)), float(u(rng)), float(u(rng))} * side;
          rays[i].origin =
              g.origin + Vec3{float(3 * u(rng) - 1), float(3 * u(rng) - 1), 2.5f} * side;
          if (i % 3 == 1) std::swap(rays[i].origin.x, rays[i].origin.z);
          rays[i].dir = normalize(target - rays[i].origin);
        }
        LodFootprint lod;
        lod.size_per_t = float(side / float(1 << L) * std::ldexp(1.0, k) * 0.3);
        std::vector<SurfaceHit> want(rays.size());
        std::vector<uint8_t> found(rays.size());
        for (size_t i = 0; i < rays.size(); ++i) {
          found[i] = structure.trace(rays[i], lod, ctx, &want[i]);
          if (!found[i]) continue;
          const SurfaceHit& hit = want[i];
          ++per_level[size_t(hit.level)];
          const uint64_t count = Nodes::child_count(hit.child);
          if (hit.level == L) {
            ASSERT_EQ(count, 1u);
            continue;
          }
          const dag::VoxelRange range = d->cube_range(hit.voxel_ref, hit.level);
          ASSERT_EQ(range.first, hit.voxel_ref);
          ASSERT_EQ(count, range.count) << "level " << hit.level;
          Color want_c, got_c;
          Vec3 want_n, got_n;
          if (const SparseVoxelDag::CubeMean* m = d->cached_mean(hit.voxel_ref, hit.level)) {
            want_c = m->color, want_n = m->normal;
          } else {
            d->mean_attributes(range, &want_c, &want_n);
          }
          structure.attributes(hit, ctx, &got_c, &got_n);
          ASSERT_EQ(std::memcmp(&got_c, &want_c, sizeof got_c), 0) << "level " << hit.level;
          ASSERT_EQ(std::memcmp(&got_n, &want_n, sizeof got_n), 0) << "level " << hit.level;
        }
        for (const Isa isa : testing::packet_isas()) {
          std::vector<SurfaceHit> got(rays.size());
          std::vector<uint8_t> got_found(rays.size());
          structure.packets()->trace_packets(rays.data(), rays.size(), lod, ctx, got.data(),
                                             got_found.data(), isa);
          for (size_t i = 0; i < rays.size(); ++i) {
            ASSERT_EQ(got_found[i], found[i]);
            if (found[i]) {
              ASSERT_TRUE(testing::same_hit(got[i], want[i])) << "ray " << i;
            }
          }
        }
      }
      for (int l = 1; l <= L; ++l) EXPECT_GT(per_level[size_t(l)], 10) << "level " << l;
    }
  }
}

// The count saturates to 0 (cube_range then answers) past 2^29 - 1 voxels;
// below, with 64-bit prefix entries at the top levels, it is cube_range's.
TEST(DagIndex64, HitCountsWithWideEntries) {
  using Nodes = ::voxcast::detail::DagNodes;
  auto d = std::make_shared<SparseVoxelDag>(box_dag(kBig));
  ASSERT_GT(d->wide_words, 0u);
  const dag::DagStructure structure(d);
  const GridTransform& g = d->grid;
  const float side = float(g.side());
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(0, 1);
  int counted = 0, saturated = 0;
  TraceContext ctx;
  for (int i = 0; i < 600; ++i) {
    const Vec3 target =
        g.origin + Vec3{float(u(rng) * kBig.w[0] / 4096.0), float(u(rng) * kBig.w[1] / 4096.0),
                        float(u(rng) * kBig.w[2] / 4096.0)} *
                       side;
    Ray ray;
    ray.origin = g.origin + Vec3{float(u(rng)), float(u(rng)), 2.5f} * side;
    ray.dir = normalize(target - ray.origin);
    LodFootprint lod;
    lod.size_at_origin = side * float(std::ldexp(1.0, -int(1 + rng() % 10)));
    SurfaceHit hit;
    ASSERT_TRUE(structure.trace(ray, lod, ctx, &hit));
    if (hit.level >= kBig.levels) continue;
    const dag::VoxelRange range = d->cube_range(hit.voxel_ref, hit.level);
    const uint64_t count = Nodes::child_count(hit.child);
    if (range.count > Nodes::kHitCountMax) {
      EXPECT_EQ(count, 0u);
      ++saturated;
    } else {
      EXPECT_EQ(count, range.count) << "level " << hit.level;
      ++counted;
    }
  }
  EXPECT_GT(counted, 100);
  EXPECT_GT(saturated, 20);
}

TEST(DagLodAttributes, RangesOfEveryLevelTileTheVoxels) {
  // For each level, walking the cubes by cube_range visits every leaf voxel
  // exactly once, in as many ranges as the level has occupied cubes.
  const VoxelSet set = testing::make_random_voxels(6, 5000, 17);
  const SparseVoxelDag d = dag::build_dag(set);
  const dag::DagStats st = d.stats();
  for (int level = 0; level <= 6; ++level) {
    uint64_t v = 0, cubes = 0;
    while (v < d.leaf_voxels) {
      const dag::VoxelRange r = d.cube_range(v, level);
      ASSERT_EQ(r.first, v);
      ASSERT_GT(r.count, 0u);
      v += r.count;
      ++cubes;
    }
    EXPECT_EQ(v, d.leaf_voxels);
    EXPECT_EQ(cubes, st.levels[size_t(level)].svo_nodes) << "level " << level;
  }
}

}  // namespace
}  // namespace voxcast
