#pragma once
// Render options the image-comparison tests share.
#include "voxcast/render.hpp"

namespace voxcast::testing {

/// A width x height render from `camera` with the depth image (the hit
/// distances the oracles compare), at `lod_pixels` (0 = finest level).
inline RenderOptions depth_render_options(const Camera& camera, int width, int height,
                                          float lod_pixels = 0.f) {
  RenderOptions ro;
  ro.width = width;
  ro.height = height;
  ro.camera = camera;
  ro.lod_pixels = lod_pixels;
  ro.want_depth = true;
  return ro;
}

}  // namespace voxcast::testing
