// Image export (PNG via libpng's simplified API, PFM by hand), reading back,
// the sRGB transfer functions and atomic file replacement.
#include <fcntl.h>
#include <fmt/format.h>
#include <png.h>
#include <unistd.h>

#include <algorithm>
#include <bit>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iterator>
#include <string>

#include "io/atomic_file.hpp"
#include "voxcast/error.hpp"
#include "voxcast/exr.hpp"
#include "voxcast/image.hpp"
#include "voxcast/progress.hpp"

namespace voxcast {

namespace {

std::string lower_extension(const std::filesystem::path& p) {
  std::string ext = p.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return char(std::tolower(c)); });
  return ext;
}

void check_image(const Image& im, const std::filesystem::path& path) {
  if (im.width <= 0 || im.height <= 0 || im.channels <= 0 ||
      im.pixels.size() != size_t(im.width) * size_t(im.height) * size_t(im.channels))
    throw Error(fmt::format("cannot write {}: image is {}x{}x{} but holds {} values", path.string(),
                            im.width, im.height, im.channels, im.pixels.size()));
}

uint8_t to_byte(float v) {
  // NaN would make the conversion undefined; treat it as black.
  if (!(v > 0.0f)) return 0;
  if (v >= 1.0f) return 255;
  return uint8_t(std::lround(v * 255.0f));
}

}  // namespace

std::vector<uint8_t> png_bytes(const Image& im, bool already_srgb) {
  const int nc = im.channels;
  // Alpha (the last channel of GA/RGBA) is coverage, not light: never sRGB-encode it.
  const bool has_alpha = nc == 2 || nc == 4;
  std::vector<uint8_t> bytes(im.pixels.size());
  for (size_t i = 0; i < bytes.size(); ++i) {
    float v = im.pixels[i];
    bool is_alpha = has_alpha && int(i % size_t(nc)) == nc - 1;
    if (!already_srgb && !is_alpha) v = linear_to_srgb(std::clamp(v, 0.0f, 1.0f));
    bytes[i] = to_byte(v);
  }
  return bytes;
}

