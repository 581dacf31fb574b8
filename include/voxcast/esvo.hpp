#pragma once
// Efficient Sparse Voxel Octree (Laine & Karras 2010, §5).
//
// Memory layout (all little-endian 32-bit words in one array, `EsvoOctree::words`):
//
//   The array is a sequence of *blocks*. Each block is
//     [descriptor area][info section][attachments...]
//   and starts at an 8 KiB boundary (word index multiple of kPageWords = 2048).
//
//   Descriptor area: 64-bit *slots* (two words). Slot indices are global
//   (word index / 2). The first slot of every 8 KiB page (slot index multiple
//   of kPageSlots = 1024) is a *page header*: word 0 = signed offset in words
//   from the page header to its block's info section, word 1 = 0. Other slots
//   hold child descriptors, far pointers or padding (all-zero).
//
//   Child descriptor (§5.1, Figure 2):
//     word 0: bits 31..17 child pointer (15 bits, unsigned, in slots, relative
//             to this descriptor's slot), bit 16 far, bits 15..8 valid mask,
//             bits 7..0 leaf mask.  Slot i of the 8 children is bit i
//             (i = x | y<<1 | z<<2, the low three Morton bits).
//             valid=0: empty; valid=1,leaf=0: subdivided; valid=1,leaf=1: leaf.
//     word 1: bits 31..8 contour pointer, bits 7..0 contour mask (§5.2; zero
//             unless the octree was built with BuildOptions::contours).
//             Bit i of the contour mask says that the voxel in child slot i
//             has a contour; the contour pointer is an unsigned offset in
//             WORDS from this descriptor's word 0 (as the listing's
//             `parent[ofs + popc8(contour_mask & 0x7F)]`, Appendix A) to the
//             first of the descriptor's consecutive contour values, one per
//             set mask bit in slot order. They live in the contour attachment
//             of the descriptor's own block (below); validate() checks that
//             pointer + popcount(mask) - 1 stays inside it.
//   The descriptors of a node's non-leaf children are stored in consecutive
//   slots in child-slot order; the child pointer points at the first. If the
//   far bit is set, the child pointer instead gives the (relative) slot of a
//   far pointer slot whose word 0 is a signed 32-bit slot offset from the
//   referencing descriptor to its first child. Children always come after
//   their parent (offset > 0), so the hierarchy is acyclic. A group of child
//   descriptors never straddles a page header. The root descriptor is the
//   first descriptor of block 0.
//
//   A block's descriptor area starts at the block start (a page header) and
//   ends right before its info section; "the block's first descriptor slot"
//   and "block first slot" below mean that start slot (the slot of the
//   block's first page header), so a slot's lookup entry index is simply
//   slot - block start slot.
//
//   Info section (one per block, 2-word aligned):
//     word 0: kInfoMagic, word 1: signed word offset from the info section to
//     the block's first descriptor slot, word 2: number of slots in the block's
//     descriptor area, word 3: attachment count A, then A pairs
//     (type, signed word offset from the info section to the attachment).
//
//   Raw attribute attachment (type kAttachRawColorNormal, §5.4, Figure 7):
//     word 0: slot count S (= the block's descriptor area size), word 1: value
//     count V, then S lookup entries (one per slot of the descriptor area,
//     gaps included): bits 31..8 value pointer (in values, relative to the
//     first value), bits 7..0 attribute mask. Then V values of two words:
//     32-bit ABGR color (R in the low byte, sRGB-encoded) and a 32-bit
//     cube-face normal: bits 31..29 face (axis*2 + (negative?1:0)),
//     bits 28..15 u (14 bits), bits 14..0 v (15 bits); u and v map [-1,1] on
//     the face to [0, 2^14-1] and [0, 2^15-1].
//   The attributes of the voxel in child slot i of descriptor d live in d's
//   block, at lookup entry (d - block first slot), value
//   pointer + popcount(mask & ((1<<i)-1)). Every voxel except the root has one.
//
//   Compressed attribute attachment (type kAttachCompressedColorNormal, §5.5,
//   Figures 9-10; chosen with BuildOptions::attributes): word 0: slot count S
//   (= the block's descriptor area size), word 1: compression block count
//   C <= ceil(S/2), then C blocks of 6 words. No lookup table: the voxel in
//   child slot i of descriptor d lives in
//     compression block  (d - block first slot) >> 1,
//     block slot         ((d - block first slot) & 1) * 8 + i,
//   i.e. compression block k covers the descriptor *pair* of slots
//   first + 2k, first + 2k + 1 (block first slots are page aligned, hence
//   even, so this is also the global slot parity). Block words (bit fields in
//   src/esvo/compress.cpp): 0 = two RGB-565 endpoints, 1 = 16 x 2-bit color
//   indices (DXT1 palette {c0, c1, 2/3 c0 + 1/3 c1, 1/3 c0 + 2/3 c1}, no
//   transparency, alpha decodes as 1), 2 = base normal n_b as a cube point
//   (raw normal encoding, not normalized), 3 = axes n_u | n_v (each: 4-bit
//   exponent + three signed 4-bit mantissas, value m * 2^(e-15)),
//   4-5 = 16 x (2-bit c_u, 2-bit c_v) with c in {-1, -1/3, 1/3, 1}; the
//   normal is normalize(n_b + c_u n_u + c_v n_v).
//   Pairing rule (enforced by validate()): the two slots of a pair never hold
//   descriptors of two different child groups ("leave gaps in the child
//   descriptor array", §5.5), so one block only mixes siblings. The builder
//   starts a group at an odd slot only if the slot before it is not a
//   descriptor (page header, far pointer or padding); otherwise it leaves one
//   padding slot. A page header (even slot, no attributes) pairs with the
//   slot after it, which may start a group (the root, slot 1, pairs with
//   block 0's header).
//   Every descriptor's pair index must be < C. A block holds exactly one
//   color/normal attachment (raw or compressed), the same type in all blocks.
//
//   Contour attachment (type kAttachContours, §5.2-5.3; only in octrees built
//   with contours, then in every block, placed right after the info section
//   so that every contour pointer fits 24 bits): word 0: contour count C,
//   then C 32-bit contour values (Figure 4, bit layout at ContourValue).
//   The final shape of a voxel is its cube intersected with its own contour
//   slab and those of all its ancestors (§5.3).
//
// Conventions of voxcast's builder, enforced by validate(): all leaf voxels
// are at depth `levels` (the finest level) -- except in octrees carrying a
// contour attachment, whose variable-depth build (§7.1, §7.3:
// BuildOptions::max_level / *_error) may stop at any depth -- every descriptor has a non-empty
// valid mask, a descriptor without subdivided children has child pointer 0
// and no far bit, and every descriptor is reachable exactly once. The array ends
// padded with zeros to a whole number of pages. Voxels built without input
// attributes get linear gray (0.5, 0.5, 0.5, 1) and the normal (0, 0, 1).
//
// The octree occupies the cube [1,2]^3 in octree space (§6.1); scale s means a
// cube of side 2^(s - kMaxScale); leaves of an N = 2^L grid are at scale
// kMaxScale - L.
#include <cstdint>
#include <string>
#include <vector>

