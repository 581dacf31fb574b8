// Environment map files (include/voxcast/environment.hpp): Radiance .hdr
// with an own reader and writer, OpenEXR through OpenEXR's scan-line
// InputFile.
//
// Why not stb_image's HDR reader: it never returns on a truncated run-length
// encoded file (a run count read past the end is 0 and never advances), in
// Debian's libstb-dev 2.27 as in the older copy libdraco exports (seen while
// writing Environment.RefusesMalformedHdr and
// MeshImport.TruncatedTexturesAreRefusedQuickly). A reader of our own checks
// every byte against the end of the buffer; mesh textures in .hdr use it too.
#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfInputFile.h>
#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <climits>
#include <cmath>
#include <cstring>
#include <exception>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "voxcast/environment.hpp"
#include "voxcast/error.hpp"

namespace voxcast {
namespace {

void check_pixels(const Image& img, const char* what) {
  for (float p : img.pixels)
    if (!(p >= 0.f) || !std::isfinite(p))
      throw Error(fmt::format("{}: radiance values must be finite and >= 0", what));
}

// RGBE -> linear: the mantissas' centers times 2^(e - 128 - 8) (Radiance's
// colr_color); e = 0 is black.
void rgbe_to_float(const uint8_t* rgbe, float* out) {
  if (rgbe[3] == 0) {
    out[0] = out[1] = out[2] = 0.f;
    return;
  }
  const float f = std::ldexp(1.f, int(rgbe[3]) - 136);
  for (int k = 0; k < 3; ++k) out[k] = (float(rgbe[k]) + 0.5f) * f;
}

void float_to_rgbe(const float* in, uint8_t* rgbe) {
  float c[3];
  for (int k = 0; k < 3; ++k) c[k] = (in[k] >= 0.f && std::isfinite(in[k])) ? in[k] : 0.f;
  const float top = std::max({c[0], c[1], c[2]});
  if (!(top > 1e-32f)) {
    rgbe[0] = rgbe[1] = rgbe[2] = rgbe[3] = 0;
    return;
  }
  int e = 0;
  const float m = std::frexp(top, &e);  // top = m * 2^e, m in [0.5, 1)
  if (e > 127) {                        // beyond RGBE's range: the largest value it holds
    rgbe[0] = rgbe[1] = rgbe[2] = 255, rgbe[3] = 255;
    return;
  }
  const float scale = m * 256.f / top;
  for (int k = 0; k < 3; ++k) rgbe[k] = uint8_t(std::min(255.f, c[k] * scale));
  rgbe[3] = uint8_t(e + 128);
}

}  // namespace

// Radiance RGBE as Radiance, Photoshop, stb and most HDR tools write it: a
// "#?" line, header lines up to an empty one (FORMAT must be
// 32-bit_rle_rgbe when present; EXPOSURE and others are ignored), the
// resolution line "-Y H +X W" (rows top to bottom; other orientations are
// refused), then H scan lines, each either run-length encoded (2, 2, W >> 8,
// W & 255, then per channel runs "128 + n, value" and literals "n, n
// values"; widths 8..32767) or flat (W x 4 bytes). Every read is checked
// against the end of the buffer; the old Radiance run format (1, 1, 1, n
// pixels) is not supported: such pixels read as plain pixels.
Image parse_hdr(std::span<const uint8_t> bytes) {
  const uint8_t* p = bytes.data();
  const size_t n = bytes.size();
  size_t at = 0;
  // One header line without its '\n'; lines are short in real files.
  std::string text;
  auto line = [&] {
    text.clear();
    while (at < n && p[at] != '\n') {
      if (text.size() >= 4096) throw Error("hdr: header line too long");
      text.push_back(char(p[at++]));
    }
    if (at == n) throw Error("hdr: truncated header");
    ++at;
  };
  if (n < 2 || p[0] != '#' || p[1] != '?') throw Error("hdr: not a Radiance file (no #? header)");
  line();
  for (int lines = 0;; ++lines) {
    if (lines > 1024) throw Error("hdr: header too long");
    line();
    if (text.empty()) break;
    if (text.rfind("FORMAT=", 0) == 0 && text != "FORMAT=32-bit_rle_rgbe")
      throw Error("hdr: unsupported FORMAT (only 32-bit_rle_rgbe)");
  }
  line();
  long h = 0, w = 0;
  {
    // Exactly "-Y <digits> +X <digits>".
    const char* s = text.c_str();
    auto number = [&](long* v) {
      if (!std::isdigit(static_cast<unsigned char>(*s))) return false;
      *v = 0;
      for (; std::isdigit(static_cast<unsigned char>(*s)); ++s) {
        *v = *v * 10 + (*s - '0');
        if (*v > (1L << 30)) return false;
      }
      return true;
    };
    auto literal = [&](const char* l) {
      const size_t k = std::strlen(l);
      if (std::strncmp(s, l, k) != 0) return false;
      s += k;
      return true;
    };
    if (!literal("-Y ") || !number(&h) || !literal(" +X ") || !number(&w) || *s != '\0')
      throw Error("hdr: unsupported resolution line (only \"-Y H +X W\")");
  }
  if (w <= 0 || h <= 0 || uint64_t(w) * uint64_t(h) > kMaxEnvironmentPixels)
    throw Error(
        fmt::format("hdr: {}x{} pixels is outside 1..{} pixels", w, h, kMaxEnvironmentPixels));
  // Run-length encoding needs >= 2 bytes per 127 values of a channel: a file
  // far too short for its size is refused before the allocation.
  if (uint64_t(n - at) * 127 < uint64_t(w) * uint64_t(h) * 8)
    throw Error(fmt::format("hdr: {} bytes cannot hold {}x{} pixels", n - at, w, h));
  Image img(int(w), int(h), 3);
  std::vector<uint8_t> scan(size_t(w) * 4);
  auto need = [&](size_t k) {
    if (n - at < k) throw Error("hdr: truncated pixels");
  };
  for (long y = 0; y < h; ++y) {
    const bool rle = w >= 8 && w < 32768 && n - at >= 4 && p[at] == 2 && p[at + 1] == 2 &&
                     (p[at + 2] & 0x80) == 0;
    if (rle) {
      if ((long(p[at + 2]) << 8 | long(p[at + 3])) != w)
        throw Error("hdr: scan line length differs from the width");
      at += 4;
      // Channel-planar in the file: R of every pixel, then G, B, E.
      for (int c = 0; c < 4; ++c) {
        long x = 0;
        while (x < w) {
          need(1);
          int count = p[at++];
          if (count > 128) {
            count -= 128;
            if (count > w - x) throw Error("hdr: run past the end of a scan line");
            need(1);
            const uint8_t v = p[at++];
            for (int i = 0; i < count; ++i) scan[size_t(x++) * 4 + size_t(c)] = v;
          } else {
            if (count == 0 || count > w - x) throw Error("hdr: bad literal in a scan line");
            need(size_t(count));
            for (int i = 0; i < count; ++i) scan[size_t(x++) * 4 + size_t(c)] = p[at++];
          }
        }
      }
    } else {
      need(size_t(w) * 4);
      std::memcpy(scan.data(), p + at, size_t(w) * 4);
      at += size_t(w) * 4;
    }
    for (long x = 0; x < w; ++x) rgbe_to_float(&scan[size_t(x) * 4], img.at(int(x), int(y)));
  }
  check_pixels(img, "hdr");
  return img;
}

void write_hdr(const std::filesystem::path& path, const Image& image) {
  if (image.channels != 3 || image.width <= 0 || image.height <= 0 ||
      image.pixels.size() != size_t(image.width) * size_t(image.height) * 3)
    throw Error(
        fmt::format("cannot write {}: .hdr needs a non-empty 3-channel image", path.string()));
  const int w = image.width, h = image.height;
  std::string out = fmt::format("#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y {} +X {}\n", h, w);
  std::vector<uint8_t> scan(size_t(w) * 4);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) float_to_rgbe(image.at(x, y), &scan[size_t(x) * 4]);
    if (w < 8 || w >= 32768) {  // flat: the only form for these widths
      out.append(reinterpret_cast<const char*>(scan.data()), scan.size());
      continue;
    }
    out += char(2), out += char(2), out += char(w >> 8), out += char(w & 255);
    for (int c = 0; c < 4; ++c) {
      auto at = [&](int x) { return scan[size_t(x) * 4 + size_t(c)]; };
      int x = 0;
      while (x < w) {
        // A run of >= 4 equal values is worth a run code; shorter ones go
        // into literals of up to 128 values.
        int run = 1;
        while (x + run < w && run < 127 && at(x + run) == at(x)) ++run;
        if (run >= 4) {
          out += char(128 + run), out += char(at(x));
          x += run;
          continue;
        }
        int lit = 0;
        while (x + lit < w && lit < 128) {
          int r = 1;
          while (x + lit + r < w && r < 4 && at(x + lit + r) == at(x + lit)) ++r;
          if (r >= 4) break;
          ++lit;
        }
        out += char(lit);
        for (int i = 0; i < lit; ++i) out += char(at(x + i));
        x += lit;
      }
    }
  }
  write_file_atomic(path, out.data(), out.size());
}

