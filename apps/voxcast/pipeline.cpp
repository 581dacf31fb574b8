#include "pipeline.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <optional>
#include <string>

#include "cli_io.hpp"
#include "commands.hpp"
#include "voxcast/displacement.hpp"
#include "voxcast/error.hpp"
#include "voxcast/image.hpp"
#include "voxcast/mesh_height.hpp"
#include "voxcast/progress.hpp"
#include "voxcast/solid.hpp"
#include "voxcast/system.hpp"
#include "voxcast/voxel_io.hpp"

namespace voxcast::cli {

VoxelizationMode parse_voxelization(const std::string& name) {
  if (name == "conservative") return VoxelizationMode::Conservative;
  if (name == "6-separating" || name == "six-separating") return VoxelizationMode::SixSeparating;
  throw UsageError("--voxelization: '" + printable(name) + "' is not conservative or 6-separating");
}

void set_voxelization_options(BuildSettings& s, uint32_t resolution, bool voxel_size_given,
                              double voxel_size, const std::string& voxelization,
                              const std::string& fill) {
  require_power_of_two("--resolution", resolution, 1, uint64_t(1) << 20);
  s.resolution = resolution;
  if (voxel_size_given) {
    require_range("--voxel-size", voxel_size, 1e-30, 1e30);
    s.voxel_size = voxel_size;
  }
  s.mode = parse_voxelization(voxelization);
  if (fill != "surface" && fill != "solid")
    throw UsageError("--fill: '" + printable(fill) + "' is not surface or solid");
  s.fill_solid = fill == "solid";
}

const char* voxelization_name(VoxelizationMode mode) {
  return mode == VoxelizationMode::Conservative ? "conservative" : "6-separating";
}

bool parse_compressed_attributes(const std::string& name) {
  if (name == "raw") return false;
  if (name == "compressed") return true;
  throw UsageError("--attributes: '" + printable(name) + "' is not raw or compressed");
}

const SceneFormat& format_of(const BuildSettings& s) {
  if (s.format.empty() && !format_registry().formats().empty())
    return format_registry().formats().front();
  return format_registry().get(s.format);
}

namespace {
// The format's build from a voxel set with a progress bar on a terminal
// (the format plans its phases).
LoadedStructure build_with_bar(const SceneFormat& format, const VoxelSet& voxels,
                               FormatBuildOptions fo) {
  Progress progress(format.name + " build", uint64_t(0));
  fo.progress = &progress;
  return format.build(voxels, fo);
}
}  // namespace

FormatBuildOptions format_build_options(const BuildSettings& s, const Mesh* mesh) {
  FormatBuildOptions fo;
  fo.compress_attributes = s.compress_attributes;
  fo.contours.enabled = s.contours;
  if (s.contours) {
    fo.contours.max_level = s.max_level;
    fo.contours.geometry_error = s.geometry_error;
    fo.contours.color_error = s.color_error;
    fo.contours.normal_error = s.normal_error;
  }
  fo.mesh = mesh;
  return fo;
}

uint64_t estimate_build_bytes(const Mesh& mesh, const GridTransform& grid) {
  // A conservatively voxelized plane of area A (in voxel units) with unit
  // normal n covers about A * (|nx|+|ny|+|nz|) voxels, plus a band along its
  // edges; every voxel also appears once per extra triangle sharing it.
  // Edges in double, in voxel units: the estimate depends on the triangles'
  // shape only, not on how far the mesh lies from the origin.
  const double inv = 1.0 / grid.voxel_size;
  auto at = [&](uint32_t i) {
    const Vec3& p = mesh.positions[i];
    return std::array<double, 3>{double(p.x), double(p.y), double(p.z)};
  };
  auto sub = [&](const std::array<double, 3>& a, const std::array<double, 3>& b) {
    return std::array<double, 3>{(a[0] - b[0]) * inv, (a[1] - b[1]) * inv, (a[2] - b[2]) * inv};
  };
  auto len = [](const std::array<double, 3>& v) {
    return std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
  };
  double pairs = 0;
  for (size_t t = 0; t < mesh.triangle_count(); ++t) {
    const auto a = at(mesh.indices[3 * t]), b = at(mesh.indices[3 * t + 1]),
               c = at(mesh.indices[3 * t + 2]);
    const auto e1 = sub(b, a), e2 = sub(c, a), e3 = sub(c, b);
    const std::array<double, 3> n{e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                                  e1[0] * e2[1] - e1[1] * e2[0]};
    const double nl = len(n);
    const double area = 0.5 * nl;
    const double l1 = nl > 0 ? (std::fabs(n[0]) + std::fabs(n[1]) + std::fabs(n[2])) / nl : 1;
    const double perim = len(e1) + len(e2) + len(e3);
    pairs += area * l1 + 2.0 * perim + 4.0;
  }
  // Per pair: 16-byte record + sort scratch; per voxel (~pairs/2): attributes
  // (40 B), octree levels and layout (~40 B).
  return uint64_t(pairs * 32.0 + pairs * 0.5 * 80.0);
}

uint64_t mesh_bytes(const Mesh& m) {
  uint64_t bytes = m.positions.size() * sizeof(Vec3) + m.normals.size() * sizeof(Vec3) +
                   m.colors.size() * sizeof(Color) + m.uvs.size() * sizeof(Vec2) +
                   m.indices.size() * sizeof(uint32_t) + m.triangle_material.size() * 4 +
                   m.materials.size() * sizeof(Material);
  for (const Texture& t : m.textures) bytes += t.rgba.size();
  return bytes;
}

namespace {
std::string count_of(size_t n, const char* one, const char* many) {
  return std::to_string(n) + " " + (n == 1 ? one : many);
}
}  // namespace

uint64_t effective_budget(uint64_t memory_budget) {
  return memory_budget ? memory_budget : uint64_t(double(available_memory_bytes()) * 0.9);
}

Mesh load_build_mesh(const std::string& path, uint64_t budget, MeshLoadStats* stats, bool verbose,
                     Image* height_map) {
  // The importer holds at least the whole file: refuse before reading it.
  std::error_code ec;
  const uint64_t file_bytes = std::filesystem::file_size(path, ec);
  if (!ec && budget && file_bytes > budget)
    throw Error(in_quotes(path) + " is " + format_bytes(double(file_bytes)) + ", more than the " +
                format_bytes(double(budget)) + " memory budget; raise --memory-budget");
  // Decoded textures get what the file leaves of the budget.
  const uint64_t held = ec ? 0 : file_bytes;
  Mesh mesh = load_mesh(path, height_map, stats, budget ? (budget > held ? budget - held : 1) : 0);
  if (!Progress::quiet())
    for (const std::string& w : stats->warnings)
      std::fprintf(stderr, "voxcast: warning: %s\n", printable(w).c_str());
  if (verbose || (stats->degenerate_dropped && !Progress::quiet()))
    std::fprintf(
        stderr, "mesh: %s, %s (%s dropped)\n",
        count_of(mesh.triangle_count(), "triangle", "triangles").c_str(),
        count_of(mesh.positions.size(), "vertex", "vertices").c_str(),
        count_of(stats->degenerate_dropped, "degenerate triangle", "degenerate triangles").c_str());
  return mesh;
}

GridTransform build_grid(const BuildSettings& s, const Aabb& bounds) {
  const GridTransform grid = s.voxel_size > 0 ? GridTransform::fit_voxel_size(bounds, s.voxel_size)
                                              : GridTransform::fit(bounds, s.resolution);
  // The scene loader refuses any other placement (README "Reliability"):
  // refuse it here, before the build, rather than write a file nothing reads.
  if (!grid.placement_is_valid()) {
    bool beyond = false;
    for (int a = 0; a < 3; ++a)
      beyond |= !(std::fabs(double(grid.origin[a])) <= kMaxWorldCoordinate) ||
                !(std::fabs(double(grid.origin[a]) + grid.side()) <= kMaxWorldCoordinate);
    char buf[400];
    std::snprintf(buf, sizeof buf,
                  "the mesh's voxel grid (origin %.6g,%.6g,%.6g, side %.6g) is not a box of float "
                  "coordinates within +-1e18 (%s); move the mesh closer to the origin",
                  double(grid.origin.x), double(grid.origin.y), double(grid.origin.z), grid.side(),
                  beyond ? "it reaches beyond 1e18"
                         : "the mesh is too small for its distance from the origin: float "
                           "coordinates cannot tell its sides apart");
    throw Error(buf);
  }
  return grid;
}

namespace {
/// A voxel file (.vox, .binvox, .vdb) is already the voxel set: built
/// through the format registry as it is (no mesh, no contours).
BuiltScene build_from_voxel_file(const BuildSettings& s, uint64_t budget, StageTimer& timer) {
  BuiltScene out;
  VoxelReadOptions ro;
  ro.memory_budget = budget;
  VoxelSet voxels = read_voxels(s.mesh_path, ro);
  out.load_seconds = timer.mark("read voxels");
  out.leaf_voxels = voxels.size();
  const SceneFormat& format = format_of(s);
  if (voxels.grid.levels < format.min_levels)
    throw Error("'" + printable(s.mesh_path) + "' is a " + std::to_string(voxels.grid.resolution) +
                "^3 grid; " + format.name + " needs at least " +
                std::to_string(1u << format.min_levels) + "^3");
  if (format.attributes_optional && !s.dag_attributes)
    voxels.colors.clear(), voxels.normals.clear(), voxels.weights.clear();
  out.structure = build_with_bar(format, voxels, format_build_options(s, nullptr));
  out.octree_seconds = timer.mark((format.name + " build").c_str());
  return out;
}

/// --fill solid: the interior added to the surface voxels, bounded by what
/// the budget holds beside the mesh and the surface.
void fill_interior(const BuildSettings& s, const Mesh& mesh, uint64_t budget, VoxelSet* voxels,
                   StageTimer& timer) {
  SolidFillStats st;
  const uint64_t used = mesh_bytes(mesh) + voxels->size() * kVoxelSetBytesPerVoxel;
  const uint64_t max_voxels = budget > used ? (budget - used) / kVoxelSetBytesPerVoxel : 1;
  *voxels = fill_solid(mesh, *voxels, &st, max_voxels);
  timer.mark("solid fill");
  if (s.verbose)
    std::fprintf(stderr,
                 "solid fill: %llu interior voxels, %llu of %llu columns by winding number\n",
                 (unsigned long long)st.interior_voxels, (unsigned long long)st.ambiguous_columns,
                 (unsigned long long)st.columns);
}
}  // namespace

std::optional<DisplacementMap> load_displacement(const BuildSettings& s,
                                                 const Image* mesh_height_map) {
  std::optional<DisplacementMap> displacement;
  if (!s.displacement.empty()) {
    const std::string ext = std::filesystem::path(s.displacement).extension().string();
    const Image image = ext == ".pfm" ? read_pfm(s.displacement) : read_png(s.displacement);
    displacement.emplace(image);
  } else if (s.displacement_from_mesh) {
    if (mesh_height_map == nullptr || mesh_height_map->width == 0)
      throw Error(in_quotes(s.mesh_path) +
                  " has no height or displacement texture in its materials; give "
                  "--displacement MAP");
    displacement.emplace(*mesh_height_map);
  }
  return displacement;
}

BuiltScene build_scene(const BuildSettings& s) {
  const uint64_t budget = effective_budget(s.memory_budget);
  StageTimer timer(s.verbose);
  if (is_voxel_input(s.mesh_path)) return build_from_voxel_file(s, budget, timer);
  MeshLoadStats stats;
  Image height_map;  // the materials' (--displacement-scale without --displacement)
  Mesh mesh = load_build_mesh(s.mesh_path, budget, &stats, s.verbose,
                              s.displacement_from_mesh ? &height_map : nullptr);
  const double load_seconds = timer.mark("load mesh");
  BuiltScene out = build_scene(s, std::move(mesh), stats, &height_map);
  out.load_seconds = load_seconds;
  return out;
}

BuiltScene build_scene(const BuildSettings& s, Mesh mesh, const MeshLoadStats& mesh_stats,
                       const Image* mesh_height_map) {
  const SceneFormat& format = format_of(s);
  BuiltScene out;
  out.mesh = std::move(mesh);
  out.mesh_stats = mesh_stats;
  StageTimer timer(s.verbose);
  const uint64_t budget = effective_budget(s.memory_budget);
  // Displacement (esvo §7.4): the grid holds the displaced surface.
  const std::optional<DisplacementMap> displacement = load_displacement(s, mesh_height_map);
  if (!s.displacement.empty()) timer.mark("load displacement map");
  const GridTransform grid = build_grid(
      s, displacement ? displaced_bounds(out.mesh, *displacement, float(s.displacement_scale))
                      : out.mesh.bounds());
  if (const int least = format_of(s).min_levels; grid.levels < least) {
    // (Only from --voxel-size: build refuses a --resolution below it as a usage error.)
    char buf[200];
    std::snprintf(buf, sizeof buf,
                  "--voxel-size %g gives the mesh a %u^3 grid; %s needs at least %u^3: a smaller "
                  "--voxel-size",
                  s.voxel_size, unsigned(grid.resolution), s.format.c_str(), 1u << least);
    throw Error(buf);
  }
  const FormatBuildOptions fo = format_build_options(s, &out.mesh);

  // The mesh stays in memory for the whole build.
  const uint64_t need = estimate_build_bytes(out.mesh, grid) + mesh_bytes(out.mesh);
  // A format's own build from the mesh (the memory-bounded ones: the DAG's
  // sub-volumes, ESVO's contour cells) decides whether this request is its;
  // the solid fill needs the whole surface in core first.
  if (format.build_from_mesh && !s.fill_solid && !displacement) {
    MeshBuildRequest r;
    r.mode = s.mode;
    r.attributes = !format.attributes_optional || s.dag_attributes;
    r.options = fo;
    r.memory_budget = budget;
    r.in_core_estimate = need;
    r.out_of_core = s.out_of_core;
    r.cell_size = s.cell_size;
    MeshBuild b = format.build_from_mesh(out.mesh, grid, r);
    if (b.structure) {
      out.structure = std::move(b.structure);
      out.leaf_voxels = b.leaf_voxels;
      out.voxelize_seconds = b.voxelize_seconds;
      out.octree_seconds = b.build_seconds;
      out.out_of_core = b.out_of_core;
      out.build_report = std::move(b.report);
      out.build_stats = std::move(b.stats);
      timer.mark(b.stage.c_str());
      return out;
    }
  }
  if (budget && need > budget)
    throw Error("resolution " + std::to_string(grid.resolution) + " needs an estimated " +
                format_bytes(double(need)) + ", more than the " + format_bytes(double(budget)) +
                " memory budget; lower --resolution or raise --memory-budget");

  VoxelSet voxels;
  {
    Progress progress("voxelize", out.mesh.triangle_count());
    VoxelizeOptions vo;
    vo.mode = s.mode;
    vo.progress = &progress;
    vo.attributes = !format.attributes_optional || s.dag_attributes || s.fill_solid;
    voxels = displacement ? voxelize_displaced(out.mesh, *displacement, float(s.displacement_scale),
                                               grid, vo)
                          : voxelize(out.mesh, grid, vo);
  }
  out.voxelize_seconds = timer.mark("voxelize");
  if (voxels.size() == 0) throw Error("the mesh produced no voxels");
  if (s.fill_solid) fill_interior(s, out.mesh, budget, &voxels, timer);
  out.leaf_voxels = voxels.size();
  if (s.fill_solid && format.attributes_optional && !s.dag_attributes)
    voxels.colors.clear(), voxels.normals.clear(), voxels.weights.clear();
  out.structure = build_with_bar(format, voxels, fo);
  out.octree_seconds = timer.mark((format.name + " build").c_str());
  return out;
}

VoxelSet input_voxels(const BuildSettings& s) {
  const uint64_t budget = effective_budget(s.memory_budget);
  StageTimer timer(s.verbose);
  if (is_voxel_input(s.mesh_path)) {
    VoxelReadOptions ro;
    ro.memory_budget = budget;
    VoxelSet voxels = read_voxels(s.mesh_path, ro);
    timer.mark("read voxels");
    return voxels;
  }
  MeshLoadStats stats;
  const Mesh mesh = load_build_mesh(s.mesh_path, budget, &stats, s.verbose);
  timer.mark("load mesh");
  const GridTransform grid = build_grid(s, mesh.bounds());
  const uint64_t need = estimate_build_bytes(mesh, grid) + mesh_bytes(mesh);
  if (budget && need > budget)
    throw Error("resolution " + std::to_string(grid.resolution) + " needs an estimated " +
                format_bytes(double(need)) + ", more than the " + format_bytes(double(budget)) +
                " memory budget; lower --resolution or raise --memory-budget");
  VoxelSet voxels;
  {
    Progress progress("voxelize", mesh.triangle_count());
    VoxelizeOptions vo;
    vo.mode = s.mode;
    vo.progress = &progress;
    vo.attributes = true;
    voxels = voxelize(mesh, grid, vo);
  }
  timer.mark("voxelize");
  if (voxels.size() == 0) throw Error("the mesh produced no voxels");
  if (s.fill_solid) fill_interior(s, mesh, budget, &voxels, timer);
  return voxels;
}

}  // namespace voxcast::cli
