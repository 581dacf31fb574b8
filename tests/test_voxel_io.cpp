// Voxel-set files (voxel_io.hpp): MagicaVoxel .vox written by MagicaVoxel
// itself loads as the file says, .vox/.binvox round trips keep the voxels
// (and the colors within palette quantization), the scene graph places
// models as documented, and damaged files are refused with voxcast::Error.
// The oracles are the test's own chunk walker and encoder, written from the
// format description shipped in tests/data/vox.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <random>
#include <regex>
#include <set>
#include <string>
#include <vector>

#include "support/cli_runner.hpp"
#include "support/voxel_compare.hpp"
#include "voxcast/error.hpp"
#include "voxcast/image.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/voxel_io.hpp"

using namespace voxcast;
using voxcast::testing::run_cli;
using voxcast::testing::TempDir;

namespace {

const std::string kVoxDir = std::string(VOXCAST_TEST_DATA_DIR) + "/vox/";

std::vector<uint8_t> file_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error("required test data not found: " + path);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

int32_t le32(const uint8_t* p) {
  return int32_t(uint32_t(p[0]) | uint32_t(p[1]) << 8 | uint32_t(p[2]) << 16 |
                 uint32_t(p[3]) << 24);
}

// The default palette as printed in the format description.
std::vector<uint32_t> spec_default_palette() {
  const std::vector<uint8_t> text = file_bytes(kVoxDir + "MagicaVoxel-file-format-vox.txt");
  std::string s(text.begin(), text.end());
  s = s.substr(s.find("default_palette[256]"));
  std::vector<uint32_t> out;
  std::regex hex("0x([0-9a-fA-F]{8})");
  for (auto it = std::sregex_iterator(s.begin(), s.end(), hex);
       it != std::sregex_iterator() && out.size() < 256; ++it)
    out.push_back(uint32_t(std::stoul((*it)[1].str(), nullptr, 16)));
  return out;
}

// Independent walk of a single-model file: the first SIZE and XYZI and the
// palette (RGBA chunk entry i = index i + 1, else the spec's table).
struct SimpleVox {
  int size[3] = {0, 0, 0};
  std::vector<std::array<uint8_t, 4>> voxels;
  std::vector<uint32_t> palette;
  int models = 0;
  std::map<std::string, int> chunks;
};
SimpleVox walk(const std::vector<uint8_t>& b) {
  SimpleVox v;
  v.palette = spec_default_palette();
  size_t p = 20;
  while (p + 12 <= b.size()) {
    const std::string id(reinterpret_cast<const char*>(&b[p]), 4);
    const int32_t n = le32(&b[p + 4]), m = le32(&b[p + 8]);
    ++v.chunks[id];
    const uint8_t* c = &b[p + 12];
    if (id == "SIZE" && v.models++ == 0)
      for (int a = 0; a < 3; ++a) v.size[a] = le32(c + 4 * a);
    if (id == "XYZI" && v.voxels.empty())
      for (int32_t i = 0; i < le32(c); ++i)
        v.voxels.push_back({c[4 + 4 * i], c[5 + 4 * i], c[6 + 4 * i], c[7 + 4 * i]});
    if (id == "RGBA")
      for (int i = 0; i < 255; ++i) v.palette[size_t(i) + 1] = uint32_t(le32(c + 4 * i));
    p += 12 + size_t(n) + size_t(m);
  }
  return v;
}

std::array<uint8_t, 4> srgb8(const Color& c) {
  auto q = [](float linear) { return uint8_t(std::lround(linear_to_srgb(linear) * 255.f)); };
  return {q(c.r), q(c.g), q(c.b), uint8_t(std::lround(c.a * 255.f))};
}

// The set's codes relative to its occupied box, sorted.
std::vector<uint64_t> normalized(const VoxelSet& s) {
  std::vector<uint64_t> out = voxcast::testing::box_relative_codes(s);
  std::sort(out.begin(), out.end());
  return out;
}

// A random voxel set with `colors` distinct colors in a box of `ext`.
VoxelSet random_set(uint32_t seed, const uint32_t ext[3], size_t count, int colors) {
  std::mt19937 rng(seed);
  std::map<uint64_t, Color> cells;
  std::vector<Color> palette;
  for (int i = 0; i < colors; ++i)
    palette.push_back({srgb_to_linear(float(rng() % 256) / 255.f),
                       srgb_to_linear(float(rng() % 256) / 255.f),
                       srgb_to_linear(float(rng() % 256) / 255.f), 1.f});
  // The box corners, so the occupied box is exactly `ext`.
  for (int c = 0; c < 8; ++c)
    cells[morton_encode(c & 1 ? ext[0] - 1 : 0, c & 2 ? ext[1] - 1 : 0, c & 4 ? ext[2] - 1 : 0)] =
        palette[0];
  while (cells.size() < count)
    cells[morton_encode(uint32_t(rng() % ext[0]), uint32_t(rng() % ext[1]),
                        uint32_t(rng() % ext[2]))] = palette[rng() % palette.size()];
  VoxelSet s;
  s.grid.resolution = std::bit_ceil(std::max({ext[0], ext[1], ext[2]}));
  s.grid.levels = std::countr_zero(s.grid.resolution);
  for (const auto& [code, color] : cells) s.codes.push_back(code), s.colors.push_back(color);
  return s;
}

void expect_valid(const VoxelSet& s) {
  ASSERT_FALSE(s.codes.empty());
  EXPECT_TRUE(std::is_sorted(s.codes.begin(), s.codes.end()));
  EXPECT_EQ(std::adjacent_find(s.codes.begin(), s.codes.end()), s.codes.end());
  EXPECT_EQ(s.colors.size(), s.codes.size());
  EXPECT_EQ(s.normals.size(), s.codes.size());
  for (uint64_t c : s.codes) {
    const MortonCoord m = morton_decode(c);
    ASSERT_LT(std::max({m.x, m.y, m.z}), s.grid.resolution);
  }
}

// A test-side .vox encoder: chunks appended to MAIN.
struct VoxBuilder {
  std::vector<uint8_t> children;
  void i32(std::vector<uint8_t>& o, int32_t v) {
    for (int k = 0; k < 4; ++k) o.push_back(uint8_t(uint32_t(v) >> (8 * k)));
  }
  void str(std::vector<uint8_t>& o, const std::string& s) {
    i32(o, int32_t(s.size()));
    o.insert(o.end(), s.begin(), s.end());
  }
  void chunk(const char* id, const std::vector<uint8_t>& content) {
    children.insert(children.end(), id, id + 4);
    i32(children, int32_t(content.size()));
    i32(children, 0);
    children.insert(children.end(), content.begin(), content.end());
  }
  void model(int sx, int sy, int sz, const std::vector<std::array<uint8_t, 4>>& voxels) {
    std::vector<uint8_t> s, x;
    i32(s, sx), i32(s, sy), i32(s, sz);
    chunk("SIZE", s);
    i32(x, int32_t(voxels.size()));
    for (const auto& v : voxels) x.insert(x.end(), v.begin(), v.end());
    chunk("XYZI", x);
  }
  void trn(int id, int child, const std::map<std::string, std::string>& frame) {
    std::vector<uint8_t> c;
    i32(c, id), i32(c, 0), i32(c, child), i32(c, -1), i32(c, 0), i32(c, 1);
    i32(c, int32_t(frame.size()));
    for (const auto& [k, v] : frame) str(c, k), str(c, v);
    chunk("nTRN", c);
  }
  void grp(int id, const std::vector<int>& kids) {
    std::vector<uint8_t> c;
    i32(c, id), i32(c, 0), i32(c, int32_t(kids.size()));
    for (int k : kids) i32(c, k);
    chunk("nGRP", c);
  }
  void shp(int id, int model) {
    std::vector<uint8_t> c;
    i32(c, id), i32(c, 0), i32(c, 1), i32(c, model), i32(c, 0);
    chunk("nSHP", c);
  }
  std::vector<uint8_t> bytes() {
    std::vector<uint8_t> o = {'V', 'O', 'X', ' '};
    i32(o, 150);
    o.insert(o.end(), {'M', 'A', 'I', 'N'});
    i32(o, 0);
    i32(o, int32_t(children.size()));
    o.insert(o.end(), children.begin(), children.end());
    return o;
  }
};

// Every truncation and every single-byte change of `bytes` is either refused
// with voxcast::Error or read as a valid voxel set; never anything else.
void damage_loop(const std::vector<uint8_t>& bytes, const std::string& name) {
  VoxelReadOptions opt;
  opt.memory_budget = uint64_t(64) << 20;
  for (size_t len = 0; len < bytes.size(); ++len) {
    std::vector<uint8_t> cut(bytes.begin(), bytes.begin() + ptrdiff_t(len));
    EXPECT_THROW(parse_vox(cut, opt), Error) << name << " truncated to " << len;
  }
  int accepted = 0;
  for (size_t i = 0; i < bytes.size(); ++i) {
    std::vector<uint8_t> flipped = bytes;
    flipped[i] ^= 0xff;
    try {
      const VoxelSet s = parse_vox(flipped, opt);
      expect_valid(s);
      ++accepted;
    } catch (const Error&) {
    }
  }
  // Voxel coordinates and colors may change validly; sizes and ids may not.
  EXPECT_LT(accepted, int(bytes.size())) << name;
}

}  // namespace

