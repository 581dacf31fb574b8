// Independent decoders (see independent_decoders.hpp). Every constant here is
// taken from the layout comments, never from the implementation's code, and
// nothing from the voxcast library is called.
#include "support/independent_decoders.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <map>
#include <stdexcept>
#include <string>

namespace voxcast::testing::independent {
namespace {

[[noreturn]] void fail(const std::string& what) {
  throw std::runtime_error("independent ESVO scan: " + what);
}

RefVec add(RefVec a, RefVec b) {
  return {a.x + b.x, a.y + b.y, a.z + b.z};
}
RefVec scale(RefVec a, double s) {
  return {a.x * s, a.y * s, a.z * s};
}
double norm(RefVec a) {
  return std::sqrt(a.x * a.x + a.y * a.y + a.z * a.z);
}

// Bit replication of a 5- or 6-bit channel to 8 bits (compress.cpp: "expands
// 5/6-bit channels to 8 bits by bit replication").
int replicate(uint32_t value, int bits) {
  return int(value << (8 - bits) | value >> (2 * bits - 8));
}

// A signed 4-bit two's complement mantissa (-8..7).
int signed4(uint32_t nibble) {
  return nibble >= 8 ? int(nibble) - 16 : int(nibble);
}

// One axis vector from its 16-bit half of word 3: | e | z | y | x | nibbles.
RefVec axis_from_half(uint32_t half) {
  const double unit = std::ldexp(1.0, int(half >> 12 & 15) - 15);
  return {signed4(half & 15) * unit, signed4(half >> 4 & 15) * unit,
          signed4(half >> 8 & 15) * unit};
}

// esvo.hpp: 8 KiB pages of 2048 words = 1024 slots, info sections tagged "INFO".
constexpr uint32_t kSlotsPerPage = 1024;
constexpr uint32_t kInfoTag = 0x4F464E49u;
constexpr uint32_t kTypeRaw = 1, kTypeCompressed = 2, kTypeContours = 3;

struct BlockInfo {
  uint64_t first_slot = 0;  // the block's first page header slot
  uint64_t area_slots = 0;
  int64_t color_normal = -1;  // word index of the raw or compressed attachment
  bool compressed = false;
  int64_t contours = -1;  // word index of the contour attachment
};

}  // namespace

double srgb8_to_linear(int code) {
  const double c = code / 255.0;
  return c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4);
}

int linear_to_srgb8(double linear) {
  const double c = std::clamp(linear, 0.0, 1.0);
  const double s = c <= 0.0031308 ? 12.92 * c : 1.055 * std::pow(c, 1.0 / 2.4) - 0.055;
  return int(std::lround(s * 255.0));
}

RefColor decode_abgr(uint32_t abgr) {
  RefColor c;
  for (int ch = 0; ch < 3; ++ch) c.srgb[ch] = int(abgr >> (8 * ch) & 0xFF);
  c.r = srgb8_to_linear(c.srgb[0]);
  c.g = srgb8_to_linear(c.srgb[1]);
  c.b = srgb8_to_linear(c.srgb[2]);
  c.a = (abgr >> 24) / 255.0;
  return c;
}

RefVec cube_point(uint32_t code, bool* ok) {
  const uint32_t face = code >> 29;
  if (ok) *ok = face <= 5;
  const int axis = int(face >> 1) % 3;
  const double major = (face & 1) ? -1.0 : 1.0;
  const double u = double(code >> 15 & 0x3FFF) * 2.0 / 16383.0 - 1.0;
  const double v = double(code & 0x7FFF) * 2.0 / 32767.0 - 1.0;
  double r[3];
  r[axis] = major;
  r[(axis + 1) % 3] = u;
  r[(axis + 2) % 3] = v;
  return {r[0], r[1], r[2]};
}

RefVec decode_cube_normal(uint32_t code, bool* ok) {
  const RefVec p = cube_point(code, ok);
  return scale(p, 1.0 / norm(p));
}

BlockNormalBasis decode_block_basis(const uint32_t* block) {
  return {cube_point(block[2]), axis_from_half(block[3] >> 16), axis_from_half(block[3] & 0xFFFF)};
}