Image read_exr_rgb(const std::filesystem::path& path) {
  try {
    Imf::InputFile file(path.c_str());
    const Imath::Box2i dw = file.header().dataWindow();
    const int64_t w = int64_t(dw.max.x) - dw.min.x + 1, h = int64_t(dw.max.y) - dw.min.y + 1;
    if (w <= 0 || h <= 0 || uint64_t(w) * uint64_t(h) > kMaxEnvironmentPixels)
      throw Error(
          fmt::format("exr: {}x{} pixels is outside 1..{} pixels", w, h, kMaxEnvironmentPixels));
    Image img(int(w), int(h), 3);
    Imf::FrameBuffer fb;
    const size_t xs = 3 * sizeof(float), ys = xs * size_t(w);
    // OpenEXR addresses pixels by their data-window coordinates.
    char* base = reinterpret_cast<char*>(img.pixels.data()) -
                 (ptrdiff_t(dw.min.x) * ptrdiff_t(xs) + ptrdiff_t(dw.min.y) * ptrdiff_t(ys));
    const char* names[3] = {"R", "G", "B"};
    for (int c = 0; c < 3; ++c)
      fb.insert(names[c], Imf::Slice(Imf::FLOAT, base + c * sizeof(float), xs, ys, 1, 1, 0.0));
    file.setFrameBuffer(fb);
    file.readPixels(dw.min.y, dw.max.y);
    check_pixels(img, "exr");
    return img;
  } catch (const Error&) {
    throw;
  } catch (const std::exception& e) {
    throw Error(fmt::format("exr: {}", e.what()));
  }
}

Environment load_environment(const std::filesystem::path& path, float scale) {
  std::string ext = path.extension().string();
  for (char& c : ext) c = char(std::tolower(static_cast<unsigned char>(c)));
  try {
    if (ext == ".exr") return Environment(read_exr_rgb(path), scale);
    if (ext != ".hdr") throw Error("environment maps are .hdr or .exr files");
    std::error_code ec;
    const auto size = std::filesystem::file_size(path, ec);
    if (ec) throw Error(ec.message());
    // The largest plausible file: 4 bytes a pixel, flat, plus a header.
    if (size > kMaxEnvironmentPixels * 4 + (1u << 20)) throw Error("file too large");
    std::ifstream in(path, std::ios::binary);
    if (!in) throw Error("cannot open");
    const std::vector<uint8_t> bytes((std::istreambuf_iterator<char>(in)),
                                     std::istreambuf_iterator<char>());
    if (in.bad()) throw Error("cannot read");
    return Environment(parse_hdr(bytes), scale);
  } catch (const Error& e) {
    throw Error("'" + path.string() + "': " + e.what());
  }
}

}  // namespace voxcast