TEST(VoxelIo, DefaultPaletteMatchesTheFormatDescription) {
  const std::vector<uint32_t> spec = spec_default_palette();
  ASSERT_EQ(spec.size(), 256u);
  for (int i = 1; i < 256; ++i) EXPECT_EQ(vox_default_palette(i), spec[size_t(i)]) << i;
}

TEST(VoxelIo, MagicaVoxelFilesLoadAsTheyAreWritten) {
  // chr_knight has a palette, chr_bow none (default palette), deer is an
  // animation (PACK of 4 models and MATT chunks: model 0 is read).
  for (const char* name : {"chr_knight.vox", "chr_bow.vox", "deer.vox", "ff1.vox"}) {
    SCOPED_TRACE(name);
    const auto bytes = file_bytes(kVoxDir + name);
    const SimpleVox v = walk(bytes);
    const VoxelSet s = read_vox(kVoxDir + name);
    expect_valid(s);
    // z-up (x, y, z) -> y-up (x, z, size_y - 1 - y).
    std::map<uint64_t, uint8_t> expect;
    for (const auto& x : v.voxels)
      expect[morton_encode(x[0], x[2], uint32_t(v.size[1] - 1 - x[1]))] = x[3];
    ASSERT_EQ(s.size(), expect.size());
    EXPECT_EQ(s.grid.resolution,
              std::bit_ceil(uint32_t(std::max({v.size[0], v.size[1], v.size[2]}))));
    size_t i = 0;
    for (const auto& [code, index] : expect) {
      ASSERT_EQ(s.codes[i], code);
      const uint32_t rgba = v.palette[index];
      const auto got = srgb8(s.colors[i]);
      EXPECT_EQ(got[0], rgba & 0xff);
      EXPECT_EQ(got[1], rgba >> 8 & 0xff);
      EXPECT_EQ(got[2], rgba >> 16 & 0xff);
      ++i;
    }
  }
  EXPECT_EQ(read_vox(kVoxDir + "chr_knight.vox").size(), 398u);
  EXPECT_EQ(read_vox(kVoxDir + "deer.vox").size(), 355u);
}

