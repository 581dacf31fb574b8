#pragma once
// Comparing voxel sets across formats that keep positions only relative to
// the occupied box (.vox): header-only, shared by tests and fuzz targets.
#include <algorithm>
#include <cstdint>
#include <vector>

#include "voxcast/morton.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast::testing {

/// Each voxel's Morton code after shifting the set so that its lowest
/// occupied coordinate is 0 on every axis, in the order of `s.codes` (the
/// shift changes the Morton order: sort before comparing sets).
inline std::vector<uint64_t> box_relative_codes(const VoxelSet& s) {
  uint32_t lo[3] = {UINT32_MAX, UINT32_MAX, UINT32_MAX};
  for (uint64_t c : s.codes) {
    const MortonCoord m = morton_decode(c);
    lo[0] = std::min(lo[0], m.x), lo[1] = std::min(lo[1], m.y), lo[2] = std::min(lo[2], m.z);
  }
  std::vector<uint64_t> out;
  out.reserve(s.codes.size());
  for (uint64_t c : s.codes) {
    const MortonCoord m = morton_decode(c);
    out.push_back(morton_encode(m.x - lo[0], m.y - lo[1], m.z - lo[2]));
  }
  return out;
}

}  // namespace voxcast::testing
