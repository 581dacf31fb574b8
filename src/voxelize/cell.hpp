#pragma once
// Cell-restricted voxelization for out-of-core builds (svdag §3 "Implementation
// details": the grid is split into sub-volumes that are voxelized and reduced
// one at a time). Not a public interface; used by src/dag/build_ooc.cpp.
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

/// The voxels of one triangle (grid units) inside the inclusive box
/// [box_lo, box_hi] of an N^3 grid, appended unsorted (possibly duplicated).
void triangle_voxels_in_box(const double tri[3][3], uint32_t resolution, VoxelizationMode mode,
                            const int box_lo[3], const int box_hi[3], std::vector<uint64_t>& out);

}  // namespace voxcast::detail