BlockSlot decode_block_slot(const uint32_t* block, int slot) {
  BlockSlot out;
  // Colors: endpoints, palette entry, 8-bit sRGB -> linear.
  const uint32_t c0 = block[0] & 0xFFFF, c1 = block[0] >> 16;
  const int e0[3] = {replicate(c0 >> 11, 5), replicate(c0 >> 5 & 63, 6), replicate(c0 & 31, 5)};
  const int e1[3] = {replicate(c1 >> 11, 5), replicate(c1 >> 5 & 63, 6), replicate(c1 & 31, 5)};
  const uint32_t k = block[1] >> (2 * slot) & 3;
  for (int ch = 0; ch < 3; ++ch) {
    const int a = e0[ch], b = e1[ch];
    const int entry[4] = {a, b, (2 * a + b + 1) / 3, (a + 2 * b + 1) / 3};
    out.color.srgb[ch] = entry[k];
  }
  out.color.r = srgb8_to_linear(out.color.srgb[0]);
  out.color.g = srgb8_to_linear(out.color.srgb[1]);
  out.color.b = srgb8_to_linear(out.color.srgb[2]);
  out.color.a = 1.0;

  // Normals: n_b + c(k_u) n_u + c(k_v) n_v.
  const BlockNormalBasis basis = decode_block_basis(block);
  const uint32_t nibble = block[4 + (slot >> 3)] >> (4 * (slot & 7)) & 15;
  const double cu = (2.0 * double(nibble & 3) - 3.0) / 3.0;
  const double cv = (2.0 * double(nibble >> 2) - 3.0) / 3.0;
  const RefVec sum = add(basis.base, add(scale(basis.u, cu), scale(basis.v, cv)));
  const double len = norm(sum);
  out.normal = len > 1e-12 ? scale(sum, 1.0 / len) : scale(basis.base, 1.0 / norm(basis.base));
  return out;
}

Descriptor decode_descriptor(uint32_t w0, uint32_t w1) {
  Descriptor d;
  d.child_pointer = w0 >> 17;
  d.far = (w0 >> 16 & 1) != 0;
  d.valid = w0 >> 8 & 0xFF;
  d.leaf = w0 & 0xFF;
  d.contour_pointer = w1 >> 8;
  d.contour_mask = w1 & 0xFF;
  return d;
}

Contour decode_contour(uint32_t value) {
  const auto field = [&](int lo, int bits, bool is_signed) {
    const int raw = int(value >> lo & ((1u << bits) - 1));
    return is_signed && raw >= (1 << (bits - 1)) ? raw - (1 << bits) : raw;
  };
  return {field(25, 7, false), field(18, 7, true), field(12, 6, true), field(6, 6, true),
          field(0, 6, true)};
}

