// The packet casters (voxcast/packet_caster.hpp) against the scalar caster
// they must reproduce bit for bit: trace_packets == trace() in every
// SurfaceHit field and occluded_packets == occluded(), for the ESVO (plain,
// with far pointers, with contours), the DAG and the brickmap world
// (BrickmapStructure's lane walk, src/brickmap/packet_walk_kernel.hpp)
// built from shipped meshes, through SurfaceQuery::packets(),
// on camera rays in 4x4 block order at LOD 0 and at a 1-pixel footprint, and
// on random rays (outside and inside the root cube, along grid planes and
// axes, short tmax, tiny and zero direction components, non-finite input),
// with and without the coarse beam pass's start regions, for every kernel
// ISA this CPU runs.
#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "brickmap/packet_walk.hpp"
#include "render/beam.hpp"
#include "support/esvo_testing.hpp"
#include "support/octree_scenes.hpp"
#include "support/packet_testing.hpp"
#include "support/test_data.hpp"
#include "voxcast/brickmap.hpp"
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

// Camera rays of a w x h image in 4x4 block order, from two views.
std::vector<Ray> camera_rays(const Aabb& bounds, int w, int h, float* pixel_angle) {
  std::vector<Ray> rays;
  for (const Camera& cam :
       {Camera::frame(bounds, w, h), Camera::orbit(bounds, w, h, 200.f, -30.f),
        Camera::orbit(bounds, w, h, 90.f, 0.f, 0.f, Projection::Orthographic)}) {
    const CameraRays cr(cam, w, h);
    *pixel_angle = cr.pixel_angle();
    std::vector<uint32_t> order;
    block_order(0, 0, w, h, &order);
    for (uint32_t xy : order) rays.push_back(cr.ray(int(xy & 0xFFFF), int(xy >> 16)));
  }
  return rays;
}

// Random world rays around the grid's cube (see the file comment).
std::vector<Ray> random_rays(const GridTransform& grid, size_t n, uint64_t seed) {
  std::mt19937_64 rng(seed);
  const float side = float(grid.side());
  const Vec3 lo = grid.origin;
  auto uni = [&](float a, float b) { return std::uniform_real_distribution<float>(a, b)(rng); };
  auto pick = [&](int k) { return std::uniform_int_distribution<int>(0, k - 1)(rng); };
  auto plane = [&] {  // a grid plane of the 256^3 grid, exact in float
    return float(pick(257)) / 256.f;
  };
  std::vector<Ray> rays;
  for (size_t i = 0; i < n; ++i) {
    Vec3 o{uni(-0.5f, 1.5f), uni(-0.5f, 1.5f), uni(-0.5f, 1.5f)};  // in units of the side
    Vec3 d;
    do d = {uni(-1, 1), uni(-1, 1), uni(-1, 1)};
    while (dot(d, d) > 1 || dot(d, d) < 1e-4f);
    d = normalize(d);
    switch (pick(6)) {
      case 0:  // aimed at a point inside
        d = normalize(Vec3{uni(0.2f, 0.8f), uni(0.2f, 0.8f), uni(0.2f, 0.8f)} - o);
        break;
      case 1: {  // along an axis, on grid planes
        const int a = pick(3);
        d = {0, 0, 0};
        d[a] = pick(2) ? 1.f : -1.f;
        o[(a + 1) % 3] = plane(), o[(a + 2) % 3] = plane();
        if (pick(2)) d[(a + 1) % 3] = pick(2) ? 0.f : -0.f;
        break;
      }
      case 2:  // in a grid plane
        o[pick(3)] = plane();
        d = normalize(Vec3{uni(0.2f, 0.8f), uni(0.2f, 0.8f), uni(0.2f, 0.8f)} - o);
        break;
      case 3:  // a tiny component
        d[pick(3)] = uni(-1e-9f, 1e-9f);
        d = normalize(d);
        break;
      default:
        break;
    }
    Ray r{lo + o * side, d, INFINITY};
    if (pick(3) == 0) r.tmax = uni(0.f, 0.5f) * side;  // short (shadow/AO-like)
    if (i % 997 == 5) r.origin.x = NAN;
    if (i % 991 == 7) r.dir.y = INFINITY;
    rays.push_back(r);
  }
  return rays;
}