#include "voxcast/bitfield.hpp"
#include "voxcast/math.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast::esvo {

inline constexpr int kMaxScale = 23;          // s_max: float mantissa bits
inline constexpr uint32_t kPageWords = 2048;  // 8 KiB pages
inline constexpr uint32_t kPageSlots = kPageWords / 2;
inline constexpr uint32_t kInfoMagic = 0x4F464E49;  // "INFO"
inline constexpr uint32_t kAttachRawColorNormal = 1;
inline constexpr uint32_t kAttachCompressedColorNormal = 2;
inline constexpr uint32_t kAttachContours = 3;

/// The bit fields of the layout above, named once and pinned to the
/// documented masks; every reader and writer of these words goes through them.
namespace layout {
// Child descriptor word 0: | 31..17 child pointer | 16 far | 15..8 valid | 7..0 leaf |
using ChildPointer = BitField<17, 15>;
using FarBit = BitField<16, 1>;
using ValidMask = BitField<8, 8>;
using LeafMask = BitField<0, 8>;
static_assert(ChildPointer::mask == 0xFFFE0000u && FarBit::mask == 0x00010000u &&
              ValidMask::mask == 0x0000FF00u && LeafMask::mask == 0x000000FFu);
static_assert(fields_tile<ChildPointer, FarBit, ValidMask, LeafMask>());
// Child descriptor word 1: | 31..8 contour pointer (words) | 7..0 contour mask |
using ContourPointer = BitField<8, 24>;
using ContourMask = BitField<0, 8>;
static_assert(ContourPointer::mask == 0xFFFFFF00u && ContourMask::mask == 0xFFu);
static_assert(fields_tile<ContourPointer, ContourMask>());
// Raw attachment lookup entry: | 31..8 value pointer | 7..0 attribute mask |
using ValuePointer = BitField<8, 24>;
using AttributeMask = BitField<0, 8>;
static_assert(ValuePointer::mask == 0xFFFFFF00u && AttributeMask::mask == 0xFFu);
static_assert(fields_tile<ValuePointer, AttributeMask>());
// Cube-face normal: | 31..29 face | 28..15 u | 14..0 v |
using NormalFace = BitField<29, 3>;
using NormalU = BitField<15, 14>;
using NormalV = BitField<0, 15>;
static_assert(NormalFace::mask == 0xE0000000u && NormalU::mask == 0x1FFF8000u &&
              NormalV::mask == 0x00007FFFu);
static_assert(fields_tile<NormalFace, NormalU, NormalV>());
// ABGR color: R in the low byte.
using ColorR = BitField<0, 8>;
using ColorG = BitField<8, 8>;
using ColorB = BitField<16, 8>;
using ColorA = BitField<24, 8>;
static_assert(ColorR::mask == 0xFFu && ColorA::mask == 0xFF000000u);
static_assert(fields_tile<ColorR, ColorG, ColorB, ColorA>());
using ColorChannels = PackedFields<8>;  // channel c = R, G, B, A for c = 0..3
static_assert(ColorChannels::get(0x44332211u, 0) == ColorR::get(0x44332211u) &&
              ColorChannels::get(0x44332211u, 2) == ColorB::get(0x44332211u));
// Contour value (ContourValue below): | 31..25 t | 24..18 p | 17..12 nx | 11..6 ny | 5..0 nz |
using ContourThickness = BitField<25, 7>;
using ContourPosition = BitField<18, 7>;  // signed
using ContourNx = BitField<12, 6>;        // signed
using ContourNy = BitField<6, 6>;         // signed
using ContourNz = BitField<0, 6>;         // signed
static_assert(ContourThickness::mask == 0xFE000000u && ContourPosition::mask == 0x01FC0000u &&
              ContourNx::mask == 0x0003F000u && ContourNy::mask == 0x00000FC0u &&
              ContourNz::mask == 0x0000003Fu);
static_assert(fields_tile<ContourThickness, ContourPosition, ContourNx, ContourNy, ContourNz>());
// Compressed block (see "Compressed attribute attachment" above and
// src/esvo/compress.cpp). Word 0: | 31..16 c1 | 15..0 c0 |, each RGB-565
// | 15..11 R | 10..5 G | 4..0 B |.
using Endpoint0 = BitField<0, 16>;
using Endpoint1 = BitField<16, 16>;
using Rgb565R = BitField<11, 5>;
using Rgb565G = BitField<5, 6>;
using Rgb565B = BitField<0, 5>;
static_assert(fields_tile<Endpoint0, Endpoint1>());
static_assert(Rgb565R::mask == 0xF800u && Rgb565G::mask == 0x07E0u && Rgb565B::mask == 0x001Fu);
static_assert(fields_tile<Rgb565R, Rgb565G, Rgb565B>(0xFFFFu));
// Word 1: 16 x 2-bit color indices, slot i at bits 2i+1..2i.
using ColorIndices = PackedFields<2>;
// Word 2: base normal n_b, the cube-normal fields above. Word 3:
// | 31..16 axis n_u | 15..0 axis n_v |, each | 15..12 e | 11..8 z | 7..4 y | 3..0 x |
// (signed 4-bit mantissas, 4-bit exponent).
using AxisU = BitField<16, 16>;
using AxisV = BitField<0, 16>;
using AxisExponent = BitField<12, 4>;
using AxisMantissas = PackedFields<4>;  // x, y, z = elements 0, 1, 2 (signed)
static_assert(fields_tile<AxisU, AxisV>());
static_assert(AxisExponent::mask == 0xF000u);
// Words 4, 5: 16 x 4-bit normal indices, slot i at word 4 + (i >> 3), element
// i & 7; each | 3..2 k_v | 1..0 k_u |.
inline constexpr uint32_t kNormalIndexWord = 4;
using NormalIndices = PackedFields<4>;
using NormalIndexU = BitField<0, 2>;
using NormalIndexV = BitField<2, 2>;
static_assert(fields_tile<NormalIndexU, NormalIndexV>(0xFu));
}  // namespace layout

