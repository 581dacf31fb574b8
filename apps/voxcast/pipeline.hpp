#pragma once
// mesh file -> voxels -> ESVO, shared by `build` and `bench`.
#include <memory>
#include <string>

#include "esvo/build_cells.hpp"
#include "voxcast/brickmap.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast::cli {

struct BuildSettings {
  std::string mesh_path;
  uint32_t resolution = 1024;  // ignored when voxel_size > 0
  double voxel_size = 0;       // > 0: fit the grid to this voxel size
  VoxelizationMode mode = VoxelizationMode::Conservative;
  uint64_t memory_budget = 0;                                     // 0: 90% of available memory
  esvo::AttributeFormat attributes = esvo::AttributeFormat::Raw;  // esvo §5.4 / §5.5
  bool verbose = false;
  bool dag = false;       // build a sparse voxel DAG (BuiltScene::dag) instead of the ESVO
  bool brickmap = false;  // build a brickmap world (BuiltScene::brickmap) instead
  // DAG: colors + normals per voxel (DATR); the out-of-core path
  // (build_dag_out_of_core) when asked or when the in-core estimate exceeds
  // the budget; cell_size 0 = chosen from the budget. ESVO with contours: the
  // same for the cell-by-cell build (esvo::build_octree_cells).
  bool dag_attributes = true;
  bool out_of_core = false;
  uint32_t cell_size = 0;
  // ESVO only (esvo §5.2, §7.1-7.3): contours and the variable-depth build.
  bool contours = false;
  int max_level = 0;
  double geometry_error = 0, color_error = -1, normal_error = -1;
};

struct BuiltScene {
  Mesh mesh;
  MeshLoadStats mesh_stats;
  esvo::EsvoOctree octree;                    // empty when BuildSettings::dag
  dag::SparseVoxelDag dag;                    // only when BuildSettings::dag
  std::shared_ptr<brickmap::World> brickmap;  // only when BuildSettings::brickmap
  uint64_t leaf_voxels = 0;
  double load_seconds = 0, voxelize_seconds = 0, octree_seconds = 0;
  bool out_of_core = false;         // the DAG came from build_dag_out_of_core, or the ESVO
                                    // from build_octree_cells
  dag::OutOfCoreReport ooc;         // when out_of_core (DAG)
  esvo::CellBuildStats esvo_cells;  // when out_of_core (ESVO)
};

/// Rough upper estimate of the peak bytes voxelizing `mesh` into `grid` takes
/// (surface voxel count from triangle areas and perimeters, times the bytes the
/// voxelizer and builder hold per voxel).
uint64_t estimate_build_bytes(const Mesh& mesh, const GridTransform& grid);

/// Bytes the mesh's arrays and textures hold.
uint64_t mesh_bytes(const Mesh& mesh);

BuiltScene build_scene(const BuildSettings& settings);

VoxelizationMode parse_voxelization(const std::string& name);
const char* voxelization_name(VoxelizationMode mode);

/// "raw" | "compressed" (esvo §5.4 / §5.5 color/normal attachments).
esvo::AttributeFormat parse_attribute_format(const std::string& name);
const char* attribute_format_name(esvo::AttributeFormat format);

}  // namespace voxcast::cli