TEST(VoxelIo, VoxRoundTripKeepsVoxelsAndColors) {
  const uint32_t ext[3] = {40, 17, 33};
  const VoxelSet a = random_set(7, ext, 3000, 200);
  const auto bytes = encode_vox(a);
  EXPECT_EQ(bytes, encode_vox(a));  // deterministic
  const SimpleVox v = walk(bytes);
  EXPECT_EQ(v.models, 1);
  EXPECT_EQ(v.chunks.count("nTRN"), 0u);
  const VoxelSet b = parse_vox(bytes);
  expect_valid(b);
  ASSERT_EQ(normalized(b), normalized(a));
  // 200 colors fit the palette: equal after 8-bit sRGB quantization.
  for (size_t i = 0; i < a.size(); ++i) ASSERT_EQ(srgb8(b.colors[i]), srgb8(a.colors[i])) << i;
}

TEST(VoxelIo, WorldsLargerThan256AreSplitIntoModelsWithASceneGraph) {
  const uint32_t ext[3] = {600, 20, 300};
  const VoxelSet a = random_set(11, ext, 20000, 50);
  const auto bytes = encode_vox(a);
  const SimpleVox v = walk(bytes);
  EXPECT_GT(v.models, 1);
  EXPECT_EQ(v.chunks.at("nSHP"), v.models);
  EXPECT_LE(v.size[0], 256);
  const VoxelSet b = parse_vox(bytes);
  expect_valid(b);
  EXPECT_EQ(b.grid.resolution, 1024u);
  ASSERT_EQ(normalized(b), normalized(a));
  for (size_t i = 0; i < a.size(); ++i) ASSERT_EQ(srgb8(b.colors[i]), srgb8(a.colors[i])) << i;
}

