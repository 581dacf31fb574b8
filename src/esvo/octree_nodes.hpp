#pragma once
// The ESVO octree as a node-access policy of the octree-family caster
// (core/octree_caster.hpp, which documents the interface): child descriptors
// (§5.1, Figure 2) with their valid/leaf masks and near/far child pointers,
// and the contour attachment (§5.2). Private to src/esvo and the tests.
#include <immintrin.h>

#include <bit>
#include <cstdint>
#include <cstring>

#include "core/octree_caster.hpp"
#include "esvo/layout_internal.hpp"
#include "voxcast/esvo.hpp"

namespace voxcast::detail {

static_assert(esvo::kMaxScale == kOctreeMaxScale);

/// Node = descriptor slot (two words per slot in EsvoOctree::words). The loop
/// never needs the scale: leaves are marked in the leaf mask, so variable
/// depth (§7.1) needs nothing here.
struct EsvoNodes {
  explicit EsvoNodes(const esvo::EsvoOctree& octree)
      : words(octree.words.data()),
        root_slot(octree.root_slot()),
        contours(octree.has_contours()) {}

  /// Word 0 (pointer | far | valid mask | leaf mask) and word 1 (contour
  /// pointer | contour mask) of a descriptor, fetched together.
  using Source = esvo::EsvoOctree;
  struct Desc {
    uint32_t w0, w1;
  };
  using Index = NoIndex;
  static constexpr bool kContours = true;  // a zero contour mask costs one test
  static constexpr bool kResidency = false;
  static constexpr bool kEnteredFace = false;

  uint32_t root() const { return root_slot; }

  template <class C>
  Desc fetch(uint32_t slot, int, C& cnt) const {
    count_add(cnt, &RayCounters::descriptor_fetches);  // 8 bytes
    return {words[size_t(slot) * 2], words[size_t(slot) * 2 + 1]};
  }
  static bool fetched(const Desc& d) { return d.w0 != 0; }  // the valid mask is never empty
  static void forget(Desc* d) { d->w0 = 0; }
  static uint32_t mask(const Desc& d) { return esvo::detail::valid_mask(d.w0); }
  static bool valid(const Desc& d, int c) { return (d.w0 >> (8 + c) & 1u) != 0; }
  static bool leaf(const Desc& d, int c, int) { return (d.w0 >> c & 1u) != 0; }

  /// The contour value of child c (§5.2: the c-th bit of the contour mask,
  /// values packed in slot order behind the contour pointer). Always inlined:
  /// the packet kernels (esvo/packet_nodes.hpp) call it from their own ISA's
  /// translation units, which must not emit a copy the baseline code links.
  [[gnu::always_inline]] bool contour(const Desc& d, uint32_t slot, int c, uint32_t* value) const {
    const uint32_t m = esvo::detail::contour_mask(d.w1);
    if ((m >> c & 1u) == 0) return false;
    *value = words[size_t(slot) * 2 + esvo::detail::contour_pointer(d.w1) +
                   uint32_t(std::popcount(m & ((1u << c) - 1)))];
    return true;
  }

  /// Slot of the first non-leaf child: the pointer is relative to `slot`; a
  /// far pointer (§5.1) names a slot holding the 32-bit signed offset.
  template <class C>
  uint32_t children(const Desc& d, uint32_t slot, int, C& cnt) const {
    uint32_t rel = esvo::detail::child_pointer(d.w0);
    if (esvo::detail::is_far(d.w0)) [[unlikely]] {
      std::memcpy(&rel, &words[size_t(slot + rel) * 2], sizeof rel);
      count_add(cnt, &RayCounters::far_reads);  // 4 bytes
    }
    return slot + rel;  // two's complement: a negative offset wraps back
  }
  /// Non-leaf children are stored contiguously in slot order.
  template <class C>
  static uint32_t child(const Desc& d, uint32_t first, int c, int, C&) {
    return first + uint32_t(std::popcount(esvo::detail::non_leaf_mask(d.w0) & ((1u << c) - 1)));
  }
  template <class I, class C>
  uint32_t descend(const Desc& d, uint32_t slot, int c, int scale, I&, C& cnt) const {
    return child(d, children(d, slot, scale, cnt), c, scale, cnt);
  }

  /// The tile caster's prefetch (core/octree_tile_kernel.hpp): the block of
  /// `slot`'s children, the walk's next fetches: the lines of its first and
  /// last descriptor (8 bytes each, up to 64 bytes, so a block spans two
  /// lines unless aligned; ~+5 % primary tile frames). (Prefetching the blocks
  /// below them as well measured no faster: a child's pointer is only known
  /// once its block has arrived.) Always inlined: the kernels call it from
  /// their own ISA's translation units.
  [[gnu::always_inline]] void prefetch_below(const Desc& d, uint32_t slot, int) const {
    const uint32_t non_leaf = esvo::detail::non_leaf_mask(d.w0);
    if (non_leaf == 0) return;  // only leaves: no child block (its pointer means nothing)
    NoCounters none;
    const uint32_t first = children(d, slot, 0, none);
    const uint32_t last = first + uint32_t(std::popcount(non_leaf)) - 1;
    _mm_prefetch(reinterpret_cast<const char*>(words + size_t(first) * 2), _MM_HINT_T0);
    _mm_prefetch(reinterpret_cast<const char*>(words + size_t(last) * 2), _MM_HINT_T0);
  }

  /// SurfaceHit naming: voxel_ref = the parent's slot, child = the slot in it
  /// (what EsvoOctree::attributes looks up).
  static void name_hit(const Source&, const OctreeCast<Index>& r, SurfaceHit* hit) {
    hit->voxel_ref = r.node;
    hit->child = uint32_t(r.child);
  }

  const uint32_t* words;
  uint32_t root_slot;
  /// The octree has contours (a contour attachment; without one validate()
  /// allows no contour mask): core/octree_caster.hpp may_narrow_spans.
  bool contours;
};

}  // namespace voxcast::detail
