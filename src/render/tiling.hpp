#pragma once
// Image tiling shared by the voxel renderer and the Embree reference so that
// both are measured with the same work split: square tiles handed out one at
// a time by TBB (work stealing balances the cheap all-miss tiles against the
// expensive ones).
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/partitioner.h>

#include <algorithm>
#include <chrono>

namespace voxcast::detail {

struct Tile {
  int x0, y0, x1, y1;  // pixel range [x0, x1) x [y0, y1)
};

/// Calls body(tile) for every tile of a width x height image in parallel and
/// returns the wall time in seconds.
template <class Body>
double for_each_tile(int width, int height, int tile_size, const Body& body) {
  const int ts = std::max(1, tile_size);
  const int tiles_x = (width + ts - 1) / ts;
  const int tiles_y = (height + ts - 1) / ts;
  const auto t0 = std::chrono::steady_clock::now();
  tbb::parallel_for(
      tbb::blocked_range<int>(0, tiles_x * tiles_y, 1),
      [&](const tbb::blocked_range<int>& r) {
        for (int i = r.begin(); i != r.end(); ++i) {
          const int tx = i % tiles_x, ty = i / tiles_x;
          Tile t{tx * ts, ty * ts, std::min(width, (tx + 1) * ts), std::min(height, (ty + 1) * ts)};
          body(t);
        }
      },
      tbb::simple_partitioner());
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace voxcast::detail
