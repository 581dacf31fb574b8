#pragma once
// The sparse voxel DAG as a node-access policy of the octree-family caster
// (core/octree_caster.hpp, which documents the interface; svdag §4: the ESVO
// loop "requires only minor changes"). Private to src/dag and the tests.
//
// The node kind follows from the scale (dag.hpp): above the leaf-mask level a
// node is a header (child mask) + one absolute pointer per present child; a
// leaf-mask node is a 64-bit 4^3 mask whose byte c is the 2^3 sub-block in
// slot c; inside a sub-block the "node" is that byte itself, and its children
// are the leaf voxels. Leaves are only at the finest level, and there are no
// contours (svdag §4: "we do not need to perform any intersection tests with
// contours"), which lets the loop stop once t_min passes the span's end.
//
// Index (Hitchhiker's guide, "Dynamic voxel indexing"): the Morton rank of
// the first leaf voxel of the current parent. Descending adds the parent's
// prefix sum for the child (stored next to the pointer in voxel_prefix, or
// the 64-bit table for the top levels, dag.hpp "64-bit voxel indices") or a
// popcount inside a mask.
#include <immintrin.h>

#include <bit>
#include <cstdint>

#include "core/octree_caster.hpp"
#include "voxcast/dag.hpp"

namespace voxcast::detail {

static_assert(esvo::kMaxScale == kOctreeMaxScale);

/// Bit c set iff byte c of m is non-zero: the child mask of a 4^3 leaf-mask
/// node over its eight 2^3 sub-blocks.
inline uint32_t byte_mask(uint64_t m) {
  m |= m >> 4;
  m |= m >> 2;
  m |= m >> 1;
  return uint32_t(_pext_u64(m, 0x0101010101010101ull));
}

/// Node = word index of a header or leaf-mask node, or at the sub-block level
/// the sub-block's 8-bit mask itself. `dag` must be finalized.
struct DagNodes {
  explicit DagNodes(const dag::SparseVoxelDag& dag)
      : words(dag.words.data()),
        prefix(dag.voxel_prefix.data()),
        prefix_wide(dag.voxel_prefix_wide.data()),
        wide_words(dag.wide_words),
        leaf_scale(esvo::kMaxScale - dag.levels()),
        mask_scale(leaf_scale + 1) {}

  using Source = dag::SparseVoxelDag;
  struct Desc {
    uint32_t mask;    // present children
    uint64_t leaf64;  // the 4^3 mask when the node is a leaf-mask node
  };
  using Index = uint64_t;  // Morton rank of the parent's first leaf voxel
  static constexpr bool kContours = false;
  static constexpr bool kResidency = false;
  static constexpr bool kEnteredFace = true;  // the normal of geometry-only DAGs

  static uint32_t root() { return 0; }

  template <class C>
  Desc fetch(uint32_t node, int scale, C& cnt) const {
    // Header words and 64-bit leaf masks are memory reads; a sub-block's
    // byte came with its parent's leaf mask.
    count_add(cnt, &RayCounters::descriptor_fetches, scale >= mask_scale);
    if (scale > mask_scale) return {dag::layout::ChildMask::get(words[node]), 0};
    if (scale == mask_scale) {
      const uint64_t m = uint64_t(words[node]) | uint64_t(words[node + 1]) << 32;
      return {byte_mask(m), m};
    }
    return {node, 0};
  }
  static bool fetched(const Desc& d) { return d.mask != 0; }  // masks are never empty
  static void forget(Desc* d) { d->mask = 0; }
  static uint32_t mask(const Desc& d) { return d.mask; }
  static bool valid(const Desc& d, int c) { return (d.mask >> c & 1u) != 0; }
  bool leaf(const Desc&, int, int scale) const { return scale == leaf_scale; }