template <class S>
void expect_same(const S& s, const std::vector<Ray>& rays, const LodFootprint& lod,
                 const std::string& what, size_t* hits_out) {
  std::vector<SurfaceHit> want(rays.size());
  std::vector<uint8_t> want_found(rays.size()), want_occ(rays.size());
  TraceContext ctx;
  for (size_t i = 0; i < rays.size(); ++i) {
    want_found[i] = s.trace(rays[i], lod, ctx, &want[i]);
    want_occ[i] = s.occluded(rays[i], lod, ctx);
  }
  size_t hits = 0;
  for (uint8_t f : want_found) hits += f;
  *hits_out = hits;
  for (const Isa isa : testing::packet_isas()) {
    std::vector<SurfaceHit> got(rays.size());
    std::vector<uint8_t> found(rays.size(), 7), occ(rays.size(), 7);
    const SurfacePackets& p = *s.packets();
    p.trace_packets(rays.data(), rays.size(), lod, ctx, got.data(), found.data(), isa);
    p.occluded_packets(rays.data(), rays.size(), lod, ctx, occ.data(), isa);
    size_t bad = 0;
    for (size_t i = 0; i < rays.size(); ++i) {
      const bool ok = found[i] == want_found[i] && (!found[i] || same_hit(got[i], want[i])) &&
                      occ[i] == want_occ[i];
      if (!ok && ++bad <= 5)
        ADD_FAILURE() << what << " " << isa_name(isa) << " ray " << i << ": found " << int(found[i])
                      << " want " << int(want_found[i]) << ", t " << got[i].t << " want "
                      << want[i].t << ", ref " << got[i].voxel_ref << " want " << want[i].voxel_ref
                      << ", child " << got[i].child << " want " << want[i].child << ", level "
                      << got[i].level << " want " << want[i].level << ", occluded " << int(occ[i])
                      << " want " << int(want_occ[i]);
    }
    EXPECT_EQ(bad, 0u) << what << " " << isa_name(isa);
    // A brickmap lane that left the grid retires to trace() (the answer
    // above is then the scalar one), so the fault is checked here.
    EXPECT_EQ(brickmap::detail::packet_lane_faults.load(), 0u) << what << " " << isa_name(isa);
  }
}

template <class S>
void check_structure(const S& s, const char* name) {
  const Scenes& sc = scenes();
  float pixel_angle = 0;
  const std::vector<Ray> cam = camera_rays(s.bounds(), 96, 72, &pixel_angle);
  size_t hits = 0;
  expect_same(s, cam, LodFootprint{}, std::string(name) + " camera lod 0", &hits);
  // The rays must exercise the hit path: the mesh covers a good part of
  // every view (18 % of these pixels on spot).
  EXPECT_GT(hits, cam.size() / 8) << name;
  LodFootprint lod;
  lod.size_per_t = 4.f * pixel_angle;  // a coarse footprint: LOD stops at several levels
  expect_same(s, cam, lod, std::string(name) + " camera lod 4 px", &hits);
  const std::vector<Ray> rnd = random_rays(sc.grid, 20000, 11);
  expect_same(s, rnd, LodFootprint{}, std::string(name) + " random", &hits);
  EXPECT_GT(hits, rnd.size() / 20) << name;
  lod.size_at_origin = float(sc.grid.voxel_size) * 3.f;
  lod.size_per_t = 0.01f;
  expect_same(s, rnd, lod, std::string(name) + " random lod", &hits);
}

