#pragma once
// OpenEXR output: one file, any number of named channels taken from Images
// (e.g. R, G, B color as half, Z depth and N.x, N.y, N.z normals as float:
// the render AOVs), scan lines top to bottom, ZIP compression.
#include <filesystem>
#include <string>
#include <vector>

#include "voxcast/image.hpp"

namespace voxcast {

struct ExrChannel {
  std::string name;              // e.g. "R", "Z", "N.x"
  const Image* image = nullptr;  // every channel's image has the same size
  int component = 0;             // which of the image's channels
  bool half = true;              // 16-bit half, else 32-bit float
};

/// Writes the channels (sorted by name, as EXR stores them) atomically.
/// Throws voxcast::Error for no channel, mismatched sizes or an I/O failure.
void write_exr(const std::filesystem::path& path, const std::vector<ExrChannel>& channels);

/// write_image's .exr: 1 channel -> Y, 2 -> Y, A, 3 -> R, G, B, 4 -> R, G,
/// B, A; half floats, linear (as the image holds them).
void write_exr_image(const std::filesystem::path& path, const Image& image);

}  // namespace voxcast
