#pragma once
// mesh file -> voxels -> structure (any registered format), shared by `build`
// and `bench`.
#include <optional>
#include <string>
#include <vector>

#include "voxcast/displacement.hpp"
#include "voxcast/format_registry.hpp"
#include "voxcast/image.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast::cli {

struct BuildSettings {
  std::string mesh_path;
  uint32_t resolution = 1024;  // ignored when voxel_size > 0
  double voxel_size = 0;       // > 0: fit the grid to this voxel size
  VoxelizationMode mode = VoxelizationMode::Conservative;
  uint64_t memory_budget = 0;        // 0: 90% of available memory
  bool compress_attributes = false;  // esvo §5.5 blocks (FormatBuildOptions)
  bool verbose = false;
  std::string format;  // a registered format (format_registry.hpp); empty: the first

  // Formats with attributes_optional (the DAG): colors + normals per voxel.
  bool dag_attributes = true;
  // The format's memory-bounded build from the mesh (SceneFormat::
  // build_from_mesh: the DAG's sub-volumes, ESVO's contour cells) when asked
  // or when the in-core estimate exceeds the budget; cell_size 0 = chosen
  // from the budget.
  bool out_of_core = false;
  uint32_t cell_size = 0;
  // Formats with SceneFormat::contours (esvo §5.2, §7.1-7.3): contours and
  // the variable-depth build.
  bool contours = false;
  int max_level = 0;
  double geometry_error = 0, color_error = -1, normal_error = -1;
  // --fill solid: the surface plus the interior (fill_solid, solid.hpp);
  // in-core builds without contours only.
  bool fill_solid = false;
  // --displacement MAP --displacement-scale S (esvo §7.4, displacement.hpp):
  // the mesh displaced by the height map along its normals; in-core builds
  // without contours only.
  std::string displacement;
  double displacement_scale = 0;
  // --displacement-scale S alone: the height map is the mesh material's
  // (Material::height_texture).
  bool displacement_from_mesh = false;
};

struct BuiltScene {
  Mesh mesh;
  MeshLoadStats mesh_stats;
  LoadedStructure structure;  // of BuildSettings::format
  uint64_t leaf_voxels = 0;
  double load_seconds = 0, voxelize_seconds = 0, octree_seconds = 0;
  bool out_of_core = false;            // built by the format's memory-bounded mesh build
  std::string build_report;            // its lines for after the build (MeshBuild::report)
  std::vector<BuildStat> build_stats;  // its statistics (`build -v`)
};

/// Rough upper estimate of the peak bytes voxelizing `mesh` into `grid` takes
/// (surface voxel count from triangle areas and perimeters, times the bytes the
/// voxelizer and builder hold per voxel).
uint64_t estimate_build_bytes(const Mesh& mesh, const GridTransform& grid);

/// Bytes the mesh's arrays and textures hold.
uint64_t mesh_bytes(const Mesh& mesh);

/// `memory_budget`, or 90% of the available memory when it is 0.
uint64_t effective_budget(uint64_t memory_budget);

/// The mesh file, refused when larger than `budget`, with the textures'
/// decoding bounded by what the file leaves of it (load_mesh); prints the
/// import's warnings and, when verbose or triangles were dropped, its counts.
Mesh load_build_mesh(const std::string& path, uint64_t budget, MeshLoadStats* stats, bool verbose,
                     Image* height_map = nullptr);

/// The displacement map of a displaced build (esvo §7.4): --displacement
/// MAP (.png or .pfm), or with displacement_from_mesh the materials' height
/// map `mesh_height_map` (an error when the mesh has none); empty otherwise.
std::optional<DisplacementMap> load_displacement(const BuildSettings& settings,
                                                 const Image* mesh_height_map);

/// The voxel grid `settings` ask for around `bounds`; refuses (voxcast::Error)
/// a grid the scene loader would refuse (GridTransform::placement_is_valid).
GridTransform build_grid(const BuildSettings& settings, const Aabb& bounds);

/// load_build_mesh, then the build below. settings.mesh_path may also name a
/// voxel file (.vox, .binvox, .vdb: is_voxel_input), which is built as it is
/// (no mesh, no contours).
BuiltScene build_scene(const BuildSettings& settings);
/// The build from an already loaded mesh (moved into BuiltScene::mesh).
/// `mesh_height_map`: the materials' height map, for displacement_from_mesh.
BuiltScene build_scene(const BuildSettings& settings, Mesh mesh, const MeshLoadStats& mesh_stats,
                       const Image* mesh_height_map = nullptr);

/// The voxel set `voxcast convert` writes: the voxel file read, or the mesh
/// voxelized in core (with the solid fill when asked).
VoxelSet input_voxels(const BuildSettings& settings);

/// The grid and voxelization options `build` and `convert` share, checked
/// (usage errors): --resolution (a power of two), --voxel-size when given
/// (finite, positive; whether its grid fits the mesh is known once the mesh
/// is read), --voxelization and --fill (surface | solid).
void set_voxelization_options(BuildSettings& s, uint32_t resolution, bool voxel_size_given,
                              double voxel_size, const std::string& voxelization,
                              const std::string& fill);

VoxelizationMode parse_voxelization(const std::string& name);
const char* voxelization_name(VoxelizationMode mode);

/// "raw" | "compressed" (esvo §5.4 / §5.5 color/normal attachments): true
/// for compressed.
bool parse_compressed_attributes(const std::string& name);

/// settings.format's registry entry (the first registered for an empty name).
const SceneFormat& format_of(const BuildSettings& settings);

/// The registry's build options of `settings` (`mesh`: the source mesh, null
/// for a voxel file).
FormatBuildOptions format_build_options(const BuildSettings& settings, const Mesh* mesh);

}  // namespace voxcast::cli
