#pragma once
// `voxcast render WORLD --stream --frames K [--path P] --budget B`: a
// brickmap world streamed from its file (brickmap_stream.hpp), frame after
// frame, printing per frame the Mrays/s and the bricks uploaded (brickmap
// paper Figure 23). cmd_render.cpp registers the options and hands over.
#include <CLI/CLI.hpp>
#include <functional>
#include <string>
#include <vector>

#include "voxcast/camera.hpp"
#include "voxcast/render.hpp"

namespace voxcast::cli {

struct StreamArgs {
  bool enabled = false;
  int frames = 1;
  std::string budget;  // empty: 512M for brickmap worlds, unlimited for slice files
  int uploads = 4096;
  int passes = 1;
  bool no_hidden_removal = false;
  bool dxt1 = false;
};

void add_stream_options(CLI::App* cmd, StreamArgs& args);

/// Renders args.frames frames of `world` into `output` (the last frame).
/// Cameras: `path` spread over the frames when not empty, else
/// auto_camera(occupied bounds, width, height) for every frame.
int render_stream(const StreamArgs& args, const std::string& world, const std::string& output,
                  RenderOptions options, const std::vector<Camera>& path,
                  const std::function<Camera(const Aabb&, int, int)>& auto_camera);

}  // namespace voxcast::cli
