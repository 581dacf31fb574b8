#include "pipeline.hpp"

#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>

#include "cli_io.hpp"
#include "commands.hpp"
#include "voxcast/error.hpp"
#include "voxcast/progress.hpp"
#include "voxcast/system.hpp"

namespace voxcast::cli {

VoxelizationMode parse_voxelization(const std::string& name) {
  if (name == "conservative") return VoxelizationMode::Conservative;
  if (name == "6-separating" || name == "six-separating") return VoxelizationMode::SixSeparating;
  throw UsageError("--voxelization: '" + printable(name) + "' is not conservative or 6-separating");
}

const char* voxelization_name(VoxelizationMode mode) {
  return mode == VoxelizationMode::Conservative ? "conservative" : "6-separating";
}

esvo::AttributeFormat parse_attribute_format(const std::string& name) {
  if (name == "raw") return esvo::AttributeFormat::Raw;
  if (name == "compressed") return esvo::AttributeFormat::Compressed;
  throw UsageError("--attributes: '" + printable(name) + "' is not raw or compressed");
}

const char* attribute_format_name(esvo::AttributeFormat format) {
  return format == esvo::AttributeFormat::Compressed ? "compressed" : "raw";
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

BuiltScene build_scene(const BuildSettings& s) {
  BuiltScene out;
  StageTimer timer(s.verbose);
  uint64_t budget = s.memory_budget;
  if (budget == 0) budget = uint64_t(double(available_memory_bytes()) * 0.9);
  {
    // The importer holds at least the whole file: refuse before reading it.
    std::error_code ec;
    const uint64_t file_bytes = std::filesystem::file_size(s.mesh_path, ec);
    if (!ec && budget && file_bytes > budget)
      throw Error(in_quotes(s.mesh_path) + " is " + format_bytes(double(file_bytes)) +
                  ", more than the " + format_bytes(double(budget)) +
                  " memory budget; raise --memory-budget");
  }
  out.mesh = load_mesh(s.mesh_path, &out.mesh_stats);
  out.load_seconds = timer.mark("load mesh");
  for (const std::string& w : out.mesh_stats.warnings)
    std::fprintf(stderr, "voxcast: warning: %s\n", printable(w).c_str());
  if (s.verbose || out.mesh_stats.degenerate_dropped)
    std::fprintf(
        stderr, "mesh: %s, %s (%s dropped)\n",
        count_of(out.mesh.triangle_count(), "triangle", "triangles").c_str(),
        count_of(out.mesh.positions.size(), "vertex", "vertices").c_str(),
        count_of(out.mesh_stats.degenerate_dropped, "degenerate triangle", "degenerate triangles")
            .c_str());

  Aabb bounds = out.mesh.bounds();
  GridTransform grid;
  if (s.voxel_size > 0)
    grid = GridTransform::fit_voxel_size(bounds, s.voxel_size);
  else
    grid = GridTransform::fit(bounds, s.resolution);

  // The mesh stays in memory for the whole build.
  const uint64_t need = estimate_build_bytes(out.mesh, grid) + mesh_bytes(out.mesh);
  if (s.dag && (s.out_of_core || (budget && need > budget))) {
    // svdag §3 "Implementation details": sub-volumes voxelized and reduced
    // one at a time, peak memory bounded by the budget.
    dag::OutOfCoreOptions oo;
    oo.mode = s.mode;
    oo.attributes = s.dag_attributes;
    oo.memory_budget = budget;
    oo.cell_size = s.cell_size;
    out.dag = dag::build_dag_out_of_core(out.mesh, grid, oo, &out.ooc);
    // esvo §5.5 blocks over the Morton-order array (dag.hpp); from the same
    // raw values as in core, so the scene bytes stay identical.
    if (s.attributes == esvo::AttributeFormat::Compressed) out.dag.compress_attributes();
    out.out_of_core = true;
    out.leaf_voxels = out.dag.leaf_voxels;
    out.voxelize_seconds = out.ooc.voxelize_seconds;
    out.octree_seconds = out.ooc.reduce_seconds;
    timer.mark("out-of-core DAG build");
    return out;
  }
  esvo::BuildOptions build_options;
  build_options.attributes = s.attributes;
  if (s.contours) {
    build_options.contours = true;
    build_options.max_level = s.max_level;
    build_options.geometry_error = s.geometry_error;
    build_options.color_error = s.color_error;
    build_options.normal_error = s.normal_error;
  }
  // esvo §7.1-7.3 "memory bounded": one cell's full-depth voxels at a time,
  // only the kept (variable-depth) octree is held; same bytes as in core.
  // Without a color/normal tolerance it voxelizes every cell once and is as
  // fast as the in-core build (docs/notes-vardepth.md), so it is the default
  // there; with one, the attribute tests stream the cells two more times
  // (with compressed attributes also once per §7.3 decoded-leaf round for
  // the cells holding a leaf to test), so only when the in-core estimate
  // exceeds the budget (or when asked).
  const bool attribute_tolerance = s.color_error >= 0 || s.normal_error >= 0;
  if (!s.dag && s.contours &&
      (s.out_of_core || (budget && need > budget) || !attribute_tolerance)) {
    VoxelizeOptions vo;
    vo.mode = s.mode;
    vo.attributes = true;
    out.octree = esvo::build_octree_cells(out.mesh, grid, vo, build_options, s.cell_size, budget,
                                          &out.esvo_cells);
    out.out_of_core = true;
    out.leaf_voxels = out.esvo_cells.voxels;
    out.octree_seconds = timer.mark("cell-by-cell octree build");
    return out;
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
    vo.attributes = !s.dag || s.dag_attributes;
    voxels = voxelize(out.mesh, grid, vo);
  }
  out.voxelize_seconds = timer.mark("voxelize");
  out.leaf_voxels = voxels.size();
  if (voxels.size() == 0) throw Error("the mesh produced no voxels");
  if (s.brickmap) {
    out.brickmap = std::make_shared<brickmap::World>(brickmap::build_world(voxels));
    out.octree_seconds = timer.mark("brickmap build");
    return out;
  }
  if (s.dag) {
    out.dag = dag::build_dag(voxels);
    if (s.attributes == esvo::AttributeFormat::Compressed) out.dag.compress_attributes();
    out.octree_seconds = timer.mark("DAG build");
    return out;
  }
  if (s.contours) {
    out.octree = esvo::build_octree(voxels, out.mesh, build_options);
  } else {
    out.octree = esvo::build_octree(voxels, build_options);
  }
  out.octree_seconds = timer.mark("octree build");
  return out;
}

}  // namespace voxcast::cli