/// How a scene stores its colors and normals (§5.4 raw, §5.5 compressed).
enum class AttributeFormat : uint32_t { Raw = 0, Compressed = 1 };

uint32_t encode_color_abgr(const Color& linear);  // sRGB-encodes
Color decode_color_abgr(uint32_t abgr);           // back to linear
uint32_t encode_normal_cube(Vec3 unit_normal);
Vec3 decode_normal_cube(uint32_t code);
/// out[i] = decode_normal_cube(codes[i]) for i < n, the same floats (the
/// same IEEE operations, 8 codes at a time in vector lanes).
void decode_normal_cubes(const uint32_t* codes, size_t n, Vec3* out);

/// One §5.5 compression block (6 words, layout above and in compress.cpp)
/// from the colors (linear; alpha ignored) and normals of its 16 slots; only
/// slots with bit i of `used` set are read and fitted.
void encode_compressed_block(const Color* colors16, const Vec3* normals16, uint32_t used,
                             uint32_t out[6]);
/// Decodes slot `slot` (0..15) of a compression block; total for any bits.
void decode_compressed_slot(const uint32_t* block, int slot, Color* color, Vec3* normal);
/// The same decoding by palette entry: slot i shows color entry
/// compressed_color_index(block, i) (0..3) and normal entry
/// compressed_normal_index(block, i) (0..15), and
/// decode_compressed_color/normal of those entries are exactly
/// decode_compressed_slot's values (one code path). Sums over many slots of
/// one block decode each entry once.
inline int compressed_color_index(const uint32_t* block, int slot) {
  return int(layout::ColorIndices::get(block[1], unsigned(slot)));
}
inline int compressed_normal_index(const uint32_t* block, int slot) {
  return int(layout::NormalIndices::get(block[layout::kNormalIndexWord + (slot >> 3)],
                                        unsigned(slot & 7)));
}
Color decode_compressed_color(const uint32_t* block, int entry);
Vec3 decode_compressed_normal(const uint32_t* block, int entry);
/// decode_compressed_normal of every entry e with bit e of `entries` set, to
/// out[e] (the block's base normal and axes decoded once).
void decode_compressed_normals(const uint32_t* block, uint32_t entries, Vec3 out[16]);