TEST(VoxelIo, ManyColorsQuantizeToTheNearestOf255) {
  // 4096 distinct colors: a smooth gradient, quantized by median cut.
  VoxelSet a;
  a.grid.resolution = 64;
  a.grid.levels = 6;
  for (uint32_t z = 0; z < 4; ++z)
    for (uint32_t y = 0; y < 32; ++y)
      for (uint32_t x = 0; x < 32; ++x) {
        a.codes.push_back(morton_encode(x, y, z));
      }
  std::sort(a.codes.begin(), a.codes.end());
  for (uint64_t c : a.codes) {
    const MortonCoord m = morton_decode(c);
    a.colors.push_back({srgb_to_linear(float(m.x * 8) / 255.f),
                        srgb_to_linear(float(m.y * 8) / 255.f),
                        srgb_to_linear(float(m.z * 64) / 255.f), 1.f});
  }
  const VoxelSet b = parse_vox(encode_vox(a));
  ASSERT_EQ(b.codes, a.codes);  // the set fills its box from 0
  std::set<std::array<uint8_t, 4>> used;
  double err = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    const auto o = srgb8(a.colors[i]), q = srgb8(b.colors[i]);
    used.insert(q);
    for (int ch = 0; ch < 3; ++ch) err += std::abs(int(o[size_t(ch)]) - int(q[size_t(ch)]));
  }
  EXPECT_LE(used.size(), 255u);
  EXPECT_GT(used.size(), 200u);
  // Each of the three channels spans 256 levels; 255 boxes of a median cut
  // leave a mean error of a few levels per channel.
  EXPECT_LT(err / double(3 * a.size()), 6.0);
  // Every voxel got its nearest palette entry (brute force).
  std::vector<std::array<uint8_t, 4>> colors;
  for (const Color& c : a.colors) colors.push_back(srgb8(c));
  const PaletteQuantization pq = quantize_palette(colors, 255);
  ASSERT_LE(pq.palette.size(), 255u);
  for (size_t i = 0; i < colors.size(); ++i) {
    int best = INT32_MAX;
    for (const auto& p : pq.palette) {
      int d = 0;
      for (int ch = 0; ch < 4; ++ch)
        d += (int(p[size_t(ch)]) - colors[i][size_t(ch)]) *
             (int(p[size_t(ch)]) - colors[i][size_t(ch)]);
      best = std::min(best, d);
    }
    const auto& got = pq.palette[pq.index[i]];
    int d = 0;
    for (int ch = 0; ch < 4; ++ch)
      d += (int(got[size_t(ch)]) - colors[i][size_t(ch)]) *
           (int(got[size_t(ch)]) - colors[i][size_t(ch)]);
    ASSERT_EQ(d, best) << i;
  }
}

