// VoxelSet -> brickmap world (include/voxcast/brickmap.hpp). The set's
// Morton order groups the voxels by brick already: the top bits of a code
// above the lowest nine are the Morton code of its 8^3 brick.
#include <algorithm>
#include <array>

#include "voxcast/brickmap.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/morton.hpp"

namespace voxcast::brickmap {

World build_world(const VoxelSet& voxels, const BuildOptions& options) {
  const bool attributes = !voxels.colors.empty();
  if (attributes &&
      (voxels.colors.size() != voxels.size() || voxels.normals.size() != voxels.size()))
    throw Error("brickmap: the voxel set's attribute arrays do not match its voxels");
  World world(voxels.grid, options.normals && attributes);
  const uint32_t n = voxels.grid.resolution;
  // Voxels without input attributes: linear gray, as ESVO (esvo.hpp).
  const uint32_t gray = esvo::encode_color_abgr({0.5f, 0.5f, 0.5f, 1.f});
  std::array<uint32_t, kBrickVoxels> color_at{}, normal_at{};
  std::array<uint32_t, kBrickVoxels> colors{}, normals{};
  for (size_t k = 1; k < voxels.size(); ++k)
    if (voxels.codes[k] <= voxels.codes[k - 1])
      throw Error("brickmap: the voxel set's codes are not sorted and unique");
  std::vector<uint64_t> cells;
  size_t i = 0;
  while (i < voxels.size()) {
    const uint64_t brick_code = voxels.codes[i] >> (3 * kBrickLog2);
    uint64_t mask[8] = {};
    size_t end = i;
    for (; end < voxels.size() && voxels.codes[end] >> (3 * kBrickLog2) == brick_code; ++end) {
      const MortonCoord c = morton_decode(voxels.codes[end]);
      if (c.x >= n || c.y >= n || c.z >= n)
        throw Error("brickmap: voxel outside the " + std::to_string(n) + "^3 grid");
      const uint32_t bit = voxel_bit(c.x & 7, c.y & 7, c.z & 7);
      mask[bit >> 6] |= uint64_t(1) << (bit & 63);
      color_at[bit] = attributes ? esvo::encode_color_abgr(voxels.colors[end]) : gray;
      if (world.has_normals()) normal_at[bit] = esvo::encode_normal_cube(voxels.normals[end]);
    }
    // Colors in bit order (§4.1: a voxel's color is at the popcount of the
    // mask below it).
    int count = 0;
    for (uint32_t w = 0; w < 8; ++w)
      for (uint64_t m = mask[w]; m != 0; m &= m - 1) {
        const uint32_t bit = w * 64 + uint32_t(std::countr_zero(m));
        colors[size_t(count)] = color_at[bit];
        normals[size_t(count)] = normal_at[bit];
        ++count;
      }
    const MortonCoord b = morton_decode(brick_code);
    const uint64_t cell = world.cell_index(b.x, b.y, b.z);
    world.set_brick(cell, mask, colors.data(), normals.data(), 0, nullptr, false);
    cells.push_back(cell);
    i = end;
  }
  world.update_occupancy(cells);  // occupancy, pyramid and clearances once for all
  return world;
}

}  // namespace voxcast::brickmap
