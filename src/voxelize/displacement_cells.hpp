#pragma once
// Cell-restricted displacement voxelization (esvo §7.4) for the top-down
// slice builder (src/esvo/slice_build.cpp). Not a public interface.
//
// Contract: for any aligned cube of the grid, voxelize() over the tasks
// binned to it (bin(), or every task) returns exactly the voxels and
// attribute values that voxelize_displaced() returns for the whole mesh,
// restricted to the cube. Both run this code: a task's pieces are split in
// the same order, pieces whose bound misses the cube (with a voxel of
// slack) are culled, and a voxel's marks are summed in the same order (per
// task in emission order, then over the tasks in task order).
#include <cstdint>
#include <vector>

#include "voxcast/displacement.hpp"
#include "voxelize/cell.hpp"

namespace voxcast::detail {

class DisplacedVoxelizer {
 public:
  /// The displacement primitives of `mesh`, cut into tasks of about 64
  /// voxels a side (the references must outlive this object).
  DisplacedVoxelizer(const Mesh& mesh, const DisplacementMap& map, float scale,
                     const GridTransform& grid);
  ~DisplacedVoxelizer();
  size_t task_count() const;
  /// Every task binned (CellBin::tri: the task index) into the cells of side
  /// 2^bits its displaced bound (plus a voxel) overlaps, sorted by (cell,
  /// task); tasks outside the grid are in no cell.
  std::vector<CellBin> bin(int bits) const;
  /// The voxels of the cube [cube_lo, cube_lo + cube_size)^3 from the tasks
  /// `tasks` (ascending; every task binned to the cube must be listed).
  VoxelSet voxelize(const uint32_t* tasks, size_t task_count, const uint32_t cube_lo[3],
                    uint32_t cube_size, const VoxelizeOptions& options,
                    DisplacementStats* stats = nullptr) const;

 private:
  struct Task;
  const Mesh& mesh_;
  const DisplacementMap& map_;
  float scale_;
  GridTransform grid_;
  std::vector<Task> tasks_;
};

}  // namespace voxcast::detail
