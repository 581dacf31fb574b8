// The DAG ray caster (svdag §4) against the brute-force double-precision DDA
// over the dense grid (support/dda_oracle), directly: first hit and any hit
// (occlusion) at the finest level, through the public DagStructure interface
// (world rays), with the criteria of the ESVO oracle test (test_traversal:
// the same voxel as the DDA unless float rounding decides an edge/corner or
// grazing tie, t between the entries of the voxel grown and shrunk by 16 ulps).
// The ESVO comparison alone would not catch a bug in what the two casters
// share (ray set-up, mirroring, POP); this one does.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "support/dda_oracle.hpp"
#include "support/esvo_testing.hpp"
#include "support/shared_meshes.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast {
namespace {

using testing::CasterHit;
using testing::DdaTally;
using testing::DenseGrid;
using testing::DVec3;
using testing::kDeltaOct;

const std::filesystem::path kMeshes = std::filesystem::path(VOXCAST_TEST_DATA_DIR) / "meshes";

struct OracleRun {
  DdaTally first, any;
};

// DagStructure::trace of a world ray as the voxel it hit. The voxel comes
// from the hit's Morton rank (voxel_ref) looked up in the set's own sorted
// codes, not from the DAG's decoding; its level, voxel size and clamped
// position are checked against that voxel's world box.
CasterHit dag_first_hit(const dag::DagStructure& s, const VoxelSet& set, const Ray& ray) {
  TraceContext ctx;
  SurfaceHit h;
  CasterHit out;
  if (!s.trace(ray, LodFootprint{}, ctx, &h)) return out;
  const GridTransform& g = set.grid;
  EXPECT_EQ(h.level, g.levels) << "LOD 0 must stop at the finest level";
  EXPECT_FLOAT_EQ(h.voxel_size, float(g.voxel_size));
  if (h.voxel_ref >= set.codes.size()) {
    ADD_FAILURE() << "voxel_ref " << h.voxel_ref << " >= " << set.codes.size() << " voxels";
    return out;
  }
  const MortonCoord c = morton_decode(set.codes[h.voxel_ref]);
  out = {true, int(c.x), int(c.y), int(c.z), double(h.t)};
  const double vs = g.voxel_size, eps = 1e-5 * g.side();
  const uint32_t xyz[3] = {c.x, c.y, c.z};
  for (int a = 0; a < 3; ++a) {
    const double lo = double(g.origin[a]) + xyz[a] * vs;
    EXPECT_GE(double(h.position[a]), lo - eps) << "hit position outside the hit voxel, axis " << a;
    EXPECT_LE(double(h.position[a]), lo + vs + eps)
        << "hit position outside the hit voxel, axis " << a;
  }
  return out;
}

// `rays` random rays (testing::OctreeRayGen, mapped to the set's world
// placement), plus one in eight starting inside a random occupied voxel,
// each checked for first hit (unbounded) and any hit (tmax of a few voxels,
// of up to the cube's side, or unbounded: AO-like, shadow-like).
void run_dag_oracle(const VoxelSet& set, int rays, uint64_t seed, OracleRun* run) {
  TraceContext ctx;
  ASSERT_FALSE(set.codes.empty());
  const dag::DagStructure s(std::make_shared<dag::SparseVoxelDag>(dag::build_dag(set)));
  const DenseGrid grid = DenseGrid::from_voxels(set);
  const GridTransform& g = set.grid;
  const double n = grid.resolution(), side = g.side(), vs = g.voxel_size;
  const double delta = kDeltaOct * n;  // grid units
  testing::OctreeRayGen gen(seed, g.levels);
  for (int i = 0; i < rays; ++i) {
    Vec3 p, d;
    gen.next(&p, &d);
    if (i % 8 == 7) {  // from inside (or on the boundary of) an occupied voxel
      const MortonCoord c = morton_decode(set.codes[size_t(gen.pick(int(set.codes.size())))]);
      p = Vec3{float(c.x) + gen.uni(0, 1), float(c.y) + gen.uni(0, 1), float(c.z) + gen.uni(0, 1)} *
              float(1.0 / n) +
          Vec3{1, 1, 1};
    }
    // Octree space -> world: the same unit direction, t scaled by the side.
    const Vec3 wo = g.origin + (p - Vec3{1, 1, 1}) * float(side);
    // The oracle maps the world ray exactly (double) into grid units; t is
    // unchanged by that mapping.
    const DVec3 go{(double(wo.x) - g.origin.x) / vs, (double(wo.y) - g.origin.y) / vs,
                   (double(wo.z) - g.origin.z) / vs};
    const DVec3 gd{double(d.x) / vs, double(d.y) / vs, double(d.z) / vs};
    const CasterHit first = dag_first_hit(s, set, Ray{wo, d, INFINITY});
    if (::testing::Test::HasFailure()) return;
    testing::expect_first_hit_matches(grid, go, gd, first, delta, &run->first, wo, d);
    if (::testing::Test::HasFailure()) return;

    float tmax = INFINITY;
    switch (i % 3) {
      case 0:
        tmax = float(vs * (0.5 + 6.0 * gen.uni(0, 1)));
        break;
      case 1:
        tmax = float(side * gen.uni(0, 1));
        break;
      default:
        break;
    }
    const bool occluded = s.occluded(Ray{wo, d, tmax}, LodFootprint{}, ctx);
    testing::expect_any_hit_matches(grid, go, gd, double(tmax), occluded, first, delta, &run->any,
                                    wo, d);
    if (::testing::Test::HasFailure()) return;
  }
}

void print_and_bound(const char* what, const OracleRun& run) {
  std::printf(
      "%s: first hit %llu rays, %llu hits, %llu exact edge/corner ties, %llu float near-ties; "
      "any hit %llu rays, %llu occluded, %llu near-ties\n",
      what, (unsigned long long)run.first.rays, (unsigned long long)run.first.hits,
      (unsigned long long)run.first.exact_ties, (unsigned long long)run.first.near_ties,
      (unsigned long long)run.any.rays, (unsigned long long)run.any.hits,
      (unsigned long long)run.any.near_ties);
  // The ray mix must hit often and miss often, or agreement would be cheap.
  EXPECT_GE(run.first.hits, run.first.rays / 5);
  EXPECT_LE(run.first.hits, run.first.rays * 19 / 20);
  EXPECT_GE(run.any.hits, run.any.rays / 10);
  EXPECT_LE(run.any.hits, run.any.rays * 19 / 20);
  // Ties come only from the deliberately degenerate rays; bound them.
  EXPECT_LE(run.first.exact_ties + run.first.near_ties, run.first.rays / 50);
  EXPECT_LE(run.any.near_ties, run.any.rays / 50);
}

// Random voxel sets of several sizes and densities (49 % down to 0.04 %),
// sphere shells, and a full grid; unit-cube placement and two others, so the
// world <-> octree mapping is part of what is checked.
TEST(DagOracle, RandomSetsShellsAndFullGridLevels3To9) {
  struct Case {
    int levels;
    size_t count;  // random voxels; 0 = sphere shell, SIZE_MAX = full grid
  };
  const Case cases[] = {{3, SIZE_MAX}, {4, 2000},  {4, 0},     {5, 8000}, {5, 0},
                        {6, 20000},    {6, 0},     {7, 60000}, {7, 0},    {8, 60000},
                        {8, 0},        {9, 60000}, {9, 0}};
  // Large sides: WorldScaleDoesNotTiltAxisRays below.
  OracleRun run;
  int k = 0;
  for (const Case& c : cases) {
    const VoxelSet set = testing::make_placed_case(c.levels, c.count, 500 + k, k);
    SCOPED_TRACE("levels " + std::to_string(c.levels) + " count " + std::to_string(c.count));
    run_dag_oracle(set, 8000, 61 + k, &run);
    if (HasFailure()) return;
    ++k;
  }
  print_and_bound("random sets", run);
  EXPECT_GE(run.first.rays, 100000u);
}

// Known defect, left failing (disabled) until the casters are fixed:
// EsvoStructure::trace and DagStructure::trace map a world ray to octree
// space as d' = d / side without normalizing, then avoid_tiny_components
// (core/octree_ray.hpp) raises every component below the absolute 2^-23 to
// +-2^-23. Relative to |d'| = 1 / side that is a tilt of up to 2^-23 * side
// radians: 1.8e-5 for the armadillo's side of 151 (an axis-aligned ray 0.001
// voxels above a voxel face drops through it after ~60 voxels at 256^3),
// 1e-3 for a side of 10^4 (a voxel of error across a 1024^3 grid), and every
// direction collapses to (+-2^-23, +-2^-23, +-2^-23) once side >= 2^23. The
// same voxels and rays at side 1 pass the oracle (the tests above).
TEST(DagOracle, WorldScaleDoesNotTiltAxisRays) {
  for (double side : {151.0, 1e4}) {
    VoxelSet set = testing::make_sphere_shell(8);
    set.grid.voxel_size = side / double(set.grid.resolution);
    SCOPED_TRACE("side " + std::to_string(side));
    OracleRun run;
    run_dag_oracle(set, 20000, 3, &run);
  }
}

// The shared meshes voxelized at 256^3. The voxels are placed in the unit
// cube (origin 0, side 1) rather than at the mesh's world placement, whose
// sides of up to 151 units run into the defect above; the world mapping
// itself is covered by the random sets' placements.
class DagMeshOracle : public ::testing::TestWithParam<const char*> {};

TEST_P(DagMeshOracle, FirstAndAnyHitMatchDda) {
  const std::filesystem::path path = kMeshes / GetParam();
  ASSERT_TRUE(std::filesystem::exists(path)) << path;
  const Mesh mesh = load_mesh(path);
  VoxelizeOptions vo;
  vo.attributes = false;
  VoxelSet set = voxelize(mesh, GridTransform::fit(mesh.bounds(), 256), vo);
  set.grid.origin = {0, 0, 0};
  set.grid.voxel_size = 1.0 / double(set.grid.resolution);
  OracleRun run;
  run_dag_oracle(set, 12000, 7, &run);
  if (HasFailure()) return;
  print_and_bound(GetParam(), run);
}

INSTANTIATE_TEST_SUITE_P(SharedMeshes, DagMeshOracle, voxcast::testing::all_shared_meshes(),
                         voxcast::testing::mesh_test_name);

}  // namespace
}  // namespace voxcast
