// Cell-by-cell variable-depth build (esvo §7.1-7.3, memory bounded): the
// octree built from one cell's voxels at a time must equal the in-core build
// byte for byte, for tiny cells (many cells, deep cell roots, refined and
// pruned cell roots), raw and compressed attributes, with and without a max
// level and attribute tolerances (compressed with a color/normal tolerance:
// the §7.3 decoded-leaf loop, streamed).
#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "esvo/build_cells.hpp"
#include "support/attribute_oracle.hpp"
#include "support/cli_runner.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast {
namespace {

Mesh load(const char* name) {
  return testing::load_mesh_with_wave_colors(name);
}

const std::filesystem::path kMeshes = std::filesystem::path(VOXCAST_TEST_DATA_DIR) / "meshes";

struct Mix {
  const char* name;
  int max_level;
  double geometry_error, color_error, normal_error;
};

// Full depth with contours; geometry only; geometry + attributes; a max
// level with a normal tolerance; attributes only; geometry + color only;
// normal only (compressed, the last five run the §7.3 decoded-leaf loop).
const Mix kMixes[] = {{"contours", 0, 0, -1, -1},
                      {"geometry", 0, 1.0, -1, -1},
                      {"geometry+attributes", 0, 1.0, 16, 12},
                      {"max-level+normal", 5, -1, -1, 10},
                      {"attributes", 0, -1, 10, 10},
                      {"geometry+color", 0, 1.0, 6, -1},
                      {"normal", 0, -1, -1, 6}};

void expect_same(const esvo::EsvoOctree& a, const esvo::EsvoOctree& b, const std::string& what) {
  EXPECT_EQ(a.block_count, b.block_count) << what;
  ASSERT_EQ(a.words.size(), b.words.size()) << what;
  size_t diff = 0;
  for (size_t i = 0; i < a.words.size(); ++i) diff += a.words[i] != b.words[i];
  EXPECT_EQ(diff, 0u) << what << ": words differ";
}

struct Case {
  const char* mesh;
  uint32_t resolution;
};

class CellBuild : public ::testing::TestWithParam<Case> {};

TEST_P(CellBuild, SameBytesAsInCore) {
  const Case& cs = GetParam();
  const Mesh mesh = load(cs.mesh);
  const GridTransform grid = GridTransform::fit(mesh.bounds(), cs.resolution);
  VoxelizeOptions vo;
  vo.attributes = true;
  const VoxelSet v = voxelize(mesh, grid, vo);
  // Over the compressed tolerance mixes: the decoded-leaf loop found
  // failing leaves inside cells and at or above the cells' roots.
  uint64_t replanned = 0, forced_top = 0;
  for (const auto format : {esvo::AttributeFormat::Raw, esvo::AttributeFormat::Compressed}) {
    for (const Mix& mix : kMixes) {
      esvo::BuildOptions o;
      o.contours = true;
      o.attributes = format;
      o.max_level = mix.max_level;
      o.geometry_error = mix.geometry_error;
      o.color_error = mix.color_error;
      o.normal_error = mix.normal_error;
      // Small blocks: many blocks and far pointers in both builds.
      o.max_block_slots = 3000;
      o.max_block_values = 6000;
      const esvo::EsvoOctree ref = esvo::build_octree(v, mesh, o);
      const bool decoded = format == esvo::AttributeFormat::Compressed &&
                           (mix.color_error >= 0 || mix.normal_error >= 0);
      // 4^3 / 8^3 cells: hundreds of cells with deep roots (CellSizeFromBudget
      // has a few large ones).
      for (uint32_t cell : {cs.resolution <= 64 ? 4u : 8u}) {
        const std::string what = std::string(cs.mesh) + " " + std::to_string(cs.resolution) +
                                 (format == esvo::AttributeFormat::Raw ? " raw " : " compressed ") +
                                 mix.name + " cell " + std::to_string(cell);
        esvo::CellBuildStats st;
        const esvo::EsvoOctree got = esvo::build_octree_cells(mesh, grid, vo, o, cell, 0, &st);
        expect_same(ref, got, what);
        EXPECT_FALSE(st.in_core) << what;
        // The loop ends with a round without failures, so it found some
        // iff it ran more than one.
        EXPECT_EQ(st.decoded_rounds > 0, decoded) << what;
        EXPECT_EQ(st.decoded_rounds > 1, st.replanned_cells + st.forced_top_leaves > 0) << what;
        replanned += st.replanned_cells;
        forced_top += st.forced_top_leaves;
        EXPECT_EQ(st.cell_size, cell) << what;
        EXPECT_EQ(st.voxels, v.size()) << what;
        // Many cells; below the max level some are planned below their root
        // and, with 4^3 cells and a geometry tolerance, some are pruned at or
        // above it.
        const int cell_depth = grid.levels - std::countr_zero(cell);
        EXPECT_GT(st.cells, cell <= 8 ? 300u : 10u) << what;
        if (mix.max_level == 0 || cell_depth < mix.max_level) {
          EXPECT_GT(st.refined_cells, 0u) << what;
        } else {
          EXPECT_EQ(st.refined_cells, 0u) << what;
        }
        if (cell <= 8 && mix.geometry_error > 0) {
          EXPECT_LT(st.refined_cells, st.cells) << what;
        }
      }
    }
  }
  EXPECT_GT(replanned, 0u);
  EXPECT_GT(forced_top, 0u);
}

INSTANTIATE_TEST_SUITE_P(Meshes, CellBuild,
                         ::testing::Values(Case{"stanford-bunny.obj", 64},
                                           Case{"stanford-bunny.obj", 128},
                                           Case{"fandisk_large.off", 64},
                                           Case{"fandisk_large.off", 128}),
                         [](const ::testing::TestParamInfo<Case>& i) {
                           std::string n = i.param.mesh;
                           n = n.substr(0, n.find_first_of("-_."));
                           return n + std::to_string(i.param.resolution);
                         });

TEST(CellBuild, SameBytesForAnyThreadCount) {
  const Mesh mesh = load("stanford-bunny.obj");
  const GridTransform grid = GridTransform::fit(mesh.bounds(), 128);
  VoxelizeOptions vo;
  vo.attributes = true;
  esvo::BuildOptions o;
  o.contours = true;
  o.geometry_error = 1;
  o.normal_error = 8;
  esvo::BuildOptions oc = o;  // and the decoded-leaf loop
  oc.attributes = esvo::AttributeFormat::Compressed;
  oc.color_error = 8;
  const esvo::EsvoOctree all = esvo::build_octree_cells(mesh, grid, vo, o, 8, 0);
  const esvo::EsvoOctree all_c = esvo::build_octree_cells(mesh, grid, vo, oc, 8, 0);
  tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
  const esvo::EsvoOctree single = esvo::build_octree_cells(mesh, grid, vo, o, 8, 0);
  expect_same(all, single, "1 thread vs all");
  expect_same(all_c, esvo::build_octree_cells(mesh, grid, vo, oc, 8, 0),
              "compressed: 1 thread vs all");
}

TEST(CellBuild, CellSizeFromBudget) {
  // No cell size: the largest cells whose estimate fits half the budget; a
  // small budget gives smaller cells, the same bytes either way.
  const Mesh mesh = load("stanford-bunny.obj");
  const GridTransform grid = GridTransform::fit(mesh.bounds(), 128);
  VoxelizeOptions vo;
  vo.attributes = true;
  esvo::BuildOptions o;
  o.contours = true;
  o.geometry_error = 1;
  esvo::CellBuildStats big, small;
  const esvo::EsvoOctree a =
      esvo::build_octree_cells(mesh, grid, vo, o, 0, uint64_t(1) << 34, &big);
  const esvo::EsvoOctree b = esvo::build_octree_cells(mesh, grid, vo, o, 0, 24u << 20, &small);
  EXPECT_EQ(big.cell_size, 64u);  // resolution / 2: the largest allowed
  EXPECT_LT(small.cell_size, big.cell_size);
  EXPECT_GT(small.cells, big.cells);
  expect_same(a, b, "budget");
  EXPECT_THROW(esvo::build_octree_cells(mesh, grid, vo, o, 3, 0), Error);
  EXPECT_THROW(esvo::build_octree_cells(mesh, grid, vo, o, 128, 0), Error);
}

std::string file_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// With a color/normal tolerance the CLI takes the cell-by-cell path when
// asked (--out-of-core / --cell-size) or when the in-core estimate exceeds
// --memory-budget, and writes the same scene file bytes as in core.
TEST(CellBuild, CliSceneEqualsInCoreScene) {
  testing::TempDir dir;
  const std::string mesh = (kMeshes / "stanford-bunny.obj").string();
  const std::string args = " --resolution 512 --contours --geometry-error 1 --normal-error 10";
  auto a = testing::run_cli("build '" + mesh + "' -o " + dir.file("a.vxc") + args);
  ASSERT_EQ(a.exit_code, 0) << a.output;
  EXPECT_EQ(a.output.find("out-of-core"), std::string::npos) << a.output;
  auto b =
      testing::run_cli("build '" + mesh + "' -o " + dir.file("b.vxc") + args + " --cell-size 32");
  ASSERT_EQ(b.exit_code, 0) << b.output;
  EXPECT_NE(b.output.find("out-of-core"), std::string::npos) << b.output;
  auto c = testing::run_cli("build '" + mesh + "' -o " + dir.file("c.vxc") + args +
                            " --memory-budget 60M");
  ASSERT_EQ(c.exit_code, 0) << c.output;
  EXPECT_NE(c.output.find("out-of-core"), std::string::npos) << c.output;
  const std::string fa = file_bytes(dir.file("a.vxc"));
  EXPECT_GT(fa.size(), 8192u);
  EXPECT_TRUE(fa == file_bytes(dir.file("b.vxc")));
  EXPECT_TRUE(fa == file_bytes(dir.file("c.vxc")));
  // Compressed with a normal tolerance: the streamed decoded-leaf loop.
  const std::string cargs = args + " --attributes compressed";
  auto f = testing::run_cli("build '" + mesh + "' -o " + dir.file("f.vxc") + cargs);
  ASSERT_EQ(f.exit_code, 0) << f.output;
  EXPECT_EQ(f.output.find("out-of-core"), std::string::npos) << f.output;
  auto g =
      testing::run_cli("build '" + mesh + "' -o " + dir.file("g.vxc") + cargs + " --cell-size 32");
  ASSERT_EQ(g.exit_code, 0) << g.output;
  EXPECT_NE(g.output.find("out-of-core"), std::string::npos) << g.output;
  const std::string ff = file_bytes(dir.file("f.vxc"));
  EXPECT_GT(ff.size(), 8192u);
  EXPECT_TRUE(ff == file_bytes(dir.file("g.vxc")));
  // Without a color/normal tolerance the cell-by-cell build is the default.
  auto e = testing::run_cli("build '" + mesh + "' -o " + dir.file("e.vxc") +
                            " --resolution 256 --contours --geometry-error 1");
  ASSERT_EQ(e.exit_code, 0) << e.output;
  EXPECT_NE(e.output.find("out-of-core"), std::string::npos) << e.output;
  // Without --contours, --cell-size is for DAG builds only.
  auto d = testing::run_cli("build '" + mesh + "' -o " + dir.file("d.vxc") +
                            " --resolution 64 --cell-size 16");
  EXPECT_NE(d.exit_code, 0) << d.output;
}

}  // namespace
}  // namespace voxcast
