#pragma once
// `voxcast render` of a slice file (esvo §7): the streamed ESVO, frame by
// frame (cmd_render_sliced.cpp). cmd_render.cpp hands over when the scene
// is a slice file.
#include <string>
#include <vector>

#include "camera_options.hpp"
#include "voxcast/render.hpp"

namespace voxcast::cli {

struct SlicedRender {
  std::string input, output, path, budget;
  const CameraArgs* camera = nullptr;
  int frames = 1;
  std::vector<std::string> frame_files;  // empty, or one image per frame (--write-frames)
};

/// `opt`: the render options parsed by `voxcast render` (size, LOD, light);
/// the camera comes from --path (K frames spread over its time span) or the
/// camera options (the same view K times).
int render_sliced(const SlicedRender& args, RenderOptions opt);

}  // namespace voxcast::cli
