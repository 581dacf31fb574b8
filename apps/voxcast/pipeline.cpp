#include "pipeline.hpp"

#include <cmath>
#include <cstdio>
#include <string>

#include "commands.hpp"
#include "voxcast/error.hpp"
#include "voxcast/progress.hpp"
#include "voxcast/system.hpp"

namespace voxcast::cli {

VoxelizationMode parse_voxelization(const std::string& name) {
  if (name == "conservative") return VoxelizationMode::Conservative;
  if (name == "6-separating" || name == "six-separating") return VoxelizationMode::SixSeparating;
  throw Error("--voxelization: '" + name + "' is not conservative or 6-separating");
}

const char* voxelization_name(VoxelizationMode mode) {
  return mode == VoxelizationMode::Conservative ? "conservative" : "6-separating";
}

esvo::AttributeFormat parse_attribute_format(const std::string& name) {
  if (name == "raw") return esvo::AttributeFormat::Raw;
  if (name == "compressed") return esvo::AttributeFormat::Compressed;
  throw Error("--attributes: '" + name + "' is not raw or compressed");
}

const char* attribute_format_name(esvo::AttributeFormat format) {
  return format == esvo::AttributeFormat::Compressed ? "compressed" : "raw";
}

uint64_t estimate_build_bytes(const Mesh& mesh, const GridTransform& grid) {
  // A conservatively voxelized plane of area A (in voxel units) with unit
  // normal n covers about A * (|nx|+|ny|+|nz|) voxels, plus a band along its
  // edges; every voxel also appears once per extra triangle sharing it.
  double inv = 1.0 / grid.voxel_size;
  double pairs = 0;
  for (size_t t = 0; t < mesh.triangle_count(); ++t) {
    Vec3 a = mesh.positions[mesh.indices[3 * t]], b = mesh.positions[mesh.indices[3 * t + 1]],
         c = mesh.positions[mesh.indices[3 * t + 2]];
    Vec3 n = cross(b - a, c - a);
    double area = 0.5 * length(n) * inv * inv;
    double l1 = length(n) > 0 ? (std::fabs(n.x) + std::fabs(n.y) + std::fabs(n.z)) / length(n) : 1;
    double perim = (length(b - a) + length(c - b) + length(a - c)) * inv;
    pairs += area * l1 + 2.0 * perim + 4.0;
  }
  // Per pair: 16-byte record + sort scratch; per voxel (~pairs/2): attributes
  // (40 B), octree levels and layout (~40 B).
  return uint64_t(pairs * 32.0 + pairs * 0.5 * 80.0);
}

BuiltScene build_scene(const BuildSettings& s) {
  BuiltScene out;
  StageTimer timer(s.verbose);
  out.mesh = load_mesh(s.mesh_path, &out.mesh_stats);
  out.load_seconds = timer.mark("load mesh");
  for (const std::string& w : out.mesh_stats.warnings)
    std::fprintf(stderr, "voxcast: warning: %s\n", w.c_str());
  if (s.verbose || out.mesh_stats.degenerate_dropped)
    std::fprintf(stderr, "mesh: %zu triangles, %zu vertices (%zu degenerate triangles dropped)\n",
                 out.mesh.triangle_count(), out.mesh.positions.size(),
                 out.mesh_stats.degenerate_dropped);

  Aabb bounds = out.mesh.bounds();
  GridTransform grid;
  if (s.voxel_size > 0)
    grid = GridTransform::fit_voxel_size(bounds, s.voxel_size);
  else
    grid = GridTransform::fit(bounds, s.resolution);

  uint64_t budget = s.memory_budget;
  if (budget == 0) budget = uint64_t(double(available_memory_bytes()) * 0.9);
  uint64_t need = estimate_build_bytes(out.mesh, grid);
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
