// The one octree-family caster (src/core/octree_caster.hpp) as such, beyond
// what the ESVO and DAG tests check through their structures:
//  * the start-region argument of cast_octree without its former near-tie
//    caveat: a region whose entry planes are the center planes the descent
//    compares against (an ancestor cube of the hit voxel, or a box of random
//    grid planes around it) gives the plain hit bit for bit, for the ESVO
//    and the DAG policies;
//  * the residency hook of streamed structures: a policy that holds only
//    the top k levels stops at the level-k cube, which is the first cube of
//    the level-k occupancy a double-precision DDA finds (independent oracle)
//    and the very hit of a constant LOD footprint of that size;
//  * ESVO any-hit (EsvoStructure::occluded) equals trace().
#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <memory>
#include <random>

#include "core/octree_caster.hpp"
#include "core/octree_packet_caster.hpp"
#include "dag/octree_nodes.hpp"
#include "esvo/octree_nodes.hpp"
#include "support/dda_oracle.hpp"
#include "support/esvo_testing.hpp"
#include "support/octree_rays.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/morton.hpp"

namespace voxcast {
namespace {

using detail::CastStop;
using detail::DagNodes;
using detail::EsvoNodes;
using detail::kOctreeMaxScale;

uint32_t bits(float f) {
  return std::bit_cast<uint32_t>(f);
}

template <class Cast>
bool same_cast(const Cast& a, const Cast& b) {
  if (a.hit != b.hit) return false;
  if (!a.hit) return true;
  return bits(a.t) == bits(b.t) && a.scale == b.scale && bits(a.pos.x) == bits(b.pos.x) &&
         bits(a.pos.y) == bits(b.pos.y) && bits(a.pos.z) == bits(b.pos.z) && a.node == b.node &&
         a.child == b.child && a.index == b.index && a.face == b.face;
}

// Rays in octree space: from outside and inside the root cube [1,2]^3, some
// aimed at it, some along grid planes (where ties are exact).
struct Rays : testing::OctreeRayRng {
  using OctreeRayRng::OctreeRayRng;
  void next(Vec3* p, Vec3* d) {
    const int kind = pick(4);
    if (kind == 0) {
      *p = {uni(1, 2), uni(1, 2), uni(1, 2)};
      *d = sphere();
    } else {
      const Vec3 target{uni(1, 2), uni(1, 2), uni(1, 2)};
      *p = Vec3{1.5f, 1.5f, 1.5f} + sphere() * uni(1.f, 2.5f);
      if (kind == 3) (*p)[pick(3)] = grid_line();  // origin in a grid plane
      *d = normalize(target - *p);
    }
  }
};

// A coordinate of the hit cube's ancestor grid at a random level at or above
// `level`, moved outward by a random number of its cells, clamped to [1, 2].
float outward(Rays& g, float c, int level, bool up) {
  const int l = g.pick(level + 1);
  const float cell = std::ldexp(1.f, -l);
  float v = 1.f + std::floor((c - 1.f) / cell) * cell;  // exact: dyadic
  if (up) v = 1.f + std::ceil((c - 1.f) / cell) * cell;
  v += (up ? 1.f : -1.f) * float(g.pick(3)) * cell;
  return std::clamp(v, 1.f, 2.f);
}

template <class P>
void check_regions(const typename P::Source& s, int levels, uint64_t seed, uint64_t* hits,
                   uint64_t* casts) {
  Rays g(seed, levels);
  for (int i = 0; i < 4000; ++i) {
    Vec3 p, d;
    g.next(&p, &d);
    const float bias = (i % 3 == 2) ? g.uni(0.f, 0.1f) : 0.f;  // some LOD stops
    const auto plain =
        detail::cast_octree<P, false, false>(s, p, d, INFINITY, 0.f, bias, nullptr, nullptr);
    if (!plain.hit) {
      // A ray that misses misses with any region.
      Aabb r;
      r.extend({g.uni(1, 2), g.uni(1, 2), g.uni(1, 2)});
      r.extend({g.uni(1, 2), g.uni(1, 2), g.uni(1, 2)});
      const auto clipped =
          detail::cast_octree<P, false, false>(s, p, d, INFINITY, 0.f, bias, &r, nullptr);
      ASSERT_FALSE(clipped.hit) << "ray " << i;
      continue;
    }
    ++*hits;
    const int level = kOctreeMaxScale - plain.scale;
    const float side = std::ldexp(1.f, -level);
    // Every ancestor cube of the hit cube: its entry planes are center
    // planes of its parent, the ties the descent decides.
    for (int l = 0; l <= level; ++l) {
      const float cell = std::ldexp(1.f, -l);
      Aabb r;
      const Vec3 lo{1.f + std::floor((plain.pos.x - 1.f) / cell) * cell,
                    1.f + std::floor((plain.pos.y - 1.f) / cell) * cell,
                    1.f + std::floor((plain.pos.z - 1.f) / cell) * cell};
      r.extend(lo);
      r.extend(lo + Vec3{cell, cell, cell});
      const auto clipped =
          detail::cast_octree<P, false, false>(s, p, d, INFINITY, 0.f, bias, &r, nullptr);
      ++*casts;
      ASSERT_TRUE(same_cast(plain, clipped)) << "ray " << i << ", ancestor level " << l;
    }
    // Boxes of random grid planes around the hit cube.
    for (int k = 0; k < 4; ++k) {
      Aabb r;
      r.extend({outward(g, plain.pos.x, level, false), outward(g, plain.pos.y, level, false),
                outward(g, plain.pos.z, level, false)});
      r.extend({outward(g, plain.pos.x + side, level, true),
                outward(g, plain.pos.y + side, level, true),
                outward(g, plain.pos.z + side, level, true)});
      const auto clipped =
          detail::cast_octree<P, false, false>(s, p, d, INFINITY, 0.f, bias, &r, nullptr);
      ++*casts;
      ASSERT_TRUE(same_cast(plain, clipped)) << "ray " << i << ", box " << k;
    }
  }
}

TEST(OctreeCaster, RegionsOnCenterPlanesGiveBitIdenticalHits) {
  uint64_t hits = 0, casts = 0;
  for (int L : {4, 6, 8}) {
    SCOPED_TRACE("levels " + std::to_string(L));
    const VoxelSet set = L == 8 ? testing::make_sphere_shell(L)
                                : testing::make_random_voxels(L, L == 4 ? 300 : 8000, 41 + L);
    const esvo::EsvoOctree o = esvo::build_octree(set);
    const dag::SparseVoxelDag dg = dag::build_dag(set);
    check_regions<EsvoNodes>(o, L, 7 + L, &hits, &casts);
    if (HasFatalFailure()) return;
    check_regions<DagNodes>(dg, L, 7 + L, &hits, &casts);
    if (HasFatalFailure()) return;
  }
  EXPECT_GT(hits, 5000u);
  EXPECT_GT(casts, 10 * hits);
}

// ---------------------------------------------------------------------------
// Residency: an ESVO whose nodes below level k are "not loaded".

template <int kLevels>
struct TopLevelsOnly : EsvoNodes {
  using EsvoNodes::EsvoNodes;
  static constexpr bool kResidency = true;
  /// Child c (a cube at `scale`) can be entered iff its level is above k.
  bool resident(const Desc&, uint32_t, int, int scale) const {
    return kOctreeMaxScale - scale < kLevels;
  }
};

template <int kLevels>
void check_residency(const VoxelSet& set, uint64_t seed) {
  const int L = set.grid.levels;
  ASSERT_LT(kLevels, L);
  const esvo::EsvoOctree o = esvo::build_octree(set);
  // Oracle: occupancy of the level-k cubes, walked by the DDA.
  testing::DenseGrid coarse(kLevels);
  for (uint64_t code : set.codes) {
    const MortonCoord c = morton_decode(code >> (3 * (L - kLevels)));
    coarse.set(c.x, c.y, c.z);
  }
  const double n = coarse.resolution();
  const float side = std::ldexp(1.f, -kLevels);
  Rays g(seed, L);
  uint64_t hits = 0, ties = 0;
  for (int i = 0; i < 6000; ++i) {
    Vec3 p, d;
    g.next(&p, &d);
    const auto r = detail::cast_octree<TopLevelsOnly<kLevels>, false, false>(o, p, d, INFINITY, 0.f,
                                                                             0.f, nullptr, nullptr);
    // The same stop as a constant LOD footprint of the level-k side.
    const auto lod = detail::cast_octree<EsvoNodes, false, false>(o, p, d, INFINITY, 0.f, side,
                                                                  nullptr, nullptr);
    ASSERT_TRUE(same_cast(r, lod)) << "ray " << i;
    const testing::DdaHit ref =
        coarse.cast({(double(p.x) - 1) * n, (double(p.y) - 1) * n, (double(p.z) - 1) * n},
                    {double(d.x) * n, double(d.y) * n, double(d.z) * n}, INFINITY);
    ASSERT_EQ(r.hit, ref.hit) << "ray " << i;
    if (!r.hit) continue;
    ++hits;
    ASSERT_EQ(r.stop, CastStop::kNotResident);
    ASSERT_EQ(r.scale, kOctreeMaxScale - kLevels);
    const int x = int((double(r.pos.x) - 1) * n), y = int((double(r.pos.y) - 1) * n),
              z = int((double(r.pos.z) - 1) * n);
    ASSERT_TRUE(coarse.occupied(x, y, z));
    // The ray enters the hit cube's closed box at the hit's t, and enters no
    // occupied cube before: the DDA's first cube may differ only where two
    // are entered at the same t (a shared face, edge or corner, or an origin
    // on a cube face), within float rounding.
    const testing::DVec3 go{(double(p.x) - 1) * n, (double(p.y) - 1) * n, (double(p.z) - 1) * n};
    const testing::DVec3 gd{double(d.x) * n, double(d.y) * n, double(d.z) * n};
    double t0, t1;
    ASSERT_TRUE(testing::DenseGrid::voxel_span(go, gd, x, y, z, &t0, &t1)) << "ray " << i;
    // Appendix A evaluates t = x * coef - p * coef per axis in float, with
    // coef = 1/|d|: t is exact to a few ulps of |p/d| (octree units), where
    // the DDA is exact.
    double tol = 1e-5;
    for (int a = 0; a < 3; ++a)
      tol = std::max(
          tol, 0x1p-20 * std::fabs(double(p[a])) / std::max(std::fabs(double(d[a])), 0x1p-23));
    ASSERT_NEAR(r.t, t0, tol) << "ray " << i;
    ASSERT_GE(ref.t_enter, t0 - tol) << "ray " << i;
    ties += x != ref.x || y != ref.y || z != ref.z;
  }
  std::printf("residency at level %d: %llu hits, %llu ties with the DDA's choice\n", kLevels,
              (unsigned long long)hits, (unsigned long long)ties);
  EXPECT_GT(hits, 1000u);
}

TEST(OctreeCaster, NonResidentChildrenStopAtTheCoarserVoxel) {
  check_residency<3>(testing::make_sphere_shell(7), 5);
  check_residency<5>(testing::make_random_voxels(7, 30000, 9), 6);
}

TEST(OctreeCaster, AllResidentChangesNothing) {
  // kLevels past the finest level: every child is resident, every hit is a
  // leaf, and the casts equal the static policy's bit for bit.
  const VoxelSet set = testing::make_random_voxels(6, 6000, 3);
  const esvo::EsvoOctree o = esvo::build_octree(set);
  Rays g(11, 6);
  uint64_t hits = 0;
  for (int i = 0; i < 4000; ++i) {
    Vec3 p, d;
    g.next(&p, &d);
    const auto a = detail::cast_octree<TopLevelsOnly<24>, false, false>(o, p, d, INFINITY, 0.f, 0.f,
                                                                        nullptr, nullptr);
    const auto b =
        detail::cast_octree<EsvoNodes, false, false>(o, p, d, INFINITY, 0.f, 0.f, nullptr, nullptr);
    ASSERT_TRUE(same_cast(a, b)) << "ray " << i;
    if (a.hit) {
      ASSERT_EQ(a.stop, CastStop::kLeaf);
    }
    hits += a.hit;
  }
  EXPECT_GT(hits, 400u);
}

TEST(OctreeCaster, EsvoOccludedEqualsTrace) {
  TraceContext ctx;
  VoxelSet set = testing::make_sphere_shell(7);
  set.grid.origin = {-1.f, 2.f, 0.5f};
  set.grid.voxel_size = 0.02;
  const esvo::EsvoStructure s(std::make_shared<const esvo::EsvoOctree>(esvo::build_octree(set)));
  const Aabb b = s.bounds();
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  int hits = 0, misses = 0;
  for (int i = 0; i < 10000; ++i) {
    Ray r;
    r.origin = b.center() + Vec3{u(rng), u(rng), u(rng)} * 4.f;
    r.dir = normalize(b.center() + Vec3{u(rng), u(rng), u(rng)} * 1.5f - r.origin);
    r.tmax = (i % 3 == 0) ? 2.f + 2.f * u(rng) : INFINITY;
    LodFootprint lod;
    if (i % 2) lod.size_per_t = 0.01f;
    SurfaceHit h;
    const bool hit = s.trace(r, lod, ctx, &h);
    ASSERT_EQ(s.occluded(r, lod, ctx), hit) << i;
    hits += hit, misses += !hit;
  }
  EXPECT_GT(hits, 1000);
  EXPECT_GT(misses, 1000);
}

// queue_rays8 (the any-hit driver's set-up of eight rays in vectors) queues
// exactly what queue_ray queues, float for float: random rays, rays on the
// root's center and face planes, axis-parallel and near-axis directions
// (avoid_tiny_components), zero and non-finite components, empty spans
// (rejected rays keep no slot) and partial batches.
TEST(OctreeCaster, VectorRaySetUpEqualsQueueRay) {
  using detail::PacketQueue;
  GridTransform g;
  g.origin = {-1.25f, 0.5f, 3.0f};
  g.voxel_size = 0.01;
  g.resolution = 256;
  g.levels = 8;
  const detail::OctreeFrame frame(g);
  const float side = float(g.side());
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(-0.5f, 1.5f), v(-1.f, 1.f);
  auto coord = [&](int a, int kind) {  // kind 0: random; 1: center plane; 2: face
    const float o = g.origin[a];
    return kind == 1 ? o + 0.5f * side : kind == 2 ? o : o + u(rng) * side;
  };
  std::vector<Ray> rays;
  for (int i = 0; i < 4000; ++i) {
    Ray r;
    r.origin = {coord(0, i % 5 == 1), coord(1, i % 7 == 2 ? 2 : 0), coord(2, i % 3 == 0)};
    Vec3 d{v(rng), v(rng), v(rng)};
    switch (i % 11) {
      case 1:
        d.y = 0.f;
        break;
      case 2:
        d = {0.f, -0.f, 1.f};
        break;
      case 3:
        d.x = 1e-9f;
        break;
      case 4:
        d.z = -3e-8f * d.y;
        break;
      case 5:
        d = {0.f, 0.f, 0.f};
        break;
      case 6:
        d.x = INFINITY;
        break;
      case 7:
        r.origin.y = NAN;
        break;
      case 8:  // between half and all of avoid_tiny_components' threshold
        d.x = 0.75f * 0x1p-23f * std::max(std::fabs(d.y), std::fabs(d.z));
        break;
      default:
        break;
    }
    r.dir = d;
    r.tmax = i % 13 == 0 ? 0.f : i % 4 == 0 ? 0.5f * side * std::fabs(v(rng)) : INFINITY;
    rays.push_back(r);
  }
  static PacketQueue a, b;
  Vec3 oa[detail::kPacketQueue], ob[detail::kPacketQueue];
  for (size_t base = 0; base < rays.size();) {
    const int m = 1 + int(base % 8);  // partial batches too
    const int n = int(std::min<size_t>(size_t(m), rays.size() - base));
    a.count = 0, b.count = 0;
    for (int i = 0; i < n; ++i)
      detail::queue_ray(frame, rays[base + size_t(i)], nullptr, 5u, int32_t(i), &a, &oa[a.count]);
    const int queued = detail::queue_rays8(frame, rays.data() + base, n, 5u, 0, &b, ob);
    ASSERT_EQ(queued, a.count);
    ASSERT_EQ(b.count, a.count);
    for (int k = 0; k < a.count; ++k) {
      auto same = [](float x, float y) {
        return std::bit_cast<uint32_t>(x) == std::bit_cast<uint32_t>(y);
      };
      EXPECT_EQ(a.id[k], b.id[k]);
      EXPECT_TRUE(same(a.cx[k], b.cx[k]) && same(a.cy[k], b.cy[k]) && same(a.cz[k], b.cz[k]));
      EXPECT_TRUE(same(a.bx[k], b.bx[k]) && same(a.by[k], b.by[k]) && same(a.bz[k], b.bz[k]));
      EXPECT_TRUE(same(a.t_min[k], b.t_min[k]) && same(a.t_max[k], b.t_max[k]) &&
                  same(a.h[k], b.h[k]))
          << "ray " << base + size_t(a.id[k]);
      EXPECT_TRUE(same(a.px[k], b.px[k]) && same(a.py[k], b.py[k]) && same(a.pz[k], b.pz[k]));
      EXPECT_TRUE(same(a.dx[k], b.dx[k]) && same(a.dy[k], b.dy[k]) && same(a.dz[k], b.dz[k]));
      EXPECT_EQ(a.flip[k], b.flip[k]);
      EXPECT_EQ(a.idx[k], b.idx[k]);
      EXPECT_EQ(a.parent[k], b.parent[k]);
      EXPECT_EQ(a.scale[k], b.scale[k]);
      EXPECT_TRUE(same(oa[k].x, ob[k].x) && same(oa[k].y, ob[k].y) && same(oa[k].z, ob[k].z));
    }
    base += size_t(n);
  }
}

}  // namespace
}  // namespace voxcast