/// One contour (§5.2, Figure 4): a pair of parallel planes bounding the
/// voxel. 32-bit value, most significant bits first:
///   bits 31..25 thickness t (7 bits, unsigned, 0..127)
///   bits 24..18 position p  (7 bits, signed, -64..63)
///   bits 17..12 nx, 11..6 ny, 5..0 nz (6 bits each, signed, -32..31)
/// This is the layout the Appendix A decode implies: `(unsigned)value` puts t
/// in the top bits, `value << 7` p, `value << 14 / 20 / 26` nx / ny / nz.
/// Fixed point (derived from the listing's constants: after the shifts every
/// field sits at the top of a 32-bit int, i.e. t, p at 2^25 and n at 2^26
/// units, so `* 0.75` and `* 1.5` relative to the normal's 2^26 give):
///   with n = (nx, ny, nz) (integer, NOT normalized), s = the voxel's side and
///   c = its center, the slab is  { x : |n.(x - c) - 0.75 s p| <= 0.375 s t }.
/// decode masks each field exactly (the listing leaves the lower fields in
/// the low bits of each float conversion, an error below one unit).
struct ContourValue {
  int nx = 0, ny = 0, nz = 0;  // -32..31
  int position = 0;            // -64..63, units of 0.75 s
  unsigned thickness = 0;      // 0..127, half-thickness in units of 0.375 s
};
uint32_t encode_contour(const ContourValue& c);  // fields are masked to their widths
ContourValue decode_contour(uint32_t value);

