#pragma once
// Helpers shared by the voxel-set readers and writers (vox.cpp, binvox.cpp).
#include <cstdint>
#include <filesystem>
#include <vector>

#include "voxcast/error.hpp"
#include "voxcast/voxel_io.hpp"

namespace voxcast::detail {

/// options.memory_budget, or 90% of the available memory when it is 0.
uint64_t voxel_budget(const VoxelReadOptions& options);
/// Throws voxcast::Error when `voxels` voxel-set entries exceed `budget` bytes.
void check_voxel_count(uint64_t voxels, uint64_t budget, const char* what);
/// The whole file, refused before reading when it is larger than `budget`.
std::vector<uint8_t> read_file_bytes(const std::filesystem::path& path, uint64_t budget);
/// parse(read_file_bytes(path)), its errors prefixed with the file name.
template <class Parse>
VoxelSet read_voxel_file(const std::filesystem::path& path, const VoxelReadOptions& options,
                         Parse parse) {
  const auto bytes = read_file_bytes(path, voxel_budget(options));
  try {
    return parse(bytes, options);
  } catch (const Error& e) {
    throw Error("'" + path.string() + "': " + e.what());
  }
}

/// Occupancy normals and unit weights for a set read from a file.
void finish_voxel_set(VoxelSet& set);
/// Origin 0, voxel size 1, the smallest power-of-two resolution >= extent.
GridTransform unit_grid(uint32_t extent);

struct Bounds3 {
  uint32_t lo[3] = {UINT32_MAX, UINT32_MAX, UINT32_MAX};
  uint32_t hi[3] = {0, 0, 0};
};
/// Grid-coordinate box of the voxels (lo > hi when there are none).
Bounds3 occupied_bounds(const VoxelSet& set);

}  // namespace voxcast::detail
