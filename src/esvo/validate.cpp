// Structural validation of an ESVO word array (layout: include/voxcast/esvo.hpp).
//
// validate() is the gate between untrusted bytes (scene files) and the ray
// caster, which follows child/far pointers and attribute lookups without any
// checks (esvo Appendix A). It proves, in O(size):
//   * every block's page headers, info section and raw attachment are in
//     bounds and mutually consistent (parse_blocks);
//   * every descriptor reachable from the root lies in a descriptor area, not
//     on a page header, is reached exactly once (so traversal work is bounded
//     by the array size), and its child group lies strictly after it, inside
//     one page of one block's descriptor area; a descriptor without
//     subdivided children has a zero pointer field (no far bit);
//   * masks are consistent with the depth (leaves exactly at depth `levels`,
//     or at most there in octrees with contours: variable depth, §7.1);
//   * every contour mask is within the valid mask and its contour pointer +
//     popcount lands inside the contour attachment of the descriptor's block
//     (§5.2; the caster reads words[2 * slot + pointer + rank] unchecked);
//   * every valid child has an attribute value inside its block's values
//     (raw), or every descriptor's pair has a compression block whose base
//     normal face is valid and pairs never mix two child groups (compressed).
#include <algorithm>
#include <bit>
#include <cmath>
#include <string>

#include "esvo/compress.hpp"
#include "esvo/layout_internal.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo.hpp"

