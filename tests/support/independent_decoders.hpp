#pragma once
// Test-side decoders for voxcast's attribute and node encodings, written from
// the documented bit layouts only (include/voxcast/esvo.hpp, the block layout
// comment at the top of src/esvo/compress.cpp, the value layout comment in
// src/esvo/attributes.cpp, include/voxcast/dag.hpp). They call no voxcast
// codec, table or traversal helper and compute in double precision, so a
// change that alters the encoder and the implementation's decoder together
// (e.g. swapping the two color endpoints, or the two normal axes) makes the
// implementation disagree with these, even though it still agrees with itself.
#include <cstdint>
#include <vector>

namespace voxcast::testing::independent {

struct RefVec {
  double x = 0, y = 0, z = 0;
};
/// Linear RGBA plus the 8-bit sRGB codes it came from.
struct RefColor {
  double r = 0, g = 0, b = 0, a = 1;
  int srgb[3] = {0, 0, 0};
};

/// IEC 61966-2-1 sRGB transfer function, 8-bit code -> linear.
double srgb8_to_linear(int code);
/// The inverse, rounded to the nearest 8-bit code (clamped to [0, 1]).
int linear_to_srgb8(double linear);

/// Raw color word (esvo.hpp, attributes.cpp): | 31..24 A | 23..16 B | 15..8 G |
/// 7..0 R |, RGB sRGB-encoded, A linear.
RefColor decode_abgr(uint32_t abgr);
/// Raw cube-face normal word (attributes.cpp): | 31..29 face | 28..15 u |
/// 14..0 v |, face = axis * 2 + negative, u on component (axis+1)%3, v on
/// (axis+2)%3, [0, 2^14-1] / [0, 2^15-1] mapped linearly onto [-1, 1].
/// cube_point is the point on the cube (major component +-1, not normalized);
/// faces 6 and 7 are not produced by any encoder: reported through `ok`.
RefVec cube_point(uint32_t code, bool* ok = nullptr);
RefVec decode_cube_normal(uint32_t code, bool* ok = nullptr);

/// One slot (0..15) of an esvo §5.5 compression block (6 words, compress.cpp):
/// word 0 = c1 << 16 | c0 (RGB-565, sRGB), word 1 = 2-bit color index of slot
/// i at bits 2i+1..2i over the DXT1 palette {c0, c1, (2 c0 + c1 + 1) / 3,
/// (c0 + 2 c1 + 1) / 3} after 5/6 -> 8-bit replication; word 2 = base normal
/// (cube point); word 3 = n_u (high half) | n_v (low half), each | e | z | y |
/// x | nibbles, component = m * 2^(e - 15), m signed 4-bit; words 4-5 = slot
/// i's nibble at word 4 + (i >> 3), bits 4(i&7).., | k_v | k_u | (2 bits
/// each), c(k) = (2k - 3) / 3; normal = normalize(n_b + c_u n_u + c_v n_v).
struct BlockSlot {
  RefColor color;
  RefVec normal;  // unit (n_b alone if the sum is ~zero, as documented)
};
BlockSlot decode_block_slot(const uint32_t* block6, int slot);

/// The block's n_b, n_u, n_v as documented (exposed for golden tests).
struct BlockNormalBasis {
  RefVec base, u, v;
};
BlockNormalBasis decode_block_basis(const uint32_t* block6);

/// ESVO child descriptor (esvo.hpp, §5.1 Figure 2): word 0 = | 31..17 child
/// pointer | 16 far | 15..8 valid | 7..0 leaf |, word 1 = | 31..8 contour
/// pointer | 7..0 contour mask |.
struct Descriptor {
  uint32_t child_pointer = 0;
  bool far = false;
  uint32_t valid = 0, leaf = 0;
  uint32_t contour_pointer = 0, contour_mask = 0;
};
Descriptor decode_descriptor(uint32_t word0, uint32_t word1);

/// ESVO contour value (esvo.hpp ContourValue, Figure 4): | 31..25 thickness
/// (unsigned) | 24..18 position | 17..12 nx | 11..6 ny | 5..0 nz | (signed).
struct Contour {
  int thickness = 0, position = 0, nx = 0, ny = 0, nz = 0;
};
Contour decode_contour(uint32_t value);

/// Every voxel of an ESVO octree (the raw `words` of the structure or of a
/// scene file's ESVO section), found by following child descriptors, far
/// pointers, page headers, info sections and attachments as esvo.hpp
/// documents them. Throws std::runtime_error on anything inconsistent with
/// the documented layout (so a layout change cannot pass silently).
struct EsvoVoxel {
  uint32_t parent_slot = 0;      // descriptor holding the voxel
  int child = 0;                 // its child slot (x | y<<1 | z<<2)
  int depth = 0;                 // 1 = a child of the root
  uint32_t x = 0, y = 0, z = 0;  // integer coordinates at `depth`
  bool leaf = false;
  BlockSlot attributes;  // decoded from the raw or the compressed attachment
  bool has_contour = false;
  uint32_t contour_value = 0;
};
struct EsvoScan {
  bool compressed = false;
  bool contours = false;
  std::vector<EsvoVoxel> voxels;  // depth-first, child-slot order
};
EsvoScan scan_esvo(const std::vector<uint32_t>& words);

/// Leaf voxel `index` (Morton rank) of a DAG's compressed attribute array
/// (dag.hpp): block index / 16 (6 words each), slot index % 16.
BlockSlot decode_dag_voxel(const std::vector<uint32_t>& blocks, uint64_t index);

/// x, y, z bits interleaved (x lowest), the Morton order of esvo.hpp child slots.
uint64_t interleave3(uint32_t x, uint32_t y, uint32_t z);

/// Angle in radians between two directions (normalized here).
double angle_between(RefVec a, RefVec b);

}  // namespace voxcast::testing::independent
