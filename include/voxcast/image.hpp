#pragma once
// Images and their export. The format follows the file extension.
#include <cstdint>
#include <filesystem>
#include <vector>

#include "voxcast/math.hpp"

namespace voxcast {

/// Linear float RGB(A) image, rows top to bottom.
struct Image {
  int width = 0, height = 0, channels = 3;
  std::vector<float> pixels;  // width * height * channels
  Image() = default;
  Image(int w, int h, int c) : width(w), height(h), channels(c), pixels(size_t(w) * h * c, 0.f) {}
  float* at(int x, int y) { return &pixels[(size_t(y) * width + x) * channels]; }
  const float* at(int x, int y) const { return &pixels[(size_t(y) * width + x) * channels]; }
};

/// Writes .png (8-bit, sRGB-encoded from linear unless `already_srgb`),
/// .pfm (float, little-endian, scale -1, rows bottom to top; 1 or 3 channels).
/// Writes to a temporary file in the same directory and renames it into place.
/// Throws voxcast::Error for an unknown extension or an I/O failure.
void write_image(const std::filesystem::path& path, const Image& image, bool already_srgb = false);

/// The 8-bit samples write_image stores in a PNG (row-major, `channels` per
/// pixel): color channels sRGB-encoded from linear unless `already_srgb`,
/// alpha as is, NaN as 0. The viewer uploads these bytes as its texture so
/// that its screenshots equal `voxcast render`'s PNGs byte for byte.
std::vector<uint8_t> png_bytes(const Image& image, bool already_srgb = false);

/// Reads a PFM written by write_image (used by tests and tools).
Image read_pfm(const std::filesystem::path& path);
/// Reads an 8-bit PNG into [0,1] floats without color conversion.
Image read_png(const std::filesystem::path& path);

float srgb_to_linear(float c);
float linear_to_srgb(float c);

/// Writes `bytes` to `path` atomically: a temporary file next to it, fsync, rename.
void write_file_atomic(const std::filesystem::path& path, const void* bytes, size_t size);

}  // namespace voxcast