EsvoScan scan_esvo(const std::vector<uint32_t>& w) {
  const uint64_t nslots = w.size() / 2;
  if (w.size() < 2 * kSlotsPerPage || w.size() % 2) fail("fewer words than one page");
  const auto word = [&](int64_t i) -> uint32_t {
    if (i < 0 || uint64_t(i) >= w.size()) fail("word index " + std::to_string(i) + " out of range");
    return w[size_t(i)];
  };
  std::map<uint64_t, BlockInfo> blocks;  // by info section word
  const auto block_of = [&](uint64_t slot) -> const BlockInfo& {
    const int64_t header = int64_t(slot / kSlotsPerPage * kSlotsPerPage) * 2;
    const int64_t info = header + int32_t(word(header));
    if (auto it = blocks.find(uint64_t(info)); it != blocks.end()) return it->second;
    if (word(info) != kInfoTag) fail("page header does not lead to an info section");
    BlockInfo b;
    const int64_t first = info + int32_t(word(info + 1));
    if (first < 0 || first % 2) fail("info section's first slot is not a slot");
    b.first_slot = uint64_t(first) / 2;
    b.area_slots = word(info + 2);
    const uint32_t count = word(info + 3);
    for (uint32_t a = 0; a < count; ++a) {
      const uint32_t type = word(info + 4 + 2 * a);
      const int64_t at = info + int32_t(word(info + 5 + 2 * a));
      if (type == kTypeRaw || type == kTypeCompressed) {
        if (b.color_normal >= 0) fail("two color/normal attachments");
        b.color_normal = at;
        b.compressed = type == kTypeCompressed;
      } else if (type == kTypeContours) {
        b.contours = at;
      }
    }
    return blocks.emplace(uint64_t(info), b).first->second;
  };

  EsvoScan scan;
  bool first_block = true;
  struct Node {
    uint64_t slot;
    int depth;
    uint32_t x, y, z;
  };
  std::vector<Node> stack{{1, 0, 0, 0, 0}};  // the root: first descriptor of block 0
  uint64_t visited = 0;
  while (!stack.empty()) {
    const Node n = stack.back();
    stack.pop_back();
    if (++visited > nslots) fail("more descriptors than slots (a cycle?)");
    const Descriptor d =
        decode_descriptor(word(int64_t(n.slot) * 2), word(int64_t(n.slot) * 2 + 1));
    if (d.valid == 0) fail("descriptor with an empty valid mask");
    if (d.leaf & ~d.valid) fail("leaf bit outside the valid mask");
    const BlockInfo& b = block_of(n.slot);
    if (first_block) {
      scan.compressed = b.compressed;
      scan.contours = b.contours >= 0;
      first_block = false;
    }
    if (b.color_normal < 0) fail("block without a color/normal attachment");
    if (n.slot < b.first_slot || n.slot - b.first_slot >= b.area_slots)
      fail("descriptor outside its block's descriptor area");
    const uint64_t rel = n.slot - b.first_slot;

    // First child descriptor (near: relative slots; far: via the far slot).
    int64_t first_child = int64_t(n.slot) + d.child_pointer;
    if (d.far) first_child = int64_t(n.slot) + int32_t(word(first_child * 2));
    const uint32_t non_leaf = d.valid & ~d.leaf;
    std::vector<Node> children;
    for (int i = 0; i < 8; ++i) {
      if (!(d.valid >> i & 1)) continue;
      EsvoVoxel v;
      v.parent_slot = uint32_t(n.slot);
      v.child = i;
      v.depth = n.depth + 1;
      v.x = n.x * 2 + uint32_t(i & 1);
      v.y = n.y * 2 + uint32_t(i >> 1 & 1);
      v.z = n.z * 2 + uint32_t(i >> 2 & 1);
      v.leaf = (d.leaf >> i & 1) != 0;
      const int64_t at = b.color_normal;
      if (b.compressed) {
        // 2 header words (S, C), then 6-word blocks, one per descriptor pair.
        const uint64_t pair = rel >> 1;
        if (pair >= word(at + 1)) fail("descriptor pair beyond the compressed block count");
        uint32_t block[6];
        for (int k = 0; k < 6; ++k) block[k] = word(at + 2 + int64_t(6 * pair) + k);
        v.attributes = decode_block_slot(block, int((rel & 1) * 8) + i);
      } else {
        // S lookup entries (value pointer << 8 | mask), then V two-word values.
        const uint32_t slots = word(at), values = word(at + 1);
        if (rel >= slots) fail("descriptor beyond the lookup table");
        const uint32_t entry = word(at + 2 + int64_t(rel));
        if (!(entry >> i & 1)) fail("voxel without an attribute mask bit");
        const uint64_t value =
            (entry >> 8) + uint64_t(std::popcount(entry & 0xFFu & ((1u << i) - 1)));
        if (value >= values) fail("value pointer beyond the values");
        const int64_t vw = at + 2 + slots + int64_t(2 * value);
        v.attributes.color = decode_abgr(word(vw));
        v.attributes.normal = decode_cube_normal(word(vw + 1));
      }
      if (d.contour_mask >> i & 1) {
        if (b.contours < 0) fail("contour bit in a block without contours");
        const int64_t cw = int64_t(n.slot) * 2 + d.contour_pointer +
                           std::popcount(d.contour_mask & ((1u << i) - 1));
        if (cw <= b.contours || cw > b.contours + int64_t(word(b.contours)))
          fail("contour pointer outside the block's contour attachment");
        v.has_contour = true;
        v.contour_value = word(cw);
      }
      if (!v.leaf) {
        const int64_t child = first_child + std::popcount(non_leaf & ((1u << i) - 1));
        if (child <= int64_t(n.slot) || uint64_t(child) >= nslots)
          fail("child descriptor not after its parent or out of range");
        children.push_back({uint64_t(child), v.depth, v.x, v.y, v.z});
      }
      scan.voxels.push_back(v);
    }
    // Depth-first in child-slot order: push the children last-first.
    for (auto it = children.rbegin(); it != children.rend(); ++it) stack.push_back(*it);
  }
  return scan;
}

BlockSlot decode_dag_voxel(const std::vector<uint32_t>& blocks, uint64_t index) {
  const uint64_t at = index / 16 * 6;
  if (at + 6 > blocks.size())
    throw std::runtime_error("DAG voxel " + std::to_string(index) + " beyond the blocks");
  return decode_block_slot(&blocks[size_t(at)], int(index % 16));
}

uint64_t interleave3(uint32_t x, uint32_t y, uint32_t z) {
  uint64_t code = 0;
  for (int bit = 0; bit < 21; ++bit)
    code |= uint64_t(x >> bit & 1) << (3 * bit) | uint64_t(y >> bit & 1) << (3 * bit + 1) |
            uint64_t(z >> bit & 1) << (3 * bit + 2);
  return code;
}

double angle_between(RefVec a, RefVec b) {
  const RefVec ua = scale(a, 1.0 / norm(a)), ub = scale(b, 1.0 / norm(b));
  const RefVec d{ua.x - ub.x, ua.y - ub.y, ua.z - ub.z};
  return 2.0 * std::asin(std::min(1.0, 0.5 * norm(d)));
}

}  // namespace voxcast::testing::independent
