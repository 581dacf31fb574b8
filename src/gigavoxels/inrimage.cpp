// INRIMAGE-4 volumes and the producer over a scalar volume (gigavoxels.hpp).
#include <zlib.h>

#include <algorithm>
#include <bit>
#include <charconv>
#include <cmath>
#include <cstring>
#include <fstream>
#include <map>
#include <string_view>

#include "volume_samples.hpp"
#include "voxcast/error.hpp"
#include "voxcast/gigavoxels.hpp"

namespace voxcast::giga {
namespace {

constexpr std::string_view kMagic = "#INRIMAGE-4#{\n";
constexpr std::string_view kEnd = "##}\n";
constexpr size_t kMaxHeader = 64 * 1024;
constexpr uint64_t kMaxVoxels = uint64_t(1) << 28;

[[noreturn]] void fail(const std::string& what) {
  throw Error("INRIMAGE: " + what);
}

int parse_int(std::string_view key, std::string_view v, int lo, int hi) {
  int x = 0;
  const auto [end, ec] = std::from_chars(v.data(), v.data() + v.size(), x);
  if (ec != std::errc() || end != v.data() + v.size() || x < lo || x > hi)
    fail(std::string(key) + "='" + std::string(v) + "' must be an integer in " +
         std::to_string(lo) + ".." + std::to_string(hi));
  return x;
}

float parse_positive(std::string_view key, std::string_view v) {
  float x = 0.f;
  const auto [end, ec] = std::from_chars(v.data(), v.data() + v.size(), x);
  if (ec != std::errc() || end != v.data() + v.size() || !std::isfinite(x) || !(x > 0.f))
    fail(std::string(key) + "='" + std::string(v) + "' must be a positive number");
  return x;
}

}  // namespace

ScalarVolume parse_inrimage(std::span<const unsigned char> bytes) {
  const std::string_view text(reinterpret_cast<const char*>(bytes.data()),
                              std::min(bytes.size(), kMaxHeader));
  if (!text.starts_with(kMagic)) fail("not an INRIMAGE-4 file (no '#INRIMAGE-4#{' line)");
  const size_t end = text.find(kEnd);
  if (end == std::string_view::npos) fail("the header has no '##}' end line");
  const size_t header = end + kEnd.size();
  if (header % 256 != 0)
    fail("the header is " + std::to_string(header) + " bytes, not a multiple of 256");

  std::map<std::string, std::string, std::less<>> fields;
  size_t pos = kMagic.size();
  while (pos < end) {
    const size_t nl = text.find('\n', pos);
    const std::string_view line = text.substr(pos, nl - pos);
    pos = nl + 1;
    if (line.empty() || line.starts_with('#')) continue;  // padding, comments
    const size_t eq = line.find('=');
    if (eq == std::string_view::npos || eq == 0)
      fail("header line '" + std::string(line) + "' is not KEY=VALUE");
    const std::string key(line.substr(0, eq));
    if (!std::all_of(key.begin(), key.end(),
                     [](char c) { return (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9'); }))
      fail("header key '" + key + "' is not an INRIMAGE key");
    if (!fields.emplace(key, std::string(line.substr(eq + 1))).second)
      fail("header field " + key + " appears twice");
  }
  auto need = [&](const char* key) -> const std::string& {
    const auto it = fields.find(key);
    if (it == fields.end()) fail(std::string("the header has no ") + key);
    return it->second;
  };
  auto get = [&](const char* key) -> const std::string* {
    const auto it = fields.find(key);
    return it == fields.end() ? nullptr : &it->second;
  };

  ScalarVolume v;
  v.nx = parse_int("XDIM", need("XDIM"), 1, 65536);
  v.ny = parse_int("YDIM", need("YDIM"), 1, 65536);
  v.nz = parse_int("ZDIM", need("ZDIM"), 1, 65536);
  if (const std::string* s = get("VDIM"); s && parse_int("VDIM", *s, 1, 65536) != 1)
    fail("VDIM=" + *s + ": only scalar volumes (VDIM=1) are supported");
  const std::string& type = need("TYPE");
  if (type != "unsigned fixed" && type != "signed fixed" && type != "float")
    fail("TYPE='" + type + "' must be 'unsigned fixed', 'signed fixed' or 'float'");
  const std::string& pixsize = need("PIXSIZE");
  if (!pixsize.ends_with(" bits")) fail("PIXSIZE='" + pixsize + "' must be 'N bits'");
  const int bits =
      parse_int("PIXSIZE", std::string_view(pixsize).substr(0, pixsize.size() - 5), 1, 64);
  const bool is_float = type == "float";
  if (is_float ? (bits != 32 && bits != 64) : (bits != 8 && bits != 16 && bits != 32))
    fail("PIXSIZE=" + pixsize + " is not a size of TYPE " + type);
  if (const std::string* s = get("SCALE")) {
    if (!s->starts_with("2**")) fail("SCALE='" + *s + "' must be 2**N");
    parse_int("SCALE", std::string_view(*s).substr(3), 0, 64);
  }
  bool big = false;
  if (const std::string* s = get("CPU")) {
    if (*s == "sun" || *s == "sgi")
      big = true;
    else if (*s != "decm" && *s != "alpha" && *s != "pc")
      fail("CPU='" + *s + "' must be decm, alpha, pc, sun or sgi");
  }
  if (const std::string* s = get("VX")) v.vx = parse_positive("VX", *s);
  if (const std::string* s = get("VY")) v.vy = parse_positive("VY", *s);
  if (const std::string* s = get("VZ")) v.vz = parse_positive("VZ", *s);

  const uint64_t count = uint64_t(v.nx) * uint64_t(v.ny) * uint64_t(v.nz);
  if (count > kMaxVoxels) fail(std::to_string(count) + " voxels exceed the limit of 2^28");
  const size_t width = size_t(bits / 8);
  const uint64_t want = count * width, have = bytes.size() - header;
  if (have < want)
    fail("truncated: the header announces " + std::to_string(want) +
         " bytes of data, the file has " + std::to_string(have));
  if (have > want)
    fail(std::to_string(have - want) + " bytes after the announced " + std::to_string(want) +
         " bytes of data");

  using detail::SampleType;
  const bool is_signed = type == "signed fixed";
  const SampleType st = is_float     ? (bits == 32 ? SampleType::F32 : SampleType::F64)
                        : bits == 8  ? (is_signed ? SampleType::I8 : SampleType::U8)
                        : bits == 16 ? (is_signed ? SampleType::I16 : SampleType::U16)
                                     : (is_signed ? SampleType::I32 : SampleType::U32);
  detail::decode_samples(bytes.data() + header, size_t(count), st, big, "INRIMAGE", &v.values);
  return v;
}

std::vector<unsigned char> gunzip(std::span<const unsigned char> in) {
  // The largest volume parse_inrimage accepts (2^28 samples of 8 bytes) plus
  // its header: a larger stream is refused before it exhausts memory.
  constexpr size_t kLimit = (size_t(8) << 28) + kMaxHeader;
  z_stream z{};
  if (inflateInit2(&z, 16 + MAX_WBITS) != Z_OK) fail("gzip: cannot start zlib");
  std::vector<unsigned char> out;
  z.next_in = const_cast<Bytef*>(in.data());
  z.avail_in = uInt(std::min<size_t>(in.size(), 0xFFFFFFFFu));
  int rc = Z_OK;
  while (rc != Z_STREAM_END) {
    if (out.size() >= kLimit) {
      inflateEnd(&z);
      fail("gzip: the decompressed file exceeds the size limit");
    }
    const size_t at = out.size();
    out.resize(std::min(kLimit, std::max<size_t>(at * 2, size_t(1) << 20)));
    z.next_out = out.data() + at;
    z.avail_out = uInt(out.size() - at);
    rc = inflate(&z, Z_NO_FLUSH);
    out.resize(out.size() - z.avail_out);
    if (rc == Z_BUF_ERROR && z.avail_in == 0) rc = Z_DATA_ERROR;  // the input ended early
    if (rc != Z_OK && rc != Z_STREAM_END) {
      const bool truncated = z.avail_in == 0;
      inflateEnd(&z);
      fail(truncated ? "gzip: the compressed stream is truncated"
                     : "gzip: the compressed stream is corrupted");
    }
  }
  const bool trailing = z.avail_in != 0;
  inflateEnd(&z);
  if (trailing) fail("gzip: bytes after the compressed stream");
  return out;
}

ScalarVolume read_inrimage(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error("cannot open '" + path + "'");
  std::vector<unsigned char> bytes((std::istreambuf_iterator<char>(in)),
                                   std::istreambuf_iterator<char>());
  if (in.bad()) throw Error("cannot read '" + path + "'");
  try {
    // A gzip'd volume (.inr.gz: the gzip magic 1f 8b) is inflated first.
    if (bytes.size() >= 2 && bytes[0] == 0x1f && bytes[1] == 0x8b) bytes = gunzip(bytes);
    return parse_inrimage(bytes);
  } catch (const Error& e) {
    throw Error(path + ": " + e.what());
  }
}

std::vector<unsigned char> write_inrimage(const ScalarVolume& v) {
  std::string h = std::string(kMagic) + "XDIM=" + std::to_string(v.nx) +
                  "\nYDIM=" + std::to_string(v.ny) + "\nZDIM=" + std::to_string(v.nz) +
                  "\nVDIM=1\nTYPE=float\nPIXSIZE=32 bits\nCPU=decm\n";
  char buf[64];
  for (auto [key, value] : {std::pair{"VX", v.vx}, std::pair{"VY", v.vy}, std::pair{"VZ", v.vz}}) {
    const auto r = std::to_chars(buf, buf + sizeof buf, value);
    h += std::string(key) + "=" + std::string(buf, r.ptr) + "\n";
  }
  const size_t padded = (h.size() + kEnd.size() + 255) / 256 * 256;
  h.append(padded - h.size() - kEnd.size(), '\n');
  h += kEnd;
  std::vector<unsigned char> out(h.begin(), h.end());
  for (float x : v.values) {
    const uint32_t u = std::bit_cast<uint32_t>(x);
    for (int i = 0; i < 4; ++i) out.push_back(uint8_t(u >> (8 * i)));
  }
  return out;
}

// ---- Producer over a scalar volume ----

namespace {

/// Dense levels (2^L M)^3 of the normalized data, finest resampled from the
/// file's grid, coarser ones by 2x2x2 averages; with min / max per voxel of
/// the finest data it covers (for constant_below).
class VolumeProducer final : public Producer {
 public:
  explicit VolumeProducer(const ScalarVolume& v) {
    if (v.values.size() != size_t(v.nx) * size_t(v.ny) * size_t(v.nz) || v.values.empty())
      throw Error("volume producer: the volume's size does not match its values");
    const int longest = std::max({v.nx, v.ny, v.nz});
    while ((kBrickSide << max_level_) < longest) ++max_level_;
    if (max_level_ > 7) throw Error("volume producer: volumes up to 1024 voxels per side");
    const auto [lo_it, hi_it] = std::minmax_element(v.values.begin(), v.values.end());
    const float lo = *lo_it, range = *hi_it - *lo_it;
    // Physical extent, centered in the unit cube with the longest side = 1.
    const double ex = v.nx * double(v.vx), ey = v.ny * double(v.vy), ez = v.nz * double(v.vz);
    const double ext = std::max({ex, ey, ez});
    const double off[3] = {(1 - ex / ext) / 2, (1 - ey / ext) / 2, (1 - ez / ext) / 2};
    const double scale[3] = {ext / v.vx, ext / v.vy, ext / v.vz};  // unit cube -> file voxels
    const int n = kBrickSide << max_level_;
    levels_.resize(size_t(max_level_) + 1);
    mins_.resize(levels_.size()), maxs_.resize(levels_.size());
    std::vector<float>& fine = levels_.back();
    fine.assign(size_t(n) * n * n, 0.f);
    auto file = [&](int x, int y, int z) {
      if (x < 0 || y < 0 || z < 0 || x >= v.nx || y >= v.ny || z >= v.nz) return 0.f;
      return range > 0.f ? (v.at(x, y, z) - lo) / range : 0.f;
    };
    for (int z = 0; z < n; ++z)
      for (int y = 0; y < n; ++y)
        for (int x = 0; x < n; ++x) {
          // Trilinear resampling at the level voxel's center (file voxel i
          // is centered at i + 0.5 of the file grid); outside the data: 0.
          const int c[3] = {x, y, z};
          int i0[3];
          float f[3];
          for (int a = 0; a < 3; ++a) {
            const double u = ((c[a] + 0.5) / n - off[a]) * scale[a] - 0.5;
            const double fl = std::floor(u);
            i0[a] = int(fl), f[a] = float(u - fl);
          }
          float acc = 0.f;
          for (int k = 0; k < 2; ++k)
            for (int j = 0; j < 2; ++j)
              for (int i = 0; i < 2; ++i)
                acc += (i ? f[0] : 1 - f[0]) * (j ? f[1] : 1 - f[1]) * (k ? f[2] : 1 - f[2]) *
                       file(i0[0] + i, i0[1] + j, i0[2] + k);
          fine[(size_t(z) * n + y) * n + x] = acc;
        }
    mins_.back() = maxs_.back() = fine;
    for (int l = max_level_ - 1; l >= 0; --l) {
      const int m = kBrickSide << l;
      const std::vector<float>&below = levels_[size_t(l) + 1], &bmin = mins_[size_t(l) + 1],
            &bmax = maxs_[size_t(l) + 1];
      std::vector<float>& out = levels_[size_t(l)];
      out.assign(size_t(m) * m * m, 0.f);
      mins_[size_t(l)].assign(out.size(), 0.f), maxs_[size_t(l)].assign(out.size(), 0.f);
      for (int z = 0; z < m; ++z)
        for (int y = 0; y < m; ++y)
          for (int x = 0; x < m; ++x) {
            float sum = 0.f, mn = INFINITY, mx = -INFINITY;
            for (int k = 0; k < 8; ++k) {
              const size_t at =
                  (size_t(2 * z + (k >> 2)) * (2 * m) + size_t(2 * y + ((k >> 1) & 1))) * (2 * m) +
                  size_t(2 * x + (k & 1));
              sum += below[at], mn = std::min(mn, bmin[at]), mx = std::max(mx, bmax[at]);
            }
            const size_t at = (size_t(z) * m + y) * m + x;
            out[at] = sum / 8, mins_[size_t(l)][at] = mn, maxs_[size_t(l)][at] = mx;
          }
    }
  }
  std::string name() const override { return "volume"; }
  int max_level() const override { return max_level_; }
  VolumeSample voxel(int level, int64_t x, int64_t y, int64_t z) const override {
    const int64_t n = int64_t(kBrickSide) << level;
    if (x < 0 || y < 0 || z < 0 || x >= n || y >= n || z >= n || level > max_level_) return {};
    const float s = levels_[size_t(level)][size_t((z * n + y) * n + x)];
    return {s, Color{1.f, 1.f, 1.f, 1.f}};
  }
  bool constant_below(const NodeRegion& r, VolumeSample* value) const override {
    // Every finest voxel under the node's voxels and their one-voxel margin
    // holds the same value (outside the cube counts as 0).
    const int64_t n = int64_t(kBrickSide) << r.level;
    float mn = INFINITY, mx = -INFINITY;
    const std::vector<float>&lo = mins_[size_t(r.level)], &hi = maxs_[size_t(r.level)];
    for (int64_t z = int64_t(r.z) * kBrickSide - 1; z <= int64_t(r.z + 1) * kBrickSide; ++z)
      for (int64_t y = int64_t(r.y) * kBrickSide - 1; y <= int64_t(r.y + 1) * kBrickSide; ++y)
        for (int64_t x = int64_t(r.x) * kBrickSide - 1; x <= int64_t(r.x + 1) * kBrickSide; ++x) {
          if (x < 0 || y < 0 || z < 0 || x >= n || y >= n || z >= n) {
            mn = std::min(mn, 0.f), mx = std::max(mx, 0.f);
          } else {
            const size_t at = size_t((z * n + y) * n + x);
            mn = std::min(mn, lo[at]), mx = std::max(mx, hi[at]);
          }
          if (mn != mx) return false;
        }
    *value = mn == 0.f ? VolumeSample{} : VolumeSample{mn, Color{1.f, 1.f, 1.f, 1.f}};
    return true;
  }

 private:
  int max_level_ = 0;
  std::vector<std::vector<float>> levels_, mins_, maxs_;
};

}  // namespace

std::shared_ptr<Producer> make_volume_producer(const ScalarVolume& v) {
  return std::make_shared<VolumeProducer>(v);
}

}  // namespace voxcast::giga
