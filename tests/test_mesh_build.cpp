// Builds from a mesh through the format registry (SceneFormat::build_from_mesh,
// issue 9): `voxcast build` chooses a format's memory-bounded build (the DAG's
// sub-volumes, ESVO's contour cells) or the in-core one through the registry
// alone, and every scene it writes must be byte for byte what the library's
// in-core builders produce from the voxelized mesh. The oracle is the in-core
// path (voxelize, then build_octree / build_dag), a different algorithm from
// the cell-by-cell and sub-volume builds the CLI takes for the out-of-core
// variants; the CLI's stdout report of those builds and the -v key/value
// statistics come from the format.
#include <gtest/gtest.h>

#include <string>

#include "support/cli_runner.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/dag_format.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/esvo_format.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast {
namespace {

using testing::read_text;
using testing::run_cli;
using testing::run_cli_split;
using testing::TempDir;

const std::string kSpot = std::string(VOXCAST_TEST_DATA_DIR) + "/meshes/spot.obj";
constexpr uint32_t kResolution = 64;

struct Reference {
  Mesh mesh;
  GridTransform grid;
  VoxelSet voxels;  // conservative, with attributes
};

const Reference& reference() {
  static const Reference r = [] {
    Reference out;
    out.mesh = load_mesh(kSpot);
    out.grid = GridTransform::fit(out.mesh.bounds(), kResolution);
    VoxelizeOptions vo;
    vo.attributes = true;
    out.voxels = voxelize(out.mesh, out.grid, vo);
    return out;
  }();
  return r;
}

SceneInfo info_of(uint64_t leaf_voxels) {
  SceneInfo info;
  info.source = "spot.obj";
  info.voxelization = "conservative";
  info.source_triangles = reference().mesh.triangle_count();
  info.leaf_voxels = leaf_voxels;
  return info;
}

std::string esvo_reference(const esvo::BuildOptions& o, const std::string& path) {
  const Reference& r = reference();
  const esvo::EsvoOctree octree =
      o.contours ? esvo::build_octree(r.voxels, r.mesh, o) : esvo::build_octree(r.voxels, o);
  save_esvo_scene(path, octree, info_of(r.voxels.size()));
  return read_text(path);
}

std::string dag_reference(bool attributes, bool compressed, const std::string& path) {
  VoxelSet v = reference().voxels;
  if (!attributes) v.colors.clear(), v.normals.clear(), v.weights.clear();
  dag::SparseVoxelDag d = dag::build_dag(v);
  if (compressed) d.compress_attributes();
  save_dag_scene(path, d, info_of(v.size()));
  return read_text(path);
}

std::string cli_build(const TempDir& dir, const std::string& name, const std::string& options,
                      std::string* output = nullptr) {
  const std::string out = dir.file(name + ".vxc");
  const testing::CliResult r = run_cli("build '" + kSpot + "' -o '" + out + "' --resolution " +
                                       std::to_string(kResolution) + " " + options);
  EXPECT_EQ(r.exit_code, 0) << name << "\n" << r.output;
  if (output) *output = r.output;
  return read_text(out);
}

TEST(MeshBuild, EsvoScenesEqualTheInCoreBuilds) {
  TempDir dir;
  esvo::BuildOptions raw, compressed, contours, variable, tolerances;
  compressed.attributes = esvo::AttributeFormat::Compressed;
  contours.contours = true;
  variable.contours = true;
  variable.geometry_error = 1;
  tolerances = variable;
  tolerances.color_error = 8;
  // Without --contours: voxelize, then the registry's build. With contours
  // and no attribute tolerance: the contour cells (build_from_mesh); with a
  // tolerance: in core, unless --out-of-core asks for the cells.
  EXPECT_TRUE(cli_build(dir, "raw", "") == esvo_reference(raw, dir.file("r0.vxc")));
  EXPECT_TRUE(cli_build(dir, "compressed", "--attributes compressed") ==
              esvo_reference(compressed, dir.file("r1.vxc")));
  EXPECT_TRUE(cli_build(dir, "contours", "--contours") ==
              esvo_reference(contours, dir.file("r2.vxc")));
  EXPECT_TRUE(cli_build(dir, "variable", "--contours --geometry-error 1") ==
              esvo_reference(variable, dir.file("r3.vxc")));
  const std::string tol = esvo_reference(tolerances, dir.file("r4.vxc"));
  EXPECT_TRUE(cli_build(dir, "tol", "--contours --geometry-error 1 --color-error 8") == tol);
  std::string output;
  EXPECT_TRUE(cli_build(dir, "tol_cells",
                        "--contours --geometry-error 1 --color-error 8 --out-of-core "
                        "--cell-size 16 -v",
                        &output) == tol);
  // The cell build reports itself: stdout line and -v statistics.
  EXPECT_NE(output.find("out-of-core: "), std::string::npos) << output;
  EXPECT_NE(output.find("cells of 16^3"), std::string::npos) << output;
  EXPECT_NE(output.find("build: cell size: 16\n"), std::string::npos) << output;
}

TEST(MeshBuild, DagScenesEqualTheInCoreBuilds) {
  TempDir dir;
  const std::string raw = dag_reference(true, false, dir.file("r0.vxc"));
  const std::string compressed = dag_reference(true, true, dir.file("r1.vxc"));
  const std::string geometry = dag_reference(false, false, dir.file("r2.vxc"));
  EXPECT_TRUE(cli_build(dir, "raw", "--format dag") == raw);
  EXPECT_TRUE(cli_build(dir, "compressed", "--format dag --attributes compressed") == compressed);
  EXPECT_TRUE(cli_build(dir, "geometry", "--format dag --no-attributes") == geometry);
  std::string output;
  EXPECT_TRUE(cli_build(dir, "ooc", "--format dag --out-of-core --cell-size 16 -v", &output) ==
              raw);
  EXPECT_NE(output.find("out-of-core: "), std::string::npos) << output;
  EXPECT_NE(output.find(" cells of 16^3, voxelize "), std::string::npos) << output;
  EXPECT_NE(output.find("build: cell size: 16\n"), std::string::npos) << output;
  EXPECT_NE(output.find("build: cells: "), std::string::npos) << output;
  EXPECT_TRUE(cli_build(dir, "ooc_compressed",
                        "--format dag --out-of-core --cell-size 32 --attributes compressed") ==
              compressed);
  EXPECT_TRUE(cli_build(dir, "ooc_geometry", "--format dag --out-of-core --no-attributes") ==
              geometry);
}

// What a memory-bounded build applies to comes from the formats' capabilities
// (SceneFormat::bounded_mesh_build, SceneFormat::contours), not from names.
TEST(MeshBuild, MemoryBoundedAndContourOptionsFollowTheFormatsCapabilities) {
  TempDir dir;
  const std::string base = "build '" + kSpot + "' -o '" + dir.file("x.vxc") + "' --resolution 64 ";
  const testing::CliResult ooc = run_cli_split(base + "--out-of-core");
  EXPECT_EQ(ooc.exit_code, 2);
  EXPECT_NE(ooc.errors.find("--out-of-core and --cell-size apply to --format dag or --contours"),
            std::string::npos)
      << ooc.errors;
  const testing::CliResult contours = run_cli_split(base + "--format dag --contours");
  EXPECT_EQ(contours.exit_code, 2);
  EXPECT_NE(contours.errors.find("--contours applies to --format esvo only"), std::string::npos)
      << contours.errors;
}

}  // namespace
}  // namespace voxcast
