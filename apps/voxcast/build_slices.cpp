#include "build_slices.hpp"

#include <cstdio>

#include "cli_io.hpp"
#include "commands.hpp"
#include "pipeline.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo_slices.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/voxel_io.hpp"

namespace voxcast::cli {

void check_slice_settings(const BuildSettings& s) {
  if (s.format != "esvo") throw UsageError("--slices needs --format esvo");
  // An in-core build to be sliced (solid fill, voxel files) is built raw and
  // compressed per slice, so its tolerances would test the raw values.
  if (s.compress_attributes && (s.color_error >= 0 || s.normal_error >= 0) &&
      (s.fill_solid || is_voxel_input(s.mesh_path)))
    throw UsageError(
        "--slices with --attributes compressed and --color-error/--normal-error needs a mesh "
        "built top-down (no --fill solid or voxel file)");
}

std::string build_slices_top_down(const BuildSettings& s, uint64_t slice_bytes, bool compressed,
                                  const std::filesystem::path& to) {
  MeshLoadStats mesh_stats;
  Image height_map;  // the materials' (--displacement-scale without --displacement)
  const Mesh mesh = load_build_mesh(s.mesh_path, effective_budget(s.memory_budget), &mesh_stats,
                                    s.verbose, s.displacement_from_mesh ? &height_map : nullptr);
  // Displacement (esvo §7.4): the grid holds the displaced surface.
  const std::optional<DisplacementMap> displacement = load_displacement(s, &height_map);
  const float scale = float(s.displacement_scale);
  const GridTransform grid =
      build_grid(s, displacement ? displaced_bounds(mesh, *displacement, scale) : mesh.bounds());
  VoxelizeOptions vo;
  vo.mode = s.mode;
  vo.attributes = true;
  esvo::SliceBuildOptions bo;
  bo.slice_bytes = slice_bytes;
  bo.memory_budget = s.memory_budget;
  bo.cell_size = s.cell_size;
  bo.contours = s.contours;
  bo.max_level = s.max_level;
  bo.geometry_error = s.geometry_error;
  bo.color_error = s.color_error;
  bo.normal_error = s.normal_error;
  bo.compressed = compressed;
  if (displacement) {
    bo.displacement = &*displacement;
    bo.displacement_scale = scale;
  }
  esvo::SliceBuildStats st;
  esvo::build_slices(mesh, grid, vo, to, bo, &st);
  char line[256];
  std::snprintf(
      line, sizeof line, "%llu slices (target %s), %s, top-down from %llu cells of %u^3%s%s",
      (unsigned long long)st.slices, format_bytes(double(slice_bytes)).c_str(),
      format_bytes(double(st.file_bytes)).c_str(), (unsigned long long)st.cells, st.cell_size,
      s.contours     ? ", contours"
      : displacement ? ", displaced"
                     : "",
      compressed ? ", compressed attributes" : "");
  return line;
}

void write_slice_file(const Structure& structure, uint64_t slice_bytes, bool compressed,
                      const std::filesystem::path& to) {
  const auto* e = dynamic_cast<const esvo::EsvoStructure*>(&structure);
  if (!e) throw Error("--slices: the built structure is not an ESVO octree");
  esvo::SliceOptions o;
  o.slice_bytes = slice_bytes;
  o.compressed = compressed;
  esvo::write_slices(e->octree(), to, o);
}

std::string describe_slice_file(const std::string& path, uint64_t slice_bytes) {
  const auto file = esvo::SliceFile::open(path);
  char line[256];
  std::snprintf(line, sizeof line, "%zu slices (target %s), %s%s", file->slices().size(),
                format_bytes(double(slice_bytes)).c_str(),
                format_bytes(double(file->header().file_bytes)).c_str(),
                file->compressed() ? ", compressed attributes" : "");
  return line;
}

}  // namespace voxcast::cli