// Camera rays with the coarse pass of their 8x8 pixel block (esvo §6.2):
// trace_packets with per-ray beams == the scalar answers `want`/`want_found`
// (trace() with the same beams), for every packet ISA the CPU runs.
template <class S>
void expect_same_with_beams(const S& s, const std::vector<Ray>& rays,
                            const std::vector<const BeamStart*>& beams, const LodFootprint& lod,
                            const std::vector<SurfaceHit>& want,
                            const std::vector<uint8_t>& want_found, const std::string& label) {
  TraceContext ctx;
  std::vector<SurfaceHit> got(rays.size());
  std::vector<uint8_t> found(rays.size(), 7);
  for (const Isa isa : testing::packet_isas()) {
    s.packets()->trace_packets(rays.data(), rays.size(), lod, ctx, got.data(), found.data(), isa,
                               beams.data());
    size_t bad = 0;
    for (size_t i = 0; i < rays.size(); ++i)
      bad += found[i] != want_found[i] || (found[i] && !same_hit(got[i], want[i]));
    EXPECT_EQ(bad, 0u) << label << ", " << isa_name(isa);
    EXPECT_EQ(brickmap::detail::packet_lane_faults.load(), 0u) << label << ", " << isa_name(isa);
  }
}

// trace_packets with the blocks' beams == trace() with the same beam.
template <class S>
void check_beams(const S& s, const char* name) {
  constexpr int w = 96, h = 72, k = 8;
  const Camera cam =
      Camera::orbit(s.bounds(), w, h, 30.f, 20.f, 0.6f * length(s.bounds().extent()));
  const CameraRays cr(cam, w, h);
  for (const float lod_pixels : {0.f, 2.f}) {
    LodFootprint lod;
    lod.size_per_t = lod_pixels * cr.pixel_angle();
    std::vector<BeamStart> starts((w / k) * (h / k));
    size_t empty = 0, regions = 0;
    TraceContext ctx;
    for (int by = 0; by < h / k; ++by)
      for (int bx = 0; bx < w / k; ++bx) {
        BeamStart& st = starts[size_t(by * (w / k) + bx)];
        s.beam_start(detail::block_beam(cr, bx * k, by * k, bx * k + k, by * k + k, lod), ctx, &st);
        empty += st.valid && st.empty;
        regions += st.valid && !st.empty;
      }
    EXPECT_GT(empty, 0u) << name;  // the view shows both empty and occupied blocks
    EXPECT_GT(regions, 0u) << name;
    std::vector<uint32_t> order;
    block_order(0, 0, w, h, &order);
    std::vector<Ray> rays;
    std::vector<const BeamStart*> beams;
    for (uint32_t xy : order) {
      const int x = int(xy & 0xFFFF), y = int(xy >> 16);
      rays.push_back(cr.ray(x, y));
      beams.push_back(&starts[size_t((y / k) * (w / k) + x / k)]);
    }
    std::vector<SurfaceHit> want(rays.size());
    std::vector<uint8_t> want_found(rays.size());
    size_t hits = 0;
    for (size_t i = 0; i < rays.size(); ++i) {
      want_found[i] = s.trace(rays[i], lod, ctx, &want[i], beams[i]);
      hits += want_found[i];
    }
    EXPECT_GT(hits, rays.size() / 8) << name;
    expect_same_with_beams(s, rays, beams, lod, want, want_found,
                           std::string(name) + " beams, lod " + std::to_string(lod_pixels));
  }
}

TEST(PacketCaster, BeamStartsEqualTheScalarCaster) {
  check_beams(*scenes().esvo, "esvo");
  check_beams(*scenes().esvo_contours, "esvo contours");
  check_beams(*scenes().dag, "dag");
  check_beams(*scenes().brickmap, "brickmap");
}

TEST(PacketCaster, EsvoHitsEqualTheScalarCaster) {
  check_structure(*scenes().esvo, "esvo");
}

TEST(PacketCaster, EsvoFarPointersHitsEqualTheScalarCaster) {
  // The block layout with 64-slot blocks must actually have far pointers.
  ASSERT_GT(scenes().esvo_far->octree().memory_stats().far_pointer_bytes, 0u);
  check_structure(*scenes().esvo_far, "esvo far");
}

TEST(PacketCaster, EsvoContoursHitsEqualTheScalarCaster) {
  check_structure(*scenes().esvo_contours, "esvo contours");
}

TEST(PacketCaster, DagHitsEqualTheScalarCaster) {
  check_structure(*scenes().dag, "dag");
}