TEST(VoxelIo, SceneGraphTranslatesAndRotatesModels) {
  // Model 0: two voxels along x, colors 1 and 2. Shape A: rotated 90 degrees
  // about z (rows: -y, +x, +z: _r = 1 | 0 << 2 | 1 << 4 = 17) at t = 0.
  // Shape B: the same model unrotated at t = (10, 0, 0).
  // By hand (pivot floor(size/2) = (1, 0, 0)): A puts voxel (0,0,0) at
  // (-1,-1,0) and (1,0,0) at (-1,0,0); B puts them at (9,0,0) and (10,0,0).
  VoxBuilder vb;
  vb.model(2, 1, 1, {{0, 0, 0, 1}, {1, 0, 0, 2}});
  vb.trn(0, 1, {});
  vb.grp(1, {2, 4});
  vb.trn(2, 3, {{"_r", "17"}});
  vb.shp(3, 0);
  vb.trn(4, 5, {{"_t", "10 0 0"}});
  vb.shp(5, 0);
  const VoxelSet s = parse_vox(vb.bytes());
  expect_valid(s);
  // MagicaVoxel (x, y, z) -> voxcast (x, z, -y - 1), shifted by the lowest
  // corner (-1, 0, -1) of the placed model boxes.
  auto at = [](int x, int y, int z) {
    return morton_encode(uint32_t(x + 1), uint32_t(z), uint32_t(-y - 1 + 1));
  };
  std::map<uint64_t, uint32_t> expect = {
      {at(-1, -1, 0), 1}, {at(-1, 0, 0), 2}, {at(9, 0, 0), 1}, {at(10, 0, 0), 2}};
  ASSERT_EQ(s.size(), expect.size());
  size_t i = 0;
  for (const auto& [code, index] : expect) {
    EXPECT_EQ(s.codes[i], code);
    const uint32_t rgba = vox_default_palette(int(index));
    EXPECT_EQ(srgb8(s.colors[i])[0], rgba & 0xff);
    ++i;
  }
}

TEST(VoxelIo, MalformedVoxIsRefused) {
  auto refused = [](VoxBuilder vb, const std::string& needle, uint64_t budget = 0) {
    VoxelReadOptions o;
    o.memory_budget = budget;
    try {
      parse_vox(vb.bytes(), o);
      ADD_FAILURE() << "accepted; expected: " << needle;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
      EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos);
    }
  };
  {
    VoxBuilder vb;
    vb.model(2, 2, 2, {{0, 0, 0, 0}});
    refused(vb, "palette index 0");
  }
  {
    VoxBuilder vb;
    vb.model(2, 2, 2, {{2, 0, 0, 1}});
    refused(vb, "outside its 2x2x2");
  }
  {
    VoxBuilder vb;
    vb.model(300, 2, 2, {{0, 0, 0, 1}});
    refused(vb, "outside 1..256");
  }
  {
    VoxBuilder vb;
    vb.model(0, 2, 2, {});
    refused(vb, "outside 1..256");
  }
  {
    VoxBuilder vb;
    vb.model(2, 2, 2, {{0, 0, 0, 1}});
    vb.trn(0, 1, {});
    vb.grp(1, {0});
    refused(vb, "recursive");
  }
  {
    VoxBuilder vb;
    vb.model(2, 2, 2, {{0, 0, 0, 1}});
    vb.trn(0, 1, {});
    vb.shp(1, 5);
    refused(vb, "model 5");
  }
  {
    VoxBuilder vb;
    vb.model(2, 2, 2, {{0, 0, 0, 1}});
    vb.trn(0, 1, {{"_r", "3"}});
    vb.shp(1, 0);
    refused(vb, "not a rotation");
  }
  {
    // Exponential instancing: 30 levels of groups listing their child twice.
    VoxBuilder vb;
    vb.model(2, 2, 2, {{0, 0, 0, 1}});
    vb.trn(0, 1, {});
    for (int level = 0; level < 30; ++level) {
      vb.grp(1 + 2 * level, {2 + 2 * level, 2 + 2 * level});
      vb.trn(2 + 2 * level, 3 + 2 * level, {});
    }
    vb.shp(61, 0);
    refused(vb, "more than");
  }
  {
    // A chain of 20000 transforms: refused by depth, not by a stack overflow.
    VoxBuilder vb;
    vb.model(2, 2, 2, {{0, 0, 0, 1}});
    for (int i = 0; i < 20000; ++i) vb.trn(i, i + 1, {});
    vb.shp(20000, 0);
    refused(vb, "deeper than");
  }
  {
    VoxBuilder vb;
    vb.model(2, 2, 2, {{0, 0, 0, 1}});
    vb.trn(0, 1, {{"_t", "2000000 0 0"}});
    vb.grp(1, {2, 4});
    vb.trn(2, 3, {});
    vb.shp(3, 0);
    vb.trn(4, 5, {{"_t", "-2000000 0 0"}});
    vb.shp(5, 0);
    refused(vb, "grid limit");
  }
  {
    // More voxels than a small budget holds.
    VoxBuilder vb;
    std::vector<std::array<uint8_t, 4>> many;
    for (int i = 0; i < 1000; ++i)
      many.push_back({uint8_t(i % 10), uint8_t(i / 10 % 10), uint8_t(i / 100), 1});
    vb.model(10, 10, 10, many);
    refused(vb, "memory budget", 1000);
  }
  {
    // A chunk whose size is negative.
    VoxBuilder vb;
    vb.model(2, 2, 2, {{0, 0, 0, 1}});
    std::vector<uint8_t> b = vb.bytes();
    b[20 + 4] = 0xff, b[20 + 5] = 0xff, b[20 + 6] = 0xff, b[20 + 7] = 0xff;
    EXPECT_THROW(parse_vox(b), Error);
  }
}

