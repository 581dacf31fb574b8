#pragma once
// Tiled multi-threaded renderer over any VoxelStructure.
#include <cstdint>

#include "voxcast/camera.hpp"
#include "voxcast/image.hpp"
#include "voxcast/structure.hpp"

namespace voxcast {

struct RenderOptions {
  int width = 1024, height = 768;
  Camera camera;
  /// LOD: stop at voxels whose projection is <= this many pixels (0 = finest level).
  float lod_pixels = 1.f;
  Vec3 light_dir = normalize(Vec3{-0.4f, -1.0f, -0.6f});  // direction the light travels
  Color background{0.08f, 0.09f, 0.11f, 1.f};
  bool want_depth = false;   // fill RenderResult::depth (world distance, +inf on miss)
  bool want_normal = false;  // fill RenderResult::normal (n*0.5+0.5)
  int tile_size = 16;
};

struct RenderResult {
  Image color;   // linear RGB
  Image depth;   // 1 channel
  Image normal;  // 3 channels
  uint64_t rays = 0, hits = 0;
  double seconds = 0;  // wall time of the ray-cast loop
};

RenderResult render(const VoxelStructure& structure, const RenderOptions& options);

}  // namespace voxcast