namespace {
// Shares of a PNG write's time: the 8-bit conversion, libpng's sizing pass
// and its encode with the file write (measured once at 8192^2, RGB: 2.7 s,
// 1.7 s, 2.1 s).
constexpr double kPngWeights[3] = {0.42, 0.26, 0.32};

void write_png(const std::filesystem::path& path, const Image& im, bool already_srgb) {
  png_image img;
  std::memset(&img, 0, sizeof img);
  img.version = PNG_IMAGE_VERSION;
  img.width = png_uint_32(im.width);
  img.height = png_uint_32(im.height);
  switch (im.channels) {
    case 1:
      img.format = PNG_FORMAT_GRAY;
      break;
    case 2:
      img.format = PNG_FORMAT_GA;
      break;
    case 3:
      img.format = PNG_FORMAT_RGB;
      break;
    case 4:
      img.format = PNG_FORMAT_RGBA;
      break;
    default:
      throw Error(fmt::format("cannot write {}: PNG needs 1 to 4 channels, image has {}",
                              path.string(), im.channels));
  }
  const int nc = im.channels;
  // A bar on a terminal (a large image takes seconds): libpng's simplified
  // API reports nothing while it encodes, so the phases are one unit each:
  // the 8-bit conversion, the sizing pass (a full encode) and the encode.
  // (Named by the stage: the CLI writes to a temporary name, then renames.)
  Progress progress(
      "write image",
      {{"convert", kPngWeights[0]}, {"size", kPngWeights[1]}, {"encode", kPngWeights[2]}});
  progress.start_phase(0, 1);
  const std::vector<uint8_t> bytes = png_bytes(im, already_srgb);
  progress.advance();  // draws (the phases report only at their ends)
  progress.start_phase(1, 1);
  png_alloc_size_t size = 0;
  const png_int_32 stride = png_int_32(im.width * nc);
  if (!png_image_write_to_memory(&img, nullptr, &size, 0, bytes.data(), stride, nullptr))
    throw Error(fmt::format("cannot encode {}: {}", path.string(), img.message));
  progress.advance();
  progress.start_phase(2, 1);
  std::vector<uint8_t> encoded(size);
  if (!png_image_write_to_memory(&img, encoded.data(), &size, 0, bytes.data(), stride, nullptr))
    throw Error(fmt::format("cannot encode {}: {}", path.string(), img.message));
  write_file_atomic(path, encoded.data(), size);
  progress.advance();
  progress.finish();
}

void append_le_float(std::string& out, float v) {
  uint32_t bits = std::bit_cast<uint32_t>(v);
  for (int k = 0; k < 4; ++k) out.push_back(char((bits >> (8 * k)) & 0xff));
}

void write_pfm(const std::filesystem::path& path, const Image& im) {
  // PFM has no alpha: 2/4-channel images keep their color channels (gray or
  // RGB) and drop alpha, which is what every PFM consumer expects anyway.
  int out_c;
  if (im.channels == 1 || im.channels == 2)
    out_c = 1;
  else if (im.channels == 3 || im.channels == 4)
    out_c = 3;
  else
    throw Error(fmt::format("cannot write {}: PFM needs 1 to 4 channels, image has {}",
                            path.string(), im.channels));
  std::string out = fmt::format("{}\n{} {}\n-1.0\n", out_c == 3 ? "PF" : "Pf", im.width, im.height);
  out.reserve(out.size() + size_t(im.width) * size_t(im.height) * size_t(out_c) * 4);
  // PFM stores the bottom row first.
  for (int y = im.height - 1; y >= 0; --y)
    for (int x = 0; x < im.width; ++x) {
      const float* p = im.at(x, y);
      for (int c = 0; c < out_c; ++c) append_le_float(out, p[c]);
    }
  write_file_atomic(path, out.data(), out.size());
}

std::string read_whole_file(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error(fmt::format("cannot open {}: {}", path.string(), std::strerror(errno)));
  std::string data((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (in.bad()) throw Error(fmt::format("cannot read {}", path.string()));
  return data;
}

}  // namespace

void write_image(const std::filesystem::path& path, const Image& image, bool already_srgb) {
  std::string ext = lower_extension(path);
  if (ext != ".png" && ext != ".pfm" && ext != ".exr")
    throw Error(
        fmt::format("cannot write {}: unknown image extension '{}' (use .png, .pfm or .exr)",
                    path.string(), path.extension().string()));
  check_image(image, path);
  if (ext == ".exr") return write_exr_image(path, image);  // exr.cpp
  if (ext == ".png")
    write_png(path, image, already_srgb);
  else
    write_pfm(path, image);
}

Image read_pfm(const std::filesystem::path& path) {
  const std::string data = read_whole_file(path);
  const std::string name = path.string();
  size_t pos = 0;
  // Header: three whitespace-separated tokens after the magic, then exactly one
  // whitespace byte before the raster.
  auto token = [&]() -> std::string {
    while (pos < data.size() && std::isspace(static_cast<unsigned char>(data[pos]))) ++pos;
    size_t start = pos;
    while (pos < data.size() && !std::isspace(static_cast<unsigned char>(data[pos]))) ++pos;
    if (start == pos) throw Error(fmt::format("{}: truncated PFM header", name));
    return data.substr(start, pos - start);
  };
  std::string magic = token();
  int channels;
  if (magic == "PF")
    channels = 3;
  else if (magic == "Pf")
    channels = 1;
  else
    throw Error(fmt::format("{}: not a PFM file (magic '{}')", name, magic.substr(0, 8)));
  long w = 0, h = 0;
  double scale = 0;
  try {
    size_t used = 0;
    std::string tw = token(), th = token(), ts = token();
    w = std::stol(tw, &used);
    if (used != tw.size()) throw std::invalid_argument("w");
    h = std::stol(th, &used);
    if (used != th.size()) throw std::invalid_argument("h");
    scale = std::stod(ts, &used);
    if (used != ts.size()) throw std::invalid_argument("scale");
  } catch (const std::logic_error&) {
    throw Error(fmt::format("{}: malformed PFM header", name));
  }
  if (w <= 0 || h <= 0 || w > (1 << 20) || h > (1 << 20) || scale == 0 || !std::isfinite(scale))
    throw Error(fmt::format("{}: invalid PFM header ({}x{}, scale {})", name, w, h, scale));
  if (pos >= data.size()) throw Error(fmt::format("{}: truncated PFM header", name));
  ++pos;  // the single whitespace byte that ends the header
  const size_t count = size_t(w) * size_t(h) * size_t(channels);
  if (data.size() - pos < count * 4)
    throw Error(fmt::format("{}: PFM raster truncated ({} of {} bytes)", name, data.size() - pos,
                            count * 4));
  const bool little = scale < 0;  // the sign of the scale encodes the byte order
  // The scale's magnitude is ignored, as by most PFM readers: write_image always writes 1.
  Image im(int(w), int(h), channels);
  const auto* src = reinterpret_cast<const unsigned char*>(data.data()) + pos;
  for (long y = 0; y < h; ++y) {
    // File rows run bottom to top; Image rows top to bottom.
    float* dst = im.at(0, int(h - 1 - y));
    for (size_t i = 0; i < size_t(w) * size_t(channels); ++i, src += 4) {
      uint32_t bits = little ? (uint32_t(src[0]) | uint32_t(src[1]) << 8 | uint32_t(src[2]) << 16 |
                                uint32_t(src[3]) << 24)
                             : (uint32_t(src[3]) | uint32_t(src[2]) << 8 | uint32_t(src[1]) << 16 |
                                uint32_t(src[0]) << 24);
      dst[i] = std::bit_cast<float>(bits);
    }
  }
  return im;
}

Image read_png(const std::filesystem::path& path) {
  const std::string data = read_whole_file(path);
  png_image img;
  std::memset(&img, 0, sizeof img);
  img.version = PNG_IMAGE_VERSION;
  if (!png_image_begin_read_from_memory(&img, data.data(), data.size()))
    throw Error(fmt::format("{}: not a readable PNG ({})", path.string(), img.message));
  // Keep the file's channel layout; palette images expand to RGB(A).
  const bool color = (img.format & PNG_FORMAT_FLAG_COLOR) != 0;
  const bool alpha = (img.format & PNG_FORMAT_FLAG_ALPHA) != 0;
  int channels = color ? (alpha ? 4 : 3) : (alpha ? 2 : 1);
  img.format = color ? (alpha ? PNG_FORMAT_RGBA : PNG_FORMAT_RGB)
                     : (alpha ? PNG_FORMAT_GA : PNG_FORMAT_GRAY);
  if (img.width == 0 || img.height == 0 || img.width > (1u << 16) || img.height > (1u << 16)) {
    png_image_free(&img);
    throw Error(
        fmt::format("{}: unsupported PNG size {}x{}", path.string(), img.width, img.height));
  }
  std::vector<uint8_t> bytes(PNG_IMAGE_SIZE(img));
  if (!png_image_finish_read(&img, nullptr, bytes.data(), 0, nullptr)) {
    std::string msg = img.message;
    png_image_free(&img);
    throw Error(fmt::format("{}: corrupt PNG ({})", path.string(), msg));
  }
  Image im(int(img.width), int(img.height), channels);
  for (size_t i = 0; i < bytes.size() && i < im.pixels.size(); ++i)
    im.pixels[i] = float(bytes[i]) / 255.0f;
  return im;
}

void write_file_atomic(const std::filesystem::path& path, const void* bytes, size_t size) {
  io::AtomicFile file(path);
  file.write_at(0, bytes, size);
  file.commit();
}

}  // namespace voxcast