struct BuildOptions {
  /// A block is closed once it holds this many descriptor slots or attribute
  /// values (whichever first); the 24-bit value pointer caps it at 2^24. Small
  /// values are useful in tests to exercise multi-block layouts and far pointers.
  uint32_t max_block_slots = 1u << 20;
  uint32_t max_block_values = 1u << 22;
  /// Raw: 8 bytes per voxel + a lookup entry per slot (§5.4). Compressed:
  /// 24 bytes per descriptor pair (§5.5), lossy (bounds in the tests).
  AttributeFormat attributes = AttributeFormat::Raw;
  /// Progress bar of the in-core build (its phases re-planned: levels,
  /// layout; with contours levels, contours, layout and, with compressed
  /// attributes and a color/normal tolerance, attributes); optional, null = none.
  Progress* progress = nullptr;

  // ---- Contours and variable depth (§5.2-5.3, §7.1-7.3): need the mesh
  // overload of build_octree. Without `contours` none of these apply and the
  // build is the full-depth one above, byte for byte. ----
  /// Build a contour for every voxel where it tightens the shape (§7.2).
  bool contours = false;
  /// Deepest level of the octree (1..grid levels; 0 = grid levels). Voxels at
  /// this depth are leaves.
  int max_level = 0;
  /// REFINE-GEOMETRY (§7.1): a voxel is subdivided only if some vertex of its
  /// final shape (cube ∩ ancestor contours ∩ own contour) lies farther than
  /// this from the surface, in voxels of the finest grid level. Also the
  /// contour omission threshold of §7.2 (a contour is left out when the
  /// shape without it is within the threshold; 0.25 when unset).
  /// <= 0: unset.
  double geometry_error = 0;
  /// REFINE-ATTRIBUTES (§7.3): a voxel is subdivided if the color it decodes
  /// to as a leaf (8-bit sRGB; with compressed attributes after the §5.5
  /// block compression of its descriptor pair) differs by more than this in
  /// any channel (0-255 units) from the raw-encoded color of some full-depth
  /// voxel below it, resp. its decoded normal by more than `normal_error`
  /// degrees. Guaranteed for every leaf above max_level (tested by brute
  /// force). < 0: unset. Variable depth is on when any of the three
  /// tolerances is set; unset tolerances never force a subdivision.
  double color_error = -1;
  double normal_error = -1;
};

/// Per-level counts for `voxcast info` (esvo §8.2). Level 0 is the root.
struct LevelStats {
  uint64_t voxels = 0;    // voxels at this level
  uint64_t non_leaf = 0;  // of which subdivided (own a descriptor)
};

struct MemoryStats {
  uint64_t descriptor_bytes = 0;  // child descriptors
  uint64_t far_pointer_bytes = 0;
  uint64_t page_header_bytes = 0;
  uint64_t padding_bytes = 0;  // unused slots (alignment, reserved far slots)
  uint64_t info_bytes = 0;     // info sections
  uint64_t attribute_lookup_bytes = 0;
  uint64_t attribute_value_bytes = 0;  // = color_bytes + normal_bytes
  uint64_t total_bytes = 0;
  // Attribute split: raw: 4 + 4 bytes per value; compressed: per compression
  // block 8 bytes of colors (words 0-1) and 16 bytes of normals (words 2-5).
  AttributeFormat attribute_format = AttributeFormat::Raw;
  uint64_t color_bytes = 0;
  uint64_t normal_bytes = 0;
  /// Compressed only: empty slots whose pair partner is a descriptor (the
  /// gaps §5.5 leaves so a block only pairs siblings). Not in padding_bytes.
  uint64_t pair_padding_bytes = 0;
  /// Contour attachments (§5.2): header word + 4 bytes per contour value.
  /// (The contour pointer/mask word of each descriptor is in descriptor_bytes.)
  uint64_t contour_bytes = 0;
  uint64_t contour_count = 0;
};

