#pragma once
// Voxel sets beyond the surface: normals from occupancy (for voxels that come
// without a surface, e.g. from .vox files) and solid voxelization.
#include <cstdint>
#include <vector>

#include "voxcast/math.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast {

/// Per voxel of `voxels` (codes sorted, unique): the normalized sum of the
/// directions to its empty 26-neighbours (grid cells outside the grid count as
/// empty), +y where they cancel (no empty neighbour, or a symmetric one).
std::vector<Vec3> occupancy_normals(const VoxelSet& voxels);

struct SolidFillStats {
  uint64_t interior_voxels = 0;    // added to the surface
  uint64_t columns = 0;            // z columns that cross the mesh
  uint64_t ambiguous_columns = 0;  // decided by the winding number (see fill_solid)
  uint64_t winding_evaluations = 0;
};

/// The surface voxels plus every voxel whose center lies inside `mesh`.
/// Inside is decided per z column by the parity of the ray through the voxel
/// centers (a consistent tie rule on shared edges and vertices, so a closed
/// mesh is crossed an even number of times). A column whose crossings do not
/// alternate entering/leaving (odd count, or two entries in a row: a hole, a
/// flipped or doubled face, a non-watertight mesh) is decided instead by the
/// generalized winding number (> 1/2 = inside), evaluated at the midpoint of
/// each span between consecutive crossings. Interior voxels take the color of
/// the surface voxel below them in their column (the one the column entered
/// through), occupancy normals and weight 1. Deterministic. Throws
/// voxcast::Error when more than `max_voxels` (0: no limit) would be added.
VoxelSet fill_solid(const Mesh& mesh, const VoxelSet& surface, SolidFillStats* stats = nullptr,
                    uint64_t max_voxels = 0);

/// Generalized winding number of `mesh` at `p` (sum of the triangles' signed
/// solid angles / 4 pi): 1 inside a closed outward-oriented mesh, 0 outside.
double winding_number(const Mesh& mesh, Vec3d p);

}  // namespace voxcast