TEST(PacketCaster, BrickmapHitsEqualTheScalarCaster) {
  check_structure(*scenes().brickmap, "brickmap");
  // Fixed footprints of 1 to 64 voxels: LOD stops at every level kind the
  // lanes answer (blocks inside bricks, brickgrid cells, pyramid nodes).
  const Scenes& sc = scenes();
  float pixel_angle = 0;
  const std::vector<Ray> cam = camera_rays(sc.brickmap->bounds(), 48, 36, &pixel_angle);
  for (const float voxels : {1.f, 2.f, 4.f, 8.f, 16.f, 64.f}) {
    LodFootprint lod;
    lod.size_at_origin = voxels * float(sc.grid.voxel_size);
    size_t hits = 0;
    expect_same(*sc.brickmap, cam, lod, "brickmap footprint " + std::to_string(voxels), &hits);
    EXPECT_GT(hits, cam.size() / 8);
  }
}

// Exact ties: on the unit grid (world = octree space - 1, so no rounding in
// the frame), rays from grid vertices with dyadic directions cross several
// grid planes at the very same t, where the tie rules decide the cube.
std::vector<Ray> tie_rays(int levels, size_t n, uint64_t seed) {
  std::mt19937_64 rng(seed);
  auto pick = [&](int k) { return std::uniform_int_distribution<int>(0, k - 1)(rng); };
  const float cell = std::ldexp(1.f, -levels);
  const float comps[] = {0.f, -0.f, 1.f, -1.f, 0.5f, -0.5f, 0.25f, -0.25f, 2.f};
  std::vector<Ray> rays;
  while (rays.size() < n) {
    Vec3 o, d;
    for (int a = 0; a < 3; ++a) {
      o[a] = float(pick((2 << levels) + 1) - (1 << (levels - 1))) * cell;  // [-0.5, 1.5]
      d[a] = comps[pick(9)];
    }
    if (dot(d, d) == 0.f) continue;
    rays.push_back({o, d, pick(4) == 0 ? float(pick(1 << levels)) * cell : INFINITY});
  }
  return rays;
}

TEST(PacketCaster, GridVertexTiesEqualTheScalarCaster) {
  constexpr int kLevels = 5;
  const VoxelSet v = testing::make_random_voxels(kLevels, 4000, 3);
  ASSERT_TRUE(v.grid.origin.x == 0 && v.grid.origin.y == 0 && v.grid.origin.z == 0);
  ASSERT_EQ(v.grid.side(), 1.0);
  const esvo::EsvoStructure e(std::make_shared<const esvo::EsvoOctree>(esvo::build_octree(v)));
  const dag::DagStructure d(std::make_shared<const dag::SparseVoxelDag>(dag::build_dag(v)));
  const std::vector<Ray> rays = tie_rays(kLevels, 20000, 17);
  size_t hits = 0;
  expect_same(e, rays, LodFootprint{}, "esvo ties", &hits);
  EXPECT_GT(hits, rays.size() / 10);
  expect_same(d, rays, LodFootprint{}, "dag ties", &hits);
  LodFootprint lod;
  lod.size_at_origin = 2.f / 32.f;  // stops one and two levels up
  expect_same(e, rays, lod, "esvo ties lod", &hits);
  expect_same(d, rays, lod, "dag ties lod", &hits);
}

// The brickmap world of make_random_voxels(7, voxels, seed): the unit grid
// of 2^7 voxels (side 1), large enough for the lane walk (pyramid nodes,
// cells with their cell-box test, voxels).
std::unique_ptr<brickmap::BrickmapStructure> random_brickmap(size_t voxels, uint64_t seed) {
  const VoxelSet v = testing::make_random_voxels(7, voxels, seed);
  EXPECT_EQ(v.grid.side(), 1.0);
  return std::make_unique<brickmap::BrickmapStructure>(
      std::make_shared<const brickmap::World>(brickmap::build_world(v)));
}