namespace voxcast::esvo {
namespace detail {
namespace {

[[noreturn]] void fail(const std::string& what) {
  throw Error("corrupt scene: " + what);
}
[[noreturn]] void fail_at(const std::string& what, uint64_t slot) {
  fail(what + " at slot " + std::to_string(slot));
}

}  // namespace

std::vector<BlockInfo> parse_blocks(const EsvoOctree& octree) {
  const std::vector<uint32_t>& w = octree.words;
  const uint64_t size = w.size();
  if (size < kPageWords || size % 2 != 0) fail("descriptor array shorter than one page");
  if (size > (uint64_t(1) << 32)) fail("descriptor array larger than 2^32 words");
  if (octree.block_count == 0 || octree.block_count > size / kPageWords)
    fail("block count " + std::to_string(octree.block_count) + " out of range");

  std::vector<BlockInfo> blocks;
  blocks.reserve(octree.block_count);
  uint64_t start = 0;  // word index of the block
  for (uint32_t b = 0; b < octree.block_count; ++b) {
    const std::string where = " in block " + std::to_string(b);
    if (start + kPageWords > size) fail("block" + where + " out of range");
    BlockInfo bi{};
    bi.first_slot = start / 2;
    const int64_t info = int64_t(start) + int32_t(w[start]);
    if (info <= int64_t(start) || info % 2 != 0 || uint64_t(info) + 4 > size)
      fail("info section out of range" + where);
    bi.info = uint64_t(info);
    if (w[bi.info + kInfoMagicWord] != kInfoMagic) fail("bad info section magic" + where);
    if (int64_t(bi.info) + int32_t(w[bi.info + kInfoFirstSlotWord]) != int64_t(start))
      fail("info section does not point at its block" + where);
    bi.slot_count = w[bi.info + kInfoSlotCountWord];
    if (bi.slot_count * 2 != bi.info - start) fail("descriptor area size mismatch" + where);
    const uint32_t attach_count = w[bi.info + kInfoAttachCountWord];
    if (attach_count == 0 || attach_count > 16) fail("bad attachment count" + where);
    bi.info_words = kInfoAttachTable + 2 * uint64_t(attach_count);
    if (bi.info + bi.info_words > size) fail("info section out of range" + where);
    bi.end = bi.info + bi.info_words;
    // Exactly one color/normal attachment, raw (§5.4) or compressed (§5.5),
    // of the same type as block 0's.
    bool found = false;
    for (uint32_t a = 0; a < attach_count; ++a) {
      const uint32_t type = w[bi.info + kInfoAttachTable + 2 * a];
      if (type == kAttachContours) {
        // §5.2 contour values: count, then the values.
        if (bi.contours != 0) fail("more than one contour attachment" + where);
        const int64_t at = int64_t(bi.info) + int32_t(w[bi.info + kInfoAttachTable + 2 * a + 1]);
        if (at < int64_t(bi.info + bi.info_words) || uint64_t(at) + 1 > size)
          fail("contour attachment out of range" + where);
        bi.contours = uint64_t(at);
        bi.contour_count = w[bi.contours];
        const uint64_t end = bi.contours + 1 + bi.contour_count;
        if (end > size) fail("contour attachment out of range" + where);
        bi.end = std::max(bi.end, end);
        continue;
      }
      if (type != kAttachRawColorNormal && type != kAttachCompressedColorNormal) continue;
      if (found) fail("more than one color/normal attachment" + where);
      if (b > 0 && type != blocks[0].attach_type)
        fail("attachment type differs from block 0" + where);
      const int64_t at = int64_t(bi.info) + int32_t(w[bi.info + kInfoAttachTable + 2 * a + 1]);
      if (at < int64_t(bi.info + bi.info_words) || uint64_t(at) + 2 > size)
        fail("attachment out of range" + where);
      bi.attach = uint64_t(at);
      bi.attach_type = type;
      if (w[bi.attach] != bi.slot_count) fail("attachment slot count mismatch" + where);
      uint64_t end = 0;
      if (type == kAttachRawColorNormal) {
        bi.value_count = w[bi.attach + 1];
        end = bi.attach + 2 + bi.slot_count + 2 * bi.value_count;
      } else {
        bi.pair_count = w[bi.attach + 1];
        if (bi.pair_count > (bi.slot_count + 1) / 2)
          fail("compressed attachment has more blocks than descriptor pairs" + where);
        end = bi.attach + 2 + kCompressedBlockWords * bi.pair_count;
      }
      if (end > size) fail("attachment out of range" + where);
      bi.end = std::max(bi.end, end);
      found = true;
    }
    if (b > 0 && (bi.contours != 0) != (blocks[0].contours != 0))
      fail("contour attachment in some blocks only" + where);
    // Every page of the descriptor area starts with a header pointing at the info section.
    for (uint64_t p = start; p < bi.info; p += kPageWords)
      if (int64_t(p) + int32_t(w[p]) != int64_t(bi.info) || w[p + 1] != 0)
        fail_at("bad page header", p / 2);
    blocks.push_back(bi);
    start = (bi.end + kPageWords - 1) / kPageWords * kPageWords;
  }
  return blocks;
}

}  // namespace detail

void EsvoOctree::validate() const {
  using namespace detail;
  const int L = grid.levels;
  if (L < 1 || L > kMaxGridLevels) fail("levels " + std::to_string(L) + " outside 1..20");
  if (grid.resolution != (1u << L)) fail("resolution is not 2^levels");
  if (!grid.placement_is_valid())
    fail("bad grid placement (the world cube is not a box of float coordinates within 1e18)");
  const std::vector<BlockInfo> blocks = parse_blocks(*this);
  const uint32_t* w = words.data();
  const uint64_t total_slots = words.size() / 2;
  const bool contours = blocks[0].contours != 0;

  // The block whose descriptor area holds `slot` (not a page header), or null.
  const auto block_of = [&](int64_t slot) -> const BlockInfo* {
    if (slot <= 0 || uint64_t(slot) >= total_slots || slot % kPageSlots == 0) return nullptr;
    auto it = std::upper_bound(blocks.begin(), blocks.end(), uint64_t(slot),
                               [](uint64_t s, const BlockInfo& b) { return s < b.first_slot; });
    if (it == blocks.begin()) return nullptr;
    --it;
    return uint64_t(slot) < it->first_slot + it->slot_count ? &*it : nullptr;
  };

  struct Item {
    uint32_t slot;
    int depth;
  };
  std::vector<uint8_t> visited(size_t(total_slots), 0);
  std::vector<Item> stack{{root_slot(), 0}};
  while (!stack.empty()) {
    const Item it = stack.back();
    stack.pop_back();
    const uint32_t s = it.slot;
    const BlockInfo* block = block_of(s);
    if (!block) fail_at("descriptor outside a descriptor area", s);
    if (visited[s] & 1) fail_at("descriptor shared", s);
    visited[s] |= 1;

    const uint32_t w0 = w[size_t(s) * 2];
    const uint32_t valid = valid_mask(w0), leaf = leaf_mask(w0), nl = non_leaf_mask(w0);
    if (leaf & ~valid) fail_at("leaf mask not within valid mask", s);
    if (!valid) fail_at("empty descriptor", s);
    // Children of this descriptor are at depth it.depth + 1; leaves only at L.
    if (it.depth + 1 == L && nl) fail_at("octree deeper than its levels", s);
    if (it.depth + 1 < L && leaf && !contours) fail_at("leaf above the finest level", s);

    // Contours (§5.2): mask within the valid mask, values inside this block's
    // contour attachment.
    const uint32_t w1 = w[size_t(s) * 2 + 1];
    const uint32_t cm = contour_mask(w1);
    if (cm & ~valid) fail_at("contour mask not within valid mask", s);
    if (!cm && w1) fail_at("contour pointer without a contour mask", s);
    if (cm) {
      if (!block->contours) fail_at("contour without a contour attachment", s);
      const uint64_t first = uint64_t(s) * 2 + contour_pointer(w1);
      if (first < block->contours + 1 ||
          first + uint64_t(std::popcount(cm)) > block->contours + 1 + block->contour_count)
        fail_at("contour pointer out of range", s);
    }

    if (block->attach_type == kAttachRawColorNormal) {
      const uint32_t entry = w[block->attach + 2 + (s - block->first_slot)];
      if ((entry & valid) != valid) fail_at("missing attribute", s);
      if (uint64_t(layout::ValuePointer::get(entry)) +
              uint64_t(std::popcount(layout::AttributeMask::get(entry))) >
          block->value_count)
        fail_at("attribute pointer out of range", s);
    } else {
      // §5.5: the descriptor's pair must have a compression block.
      const uint64_t pair = (s - block->first_slot) >> 1;
      if (pair >= block->pair_count) fail_at("missing compression block", s);
      const uint32_t base = w[block->attach + 2 + kCompressedBlockWords * pair + 2];
      if (layout::NormalFace::get(base) > 5) fail_at("bad compressed base normal", s);
    }

    // A descriptor without subdivided children has no child group, and the
    // builder leaves its pointer field zero. Readers that fetch the pointer
    // before looking at the masks (the beam's coarse pass, esvo §6.2) would
    // otherwise follow a far bit into arbitrary memory: the field must be
    // zero, so no reader can see a pointer this walk has not checked.
    if (!nl) {
      if (child_pointer(w0) != 0 || is_far(w0)) fail_at("child pointer without children", s);
      continue;
    }
    const uint32_t ptr = child_pointer(w0);
    if (ptr == 0) fail_at("child pointer does not point forward", s);
    int64_t group = int64_t(s) + ptr;
    if (is_far(w0)) {
      if (!block_of(group)) fail_at("far pointer out of range", s);
      const int32_t off = int32_t(w[size_t(group) * 2]);
      if (off <= 0) fail_at("far pointer does not point forward", s);
      group = int64_t(s) + off;
    }
    const BlockInfo* gb = block_of(group);
    const int k = std::popcount(nl);
    if (!gb || uint64_t(group) + uint64_t(k) > gb->first_slot + gb->slot_count)
      fail_at("child pointer out of range", s);
    if (uint64_t(group) / kPageSlots != (uint64_t(group) + uint64_t(k) - 1) / kPageSlots)
      fail_at("child group crosses a page header", s);
    for (int i = k - 1; i >= 0; --i) stack.push_back({uint32_t(group) + uint32_t(i), it.depth + 1});
    // Mark group starts (bit 1) so the pairing rule can be checked below.
    visited[size_t(group)] |= 2;
  }
  visited[root_slot()] |= 2;

  // §5.5 pairing rule: a compression block only holds siblings, i.e. when both
  // slots of a pair (2k, 2k+1) are descriptors, 2k+1 continues 2k's group.
  if (blocks[0].attach_type == kAttachCompressedColorNormal)
    for (uint64_t s = 0; s + 1 < total_slots; s += 2)
      if ((visited[s] & 1) && (visited[s + 1] & 2))
        fail_at("compression block shared by two child groups", s);
}

}  // namespace voxcast::esvo
