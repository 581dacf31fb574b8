// Out-of-core DAG construction (svdag §3 "Implementation details": per
// sub-volume voxelization and reduction, sub-DAGs merged): the result is the
// in-core build_dag(voxelize(...)) byte for byte, for many cell sizes, both
// voxelization modes, with and without attributes; the cell-restricted
// rasterizer is exactly the full one restricted to the cell; budgets that
// cannot work are refused with one clear message.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include "support/cli_runner.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/dag_format.hpp"
#include "voxcast/error.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/scene_file.hpp"
#include "voxelize/cell.hpp"

namespace voxcast {
namespace {

const std::filesystem::path kMeshes = VOXCAST_TEST_DATA_DIR "/meshes";

const Mesh& bunny() {
  static const Mesh m = load_mesh(kMeshes / "stanford-bunny.obj");
  return m;
}

void expect_same_dag(const dag::SparseVoxelDag& a, const dag::SparseVoxelDag& b) {
  ASSERT_EQ(a.words.size(), b.words.size());
  EXPECT_TRUE(a.words == b.words);
  EXPECT_TRUE(a.colors == b.colors);
  EXPECT_TRUE(a.normals == b.normals);
  EXPECT_TRUE(a.attribute_blocks == b.attribute_blocks);
  EXPECT_EQ(a.leaf_voxels, b.leaf_voxels);
  EXPECT_TRUE(a.level_start == b.level_start);
}

dag::SparseVoxelDag in_core(const Mesh& mesh, const GridTransform& grid, VoxelizationMode mode,
                            bool attributes) {
  VoxelizeOptions vo;
  vo.mode = mode;
  vo.attributes = attributes;
  return dag::build_dag(voxelize(mesh, grid, vo));
}

dag::SparseVoxelDag out_of_core(const Mesh& mesh, const GridTransform& grid, VoxelizationMode mode,
                                bool attributes, uint32_t cell, dag::OutOfCoreReport* rep = nullptr,
                                bool compress = false) {
  dag::OutOfCoreOptions o;
  o.mode = mode;
  o.attributes = attributes;
  o.compress_attributes = compress;
  o.cell_size = cell;
  o.progress = false;
  o.memory_budget = uint64_t(8) << 30;
  return dag::build_dag_out_of_core(mesh, grid, o, rep);
}

struct Case {
  uint32_t resolution;
  VoxelizationMode mode;
  bool attributes;
};

class OocBunny : public ::testing::TestWithParam<Case> {};

TEST_P(OocBunny, ByteIdenticalToInCoreForEveryCellSize) {
  const Case c = GetParam();
  const GridTransform grid = GridTransform::fit(bunny().bounds(), c.resolution);
  const dag::SparseVoxelDag ref = in_core(bunny(), grid, c.mode, c.attributes);
  for (uint32_t cell : {4u, 16u, 32u, c.resolution / 4, c.resolution}) {
    SCOPED_TRACE("cell " + std::to_string(cell));
    dag::OutOfCoreReport rep;
    const dag::SparseVoxelDag d = out_of_core(bunny(), grid, c.mode, c.attributes, cell, &rep);
    EXPECT_EQ(rep.cell_size, cell);
    if (cell <= 32) {
      EXPECT_GT(rep.cells, 50u);  // really split
    }
    expect_same_dag(ref, d);
  }
}

INSTANTIATE_TEST_SUITE_P(Modes, OocBunny,
                         ::testing::Values(Case{256, VoxelizationMode::Conservative, true},
                                           Case{256, VoxelizationMode::SixSeparating, true},
                                           Case{256, VoxelizationMode::Conservative, false},
                                           Case{1024, VoxelizationMode::SixSeparating, false}));

TEST(OocDag, CompressedAttributesByteIdenticalToInCore) {
  // Compressed attributes (dag.hpp, esvo §5.5 on Morton runs) are encoded
  // from the raw arrays, which are identical, so the blocks are too.
  const GridTransform grid = GridTransform::fit(bunny().bounds(), 256);
  dag::SparseVoxelDag ref = in_core(bunny(), grid, VoxelizationMode::Conservative, true);
  ref.compress_attributes();
  ASSERT_TRUE(ref.compressed_attributes());
  for (uint32_t cell : {16u, 64u}) {
    SCOPED_TRACE("cell " + std::to_string(cell));
    dag::SparseVoxelDag d = out_of_core(bunny(), grid, VoxelizationMode::Conservative, true, cell);
    d.compress_attributes();
    expect_same_dag(ref, d);
    EXPECT_TRUE(ref.attribute_prefix == d.attribute_prefix);
    // Encoded cell by cell as the cells arrive (OutOfCoreOptions::
    // compress_attributes): 16-voxel blocks straddle cells of 16^3 (most
    // cells hold no multiple of 16 voxels), still the same blocks.
    dag::OutOfCoreReport rep;
    const dag::SparseVoxelDag e =
        out_of_core(bunny(), grid, VoxelizationMode::Conservative, true, cell, &rep, true);
    if (cell == 16) {
      EXPECT_GT(rep.cells, 50u);
    }
    EXPECT_TRUE(e.colors.empty());
    expect_same_dag(ref, e);
    EXPECT_TRUE(ref.attribute_blocks == e.attribute_blocks);
    EXPECT_TRUE(ref.attribute_prefix == e.attribute_prefix);
  }
}

TEST(OocDag, AutomaticCellSizeFollowsTheBudget) {
  // A budget far below the in-core need forces small cells; still identical.
  const GridTransform grid = GridTransform::fit(bunny().bounds(), 1024);
  const dag::SparseVoxelDag ref = in_core(bunny(), grid, VoxelizationMode::Conservative, false);
  dag::OutOfCoreOptions o;
  o.progress = false;
  o.memory_budget = uint64_t(48) << 20;
  dag::OutOfCoreReport rep;
  const dag::SparseVoxelDag d = dag::build_dag_out_of_core(bunny(), grid, o, &rep);
  EXPECT_LT(rep.cell_size, 1024u);
  EXPECT_GT(rep.cells, 8u);
  EXPECT_LE(rep.fixed_bytes + 2 * rep.estimated_cell_bytes, o.memory_budget);
  expect_same_dag(ref, d);
  // A generous budget takes the whole grid as one cell.
  o.memory_budget = uint64_t(16) << 30;
  const dag::SparseVoxelDag whole = dag::build_dag_out_of_core(bunny(), grid, o, &rep);
  EXPECT_EQ(rep.cell_size, 1024u);
  expect_same_dag(ref, whole);
}

TEST(OocDag, BudgetTooSmallIsAClearError) {
  const GridTransform grid = GridTransform::fit(bunny().bounds(), 1024);
  dag::OutOfCoreOptions o;
  o.progress = false;
  o.memory_budget = 1 << 20;  // the mesh alone is larger
  try {
    dag::build_dag_out_of_core(bunny(), grid, o);
    FAIL() << "expected an error";
  } catch (const Error& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("memory budget"), std::string::npos) << msg;
    EXPECT_NE(msg.find("32^3 cells"), std::string::npos) << msg;
    EXPECT_EQ(msg.find('\n'), std::string::npos);
  }
  o.memory_budget = uint64_t(1) << 30;
  o.cell_size = 48;
  EXPECT_THROW(dag::build_dag_out_of_core(bunny(), grid, o), Error);
}

// Random triangles, including huge, thin, axis-aligned, on-grid-line and
// zero-area ones: the union of the per-cell voxels over a partition into
// cells is exactly triangle_voxels() of the whole grid.
TEST(OocDag, CellRasterizerIsTheFullRasterizerRestricted) {
  std::mt19937_64 rng(7);
  const uint32_t n = 64;
  std::uniform_real_distribution<double> u(-2.0, 66.0);
  std::uniform_int_distribution<int> gi(0, 64);
  for (int trial = 0; trial < 400; ++trial) {
    double tri[3][3];
    for (auto& v : tri)
      for (double& x : v) x = (trial % 3 == 0) ? double(gi(rng)) : u(rng);
    if (trial % 7 == 0)  // zero area: a segment
      for (int a = 0; a < 3; ++a) tri[2][a] = 0.5 * (tri[0][a] + tri[1][a]);
    if (trial % 11 == 0)  // a small triangle
      for (int k = 1; k < 3; ++k)
        for (int a = 0; a < 3; ++a) tri[k][a] = tri[0][a] + (tri[k][a] - tri[0][a]) * 0.03;
    for (VoxelizationMode mode :
         {VoxelizationMode::Conservative, VoxelizationMode::SixSeparating}) {
      std::vector<uint64_t> full;
      triangle_voxels(tri, n, mode, full);
      std::sort(full.begin(), full.end());
      full.erase(std::unique(full.begin(), full.end()), full.end());
      for (int cell : {4, 16}) {
        std::vector<uint64_t> cells;
        for (int z = 0; z < int(n); z += cell)
          for (int y = 0; y < int(n); y += cell)
            for (int x = 0; x < int(n); x += cell) {
              const int lo[3] = {x, y, z}, hi[3] = {x + cell - 1, y + cell - 1, z + cell - 1};
              std::vector<uint64_t> part;
              detail::triangle_voxels_in_box(tri, n, mode, lo, hi, part);
              for (uint64_t code : part) {
                const MortonCoord m = morton_decode(code);
                ASSERT_TRUE(int(m.x) >= lo[0] && int(m.x) <= hi[0] && int(m.y) >= lo[1] &&
                            int(m.y) <= hi[1] && int(m.z) >= lo[2] && int(m.z) <= hi[2]);
              }
              cells.insert(cells.end(), part.begin(), part.end());
            }
        std::sort(cells.begin(), cells.end());
        cells.erase(std::unique(cells.begin(), cells.end()), cells.end());
        ASSERT_EQ(cells, full) << "trial " << trial << " cell " << cell;
      }
    }
  }
}

// 2^20 voxels per axis (20 levels, the maximum): two tiny triangles in
// opposite corners of the unit cube. Out-of-core equals in-core, the scene
// round-trips through a file, and a ray finds the surface at the right depth.
TEST(OocDag, TwentyLevelsBuildSaveLoadAndTrace) {
  TraceContext ctx;
  Mesh m;
  const float e = 2e-5f;
  m.positions = {{0, 0, 0.5f * e},     {e, 0, 0.5f * e},         {0, e, 0.5f * e},
                 {1, 1, 1 - 0.5f * e}, {1 - e, 1, 1 - 0.5f * e}, {1, 1 - e, 1 - 0.5f * e}};
  m.indices = {0, 1, 2, 3, 4, 5};
  const GridTransform grid = GridTransform::fit(m.bounds(), 1u << 20);
  ASSERT_EQ(grid.levels, 20);
  const dag::SparseVoxelDag ref = in_core(m, grid, VoxelizationMode::Conservative, true);
  dag::OutOfCoreReport rep;
  const dag::SparseVoxelDag d = out_of_core(m, grid, VoxelizationMode::Conservative, true, 0, &rep);
  expect_same_dag(ref, d);
  EXPECT_GT(d.leaf_voxels, 100u);
  testing::TempDir dir;
  SceneInfo info;
  info.source = "two triangles";
  info.voxelization = "conservative";
  info.leaf_voxels = d.leaf_voxels;
  save_dag_scene(dir.file("t.vxc"), d, info);
  auto loaded = std::make_shared<const dag::SparseVoxelDag>(load_dag_scene(dir.file("t.vxc")));
  EXPECT_EQ(loaded->levels(), 20);
  const dag::DagStructure s(loaded);
  Ray ray;
  ray.origin = {0.3f * e, 0.3f * e, -1.0f};
  ray.dir = {0, 0, 1};
  SurfaceHit hit;
  ASSERT_TRUE(s.trace(ray, {}, ctx, &hit));
  EXPECT_EQ(hit.level, 20);
  EXPECT_NEAR(hit.t, 1.0 + 0.5 * e, 2.0 * grid.voxel_size);
  ray.origin = {0.5f, 0.5f, -1.0f};  // between the triangles: empty
  EXPECT_FALSE(s.trace(ray, {}, ctx, &hit));
}

// The CLI takes the out-of-core path when asked (or when the in-core
// estimate exceeds the budget) and writes the same scene file bytes.
TEST(OocDag, CliOutOfCoreSceneEqualsInCoreScene) {
  testing::TempDir dir;
  const std::string mesh = (kMeshes / "stanford-bunny.obj").string();
  auto a = testing::run_cli("build '" + mesh + "' -o " + dir.file("a.vxc") +
                            " --format dag --resolution 256");
  ASSERT_EQ(a.exit_code, 0) << a.output;
  auto b = testing::run_cli("build '" + mesh + "' -o " + dir.file("b.vxc") +
                            " --format dag --resolution 256 --out-of-core --cell-size 32");
  ASSERT_EQ(b.exit_code, 0) << b.output;
  EXPECT_NE(b.output.find("out-of-core"), std::string::npos) << b.output;
  // META differs only in the timings; geometry and attributes must match.
  SceneInfo ia, ib;
  const dag::SparseVoxelDag da = load_dag_scene(dir.file("a.vxc"), &ia);
  const dag::SparseVoxelDag db = load_dag_scene(dir.file("b.vxc"), &ib);
  expect_same_dag(da, db);
  // Automatic switch: a budget below the in-core estimate.
  auto c = testing::run_cli("build '" + mesh + "' -o " + dir.file("c.vxc") +
                            " --format dag --resolution 512 --no-attributes --memory-budget 40M");
  ASSERT_EQ(c.exit_code, 0) << c.output;
  EXPECT_NE(c.output.find("out-of-core"), std::string::npos) << c.output;
  const dag::SparseVoxelDag dc = load_dag_scene(dir.file("c.vxc"));
  EXPECT_FALSE(dc.has_attributes());
  const GridTransform grid = GridTransform::fit(bunny().bounds(), 512);
  expect_same_dag(in_core(bunny(), grid, VoxelizationMode::Conservative, false), dc);
}

TEST(OocDag, CliBadInput) {
  testing::TempDir dir;
  const std::string mesh = (kMeshes / "stanford-bunny.obj").string();
  auto r = testing::run_cli("build '" + mesh + "' -o " + dir.file("a.vxc") +
                            " --format dag --resolution 1024 --out-of-core --memory-budget 3M");
  // (3M: above the 2.3 MiB file, which a smaller budget refuses before import.)
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("voxcast: error: out-of-core DAG build"), std::string::npos) << r.output;
  r = testing::run_cli("build '" + mesh + "' -o " + dir.file("a.vxc") +
                       " --format esvo --out-of-core");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("--out-of-core"), std::string::npos) << r.output;
  r = testing::run_cli("build '" + mesh + "' -o " + dir.file("a.vxc") +
                       " --format dag --out-of-core --cell-size 100");
  EXPECT_EQ(r.exit_code, 2) << r.output;  // a usage error: never a power of two
  EXPECT_NE(r.output.find("--cell-size: 100"), std::string::npos) << r.output;
  EXPECT_FALSE(std::filesystem::exists(dir.file("a.vxc")));
}

}  // namespace
}  // namespace voxcast