// The same exact ties for the brickmap lane walk, on a grid large enough
// for it (2^7 voxels: pyramid nodes, cells with their cell-box test, voxels).
TEST(PacketCaster, BrickmapGridVertexTiesEqualTheScalarCaster) {
  constexpr int kLevels = 7;
  const std::vector<Ray> rays = tie_rays(kLevels, 20000, 19);
  // Dense (many bricks) and sparse (empty cells with clearances: jumps).
  for (const size_t voxels : {40000, 200}) {
    const auto bm = random_brickmap(voxels, 5);
    const brickmap::BrickmapStructure& b = *bm;
    size_t hits = 0;
    expect_same(b, rays, LodFootprint{}, "brickmap ties " + std::to_string(voxels), &hits);
    EXPECT_GT(hits, rays.size() / 1000);
    for (const float side : {2.f, 16.f}) {  // LOD stops in bricks, at nodes
      LodFootprint lod;
      lod.size_at_origin = side / 128.f;
      expect_same(b, rays, lod, "brickmap ties lod " + std::to_string(voxels), &hits);
    }
  }
}

// Beam regions whose faces lie on grid planes: a tie ray enters its region
// exactly where it crosses grid planes, so the lanes' start cell there
// (start_cell_exact) and their LOD test at the region's entry meet the
// scalar walk's ties. Regions are cubes of 1 to 16 voxels: for a ray that
// hits without a region, its near corner is the hit's cube, so the ray
// enters the region where it hits; otherwise anywhere. They need not be
// conservative: trace() and trace_packets() walk the same clipped span.
// `rays`: on the 2^7 grid of make_random_voxels(7, ...), whose side is 1.
void expect_brickmap_regions_equal_the_scalar_caster(const std::vector<Ray>& rays,
                                                     const std::string& what) {
  constexpr int kSide = 1 << 7;
  const auto bm = random_brickmap(40000, 7);
  const brickmap::BrickmapStructure& b = *bm;
  std::mt19937_64 rng(29);
  auto pick = [&](int lo, int hi) { return std::uniform_int_distribution<int>(lo, hi)(rng); };
  for (const float side : {0.f, 2.f, 16.f}) {  // LOD 0; stops in bricks; at nodes
    LodFootprint lod;
    lod.size_at_origin = side / float(kSide);
    TraceContext ctx;
    std::vector<BeamStart> starts(rays.size());
    for (size_t i = 0; i < rays.size(); ++i) {
      SurfaceHit free;
      const bool hit = b.trace(rays[i], lod, ctx, &free);
      const int unit = 1 << pick(0, 4), cells = kSide / unit;
      BeamStart& st = starts[i];
      st.valid = true;
      for (int a = 0; a < 3; ++a) {
        int lo = pick(0, cells - 1), hi = pick(lo + 1, cells);
        if (hit) {  // the near face through the hit's cube (unit-aligned)
          const int c = std::clamp(int(std::floor(free.position[a] * float(cells))), 0, cells - 1);
          if (rays[i].dir[a] < 0.f)
            hi = c + 1, lo = pick(0, c);
          else
            lo = c, hi = pick(c + 1, cells);
        }
        st.region.lo[a] = 1.f + float(lo * unit) / float(kSide);
        st.region.hi[a] = 1.f + float(hi * unit) / float(kSide);
      }
    }
    std::vector<const BeamStart*> beams;
    for (const BeamStart& st : starts) beams.push_back(&st);
    std::vector<SurfaceHit> want(rays.size());
    std::vector<uint8_t> want_found(rays.size());
    size_t hits = 0, at_entry = 0;
    for (size_t i = 0; i < rays.size(); ++i) {
      want_found[i] = b.trace(rays[i], lod, ctx, &want[i], beams[i]);
      hits += want_found[i];
      // Hits at the t the ray enters its region: the start cell decided them.
      if (!want_found[i]) continue;
      float entry = -INFINITY;
      for (int a = 0; a < 3; ++a) {
        const float d = rays[i].dir[a];
        if (d == 0.f) continue;
        const float plane = (d > 0.f ? starts[i].region.lo[a] : starts[i].region.hi[a]) - 1.f;
        entry = std::max(entry, (plane - rays[i].origin[a]) / d);
      }
      at_entry += entry == want[i].t;
    }
    EXPECT_GT(hits, rays.size() / 10) << what << ", lod " << side;
    EXPECT_GT(at_entry, rays.size() / 20) << what << ", lod " << side;
    expect_same_with_beams(b, rays, beams, lod, want, want_found,
                           "brickmap " + what + ", lod " + std::to_string(side));
  }
}