  /// First pointer word (interior nodes); unused below.
  template <class C>
  uint32_t children(const Desc&, uint32_t node, int, C&) const {
    return node + 1;
  }
  template <class C>
  uint32_t child(const Desc& d, uint32_t first, int c, int scale, C& cnt) const {
    if (scale > mask_scale) {
      count_add(cnt, &RayCounters::far_reads);  // a pointer word
      return words[first + below(d.mask, c)];
    }
    return sub_block(d, c);  // into sub-block c of the 4^3 mask
  }
  template <class I, class C>
  uint32_t descend(const Desc& d, uint32_t node, int c, int scale, I& index, C& cnt) const {
    constexpr bool kIndexed = !std::is_same_v<I, NoIndex>;
    if (scale > mask_scale) {
      const uint32_t w = node + 1 + below(d.mask, c);
      if constexpr (kIndexed) index += w < wide_words ? prefix_wide[w] : prefix[w];
      count_add(cnt, &RayCounters::far_reads);
      return words[w];
    }
    if constexpr (kIndexed) index += uint32_t(std::popcount(d.leaf64 & ((1ull << (8 * c)) - 1)));
    return sub_block(d, c);
  }
  /// The tile caster's prefetch (core/octree_tile_kernel.hpp): above the
  /// leaf-mask level, the words of every child node (the walk's next
  /// fetches; the pointers are in the node's own words).
  [[gnu::always_inline]] void prefetch_below(const Desc& d, uint32_t node, int scale) const {
    if (scale <= mask_scale) return;
    const int n = std::popcount(d.mask);
    for (int i = 0; i < n; ++i)
      _mm_prefetch(reinterpret_cast<const char*>(words + words[node + 1 + uint32_t(i)]),
                   _MM_HINT_T0);
  }
  /// Rank of the first leaf voxel of hit cube c.
  uint64_t hit_index(uint64_t index, const Desc& d, uint32_t node, int c, int scale) const {
    if (scale == leaf_scale) return index + below(d.mask, c);
    if (scale == mask_scale)
      return index + uint32_t(std::popcount(d.leaf64 & ((1ull << (8 * c)) - 1)));
    const uint32_t w = node + 1 + below(d.mask, c);
    return index + (w < wide_words ? prefix_wide[w] : prefix[w]);
  }

  /// Leaf voxels in hit cube c of `node` at `scale` (the loop's parent and
  /// slot, as hit_index takes them): one voxel; the bits of sub-block c's
  /// byte; or, below a header, the prefix entry after child c's pointer (the
  /// next pointer's, or after the last one the node's own count) less its own:
  /// words next to those hit_index read, so a LOD hit needs no second descent
  /// (SparseVoxelDag::cube_range) to know its cube.
  static uint64_t hit_count(const Source& s, uint32_t node, int c, int scale) {
    const int leaf_scale = esvo::kMaxScale - s.levels();
    if (scale == leaf_scale) return 1;
    if (scale == leaf_scale + 1) {
      const uint64_t m = uint64_t(s.words[node]) | uint64_t(s.words[node + 1]) << 32;
      return uint64_t(std::popcount(dag::layout::LeafMaskBytes::get(m, unsigned(c))));
    }
    const uint32_t mask = dag::layout::ChildMask::get(s.words[node]);
    const uint32_t j = below(mask, c), w = node + 1 + j;
    const uint64_t next =
        int(j) + 1 < std::popcount(mask) ? s.prefix_entry(w + 1) : s.prefix_entry(node);
    return next - s.prefix_entry(w);
  }

  /// SurfaceHit::child of a DAG hit: the entered face (bits 2..0, dag.hpp
  /// CastResult::face) and the hit cube's leaf voxel count above it, 0 where
  /// it does not fit (the count is then cube_range's).
  static constexpr int kHitCountShift = 3;
  static constexpr uint64_t kHitCountMax = (uint64_t(1) << (32 - kHitCountShift)) - 1;
  static uint32_t child_face(uint32_t child) { return child & ((1u << kHitCountShift) - 1); }
  static uint64_t child_count(uint32_t child) { return child >> kHitCountShift; }

  /// SurfaceHit naming: voxel_ref = Morton rank of the hit cube's first leaf
  /// voxel, child = the entered face | the cube's voxel count (above).
  static void name_hit(const Source& s, const OctreeCast<Index>& r, SurfaceHit* hit) {
    hit->voxel_ref = r.index;
    // An 8^3 (L - 3) hit is shaded from fine_mean(first voxel) after the
    // rest of its rays are traced: start loading its line of start bits and
    // its count now, so that the lookup then finds them cached.
    const uint64_t line = r.index >> 9;
    if (r.scale == esvo::kMaxScale - s.levels() + 3 && line < s.fine_starts.size()) {
      _mm_prefetch(reinterpret_cast<const char*>(&s.fine_starts[size_t(line)]), _MM_HINT_T0);
      _mm_prefetch(reinterpret_cast<const char*>(&s.fine_before[size_t(line)]), _MM_HINT_T0);
    }
    const uint64_t n = hit_count(s, r.node, r.child, r.scale);
    hit->child = uint32_t(r.face) | uint32_t(n <= kHitCountMax ? n : 0) << kHitCountShift;
  }

  const uint32_t* words;
  const uint32_t* prefix;
  const uint64_t* prefix_wide;  // words [0, wide_words) take 64-bit entries
  uint32_t wide_words;
  int leaf_scale;  // scale of the leaf voxels
  int mask_scale;  // scale of the children of a leaf-mask node

 private:
  static uint32_t sub_block(const Desc& d, int c) {
    return uint32_t(dag::layout::LeafMaskBytes::get(d.leaf64, unsigned(c)));
  }
  static uint32_t below(uint32_t mask, int c) {
    return uint32_t(std::popcount(mask & ((1u << c) - 1)));
  }
};

}  // namespace voxcast::detail
