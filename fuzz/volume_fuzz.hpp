#pragma once
// Shared by the volume-file fuzz targets: what a parser accepted must make a
// producer whose root brick can be produced (small volumes only, to keep
// each input fast).
#include <cstddef>
#include <vector>

#include "voxcast/gigavoxels.hpp"

inline void fuzz_volume_through_producer(const voxcast::giga::ScalarVolume& v) {
  using namespace voxcast;
  if (v.values.size() > (size_t(1) << 18)) return;
  const auto producer = giga::make_volume_producer(v);
  std::vector<giga::BrickVoxel> brick(giga::kBrickVoxels);
  (void)producer->produce(giga::NodeRegion{}, brick);
}