TEST(VoxelIo, DamagedVoxFilesAreRefusedOrValid) {
  for (const char* name : {"chr_knight.vox", "chr_bow.vox"})
    damage_loop(file_bytes(kVoxDir + name), name);
  const uint32_t ext[3] = {300, 8, 20};
  damage_loop(encode_vox(random_set(3, ext, 200, 10)), "written scene graph");
}

// Inputs from fuzz_vox runs (tests/data/regress/vox): the smallest input of
// each refusal the fuzzer reached, and a few it accepted. Refused ones stay
// refused with voxcast::Error; accepted ones stay valid and write and read
// back unchanged (the fuzz target's own check).
TEST(VoxelIo, CommittedRegressionInputs) {
  const std::filesystem::path dir =
      std::filesystem::path(VOXCAST_TEST_DATA_DIR) / "regress" / "vox";
  size_t refused = 0, accepted = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir)) {
    const std::string name = e.path().filename().string();
    SCOPED_TRACE(name);
    const auto bytes = file_bytes(e.path().string());
    const bool binvox = e.path().extension() == ".binvox";
    if (name.rfind("refused-", 0) == 0) {
      EXPECT_THROW(binvox ? parse_binvox(bytes) : parse_vox(bytes), Error);
      ++refused;
    } else {
      const VoxelSet a = binvox ? parse_binvox(bytes) : parse_vox(bytes);
      expect_valid(a);
      const VoxelSet b = binvox ? parse_binvox(encode_binvox(a)) : parse_vox(encode_vox(a));
      EXPECT_EQ(normalized(b), normalized(a));
      ++accepted;
    }
  }
  EXPECT_GE(refused, 40u);
  EXPECT_GE(accepted, 3u);
}

