#pragma once
// Small helpers shared by the ESVO builder, validator, statistics and
// attribute lookup (private to src/esvo). Layout: see include/voxcast/esvo.hpp.
#include <cstddef>
#include <cstdint>
#include <vector>

#include "voxcast/esvo.hpp"

namespace voxcast::esvo::detail {

// Child descriptor fields: esvo::layout (include/voxcast/esvo.hpp).
inline constexpr uint32_t kMaxNearPointer = layout::ChildPointer::max;
inline uint32_t valid_mask(uint32_t w0) {
  return layout::ValidMask::get(w0);
}
inline uint32_t leaf_mask(uint32_t w0) {
  return layout::LeafMask::get(w0);
}
inline uint32_t non_leaf_mask(uint32_t w0) {
  return valid_mask(w0) & ~leaf_mask(w0);
}
inline uint32_t child_pointer(uint32_t w0) {
  return layout::ChildPointer::get(w0);
}
inline bool is_far(uint32_t w0) {
  return layout::FarBit::test(w0);
}
inline constexpr uint32_t kMaxContourPointer = layout::ContourPointer::max;
inline uint32_t contour_mask(uint32_t w1) {
  return layout::ContourMask::get(w1);
}
inline uint32_t contour_pointer(uint32_t w1) {
  return layout::ContourPointer::get(w1);
}

// Info section layout (word offsets from the info section).
inline constexpr size_t kInfoMagicWord = 0, kInfoFirstSlotWord = 1, kInfoSlotCountWord = 2,
                        kInfoAttachCountWord = 3, kInfoAttachTable = 4;

/// Word index of the first attachment of `type` of the info section at word
/// `info`. Unchecked: callers rely on validate()/the builder. Returns the
/// first attachment if the type is absent (validate() guarantees presence).
inline size_t find_attachment(const uint32_t* w, size_t info, uint32_t type) {
  const uint32_t count = w[info + kInfoAttachCountWord];
  for (uint32_t a = 0; a < count; ++a)
    if (w[info + kInfoAttachTable + 2 * a] == type)
      return size_t(int64_t(info) + int32_t(w[info + kInfoAttachTable + 2 * a + 1]));
  return size_t(int64_t(info) + int32_t(w[info + kInfoAttachTable + 1]));
}

/// The color/normal attachment of the info section at word `info`: the first
/// attachment of type kAttachRawColorNormal or kAttachCompressedColorNormal
/// (validate() guarantees exactly one). Unchecked; `type` receives its type.
inline size_t find_color_attachment(const uint32_t* w, size_t info, uint32_t* type) {
  const uint32_t count = w[info + kInfoAttachCountWord];
  for (uint32_t a = 0; a < count; ++a) {
    const uint32_t t = w[info + kInfoAttachTable + 2 * a];
    if (t == kAttachRawColorNormal || t == kAttachCompressedColorNormal) {
      *type = t;
      return size_t(int64_t(info) + int32_t(w[info + kInfoAttachTable + 2 * a + 1]));
    }
  }
  *type = w[info + kInfoAttachTable];
  return size_t(int64_t(info) + int32_t(w[info + kInfoAttachTable + 1]));
}

/// Slot of the first descriptor of the child group of the descriptor at
/// `slot` (follows a far pointer if the far bit is set). Unchecked.
inline uint32_t child_group(const uint32_t* w, uint32_t slot) {
  const uint32_t w0 = w[size_t(slot) * 2];
  const uint32_t p = slot + child_pointer(w0);
  if (!is_far(w0)) return p;
  return uint32_t(int64_t(slot) + int32_t(w[size_t(p) * 2]));
}

/// One block, as located by parse_blocks().
struct BlockInfo {
  uint64_t first_slot;         // block start (its first page header)
  uint64_t slot_count;         // descriptor area size in slots (page headers included)
  uint64_t info;               // word index of the info section
  uint64_t info_words;         // 4 + 2 * attachment count
  uint64_t attach;             // word index of the color/normal attachment
  uint32_t attach_type;        // kAttachRawColorNormal or kAttachCompressedColorNormal
  uint64_t value_count;        // raw: values in that attachment; compressed: 0
  uint64_t pair_count;         // compressed: compression blocks (descriptor pairs); raw: 0
  uint64_t end;                // one past the last word of the block
  uint64_t contours = 0;       // word index of the contour attachment (0 = none)
  uint64_t contour_count = 0;  // contour values in it
};

/// Locates and bounds-checks every block's page headers, info section and
/// color/normal attachment (validate.cpp). Throws voxcast::Error on the first problem.
std::vector<BlockInfo> parse_blocks(const EsvoOctree& octree);

}  // namespace voxcast::esvo::detail