class EsvoOctree {
 public:
  GridTransform grid;           // world placement of the root cube
  std::vector<uint32_t> words;  // the blocks, layout above
  uint32_t block_count = 0;

  int levels() const { return grid.levels; }
  /// Root descriptor slot (first descriptor of block 0, i.e. slot 1).
  uint32_t root_slot() const { return 1; }
  const uint32_t* slot_ptr(uint32_t slot) const { return words.data() + size_t(slot) * 2; }

  /// Color (linear) and unit normal of the voxel in child slot `child` of the
  /// descriptor at `parent_slot`.
  void attributes(uint32_t parent_slot, int child, Color* color, Vec3* normal) const;
  /// attributes(parent_slots[i], children[i], &colors[i], &normals[i]) for
  /// i < n, the same floats: with raw attachments every value of a group
  /// is located (one page header -> info -> attachment chain per page) and
  /// prefetched before any is read, and the normals are decoded in vector
  /// lanes (decode_normal_cubes).
  void attributes(const uint32_t* parent_slots, const uint8_t* children, size_t n, Color* colors,
                  Vec3* normals) const;
  /// What attributes(parent_slot, child) reads, as cache hints in two steps
  /// (a raw lookup is a chain: the slot's lookup entry, then the value it
  /// points to): prefetch_attribute_entry starts the entry's read (a
  /// compressed block's: the block), prefetch_attribute_value, called once
  /// the entry has had time to arrive, reads it and starts the value's.
  void prefetch_attribute_entry(uint32_t parent_slot) const;
  void prefetch_attribute_value(uint32_t parent_slot, int child) const;

  /// The attachment type of block 0 (all blocks agree after validate()).
  /// Bounds-checked: safe on unvalidated words (reads Raw when unsure).
  AttributeFormat attribute_format() const;
  /// True if block 0 has a contour attachment (bounds-checked like attribute_format).
  bool has_contours() const;

  std::vector<LevelStats> level_stats() const;
  MemoryStats memory_stats() const;

  /// Full structural check of `words` (every page header, info section,
  /// descriptor, far pointer and lookup entry reachable from the root):
  /// throws voxcast::Error naming the first problem. After it succeeds,
  /// traversal and attribute lookup cannot read out of bounds or loop.
  void validate() const;
};

/// Builds the octree from sorted unique Morton codes of `voxels` (bottom-up,
/// esvo §7.1 / hitchhiker's guide): parent attributes are the area-weighted
/// average of their children so that every level is a valid LOD.
EsvoOctree build_octree(const VoxelSet& voxels, const BuildOptions& options = {});

/// The same with the source mesh (`voxels` must be its voxelization into
/// voxels.grid), needed for BuildOptions::contours and the variable-depth
/// build (§7.1-7.3); without `contours` it equals build_octree(voxels, options).
EsvoOctree build_octree(const VoxelSet& voxels, const Mesh& mesh, const BuildOptions& options);

/// World-space bounds of the occupied voxels, resolved down to `max_level`
/// (coarser levels give a slightly larger box). Used for automatic cameras.
Aabb occupied_bounds(const EsvoOctree& octree, int max_level = 7);

/// The set of leaf voxels as sorted Morton codes at the octree's finest level
/// (inverse of build_octree; used by tests and tools). Leaves above the
/// finest level (variable-depth builds) are not listed.
std::vector<uint64_t> decode_leaves(const EsvoOctree& octree);

}  // namespace voxcast::esvo
