// Snowfall on a brickmap world (§5.5; brickmap.hpp snow_step): one voxel of
// snow on top of the highest solid voxel of some columns, through stamp().
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <vector>

#include "voxcast/brickmap.hpp"
#include "voxcast/error.hpp"
#include "voxcast/morton.hpp"

namespace voxcast::brickmap {

EditResult snow_step(World& w, uint32_t step, const SnowOptions& o) {
  if (!(o.rate >= 0 && o.rate <= 1)) throw Error("brickmap snow: the rate must be in [0, 1]");
  const GridTransform& g = w.grid();
  const std::array<uint32_t, 3>& d = w.dims();
  const uint32_t top = std::min(g.resolution, d[1] * uint32_t(kBrickSide));  // voxels in y
  const uint64_t threshold = uint64_t(o.rate * 65536.0);
  VoxelSet snow;
  snow.grid = g;
  // Brick rows (one z) in parallel, each into its own list; the lists are
  // joined in row order, so the set is the same whatever the threads.
  std::vector<std::vector<uint64_t>> rows(d[2]);
  std::atomic<bool> not_resident{false};
  tbb::parallel_for(uint32_t(0), d[2], [&](uint32_t k) {
    std::vector<uint64_t>& codes = rows[k];
    for (uint32_t i = 0; i < d[0]; ++i) {
      // The highest solid voxel of each of the 64 voxel columns of this
      // brick column, walking its cells down from the top.
      int highest[64];
      std::fill(highest, highest + 64, -1);
      int open = 64;
      for (uint32_t j = d[1]; j-- > 0 && open > 0;) {
        const uint32_t cell = w.cell(w.cell_index(i, j, k));
        if (cell == 0) continue;
        if (cell_state(cell) != kStateResident) {
          not_resident = true;
          return;
        }
        const Brick& b = w.brick(cell_brick(cell));
        for (int c = 0; c < 64; ++c) {
          if (highest[c] >= 0) continue;
          const int x = c & 7, z = c >> 3;
          for (int y = 7; y >= 0; --y)
            if ((b.mask[z] >> voxel_bit(uint32_t(x), uint32_t(y), 0)) & 1) {
              highest[c] = int(j) * kBrickSide + y;
              --open;
              break;
            }
        }
      }
      for (int c = 0; c < 64; ++c) {
        if (highest[c] < 0 || uint32_t(highest[c]) + 1 >= top) continue;
        const uint32_t x = i * kBrickSide + uint32_t(c & 7), z = k * kBrickSide + uint32_t(c >> 3);
        // Where it falls this step: a hash of the column, the step and the seed.
        uint64_t h = (uint64_t(x) << 32 | z) ^ (uint64_t(step) * 0x9E3779B97F4A7C15ull) ^ o.seed;
        h = (h ^ (h >> 31)) * 0xbf58476d1ce4e5b9ull;
        h = (h ^ (h >> 27)) * 0x94d049bb133111ebull;
        if (((h ^ (h >> 31)) & 0xFFFF) >= threshold) continue;
        codes.push_back(morton_encode(x, uint32_t(highest[c]) + 1, z));
      }
    }
  });
  if (not_resident) throw Error("brickmap snow: a brick of the world is not resident");
  size_t total = 0;
  for (const auto& r : rows) total += r.size();
  snow.codes.reserve(total);
  for (const auto& r : rows) snow.codes.insert(snow.codes.end(), r.begin(), r.end());
  tbb::parallel_sort(snow.codes.begin(), snow.codes.end());
  snow.colors.assign(snow.codes.size(), o.color);
  snow.normals.assign(snow.codes.size(), Vec3{0, 1, 0});
  return stamp(w, snow, EditOp::Add, o.color);
}

}  // namespace voxcast::brickmap
