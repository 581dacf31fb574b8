#pragma once
// Memory-bounded variable-depth ESVO build (esvo §7.1-7.3, "build in
// parallel over subtrees, memory bounded"): the grid is split into cells
// that are voxelized one at a time (voxelize/cell.hpp); only the pruned
// octree is kept. Private to the library and the CLI; defined in builder.cpp.
#include <cstdint>

#include "voxcast/esvo.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast::esvo {

struct CellBuildStats {
  uint32_t cell_size = 0;        // voxels per cell side
  uint64_t cells = 0;            // non-empty cells
  uint64_t refined_cells = 0;    // cells whose subtree was planned (pass 3)
  uint64_t max_cell_voxels = 0;  // full-depth voxels of the fullest cell
  uint64_t voxels = 0;           // full-depth voxels in all
  uint64_t estimated_bytes = 0;  // fixed parts + the fullest cell's working set
  bool in_core = false;          // never set any more (every option mix streams)
  // Compressed attributes with a color/normal tolerance (§7.3 decoded-leaf
  // loop): layout rounds, cells re-planned for failing leaves inside them,
  // and failing leaves at or above the cells' roots (forced in the top plan).
  uint32_t decoded_rounds = 0;
  uint64_t replanned_cells = 0;
  uint64_t forced_top_leaves = 0;
};

/// Equals build_octree(voxelize(mesh, grid, voxelize), mesh, options) byte
/// for byte (options.contours must be set), holding at most one cell's
/// full-depth voxels at a time. `cell_size`: voxels per cell side (a power
/// of two, 2 .. resolution / 2); 0 = the largest whose estimated working set
/// fits half of `memory_budget` (bytes; 0 = 90% of free memory) after the
/// mesh and triangle bins. Compressed attributes with a color or normal
/// tolerance run the in-core build's decoded-leaf loop, streaming only the
/// cells that hold a leaf to test in each round.
EsvoOctree build_octree_cells(const Mesh& mesh, const GridTransform& grid,
                              const VoxelizeOptions& voxelize, const BuildOptions& options,
                              uint32_t cell_size, uint64_t memory_budget,
                              CellBuildStats* stats = nullptr);

}  // namespace voxcast::esvo
