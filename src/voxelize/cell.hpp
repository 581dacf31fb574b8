#pragma once
// Cell-restricted voxelization for out-of-core builds (svdag §3 "Implementation
// details": the grid is split into sub-volumes that are voxelized and reduced
// one at a time). Not a public interface; used by src/dag/build_ooc.cpp and the
// ESVO cell-by-cell build (src/esvo/build_cells.cpp).
//
// Contract: for any aligned cube ("cell") of the grid, voxelize_cell() returns
// exactly the voxels (and, with attributes, exactly the attribute values) that
// voxelize() returns for the whole mesh, restricted to that cell. The
// rasterizer evaluates the same per-voxel predicates on the same grid-unit
// vertices as voxelize.cpp and only narrows the loop bounds to the cell, so
// the restriction is exact (tests/test_dag_ooc.cpp checks it).
#include <array>
#include <cstdint>
#include <vector>

#include "voxcast/mesh.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast::detail {

/// Mesh vertices in grid units, computed exactly as voxelize() does
/// ((position - origin) * (1 / voxel_size) in double).
std::vector<std::array<double, 3>> grid_vertices(const Mesh& mesh, const GridTransform& grid);

/// Inclusive voxel range [lo, hi] of the bounding box of triangle `t` clipped
/// to the grid, as the rasterizer computes it; false if it misses the grid.
bool triangle_voxel_range(const std::vector<std::array<double, 3>>& gv, const Mesh& mesh, size_t t,
                          uint32_t resolution, uint32_t lo[3], uint32_t hi[3]);

/// The voxels of the cube [cell_lo, cell_lo + cell_size)^3 covered by the
/// triangles `tris` (ascending triangle indices; every triangle of the mesh
/// that touches the cell must be listed). Codes are global Morton codes,
/// ascending and unique; attributes follow VoxelizeOptions::attributes and
/// equal voxelize()'s bit for bit. options.progress is not used.
VoxelSet voxelize_cell(const Mesh& mesh, const GridTransform& grid,
                       const std::vector<std::array<double, 3>>& gv, const uint32_t* tris,
                       size_t tri_count, const uint32_t cell_lo[3], uint32_t cell_size,
                       const VoxelizeOptions& options);

/// One (cell, triangle) entry of the triangle bins of a cell-by-cell build.
struct CellBin {
  uint64_t cell;  // Morton code of the cell at the cell level
  uint32_t tri;
  bool operator<(const CellBin& o) const { return cell != o.cell ? cell < o.cell : tri < o.tri; }
};

/// Every triangle binned into the cells of side 2^bits its voxel bounding
/// box overlaps, sorted by (cell Morton code, triangle): cells in Morton
/// order, each cell's triangles ascending as voxelize_cell() needs them.
std::vector<CellBin> bin_triangles(const Mesh& mesh, const std::vector<std::array<double, 3>>& gv,
                                   const GridTransform& grid, int bits);

/// Estimated (voxel, triangle) pairs of one triangle (grid units): area *
/// L1 norm of the unit normal + an edge band (as the CLI's in-core estimate).
double triangle_pairs(const double v[3][3]);

/// Bytes held by the mesh's arrays.
uint64_t mesh_bytes(const Mesh& mesh);

/// Memory estimate of a cell-by-cell build with cells of side 2^bits.
struct CellPlan {
  int bits = 0;               // cell side = 2^bits voxels
  uint64_t bins = 0;          // (cell, triangle) entries
  double max_cell_pairs = 0;  // estimated pairs of the fullest cell
  uint64_t fixed_bytes = 0;   // mesh + vertices + bins
  uint64_t cell_bytes = 0;    // working set of the fullest cell
};

/// The estimate for cells of side 2^bits, with `bytes_per_pair` bytes of
/// working set per estimated (voxel, triangle) pair of a cell.
CellPlan plan_cells(const Mesh& mesh, const std::vector<std::array<double, 3>>& gv,
                    const GridTransform& grid, int bits, double bytes_per_pair);

/// The voxels of one triangle (grid units) inside the inclusive box
/// [box_lo, box_hi] of an N^3 grid, appended unsorted (possibly duplicated).
void triangle_voxels_in_box(const double tri[3][3], uint32_t resolution, VoxelizationMode mode,
                            const int box_lo[3], const int box_hi[3], std::vector<uint64_t>& out);

}  // namespace voxcast::detail
