// Statistics over a built or validated octree (esvo §8.2 reports per-level
// voxel counts and the memory split) and leaf decoding.
#include <bit>

#include "esvo/layout_internal.hpp"
#include "voxcast/esvo.hpp"

namespace voxcast::esvo {
namespace {

/// Depth-first walk over all descriptors in child-slot order; calls
/// `on_descriptor(slot, depth, code)` (code = Morton code of the node at its
/// depth). Children are pushed in reverse so they pop in ascending order,
/// which makes the leaf codes come out sorted.
template <class F>
void walk(const EsvoOctree& octree, F&& on_descriptor) {
  struct Item {
    uint32_t slot;
    int depth;
    uint64_t code;
  };
  const uint32_t* w = octree.words.data();
  std::vector<Item> stack{{octree.root_slot(), 0, 0}};
  while (!stack.empty()) {
    const Item it = stack.back();
    stack.pop_back();
    on_descriptor(it.slot, it.depth, it.code);
    const uint32_t w0 = w[size_t(it.slot) * 2];
    const uint32_t nl = detail::non_leaf_mask(w0);
    if (!nl || it.depth + 1 >= octree.levels()) continue;
    const uint32_t group = detail::child_group(w, it.slot);
    for (int i = 7; i >= 0; --i)
      if (nl >> i & 1)
        stack.push_back({group + uint32_t(std::popcount(nl & ((1u << i) - 1))), it.depth + 1,
                         it.code << 3 | uint64_t(i)});
  }
}

}  // namespace

std::vector<uint64_t> decode_leaves(const EsvoOctree& octree) {
  std::vector<uint64_t> out;
  const uint32_t* w = octree.words.data();
  const int L = octree.levels();
  walk(octree, [&](uint32_t slot, int depth, uint64_t code) {
    // Without contours validate() guarantees every leaf is at the finest
    // level (depth L); variable-depth leaves above it are not listed.
    if (depth + 1 != L) return;
    const uint32_t leaf = detail::leaf_mask(w[size_t(slot) * 2]);
    for (int i = 0; i < 8; ++i)
      if (leaf >> i & 1) out.push_back(code << 3 | uint64_t(i));
  });
  return out;
}

std::vector<LevelStats> EsvoOctree::level_stats() const {
  std::vector<LevelStats> s(size_t(levels()) + 1);
  s[0].voxels = 1;
  s[0].non_leaf = 1;  // the root always owns a descriptor
  const uint32_t* w = words.data();
  walk(*this, [&](uint32_t slot, int depth, uint64_t) {
    const uint32_t w0 = w[size_t(slot) * 2];
    s[size_t(depth) + 1].voxels += uint64_t(std::popcount(detail::valid_mask(w0)));
    s[size_t(depth) + 1].non_leaf += uint64_t(std::popcount(detail::non_leaf_mask(w0)));
  });
  return s;
}

MemoryStats EsvoOctree::memory_stats() const {
  MemoryStats m;
  const std::vector<detail::BlockInfo> blocks = detail::parse_blocks(*this);
  const uint32_t* w = words.data();
  const bool compressed = blocks[0].attach_type == kAttachCompressedColorNormal;
  m.attribute_format = compressed ? AttributeFormat::Compressed : AttributeFormat::Raw;
  // Compressed: which slots hold descriptors (1) or far pointers (2), to find
  // the pairing gaps (§5.5).
  std::vector<uint8_t> used(compressed ? words.size() / 2 : 0, 0);
  uint64_t descriptors = 0, far = 0;
  walk(*this, [&](uint32_t slot, int, uint64_t) {
    ++descriptors;
    const uint32_t w0 = w[size_t(slot) * 2];
    const bool has_far = detail::is_far(w0) && detail::non_leaf_mask(w0);
    far += has_far ? 1 : 0;
    if (compressed) {
      used[slot] = 1;
      if (has_far) used[slot + detail::child_pointer(w0)] = 2;
    }
  });
  uint64_t pages = 0;
  for (const auto& b : blocks) {
    pages += (b.slot_count + kPageSlots - 1) / kPageSlots;
    m.info_bytes += b.info_words * 4;
    if (b.contours != 0) {  // §5.2: count word + values
      m.contour_bytes += (1 + b.contour_count) * 4;
      m.contour_count += b.contour_count;
    }
    if (compressed) {
      m.attribute_lookup_bytes += 2 * 4;    // attachment header only, no lookup table
      m.color_bytes += b.pair_count * 8;    // words 0-1 of each compression block
      m.normal_bytes += b.pair_count * 16;  // words 2-5
      // Pairing gaps: empty slots (not a page header, descriptor or far
      // pointer) whose pair partner is a descriptor.
      for (uint64_t s = b.first_slot; s < b.first_slot + b.slot_count; ++s)
        if (s % kPageSlots != 0 && !used[s] && used[s ^ 1] == 1) m.pair_padding_bytes += 8;
    } else {
      m.attribute_lookup_bytes += (2 + b.slot_count) * 4;  // header + one entry per slot
      m.color_bytes += b.value_count * 4;
      m.normal_bytes += b.value_count * 4;
    }
  }
  m.attribute_value_bytes = m.color_bytes + m.normal_bytes;
  m.descriptor_bytes = descriptors * 8;
  m.far_pointer_bytes = far * 8;
  m.page_header_bytes = pages * 8;
  m.total_bytes = uint64_t(words.size()) * 4;
  // Everything else: padding slots in front of page-straddling groups, block
  // alignment to 8 KiB and the tail of the last page.
  m.padding_bytes = m.total_bytes - m.descriptor_bytes - m.far_pointer_bytes - m.page_header_bytes -
                    m.info_bytes - m.attribute_lookup_bytes - m.attribute_value_bytes -
                    m.pair_padding_bytes - m.contour_bytes;
  return m;
}

}  // namespace voxcast::esvo
