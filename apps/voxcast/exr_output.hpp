#pragma once
// `render -o X.exr --aov depth,normal`: the color and the requested AOVs as
// layers of one OpenEXR file (exr.hpp).
#include <filesystem>
#include <string>

#include "voxcast/render.hpp"

namespace voxcast::cli {

struct ExrLayers {
  bool depth = false, normal = false;
};

/// "depth", "normal", "depth,normal" (empty: none); a UsageError for
/// anything else or when `output` is not an .exr file.
ExrLayers parse_exr_layers(const std::string& list, const std::string& output);

/// R, G, B (half, linear color), Z (float, world distance, +inf on a miss)
/// and N.x, N.y, N.z (float, the unit voxel normal, 0 on a miss).
void write_exr_layers(const std::filesystem::path& path, const RenderResult& result,
                      const ExrLayers& layers);

}  // namespace voxcast::cli