TEST(VoxelIo, BinvoxRoundTripAndRawGrid) {
  const uint32_t ext[3] = {50, 37, 21};
  VoxelSet a = random_set(5, ext, 4000, 1);
  a.grid.origin = {-1.5f, 2.25f, 0.125f};
  a.grid.voxel_size = 0.03125;
  const auto bytes = encode_binvox(a);
  const VoxelSet b = parse_binvox(bytes);
  expect_valid(b);
  EXPECT_EQ(b.codes, a.codes);
  EXPECT_EQ(b.grid.resolution, a.grid.resolution);
  EXPECT_EQ(b.grid.voxel_size, a.grid.voxel_size);
  EXPECT_EQ(b.grid.origin.x, a.grid.origin.x);
  EXPECT_EQ(b.grid.origin.z, a.grid.origin.z);
  // Truncated or padded data is refused.
  for (size_t len : {size_t(0), size_t(10), bytes.size() - 1, bytes.size() - 2}) {
    std::vector<uint8_t> cut(bytes.begin(), bytes.begin() + ptrdiff_t(len));
    EXPECT_THROW(parse_binvox(cut), Error) << len;
  }
  std::vector<uint8_t> padded = bytes;
  padded.push_back(0), padded.push_back(1);
  EXPECT_THROW(parse_binvox(padded), Error);

  const RawGrid raw = encode_raw_grid(a);
  EXPECT_EQ(raw.dims[0], 50u);
  EXPECT_EQ(raw.dims[1], 37u);
  EXPECT_EQ(raw.dims[2], 21u);
  ASSERT_EQ(raw.cells.size(), 50u * 37u * 21u);
  EXPECT_EQ(size_t(std::count(raw.cells.begin(), raw.cells.end(), 1)), a.size());
  for (uint64_t c : a.codes) {
    const MortonCoord m = morton_decode(c);
    ASSERT_EQ(raw.cells[m.x + 50 * (m.y + 37 * m.z)], 1);
  }
  EXPECT_NE(raw.json.find("\"dims\""), std::string::npos);
}

TEST(VoxelIo, CliConvertsAndBuildsVoxFiles) {
  TempDir dir;
  const std::string knight = kVoxDir + "chr_knight.vox";
  auto r = run_cli("convert " + knight + " " + dir.file("k.binvox"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(read_binvox(dir.file("k.binvox")).codes, read_vox(knight).codes);
  r = run_cli("convert " + dir.file("k.binvox") + " " + dir.file("k.vox"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(normalized(read_vox(dir.file("k.vox"))), normalized(read_vox(knight)));
  r = run_cli("convert " + knight + " " + dir.file("k.raw"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_TRUE(std::filesystem::exists(dir.file("k.raw.json")));
  // .vox -> ESVO and DAG scenes, the same leaf voxels.
  for (const char* format : {"esvo", "dag"}) {
    r = run_cli(std::string("build ") + knight + " --format " + format + " -o " +
                dir.file("k.vxc"));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    r = run_cli("info --json " + dir.file("k.vxc"));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    EXPECT_NE(r.output.find("\"leaf_voxels\": 398"), std::string::npos) << r.output;
  }
  // A mesh through the voxelizer into a .vox.
  r = run_cli("convert " + std::string(VOXCAST_SOURCE_DIR) + "/scenes/bunny.obj " +
              dir.file("b.vox") + " --resolution 32");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_GT(read_vox(dir.file("b.vox")).size(), 500u);
  // A damaged file: one line, exit 1.
  auto bytes = file_bytes(knight);
  bytes.resize(bytes.size() / 2);
  std::ofstream(dir.file("bad.vox"), std::ios::binary)
      .write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
  r = run_cli("convert " + dir.file("bad.vox") + " " + dir.file("x.binvox"));
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("voxcast: error: "), std::string::npos) << r.output;
  EXPECT_EQ(std::count(r.output.begin(), r.output.end(), '\n'), 1) << r.output;
  EXPECT_FALSE(std::filesystem::exists(dir.file("x.binvox")));
  r = run_cli("build " + dir.file("bad.vox") + " -o " + dir.file("x.vxc"));
  EXPECT_EQ(r.exit_code, 1) << r.output;
  // Voxelization options with a voxel input are a usage error.
  r = run_cli("convert " + knight + " " + dir.file("y.vox") + " --resolution 64");
  EXPECT_EQ(r.exit_code, 2) << r.output;
}