TEST(PacketCaster, BrickmapBeamRegionTiesEqualTheScalarCaster) {
  expect_brickmap_regions_equal_the_scalar_caster(tie_rays(7, 20000, 23), "region ties");
}

// The same regions for rays of any origin and direction, whose positions
// at the walk's start (just before the region's entry) round either way:
// start_cell_exact's backward correction moves ~16,000 lanes here (the tie
// rays' exact positions: ~11,000), and a walk without it fails both tests.
// Its forward correction moves none in either (it needs another axis'
// plane crossed exactly at the float before the region's entry): the next
// test builds such rays.
TEST(PacketCaster, BrickmapBeamRegionsOfRandomRaysEqualTheScalarCaster) {
  const GridTransform grid = testing::make_random_voxels(7, 40000, 7).grid;
  expect_brickmap_regions_equal_the_scalar_caster(random_rays(grid, 20000, 31),
                                                  "regions of random rays");
}

// start_cell_exact's forward correction: rays whose region entry comes
// just after they cross a voxel plane on another axis, so that the walk
// starts (at the float before the entry) at exactly that plane's t while
// the position there still rounds to the cell behind it. The DDA has then
// taken that crossing (its exit plane's t is <= t, equal here), so the
// start cell is the one ahead; a lane that compared with < instead of <=
// would start behind it, in another voxel or through another face. Built
// in grid units (the unit grid of 2^7 voxels: world = grid / 128 exactly;
// regions are quantized to 2^-16 grid units by their [1, 2] frame, so the
// entry plane is searched among those), on a dense world where the first
// voxels decide the hit. A < for the <= of the forward loop (lanes or
// scalar walk), or a >= for the > of the lanes' backward loop, changes
// about a third of these rays' hits.
TEST(PacketCaster, BrickmapRegionEntryRightAfterAPlaneEqualsTheScalarCaster) {
  constexpr float kN = float(1 << 7);
  const auto bm = random_brickmap(1100000, 13);
  const brickmap::BrickmapStructure& b = *bm;
  std::mt19937_64 rng(41);
  auto uni = [&](float lo, float hi) { return std::uniform_real_distribution<float>(lo, hi)(rng); };
  constexpr size_t kRays = 3000;
  std::vector<Ray> rays;
  std::vector<BeamStart> starts;
  while (rays.size() < kRays) {
    float o[3], d[3], inv[3];
    for (int k = 0; k < 3; ++k) {
      o[k] = uni(8.f, kN - 8.f);
      const float m = uni(0.1f, 1.f);
      d[k] = (rng() & 1 ? m : -m) * kN;  // a world direction times 128: exact
      inv[k] = 1.f / d[k];
    }
    // Every voxel plane ahead on each axis a: its crossing t (the walk's
    // plane_t), where the position rounds back into the cell behind it...
    for (int a = 0; a < 3 && rays.size() < kRays; ++a) {
      const bool up = d[a] > 0.f;
      for (float P = std::floor(o[a]) + (up ? 1.f : 0.f); P > 0.f && P < kN && rays.size() < kRays;
           P += up ? 1.f : -1.f) {
        const float tp = (P - o[a]) * inv[a];
        const float p = o[a] + d[a] * tp;
        if (!(up ? p < P : p > P)) continue;
        // ...and another axis' region plane entered at the next float
        // after it (the walk starts at the float before the entry: tp).
        const float entry_t = std::nextafter(tp, INFINITY);
        for (int j = 1; j <= 2; ++j) {
          const int bx = (a + j) % 3;
          const double guess = (double(o[bx]) + double(d[bx]) * double(entry_t)) * 65536.0;
          float plane = NAN;
          for (int q = -4; q <= 4 && plane != plane; ++q) {
            const float c = float((std::floor(guess) + q) / 65536.0);  // 2^-16 steps: exact
            if (c > 0.f && c < kN && (c - o[bx]) * inv[bx] == entry_t) plane = c;
          }
          if (plane != plane) continue;
          BeamStart st;
          st.valid = true;
          for (int k = 0; k < 3; ++k) {
            float lo = 0.f, hi = kN;  // the other axes entered before the start
            if (k == bx) (d[bx] > 0.f ? lo : hi) = plane;
            st.region.lo[k] = 1.f + lo / kN;
            st.region.hi[k] = 1.f + hi / kN;
          }
          starts.push_back(st);
          rays.push_back(
              Ray{{o[0] / kN, o[1] / kN, o[2] / kN}, {d[0] / kN, d[1] / kN, d[2] / kN}, INFINITY});
          break;
        }
      }
    }
  }
  std::vector<const BeamStart*> beams;
  for (const BeamStart& st : starts) beams.push_back(&st);
  TraceContext ctx;
  std::vector<SurfaceHit> want(rays.size());
  std::vector<uint8_t> want_found(rays.size());
  size_t hits = 0;
  for (size_t i = 0; i < rays.size(); ++i)
    hits += want_found[i] = b.trace(rays[i], LodFootprint{}, ctx, &want[i], beams[i]);
  EXPECT_GT(hits, rays.size() / 2);
  expect_same_with_beams(b, rays, beams, LodFootprint{}, want, want_found,
                         "brickmap region entry right after a plane");
}

// The packet casters as a capability of the surface query (SurfacePackets,
// what render, bench and other structure-agnostic callers use): the same answers as
// the scalar caster through the Structure interface alone.
TEST(PacketCaster, OfferedThroughTheSurfaceQuery) {
  const Scenes& sc = scenes();
  float pixel_angle = 0;
  const Structure* structures[] = {sc.esvo.get(), sc.dag.get(), sc.brickmap.get()};
  for (const Structure* st : structures) {
    const SurfaceQuery* q = st->surface();
    ASSERT_NE(q, nullptr) << st->name();
    const SurfacePackets* p = q->packets();
    ASSERT_NE(p, nullptr) << st->name();
    const std::vector<Ray> rays = camera_rays(st->bounds(), 48, 36, &pixel_angle);
    std::vector<SurfaceHit> got(rays.size());
    std::vector<uint8_t> found(rays.size(), 7), occ(rays.size(), 7);
    TraceContext ctx;
    p->trace_packets(rays.data(), rays.size(), LodFootprint{}, ctx, got.data(), found.data(),
                     active_isa());
    p->occluded_packets(rays.data(), rays.size(), LodFootprint{}, ctx, occ.data(), active_isa());
    size_t hits = 0, bad = 0;
    for (size_t i = 0; i < rays.size(); ++i) {
      SurfaceHit want;
      const bool f = q->trace(rays[i], LodFootprint{}, ctx, &want);
      hits += f;
      bad += found[i] != f || (f && !same_hit(got[i], want)) ||
             occ[i] != q->occluded(rays[i], LodFootprint{}, ctx);
    }
    EXPECT_GT(hits, rays.size() / 8) << st->name();
    EXPECT_EQ(bad, 0u) << st->name();
  }
}

TEST(PacketCaster, BlockOrderCoversEveryPixelOnceIn4x4Blocks) {
  std::vector<uint32_t> order;
  block_order(3, 5, 10, 7, &order);
  ASSERT_EQ(order.size(), 70u);
  std::vector<int> seen(70, 0);
  for (size_t i = 0; i < order.size(); ++i) {
    const int x = int(order[i] & 0xFFFF) - 3, y = int(order[i] >> 16) - 5;
    ASSERT_TRUE(x >= 0 && x < 10 && y >= 0 && y < 7);
    ++seen[size_t(y * 10 + x)];
  }
  for (int v : seen) EXPECT_EQ(v, 1);
  // The first 16 entries are the full block at the corner.
  for (size_t i = 0; i < 16; ++i) {
    EXPECT_EQ(int(order[i] & 0xFFFF) - 3, int(i % 4));
    EXPECT_EQ(int(order[i] >> 16) - 5, int(i / 4));
  }
}

}  // namespace
}  // namespace voxcast
