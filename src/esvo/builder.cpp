// ESVO construction (esvo §7.1; hitchhiker's guide to voxels, bottom-up octree
// from sorted Morton codes).
//
// Phase 1, bottom-up (parallel with TBB): the leaves are the sorted Morton
// codes at level L. Voxels with the same parent are adjacent and the parent's
// code is `code >> 3`, so each coarser level is one run-length pass over the
// finer one. Every parent gets its valid mask, the index of its first child,
// area-weighted attributes (so that every level is a valid LOD, §7.1) and the
// size of its subtree (descriptors and attribute values), which phase 2 uses
// to decide ahead of time which child pointers may need a far pointer.
//
// Phase 2, layout (sequential, deterministic): approximately depth-first as
// in §5.1/§7.1: when a node is visited, the descriptors of its non-leaf
// children are placed as one consecutive group (followed by the far pointer
// slots reserved for them), then the children are visited in slot order, so
// child i+1's group comes after child i's whole subtree. This keeps most child
// pointers short (15-bit relative pointer), and parents close to their
// children in memory (§5.1 "far pointers are rare").
//
// Blocks (§5.3-5.4): a block is closed when the next group would take it past
// BuildOptions::max_block_slots / max_block_values; the next block starts at
// the next 8 KiB boundary. Each block ends with its info section and raw
// color/normal attachment (§5.4, Figure 7), holding the attributes of the
// children of every descriptor in the block, or with BuildOptions::attributes
// = Compressed one §5.5 compression block per descriptor pair (compress.cpp);
// then groups are placed so that a pair only holds siblings (alloc()).
//
// Contours and variable depth (BuildOptions::contours, the mesh overload):
// phase 1 is the same; then contours.cpp walks the tree top-down (§7.1-7.2)
// and returns a contour value per voxel and the voxels whose subtrees are
// dropped (variable depth). Phase 2 then lays out only the kept tree: the
// descriptor's leaf mask also flags the dropped voxels, word 1 gets the
// contour mask, and each block gets a contour attachment right after its
// info section (§5.2, Figure 1: "an info section, contour data, and ...");
// the contour pointers (relative to the descriptor, Appendix A) are filled
// in when the block is closed, and a block is closed early if they could
// exceed 24 bits.
//
// Decoded-attribute tolerance (§7.3: "attribute quantization and compression
// is performed before the test"): the planner tests a leaf's raw 8-bit
// encoding, which is exactly what a raw build stores. A compressed leaf
// decodes to what the §5.5 block of its parent's descriptor pair makes of
// it, and the pairs are only known after the layout. So with compressed
// attributes and a color/normal tolerance the builder decodes every leaf
// above the max level from the laid-out octree, compares it with every
// full-depth voxel below it, forces the ones out of tolerance to subdivide
// (ContourPlanner::refine) and lays out again, until no leaf is out of
// tolerance. Refinement only grows and stops at max_level, so this ends;
// every step is deterministic, so the output does not depend on the thread
// count.
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <map>
#include <numeric>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "esvo/build_cells.hpp"
#include "esvo/compress.hpp"
#include "esvo/contours.hpp"
#include "esvo/layout_internal.hpp"
#include "esvo/reduce.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/progress.hpp"
#include "voxcast/system.hpp"
#include "voxelize/cell.hpp"

namespace voxcast::esvo {
namespace {

using detail::kMaxNearPointer;

using detail::encode_value;   // esvo/reduce.hpp
using detail::kDefaultColor;  // esvo/reduce.hpp
using detail::kDefaultNormal;

/// Nodes of one octree level that own a descriptor (levels 0..L-1).
struct Level {
  std::vector<uint64_t> code;          // Morton code at this level (freed after use)
  std::vector<uint8_t> mask;           // valid mask
  std::vector<uint32_t> first_child;   // index of the first child in the next level
  std::vector<uint64_t> desc_below;    // descriptors strictly below this node
  std::vector<uint64_t> values_below;  // attribute values of those descriptors
  std::vector<uint64_t> value;         // this node's encoded attributes (levels >= 1)
  // Aggregated attributes (only while building the next coarser level).
  std::vector<Color> color;
  std::vector<Vec3> normal;
  std::vector<float> weight;
};

constexpr size_t kChunk = size_t(1) << 15;

/// One bottom-up step: groups the sorted codes of the finer level by parent.
/// Chunks start at parent boundaries, so the output is independent of the
/// thread count.
void reduce_codes(const std::vector<uint64_t>& child, Level& parent) {
  const size_t n = child.size();
  const size_t chunks = (n + kChunk - 1) / kChunk;
  std::vector<size_t> start(chunks + 1, n), count(chunks + 1, 0);
  for (size_t c = 0; c < chunks; ++c) {
    size_t s = c * kChunk;
    while (s > 0 && s < n && (child[s] >> 3) == (child[s - 1] >> 3)) ++s;
    start[c] = s;
  }
  tbb::parallel_for(size_t(0), chunks, [&](size_t c) {
    size_t k = 0;
    for (size_t i = start[c]; i < start[c + 1]; ++i)
      k += (i == start[c] || (child[i] >> 3) != (child[i - 1] >> 3));
    count[c] = k;
  });
  std::exclusive_scan(count.begin(), count.end(), count.begin(), size_t(0));
  const size_t m = count[chunks];
  parent.code.resize(m);
  parent.mask.assign(m, 0);
  parent.first_child.resize(m);
  tbb::parallel_for(size_t(0), chunks, [&](size_t c) {
    size_t out = count[c];
    for (size_t i = start[c]; i < start[c + 1]; ++i) {
      if (i != start[c] && (child[i] >> 3) == (child[i - 1] >> 3)) {
        parent.mask[out - 1] |= uint8_t(1u << (child[i] & 7));
        continue;
      }
      parent.code[out] = child[i] >> 3;
      parent.mask[out] = uint8_t(1u << (child[i] & 7));
      parent.first_child[out] = uint32_t(i);
      ++out;
    }
  });
}

/// Area-weighted average of the children's attributes (§7.1: each level is a
/// box-filtered LOD of the one below). Colors average linearly; normals are
/// the normalized weighted sum; weights add up.
void reduce_attributes(const std::vector<Color>& cc, const std::vector<Vec3>& cn,
                       const std::vector<float>& cw, Level& p) {
  const size_t m = p.mask.size();
  p.color.resize(m);
  p.normal.resize(m);
  p.weight.resize(m);
  tbb::parallel_for(tbb::blocked_range<size_t>(0, m, 4096),
                    [&](const tbb::blocked_range<size_t>& r) {
                      for (size_t i = r.begin(); i != r.end(); ++i) {
                        const uint32_t first = p.first_child[i];
                        detail::reduce_node(&cc[first], &cn[first], &cw[first],
                                            std::popcount(unsigned(p.mask[i])), &p.color[i],
                                            &p.normal[i], &p.weight[i]);
                      }
                    });
}

void encode_values(const std::vector<Color>& c, const std::vector<Vec3>& n,
                   std::vector<uint64_t>& out) {
  out.resize(c.size());
  tbb::parallel_for(tbb::blocked_range<size_t>(0, c.size(), 8192),
                    [&](const tbb::blocked_range<size_t>& r) {
                      for (size_t i = r.begin(); i != r.end(); ++i)
                        out[i] = encode_value(c[i], n[i]);
                    });
}

void check_input(const VoxelSet& v) {
  const int L = v.grid.levels;
  if (L < 1 || L > kMaxGridLevels)
    throw Error("cannot build octree: grid levels " + std::to_string(L) + " outside 1.." +
                std::to_string(kMaxGridLevels));
  if (v.grid.resolution != (1u << L))
    throw Error("cannot build octree: grid resolution " + std::to_string(v.grid.resolution) +
                " is not 2^levels");
  if (v.codes.empty()) throw Error("cannot build octree: no voxels");
  if (v.codes.size() >= (uint64_t(1) << 32))
    throw Error("cannot build octree: more than 2^32 voxels");
  const size_t n = v.codes.size();
  const bool has_attr = !v.colors.empty() || !v.normals.empty() || !v.weights.empty();
  if (has_attr && (v.colors.size() != n || v.normals.size() != n ||
                   (!v.weights.empty() && v.weights.size() != n)))
    throw Error("cannot build octree: attribute arrays do not match the voxel count");
  if (v.codes.back() >> (3 * L))
    throw Error("cannot build octree: voxel code outside the 2^" + std::to_string(L) + " grid");
  for (size_t i = 1; i < n; ++i)
    if (v.codes[i] <= v.codes[i - 1])
      throw Error("cannot build octree: voxel codes are not sorted and unique");
}

/// Upper bound on the slots the layout of a subtree with `desc` descriptors
/// below its root can span: the descriptors, at most one far slot each, and
/// per 8 KiB page one header plus at most 15 slots of padding in front of a
/// group (+ far slots, <= 16 slots) that would straddle it:
///   X <= 2d + 16 (X/1024 + 1)  =>  X <= 2d + 2d/63 + 17.
/// With compressed attributes (§5.5) a group may also be preceded by one
/// pairing padding slot, at most one per descriptor:
///   X <= 3d + 16 (X/1024 + 1)  =>  X <= 3d + 3d/63 + 17.
uint64_t span_bound(uint64_t desc, bool compressed) {
  const uint64_t k = compressed ? 3 : 2;
  return k * desc + (k * desc) / 63 + 32;
}

class Layout {
 public:
  Layout(const std::vector<Level>& levels, const std::vector<uint64_t>& leaf_values,
         const BuildOptions& opt, const detail::ContourPlan* plan = nullptr)
      : lv_(levels), leaf_values_(leaf_values), opt_(opt), L_(int(levels.size())), plan_(plan) {}

  /// Advance `progress` (its current phase) by the descriptors placed.
  void set_progress(Progress* progress) { progress_ = progress; }

  EsvoOctree run(const GridTransform& grid) {
    uint64_t total_desc = 1 + lv_[0].desc_below[0];
    uint64_t total_values = lv_[0].values_below[0] + std::popcount(unsigned(lv_[0].mask[0]));
    out_.reserve(
        size_t(span_bound(total_desc, compressed_) + total_desc + 2 * total_values + 4096));

    open_block(0);
    // The root: slot 1, the first descriptor of block 0 (slot 0 is the page header).
    const uint32_t root = alloc(1, 1);
    place_descriptor(root, 0, 0);
    stack_.push_back({0, 0, root, 0});
    uint64_t visited = 0;
    while (!stack_.empty()) {
      const Node n = stack_.back();
      stack_.pop_back();
      visit(n);
      // The bar follows the descriptors placed (one per visited node).
      if (progress_ && ++visited % 4096 == 0) progress_->advance(4096);
    }
    if (progress_) progress_->advance(visited % 4096);
    close_block();
    // Pad to whole pages: the array is a sequence of 8 KiB pages.
    out_.resize((out_.size() + kPageWords - 1) / kPageWords * kPageWords, 0);

    EsvoOctree octree;
    octree.grid = grid;
    octree.words = std::move(out_);
    octree.block_count = block_count_;
    return octree;
  }

 private:
  struct Node {
    int depth;
    uint32_t index;     // in lv_[depth]
    uint32_t slot;      // its descriptor
    uint32_t far_slot;  // reserved far pointer slot, 0 = use a near pointer
  };

  uint64_t child_value(int depth, uint32_t child_index) const {
    return depth + 1 == L_ ? leaf_values_[child_index] : lv_[depth + 1].value[child_index];
  }

  void ensure_words(uint64_t slots) {
    if (slots >= (uint64_t(1) << 31)) throw Error("cannot build octree: more than 2^31 slots");
    if (out_.size() < slots * 2) out_.resize(size_t(slots * 2), 0);
  }

  /// Allocates `n` (<= 16) consecutive slots that do not straddle a page
  /// header, of which the first `descs` will hold descriptors. Compressed
  /// attributes (§5.5): a group may start at an odd slot only if the slot
  /// before it is not a descriptor of the previous group (else one padding
  /// slot), so a descriptor pair (2k, 2k+1) never mixes two groups.
  uint32_t alloc(uint32_t n, uint32_t descs) {
    for (;;) {
      if (cursor_ % kPageSlots == 0) ++cursor_;  // page header
      if (compressed_ && (cursor_ & 1) && cursor_ == last_desc_end_) {
        ++cursor_;
        continue;
      }
      if (cursor_ % kPageSlots + n > kPageSlots) {
        cursor_ = (cursor_ / kPageSlots + 1) * kPageSlots + 1;
        continue;
      }
      break;
    }
    const uint32_t s = uint32_t(cursor_);
    cursor_ += n;
    last_desc_end_ = s + descs;
    ensure_words(cursor_);
    lookup_.resize(size_t(cursor_ - block_start_), 0);
    return s;
  }

  /// True if child `c` (index at depth + 1 < L) is a leaf of the planned
  /// variable-depth tree (its subtree is dropped).
  bool planned_leaf(int depth, uint32_t c) const {
    return plan_ != nullptr && depth + 1 < L_ && plan_->leaf[size_t(depth) + 1][c] != 0;
  }

  /// Writes the masks of the descriptor of node (depth, index) at `slot` (the
  /// child pointer follows when it is visited) and its children's attributes.
  void place_descriptor(uint32_t slot, int depth, uint32_t index) {
    const uint32_t valid = lv_[depth].mask[index];
    uint32_t leaf = depth + 1 == L_ ? valid : 0;  // all leaves sit at depth L
    out_[size_t(slot) * 2 + 1] = 0;               // no contour (§5.2)
    lookup_[slot - block_start_] =
        layout::ValuePointer::put(uint32_t(values_.size())) | layout::AttributeMask::put(valid);
    const uint32_t first = lv_[depth].first_child[index];
    const int k = std::popcount(valid);
    for (int j = 0; j < k; ++j) values_.push_back(child_value(depth, first + uint32_t(j)));
    if (plan_ != nullptr) {
      // Contour mask + values (§5.2); the pointer is set in close_block().
      uint32_t cmask = 0;
      const size_t cstart = contours_.size();
      for (int j = 0, i = 0; i < 8; ++i) {
        if (!(valid >> i & 1)) continue;
        const uint32_t c = first + uint32_t(j++);
        if (planned_leaf(depth, c)) leaf |= 1u << i;
        const uint32_t value = plan_->contour[size_t(depth) + 1][c];
        if (value != 0) cmask |= 1u << i, contours_.push_back(value);
      }
      if (cmask != 0) {
        out_[size_t(slot) * 2 + 1] = layout::ContourMask::put(cmask);
        contour_desc_.push_back({slot, uint32_t(cstart)});
      }
    }
    out_[size_t(slot) * 2] = layout::ValidMask::put(valid) | layout::LeafMask::put(leaf);
  }

  void visit(const Node& n) {
    if (n.depth + 1 == L_) return;  // only leaf children: no child pointer
    const Level& cl = lv_[n.depth + 1];
    const uint32_t first = lv_[n.depth].first_child[n.index];
    const uint32_t k = uint32_t(std::popcount(unsigned(lv_[n.depth].mask[n.index])));
    // The non-leaf children (all of them unless the plan drops subtrees).
    uint32_t kid[8], g = 0;
    for (uint32_t j = 0; j < k; ++j)
      if (!planned_leaf(n.depth, first + j)) kid[g++] = first + j;
    if (g == 0) return;
    uint64_t group_values = 0;
    for (uint32_t i = 0; i < g; ++i) group_values += std::popcount(unsigned(cl.mask[kid[i]]));

    // Start a new block if this group would overflow the current one. The
    // block always takes at least one group besides the root, and a group is
    // never split. The node itself must have a far pointer then: see below.
    const uint64_t used = cursor_ - block_start_;
    // With contours, also keep every contour pointer within 24 bits (it
    // spans at most the descriptor area, the info section and the contours).
    if (block_groups_ > 0 &&
        (used + 2 * g + 16 > opt_.max_block_slots ||
         values_.size() + group_values > opt_.max_block_values ||
         (plan_ != nullptr &&
          2 * (used + 2 * g + 16) + contours_.size() + 8 * g + 64 > detail::kMaxContourPointer))) {
      close_block();
      open_block((cursor_ * 2 + kPageWords - 1) / kPageWords * kPageWords / 2);
    }

    // Which children may need a far pointer? Child i's own group is placed
    // after the rest of this group, the reserved far slots, and the subtrees
    // of children 0..i-1. If all of that provably stays inside this block
    // (no block break, which would insert an info section and attachment)
    // and within 2^15-1 slots, a near pointer suffices; otherwise reserve a
    // far slot right after the group (conservative: it is used regardless).
    uint32_t far_mask = 0;
    {
      const uint64_t used_after = (cursor_ - block_start_) + 16 + 2 * g;
      uint64_t span = 0, vals = values_.size() + group_values;
      for (uint32_t i = 0; i < g; ++i) {
        const uint32_t c = kid[i];
        vals += cl.values_below[c];
        const bool no_break =
            used_after + span + 48 <= opt_.max_block_slots && vals <= opt_.max_block_values &&
            (plan_ == nullptr || 2 * (used_after + span + 48) + contours_.size() + vals + 64 <=
                                     detail::kMaxContourPointer);
        const uint64_t distance = (g - i) + g + span + 32;
        if (cl.desc_below[c] > 0 && !(no_break && distance <= kMaxNearPointer)) far_mask |= 1u << i;
        span += span_bound(cl.desc_below[c], compressed_);
      }
    }
    const uint32_t far_count = uint32_t(std::popcount(far_mask));
    const uint32_t group = alloc(g + far_count, g);
    ++block_groups_;
    far_slots_ += far_count;

    // This node's pointer to the group.
    const uint64_t rel = group - n.slot;
    if (n.far_slot) {
      out_[size_t(n.far_slot) * 2] = uint32_t(int32_t(rel));  // < 2^31 (ensure_words)
      out_[size_t(n.slot) * 2] |=
          layout::ChildPointer::put(n.far_slot - n.slot) | layout::FarBit::put(1);
    } else {
      if (rel > kMaxNearPointer)  // the far-slot bound above is broken
        throw std::logic_error("esvo builder: near child pointer overflow");
      out_[size_t(n.slot) * 2] |= layout::ChildPointer::put(uint32_t(rel));
    }

    uint32_t next_far = group + g;
    Node kids[8];
    for (uint32_t i = 0; i < g; ++i) {
      place_descriptor(group + i, n.depth + 1, kid[i]);
      kids[i] = {n.depth + 1, kid[i], group + i, (far_mask >> i & 1) ? next_far++ : 0};
    }
    for (uint32_t i = g; i-- > 0;) stack_.push_back(kids[i]);
  }

  void open_block(uint64_t start_slot) {
    ensure_words(start_slot);
    block_start_ = start_slot;
    cursor_ = start_slot;
    lookup_.clear();
    values_.clear();
    contours_.clear();
    contour_desc_.clear();
    block_groups_ = 0;
  }

  /// Appends the block's info section and color/normal attachment (raw §5.4
  /// or compressed §5.5) after its descriptor area and fills in the page headers.
  void close_block() {
    const uint64_t slots = cursor_ - block_start_;
    const uint64_t info = cursor_ * 2;
    // With contours: a second attachment entry, then the contour attachment
    // (count + values, padded to an even length) before the color one.
    const uint64_t info_words = plan_ != nullptr ? 8 : 6;
    const uint64_t contour_at = info + info_words;
    const uint64_t contour_words = plan_ != nullptr ? (1 + contours_.size() + 1) / 2 * 2 : 0;
    const uint64_t attach = info + info_words + contour_words;
    const uint64_t pairs = (slots + 1) / 2;
    const uint64_t end = compressed_ ? attach + 2 + detail::kCompressedBlockWords * pairs
                                     : attach + 2 + slots + 2 * values_.size();
    if (end >= (uint64_t(1) << 32)) throw Error("cannot build octree: more than 2^32 words");
    out_.resize(size_t(end), 0);
    for (uint64_t p = block_start_; p < cursor_; p += kPageSlots) {
      out_[size_t(p * 2)] = uint32_t(int32_t(int64_t(info) - int64_t(p * 2)));
      out_[size_t(p * 2 + 1)] = 0;
    }
    uint32_t* w = out_.data() + info;
    w[detail::kInfoMagicWord] = kInfoMagic;
    w[detail::kInfoFirstSlotWord] = uint32_t(int32_t(int64_t(block_start_ * 2) - int64_t(info)));
    w[detail::kInfoSlotCountWord] = uint32_t(slots);
    w[detail::kInfoAttachCountWord] = plan_ != nullptr ? 2 : 1;
    w[4] = compressed_ ? kAttachCompressedColorNormal : kAttachRawColorNormal;
    w[5] = uint32_t(attach - info);
    if (plan_ != nullptr) {
      w[6] = kAttachContours;
      w[7] = uint32_t(contour_at - info);
      out_[size_t(contour_at)] = uint32_t(contours_.size());
      std::copy(contours_.begin(), contours_.end(), out_.begin() + ptrdiff_t(contour_at + 1));
      for (const ContourRef& r : contour_desc_) {
        const uint64_t ptr = contour_at + 1 + r.first - uint64_t(r.slot) * 2;
        if (ptr > detail::kMaxContourPointer)  // the block break rule above is broken
          throw std::logic_error("esvo builder: contour pointer overflow");
        out_[size_t(r.slot) * 2 + 1] |= layout::ContourPointer::put(uint32_t(ptr));
      }
    }
    uint32_t* a = out_.data() + attach;
    a[0] = uint32_t(slots);
    if (compressed_) {
      // §5.5: compression block k = descriptor slots 2k, 2k+1 of the block;
      // the lookup entries (value pointer | valid mask) say which values
      // belong to which slot. Page headers, far pointers and padding have
      // an empty mask. The encoder starts from the raw 8-bit sRGB colors and
      // cube normals (within 0.5/255 and 7e-5 rad of the input). Independent
      // blocks: encoded in parallel, deterministic for any thread count.
      a[1] = uint32_t(pairs);
      uint32_t* blocks = a + 2;
      lookup_.resize(size_t(2 * pairs), 0);
      tbb::parallel_for(tbb::blocked_range<size_t>(0, size_t(pairs), 1024),
                        [&](const tbb::blocked_range<size_t>& r) {
                          uint64_t vals[16];
                          for (size_t k = r.begin(); k != r.end(); ++k) {
                            uint32_t used = 0;
                            int n = 0;
                            for (int half = 0; half < 2; ++half) {
                              const uint32_t e = lookup_[2 * k + size_t(half)];
                              const uint32_t mask = layout::AttributeMask::get(e);
                              used |= mask << (8 * half);
                              for (int j = 0; j < std::popcount(mask); ++j)
                                vals[n++] = values_[layout::ValuePointer::get(e) + uint32_t(j)];
                            }
                            detail::encode_block_from_raw(
                                vals, used, blocks + detail::kCompressedBlockWords * k);
                          }
                        });
    } else {
      a[1] = uint32_t(values_.size());
      std::copy(lookup_.begin(), lookup_.end(), a + 2);
      uint32_t* v = a + 2 + slots;
      for (size_t i = 0; i < values_.size(); ++i) {
        v[2 * i] = uint32_t(values_[i]);
        v[2 * i + 1] = uint32_t(values_[i] >> 32);
      }
    }
    ++block_count_;
    cursor_ = (end + 1) / 2;
  }

  const std::vector<Level>& lv_;
  const std::vector<uint64_t>& leaf_values_;
  const BuildOptions& opt_;
  const int L_;
  Progress* progress_ = nullptr;
  const detail::ContourPlan* plan_;  // null: full depth, no contours
  struct ContourRef {
    uint32_t slot;   // descriptor with a non-empty contour mask
    uint32_t first;  // its first value in contours_
  };
  std::vector<uint32_t> contours_;        // current block's contour values
  std::vector<ContourRef> contour_desc_;  // current block
  std::vector<uint32_t> out_;
  std::vector<Node> stack_;
  std::vector<uint32_t> lookup_;  // current block, per slot from block_start_
  std::vector<uint64_t> values_;  // current block
  const bool compressed_ = opt_.attributes == AttributeFormat::Compressed;
  uint64_t cursor_ = 0, block_start_ = 0, far_slots_ = 0;
  uint64_t last_desc_end_ = 0;  // one past the last descriptor of the last group
  uint32_t block_count_ = 0, block_groups_ = 0;
};

}  // namespace

namespace {

void check_block_limits(const BuildOptions& options) {
  if (options.max_block_slots == 0 || options.max_block_values == 0 ||
      options.max_block_values > (1u << 24))
    throw Error("cannot build octree: block limits must be in 1..2^32 slots and 1..2^24 values");
}

/// Phase 1 (bottom-up levels) into `lv` and the leaf values, up to depth
/// `stop` (a cell's root in the cell-by-cell build: its voxels have one
/// node there, which keeps its float attributes and code; lv[0..stop) stay
/// empty).
void build_levels(const VoxelSet& voxels, std::vector<Level>& lv,
                  std::vector<uint64_t>& leaf_values, int stop = 0, Progress* progress = nullptr) {
  const int L = voxels.grid.levels;
  const size_t n = voxels.size();

  // Leaf attributes (defaults when the VoxelSet has none).
  const bool has_attr = !voxels.colors.empty();
  std::vector<Color> dc;
  std::vector<Vec3> dn;
  std::vector<float> dw;
  if (!has_attr) {
    dc.assign(n, kDefaultColor);
    dn.assign(n, kDefaultNormal);
  }
  if (voxels.weights.empty()) dw.assign(n, 1.f);
  const std::vector<Color>& leaf_color = has_attr ? voxels.colors : dc;
  const std::vector<Vec3>& leaf_normal = has_attr ? voxels.normals : dn;
  const std::vector<float>& leaf_weight = voxels.weights.empty() ? dw : voxels.weights;
  encode_values(leaf_color, leaf_normal, leaf_values);

  // Phase 1: levels L-1 .. stop.
  lv.assign(static_cast<size_t>(L), Level{});
  // The bar's units are the nodes each level reduces: the leaves first,
  // then every level's own nodes, added once they are known.
  if (progress) progress->start_phase(0, n);
  for (int d = L - 1; d >= stop; --d) {
    Level& p = lv[size_t(d)];
    if (progress && d < L - 1) progress->add_units(lv[size_t(d) + 1].mask.size());
    if (d == L - 1) {
      reduce_codes(voxels.codes, p);
      reduce_attributes(leaf_color, leaf_normal, leaf_weight, p);
    } else {
      Level& c = lv[size_t(d) + 1];
      reduce_codes(c.code, p);
      reduce_attributes(c.color, c.normal, c.weight, p);
      encode_values(c.color, c.normal, c.value);
      std::vector<uint64_t>().swap(c.code);
      std::vector<Color>().swap(c.color);
      std::vector<Vec3>().swap(c.normal);
      std::vector<float>().swap(c.weight);
    }
    // Subtree sizes for the far pointer decisions of phase 2.
    const size_t m = p.mask.size();
    p.desc_below.assign(m, 0);
    p.values_below.assign(m, 0);
    if (d < L - 1) {
      const Level& c = lv[size_t(d) + 1];
      tbb::parallel_for(size_t(0), m, [&](size_t i) {
        const uint32_t first = p.first_child[i];
        const int k = std::popcount(unsigned(p.mask[i]));
        uint64_t desc = 0, vals = 0;
        for (int j = 0; j < k; ++j) {
          desc += 1 + c.desc_below[first + j];
          vals += uint64_t(std::popcount(unsigned(c.mask[first + j]))) + c.values_below[first + j];
        }
        p.desc_below[i] = desc;
        p.values_below[i] = vals;
      });
    }
    if (progress) progress->advance(d == L - 1 ? n : lv[size_t(d) + 1].mask.size());
  }
  if (lv[size_t(stop)].mask.size() != 1)
    throw std::logic_error("esvo builder: root level is not a single node");
}

/// A leaf of the laid-out octree above the max level with the attributes it
/// decodes to (§7.3: after the §5.5 compression of its descriptor pair).
struct DecodedLeaf {
  int depth;
  uint32_t index;  // in phase 1's tree (the kept tree in the cell build)
  uint32_t color;  // 8-bit sRGB code
  Vec3 normal;
};

/// Every leaf of the laid-out `octree` above depth `lmax`, decoded, in
/// descriptor walk order.
std::vector<DecodedLeaf> decoded_leaves(const EsvoOctree& octree, const detail::TreeView& tree,
                                        int lmax) {
  struct Leaf {
    uint32_t parent_slot;
    int child, depth;
    uint32_t index;
  };
  std::vector<Leaf> leaves;
  struct Item {
    uint32_t slot;
    int depth;
    uint32_t index;
  };
  std::vector<Item> stack{{octree.root_slot(), 0, 0}};
  const uint32_t* w = octree.words.data();
  while (!stack.empty()) {
    const Item it = stack.back();
    stack.pop_back();
    const uint32_t w0 = w[size_t(it.slot) * 2];
    const uint32_t valid = detail::valid_mask(w0), leaf = detail::leaf_mask(w0);
    const uint32_t first = tree.first_child[size_t(it.depth)][it.index];
    const uint32_t group = valid & ~leaf ? detail::child_group(w, it.slot) : 0;
    for (uint32_t i = 0, r = 0, g = 0; i < 8; ++i) {
      if (!(valid >> i & 1)) continue;
      const uint32_t c = first + r++;
      if (!(leaf >> i & 1))
        stack.push_back({group + g++, it.depth + 1, c});
      else if (it.depth + 1 < lmax)
        leaves.push_back({it.slot, int(i), it.depth + 1, c});
    }
  }
  std::vector<DecodedLeaf> out(leaves.size());
  tbb::parallel_for(tbb::blocked_range<size_t>(0, leaves.size(), 64),
                    [&](const tbb::blocked_range<size_t>& r) {
                      for (size_t k = r.begin(); k != r.end(); ++k) {
                        const Leaf& l = leaves[k];
                        Color color;
                        Vec3 normal;
                        octree.attributes(l.parent_slot, l.child, &color, &normal);
                        // Decoded colors are 8-bit sRGB codes mapped to linear
                        // (raw and §5.5 alike); encoding maps them back exactly.
                        out[k] = {l.depth, l.index, encode_color_abgr(color), normal};
                      }
                    });
  return out;
}

/// The leaves of the laid-out `octree` above depth `lmax` whose decoded
/// attributes are out of tolerance (§7.3), as (depth, index in phase 1's tree).
std::vector<std::pair<int, uint32_t>> decoded_violations(const EsvoOctree& octree,
                                                         const detail::TreeView& tree,
                                                         const BuildOptions& options, int lmax) {
  const std::vector<DecodedLeaf> leaves = decoded_leaves(octree, tree, lmax);
  std::vector<uint8_t> bad(leaves.size(), 0);
  tbb::parallel_for(
      tbb::blocked_range<size_t>(0, leaves.size(), 64), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t k = r.begin(); k != r.end(); ++k) {
          const DecodedLeaf& l = leaves[k];
          bad[k] = detail::attributes_exceed(tree, l.depth, l.index, l.color, l.normal, options);
        }
      });
  std::vector<std::pair<int, uint32_t>> out;
  for (size_t k = 0; k < leaves.size(); ++k)
    if (bad[k]) out.push_back({leaves[k].depth, leaves[k].index});
  return out;
}

/// Subtree sizes of the planned (variable-depth) tree for phase 2's far
/// pointer and block decisions: dropped subtrees count nothing. Depths
/// `top` down to `stop` (default: all).
void planned_sizes(std::vector<Level>& lv, const detail::ContourPlan& plan, int top = -1,
                   int stop = 0) {
  const int L = int(lv.size());
  for (int d = top >= 0 ? top : L - 2; d >= stop; --d) {
    Level& p = lv[size_t(d)];
    const Level& c = lv[size_t(d) + 1];
    const std::vector<uint8_t>& leaf = plan.leaf[size_t(d) + 1];
    tbb::parallel_for(size_t(0), p.mask.size(), [&](size_t i) {
      const uint32_t first = p.first_child[i];
      const int k = std::popcount(unsigned(p.mask[i]));
      uint64_t desc = 0, vals = 0;
      for (int j = 0; j < k; ++j) {
        if (leaf[first + uint32_t(j)]) continue;
        desc += 1 + c.desc_below[first + j];
        vals += uint64_t(std::popcount(unsigned(c.mask[first + j]))) + c.values_below[first + j];
      }
      p.desc_below[i] = desc;
      p.values_below[i] = vals;
    });
  }
}

}  // namespace

EsvoOctree build_octree(const VoxelSet& voxels, const BuildOptions& options) {
  check_input(voxels);
  check_block_limits(options);
  std::vector<Level> lv;
  std::vector<uint64_t> leaf_values;
  Progress* const progress = options.progress;
  // Weights: the phases' shares of the time (measured once on the bunny at
  // 2048^3, 14.3 M leaf voxels: levels 1.83 s, layout 0.91 s).
  if (progress) progress->set_phases({{"levels", 0.67}, {"layout", 0.33}});
  build_levels(voxels, lv, leaf_values, 0, progress);
  Layout layout(lv, leaf_values, options);
  if (progress) {
    progress->start_phase(1, 1 + lv[0].desc_below[0]);
    layout.set_progress(progress);
  }
  EsvoOctree octree = layout.run(voxels.grid);
  if (progress) progress->finish();
  return octree;
}

// Shares of the in-core contour build's time: levels, contours (the
// planner), layout, the decoded-leaf rounds (when any); measured once on
// spot at 4096^3 with --color-error 8 and compressed attributes (levels
// 3.0 s, planner 1.1 s, layout 0.3 s, decoded rounds 0.1 s).
constexpr double kContourWeights[4] = {0.65, 0.25, 0.07, 0.03};

EsvoOctree build_octree(const VoxelSet& voxels, const Mesh& mesh, const BuildOptions& options) {
  const bool variable = options.max_level != 0 || options.geometry_error > 0 ||
                        options.color_error >= 0 || options.normal_error >= 0;
  if (!options.contours) {
    if (variable) throw Error("cannot build octree: max level and error tolerances need contours");
    return build_octree(voxels, options);
  }
  check_input(voxels);
  check_block_limits(options);
  const int L = voxels.grid.levels;
  if (options.max_level < 0 || options.max_level > L)
    throw Error("cannot build octree: max level " + std::to_string(options.max_level) +
                " outside 1.." + std::to_string(L));
  if (!std::isfinite(options.geometry_error) || !std::isfinite(options.color_error) ||
      !std::isfinite(options.normal_error))
    throw Error("cannot build octree: error tolerances must be finite");
  std::vector<Level> lv;
  std::vector<uint64_t> leaf_values;
  Progress* const progress = options.progress;
  const bool check_decoded = options.attributes == AttributeFormat::Compressed &&
                             (options.color_error >= 0 || options.normal_error >= 0);
  // Phases as in the full-depth build, with the planner's walk between
  // levels and layout (one unit: it reports no progress of its own), and
  // with compressed attributes and a color/normal tolerance the §7.3
  // decoded-leaf rounds (re-plan, lay out again), which do not advance the
  // bar. Weights: kContourWeights.
  if (progress) {
    std::vector<Progress::Phase> phases = {{"levels", kContourWeights[0]},
                                           {"contours", kContourWeights[1]},
                                           {"layout", kContourWeights[2]}};
    if (check_decoded) phases.push_back({"attributes", kContourWeights[3]});
    progress->set_phases(std::move(phases));
  }
  build_levels(voxels, lv, leaf_values, 0, progress);

  detail::TreeView tree;
  tree.levels = L;
  tree.count.resize(size_t(L) + 1);
  tree.value.assign(size_t(L) + 1, nullptr);
  for (int d = 0; d < L; ++d) {
    tree.mask.push_back(lv[size_t(d)].mask.data());
    tree.first_child.push_back(lv[size_t(d)].first_child.data());
    tree.count[size_t(d)] = lv[size_t(d)].mask.size();
    if (d >= 1) tree.value[size_t(d)] = lv[size_t(d)].value.data();
  }
  tree.count[size_t(L)] = leaf_values.size();
  tree.value[size_t(L)] = leaf_values.data();
  detail::ContourPlanner planner(tree, voxels.grid, mesh, options);
  const int lmax = options.max_level > 0 ? options.max_level : L;
  for (bool first = true;; first = false) {
    if (progress && first) progress->start_phase(1, 1);
    const detail::ContourPlan& plan = planner.plan();
    planned_sizes(lv, plan);
    Layout layout(lv, leaf_values, options, &plan);
    if (progress && first) {
      progress->start_phase(2, 1 + lv[0].desc_below[0]);
      layout.set_progress(progress);
    }
    EsvoOctree octree = layout.run(voxels.grid);
    // Raw leaves decode to the raw encoding the planner already tested.
    if (progress && first && check_decoded) progress->start_phase(3, 0);
    const bool done = !check_decoded || [&] {
      const auto bad = decoded_violations(octree, tree, options, lmax);
      if (bad.empty()) return true;
      planner.refine(bad);
      return false;
    }();
    if (done) {
      if (progress) {
        progress->start_phase(check_decoded ? 3 : 2, 1);
        progress->set_done(1);
        progress->finish();
      }
      return octree;
    }
  }
}

// ---- Cell-by-cell variable-depth build (build_cells.hpp) ----
//
// The in-core build above holds the full-depth voxel set and phase 1 over
// it (about 70 B per voxel) although a variable-depth octree keeps only a
// small part of it. Here the grid is split into aligned cells of side 2^c
// (node depth C = L - c), visited in Morton order, so the octree below a
// cell's root is that cell's own full-depth tree, and the cells' nodes of
// any level, concatenated in visit order, are that level in Morton order.
// A cell is voxelized with voxelize_cell() (exactly voxelize()'s voxels and
// attributes inside the cell) and phase 1 runs up to its root.
// reduce_attributes() is a pure function of a node's children, so the top
// levels 0..C built from the cell roots equal the in-core ones bit for bit.
// The planner (§7.1-7.2) plans depths 1..C (the top plan); a refined cell
// root leaves a seed (its triangles and ancestor slabs) instead of
// descending, and that cell's own planner continues from the seed, which
// gives the in-core plan below it (a voxel's plan depends only on what its
// ancestors hand down). Of each refined cell only the nodes the plan keeps
// are appended: the children of kept refined voxels, with their planned
// subtree sizes. The layout then runs on the kept tree; it only reads nodes
// it visits and their children, so it writes the in-core bytes.
//   Without a color/normal tolerance, one pass: the top plan needs no
//   attributes and no cell's voxels (a voxel's plan does not depend on its
//   siblings, so it is planned on the tree of all cells that have
//   triangles, a superset), then each cell is voxelized once.
//   With one, REFINE-ATTRIBUTES of a top voxel (§7.3) needs its value (the
//   top levels) and every full-depth voxel below it: pass 1 collects the
//   cell roots, pass 2 streams the cells against their ancestors' values
//   (flags OR-ed over the cells), pass 3 plans the refined cells.
//   With compressed attributes too, the in-core decoded-leaf loop (§7.3)
//   follows, per round streaming only the cells that hold a leaf to test;
//   each refined cell's kept nodes stay a separate segment, so a cell
//   re-planned with forced leaves replaces only its own (see the loop).
// Peak memory: the mesh, triangle bins and planner mesh data, the top
// levels (one node per cell and above) with the seeds, one cell's build,
// and the kept output.
namespace {

// Working set of a cell per estimated (voxel, triangle) pair: the pairs
// (16 B, twice while concatenated, + sort), and per voxel (about half a pair)
// the VoxelSet (40 B), leaf values (8), phase 1 (~24) and the cell's plan (~9).
constexpr double kCellBytesPerPair = 32.0 + 24.0 + 12.0 + 0.5 * (8.0 + 24.0 + 9.0);
// Planner mesh data per triangle (grid-unit vertices, normal, box, boundary
// flags) and the boundary-edge map while it is built.
constexpr double kPlannerBytesPerTriangle = 72.0 + 24.0 + 48.0 + 1.0 + 3.0 * 48.0;

/// One cell's full-depth voxels.
VoxelSet voxelize_one(const Mesh& mesh, const GridTransform& grid,
                      const std::vector<std::array<double, 3>>& gv,
                      const std::vector<uint32_t>& tris, uint64_t cell, int c,
                      const VoxelizeOptions& vo) {
  const MortonCoord cc = morton_decode(cell);
  const uint32_t lo[3] = {cc.x << c, cc.y << c, cc.z << c};
  return voxcast::detail::voxelize_cell(mesh, grid, gv, tris.data(), tris.size(), lo, 1u << c, vo);
}

/// The TreeView of levels [from, L) of `lv` plus the leaf values (null /
/// zero entries elsewhere).
detail::TreeView tree_view(const std::vector<Level>& lv, const std::vector<uint64_t>* leaf_values,
                           int from, int to) {
  const int L = int(lv.size());
  detail::TreeView tree;
  tree.levels = L;
  tree.mask.assign(size_t(L), nullptr);
  tree.first_child.assign(size_t(L), nullptr);
  tree.count.assign(size_t(L) + 1, 0);
  tree.value.assign(size_t(L) + 1, nullptr);
  for (int d = from; d <= std::min(to, L - 1); ++d) {
    tree.mask[size_t(d)] = lv[size_t(d)].mask.data();
    tree.first_child[size_t(d)] = lv[size_t(d)].first_child.data();
    tree.count[size_t(d)] = lv[size_t(d)].mask.size();
    if (d >= 1 && !lv[size_t(d)].value.empty()) tree.value[size_t(d)] = lv[size_t(d)].value.data();
  }
  if (leaf_values != nullptr) {
    tree.count[size_t(L)] = leaf_values->size();
    tree.value[size_t(L)] = leaf_values->data();
  }
  return tree;
}

}  // namespace

EsvoOctree build_octree_cells(const Mesh& mesh, const GridTransform& grid,
                              const VoxelizeOptions& voxelize_options, const BuildOptions& options,
                              uint32_t cell_size, uint64_t memory_budget, CellBuildStats* stats) {
  CellBuildStats st;
  if (!options.contours) throw Error("cannot build octree cell by cell: needs contours");
  check_block_limits(options);
  const int L = grid.levels;
  if (L < 2 || L > kMaxGridLevels || grid.resolution != (1u << L))
    throw Error("cannot build octree cell by cell: the grid must have 2.." +
                std::to_string(kMaxGridLevels) + " levels");
  if (options.max_level < 0 || options.max_level > L)
    throw Error("cannot build octree: max level " + std::to_string(options.max_level) +
                " outside 1.." + std::to_string(L));
  if (!std::isfinite(options.geometry_error) || !std::isfinite(options.color_error) ||
      !std::isfinite(options.normal_error))
    throw Error("cannot build octree: error tolerances must be finite");
  if (mesh.triangle_count() > size_t(UINT32_MAX))
    throw Error("cannot build octree: more than 2^32-1 triangles");
  VoxelizeOptions vo = voxelize_options;
  // The caller's bar follows the cells, not each cell's small voxelization.
  Progress* const progress = vo.progress;
  vo.progress = nullptr;
  const bool attr_tolerance = options.color_error >= 0 || options.normal_error >= 0;
  // With compressed attributes a leaf decodes to what the §5.5 block of its
  // descriptor pair makes of it (§7.3), known only after the layout: the
  // decoded-leaf loop at the end.
  const bool check_decoded = options.attributes == AttributeFormat::Compressed && attr_tolerance;
  const std::vector<std::array<double, 3>> gv = voxcast::detail::grid_vertices(mesh, grid);
  voxcast::detail::CellPlan cp;
  const uint64_t planner_bytes = uint64_t(kPlannerBytesPerTriangle * double(mesh.triangle_count()));
  if (cell_size != 0) {
    if (!std::has_single_bit(cell_size) || cell_size < 2 || cell_size > grid.resolution / 2)
      throw Error("cell size " + std::to_string(cell_size) +
                  " is not a power of two between 2 and half the resolution " +
                  std::to_string(grid.resolution));
    cp =
        voxcast::detail::plan_cells(mesh, gv, grid, std::countr_zero(cell_size), kCellBytesPerPair);
  } else {
    uint64_t budget = memory_budget;
    if (budget == 0) budget = uint64_t(double(available_memory_bytes()) * 0.9);
    const int min_bits = std::min(L - 1, 5);  // 32^3: smaller cells only multiply the bins
    for (int bits = L - 1; bits >= min_bits; --bits) {
      cp = voxcast::detail::plan_cells(mesh, gv, grid, bits, kCellBytesPerPair);
      const uint64_t fixed = cp.fixed_bytes + planner_bytes;
      if (budget == 0 || (fixed < budget && cp.cell_bytes <= (budget - fixed) / 2)) break;
    }
  }
  const int c = cp.bits;
  const int C = L - c;  // depth of the cells' roots
  st.cell_size = 1u << c;
  st.estimated_bytes = cp.fixed_bytes + planner_bytes + cp.cell_bytes;
  std::vector<voxcast::detail::CellBin> bins = voxcast::detail::bin_triangles(mesh, gv, grid, c);
  // Cell b's triangles: bins[cell_start[b], cell_start[b + 1]).
  std::vector<size_t> cell_start;
  for (size_t i = 0; i < bins.size(); ++i)
    if (i == 0 || bins[i].cell != bins[i - 1].cell) cell_start.push_back(i);
  cell_start.push_back(bins.size());
  const size_t nbins = cell_start.size() - 1;
  std::vector<uint32_t> tris;
  auto cell_tris = [&](size_t b) {
    tris.clear();
    for (size_t i = cell_start[b]; i < cell_start[b + 1]; ++i) tris.push_back(bins[i].tri);
    return bins[cell_start[b]].cell;
  };

  const std::shared_ptr<const detail::PlannerMesh> pmesh = detail::make_planner_mesh(grid, mesh);
  std::vector<Level> lv(static_cast<size_t>(L));
  detail::ContourPlan plan;
  plan.contour.resize(size_t(L) + 1);
  plan.leaf.resize(size_t(L));
  std::vector<uint64_t> leaf_values;  // kept depth-L voxels

  // The non-empty cells' roots, in Morton order.
  struct Roots {
    std::vector<uint32_t> bin;  // its bin group
    std::vector<uint64_t> code;
    std::vector<uint8_t> mask;
    std::vector<Color> color;
    std::vector<Vec3> normal;
    std::vector<float> weight;
    std::vector<uint32_t> first_child;  // in lv[C + 1], if refined
    std::vector<uint64_t> desc_below, values_below;
  } roots;
  // Voxelizes cell group b and runs phase 1 up to its root; false if empty.
  auto cell_levels = [&](size_t b, std::vector<Level>& clv, std::vector<uint64_t>& cleaf) {
    const uint64_t cell = cell_tris(b);
    const VoxelSet vs = voxelize_one(mesh, grid, gv, tris, cell, c, vo);
    if (vs.codes.empty()) return false;
    if (vs.size() >= (uint64_t(1) << 32))
      throw Error("cannot build octree: more than 2^32 voxels in one cell");
    build_levels(vs, clv, cleaf, C);
    return true;
  };
  auto add_root = [&](size_t b, const std::vector<Level>& clv, size_t voxels) {
    const Level& r = clv[size_t(C)];
    st.voxels += voxels;
    st.max_cell_voxels = std::max<uint64_t>(st.max_cell_voxels, voxels);
    roots.bin.push_back(uint32_t(b));
    roots.code.push_back(r.code[0]);
    roots.mask.push_back(r.mask[0]);
    roots.color.push_back(r.color[0]);
    roots.normal.push_back(r.normal[0]);
    roots.weight.push_back(r.weight[0]);
    roots.first_child.push_back(0);
    roots.desc_below.push_back(0);
    roots.values_below.push_back(0);
  };
  // A refined cell's kept nodes below its root (depths C+1..L), with
  // first_child local to the segment (0 for leaves). The decoded-leaf loop
  // keeps one per cell, so that re-planning a cell replaces only its own.
  struct Segment {
    std::vector<Level> lv;  // depths C+1..L-1
    detail::ContourPlan plan;
    std::vector<uint64_t> leaf_values;
    std::vector<std::vector<uint32_t>> local;   // [depth]: index in the cell's tree (loop only)
    uint64_t desc_below = 0, values_below = 0;  // of the cell's root
  };
  // Plans a cell's subtree from its seed (forcing `forced`, (depth, index in
  // the cell's tree), as refine() does in core) and keeps the nodes the plan
  // keeps below its root: the children of kept refined voxels.
  std::vector<uint32_t> cur, next;
  auto plan_cell = [&](std::vector<Level>& clv, const std::vector<uint64_t>& cleaf,
                       const detail::SubtreeSeed& seed,
                       const std::vector<std::pair<int, uint32_t>>* forced, Segment& seg) {
    const detail::TreeView ct = tree_view(clv, &cleaf, C, L - 1);
    detail::ContourPlanner cplanner(ct, pmesh, options, seed);
    const detail::ContourPlan* cp = &cplanner.plan();
    if (forced != nullptr && !forced->empty()) {
      cplanner.refine(*forced);
      cp = &cplanner.plan();
    }
    const detail::ContourPlan& cplan = *cp;
    planned_sizes(clv, cplan, L - 2, C);
    seg = Segment{};
    seg.lv.resize(size_t(L));
    seg.plan.contour.resize(size_t(L) + 1);
    seg.plan.leaf.resize(size_t(L));
    if (check_decoded) seg.local.resize(size_t(L));
    seg.desc_below = clv[size_t(C)].desc_below[0];
    seg.values_below = clv[size_t(C)].values_below[0];
    cur.assign(1, 0);
    for (int d = C; d < L; ++d) {
      const Level& src = clv[size_t(d)];
      Level& dst = seg.lv[size_t(d)];
      next.clear();
      for (const uint32_t i : cur) {
        const bool refined = d == C || !cplan.leaf[size_t(d)][i];
        uint32_t fc = 0;
        if (refined) {
          fc = uint32_t(next.size());
          const uint32_t first = src.first_child[i];
          for (int j = 0; j < std::popcount(unsigned(src.mask[i])); ++j)
            next.push_back(first + uint32_t(j));
        }
        if (d == C) continue;
        dst.mask.push_back(src.mask[i]);
        dst.first_child.push_back(fc);
        dst.desc_below.push_back(src.desc_below[i]);
        dst.values_below.push_back(src.values_below[i]);
        dst.value.push_back(src.value[i]);
        seg.plan.contour[size_t(d)].push_back(cplan.contour[size_t(d)][i]);
        seg.plan.leaf[size_t(d)].push_back(cplan.leaf[size_t(d)][i]);
        if (check_decoded) seg.local[size_t(d)].push_back(i);
      }
      cur.swap(next);
    }
    for (const uint32_t i : cur) {  // depth L
      seg.leaf_values.push_back(cleaf[i]);
      seg.plan.contour[size_t(L)].push_back(cplan.contour[size_t(L)][i]);
    }
  };
  // Appends cell k's segment to the global levels (Morton order: cells are
  // appended in visit order) with global first_child, and sets its root's.
  auto append_segment = [&](size_t k, const Segment& seg, std::vector<uint32_t>& root_first,
                            std::vector<uint64_t>& root_desc, std::vector<uint64_t>& root_vals) {
    auto base = [&](int d) {  // where depth d's next node goes
      return d < L ? lv[size_t(d)].mask.size() : leaf_values.size();
    };
    if (base(C + 1) >= (uint64_t(1) << 32))
      throw Error("cannot build octree: more than 2^32 nodes");
    root_first[k] = uint32_t(base(C + 1));
    root_desc[k] = seg.desc_below;
    root_vals[k] = seg.values_below;
    for (int d = C + 1; d < L; ++d) {
      const Level& src = seg.lv[size_t(d)];
      Level& dst = lv[size_t(d)];
      const uint64_t b = base(d + 1);
      if (b + (d + 1 < L ? seg.lv[size_t(d) + 1].mask.size() : seg.leaf_values.size()) >=
          (uint64_t(1) << 32))
        throw Error("cannot build octree: more than 2^32 nodes");
      const std::vector<uint8_t>& leaf = seg.plan.leaf[size_t(d)];
      for (size_t j = 0; j < src.mask.size(); ++j)
        dst.first_child.push_back(leaf[j] ? 0 : uint32_t(b + src.first_child[j]));
      dst.mask.insert(dst.mask.end(), src.mask.begin(), src.mask.end());
      dst.desc_below.insert(dst.desc_below.end(), src.desc_below.begin(), src.desc_below.end());
      dst.values_below.insert(dst.values_below.end(), src.values_below.begin(),
                              src.values_below.end());
      dst.value.insert(dst.value.end(), src.value.begin(), src.value.end());
      plan.contour[size_t(d)].insert(plan.contour[size_t(d)].end(),
                                     seg.plan.contour[size_t(d)].begin(),
                                     seg.plan.contour[size_t(d)].end());
      plan.leaf[size_t(d)].insert(plan.leaf[size_t(d)].end(), leaf.begin(), leaf.end());
    }
    leaf_values.insert(leaf_values.end(), seg.leaf_values.begin(), seg.leaf_values.end());
    plan.contour[size_t(L)].insert(plan.contour[size_t(L)].end(),
                                   seg.plan.contour[size_t(L)].begin(),
                                   seg.plan.contour[size_t(L)].end());
  };
  Segment seg;
  // The top levels 0..C from the cell roots, as build_levels() reduces them
  // (codes kept per depth in top_codes).
  std::vector<std::vector<uint64_t>> top_codes(size_t(C) + 1);
  auto build_top = [&]() {
    if (roots.code.empty()) throw Error("cannot build octree: no voxels");
    st.cells = roots.code.size();
    Level& r = lv[size_t(C)];
    r.code = std::move(roots.code);
    r.mask = std::move(roots.mask);
    r.color = std::move(roots.color);
    r.normal = std::move(roots.normal);
    r.weight = std::move(roots.weight);
    r.first_child = std::move(roots.first_child);
    r.desc_below = std::move(roots.desc_below);
    r.values_below = std::move(roots.values_below);
    for (int d = C - 1; d >= 0; --d) {
      Level& p = lv[size_t(d)];
      Level& ch = lv[size_t(d) + 1];
      reduce_codes(ch.code, p);
      reduce_attributes(ch.color, ch.normal, ch.weight, p);
      encode_values(ch.color, ch.normal, ch.value);
      top_codes[size_t(d) + 1] = std::move(ch.code);
      std::vector<Color>().swap(ch.color);
      std::vector<Vec3>().swap(ch.normal);
      std::vector<float>().swap(ch.weight);
      p.desc_below.assign(p.mask.size(), 0);
      p.values_below.assign(p.mask.size(), 0);
    }
    if (lv[0].mask.size() != 1)
      throw std::logic_error("esvo builder: root level is not a single node");
  };

  if (!attr_tolerance) {
    // One pass. Without a color/normal tolerance a voxel's contour and
    // decision depend only on its ancestors' triangles and slabs (§7.1-7.2),
    // not on its siblings or any attributes, so the top levels can be
    // planned before any cell is voxelized, on the tree of the cells that
    // have triangles (a superset of the non-empty ones); each cell is then
    // voxelized once, its root kept and, if refined, its subtree planned.
    std::vector<Level> sup(static_cast<size_t>(L));
    for (size_t b = 0; b < nbins; ++b) sup[size_t(C)].code.push_back(bins[cell_start[b]].cell);
    sup[size_t(C)].mask.assign(nbins, 0);
    sup[size_t(C)].first_child.assign(nbins, 0);
    for (int d = C - 1; d >= 0; --d) reduce_codes(sup[size_t(d) + 1].code, sup[size_t(d)]);
    // Values are not read without an attribute tolerance (the planner's
    // REFINE-ATTRIBUTES is off), but the view needs them.
    for (int d = 1; d <= C; ++d) sup[size_t(d)].value.assign(sup[size_t(d)].mask.size(), 0);
    const detail::TreeView top = tree_view(sup, nullptr, 0, C);
    detail::ContourPlanner planner(top, pmesh, options, C, nullptr);
    const detail::ContourPlan& tp = planner.plan();
    // The cells stream (voxelize + plan each) is nearly all of the time; the
    // layout of the kept tree follows.
    if (progress) {
      progress->set_phases({{"cells", 0.9}, {"layout", 0.1}});
      progress->start_phase(0, nbins);
    }
    for (size_t b = 0; b < nbins; ++b) {
      std::vector<Level> clv;
      std::vector<uint64_t> cleaf;
      if (progress) progress->advance();
      if (!cell_levels(b, clv, cleaf)) continue;
      add_root(b, clv, cleaf.size());
      if (const auto seed = planner.take_seed(uint32_t(b))) {
        ++st.refined_cells;
        plan_cell(clv, cleaf, *seed, nullptr, seg);
        append_segment(roots.bin.size() - 1, seg, roots.first_child, roots.desc_below,
                       roots.values_below);
      }
    }
    build_top();
    // The top plan of the non-empty nodes (a subsequence of sup's, by code).
    for (int d = 1; d <= C; ++d) {
      const std::vector<uint64_t>& real = top_codes[size_t(d)];
      const std::vector<uint64_t>& all = sup[size_t(d)].code;
      plan.contour[size_t(d)].resize(real.size());
      if (d < L) plan.leaf[size_t(d)].resize(real.size());
      for (size_t i = 0, j = 0; i < real.size(); ++i, ++j) {
        while (all[j] != real[i]) ++j;
        plan.contour[size_t(d)][i] = tp.contour[size_t(d)][j];
        if (d < L) plan.leaf[size_t(d)][i] = tp.leaf[size_t(d)][j];
      }
    }
  } else {
    // Pass 1: the cell roots. (The bar follows the first two streams over
    // the cells; the attribute rounds after them show as "attributes".)
    if (progress) {
      progress->set_phases({{"cell roots", 1}, {"attribute flags", 1}, {"attributes", 1}});
      progress->start_phase(0, nbins);
    }
    for (size_t b = 0; b < nbins; ++b) {
      std::vector<Level> clv;
      std::vector<uint64_t> cleaf;
      if (cell_levels(b, clv, cleaf)) add_root(b, clv, cleaf.size());
      if (progress) progress->advance();
    }
    const std::vector<uint32_t> cell_bin = roots.bin;
    build_top();
    const size_t ncells = cell_bin.size();

    // Pass 2: REFINE-ATTRIBUTES flags of the top voxels (depth 1..C).
    std::vector<std::vector<uint8_t>> attr_flags(size_t(C) + 1);
    for (int d = 1; d <= C; ++d) attr_flags[size_t(d)].assign(lv[size_t(d)].mask.size(), 0);
    std::vector<uint64_t> values;
    if (progress) progress->start_phase(1, ncells);
    for (size_t k = 0; k < ncells; ++k) {
      if (progress) progress->advance();
      // The cell's ancestors (depth C: itself), bottom-up.
      uint32_t anc[kMaxGridLevels + 1];
      anc[C] = uint32_t(k);
      for (int d = C - 1; d >= 1; --d) {
        const std::vector<uint32_t>& fc = lv[size_t(d)].first_child;
        anc[d] = uint32_t(std::upper_bound(fc.begin(), fc.end(), anc[d + 1]) - fc.begin() - 1);
      }
      bool all_set = true;
      for (int d = 1; d <= C; ++d) all_set = all_set && attr_flags[size_t(d)][anc[d]];
      if (all_set) continue;
      const uint64_t cell = cell_tris(cell_bin[k]);
      VoxelSet vs = voxelize_one(mesh, grid, gv, tris, cell, c, vo);
      if (vs.colors.empty()) {
        vs.colors.assign(vs.size(), kDefaultColor);
        vs.normals.assign(vs.size(), kDefaultNormal);
      }
      encode_values(vs.colors, vs.normals, values);
      vs = VoxelSet{};
      tbb::parallel_for(1, C + 1, [&](int d) {
        uint8_t& f = attr_flags[size_t(d)][anc[d]];
        if (f) return;
        const uint64_t v = lv[size_t(d)].value[anc[d]];
        f = detail::values_exceed(values.data(), 0, values.size(), uint32_t(v),
                                  decode_normal_cube(uint32_t(v >> 32)), options);
      });
    }

    // The top plan (depths 1..C), then pass 3: every refined cell again.
    const detail::TreeView top = tree_view(lv, nullptr, 0, C);
    detail::ContourPlanner planner(top, pmesh, options, C, &attr_flags);
    const detail::ContourPlan& tp = planner.plan();
    auto copy_top_plan = [&]() {
      for (int d = 1; d <= C; ++d) {
        plan.contour[size_t(d)] = tp.contour[size_t(d)];
        if (d < L) plan.leaf[size_t(d)] = tp.leaf[size_t(d)];
      }
    };
    copy_top_plan();
    Level& r = lv[size_t(C)];
    if (progress) progress->start_phase(2, 0);
    if (!check_decoded) {
      attr_flags = {};
      roots.first_child = std::move(r.first_child);
      roots.desc_below = std::move(r.desc_below);
      roots.values_below = std::move(r.values_below);
      for (size_t k = 0; k < ncells; ++k) {
        const auto seed = planner.take_seed(uint32_t(k));
        if (!seed) continue;
        std::vector<Level> clv;
        std::vector<uint64_t> cleaf;
        cell_levels(cell_bin[k], clv, cleaf);
        ++st.refined_cells;
        plan_cell(clv, cleaf, *seed, nullptr, seg);
        append_segment(k, seg, roots.first_child, roots.desc_below, roots.values_below);
      }
      r.first_child = std::move(roots.first_child);
      r.desc_below = std::move(roots.desc_below);
      r.values_below = std::move(roots.values_below);
    } else {
      // The §7.3 decoded-leaf loop of the in-core build, streamed. Each
      // round: lay out, decode every leaf above the max level, stream the
      // cells holding one (a top leaf, depth <= C, covers whole cells; a
      // deeper one lies in one cell) to test it against its full-depth
      // voxels, force the failures (top leaves in the top planner, deeper
      // ones in their cell's plan) and re-plan only the cells that changed.
      // Every round lays out the in-core round's tree, so both find the
      // same failures and force the same set: the same bytes. The top
      // planner keeps the attribute flags of pass 2 for the voxels it
      // reaches below newly forced top leaves.
      std::vector<Segment> segs(ncells);
      std::vector<uint8_t> has_seg(ncells, 0);
      std::vector<std::shared_ptr<const detail::SubtreeSeed>> seeds(ncells);
      std::vector<std::vector<std::pair<int, uint32_t>>> forced(ncells);
      auto replan = [&](size_t k, std::vector<Level>& clv, const std::vector<uint64_t>& cleaf) {
        plan_cell(clv, cleaf, *seeds[k], &forced[k], segs[k]);
        has_seg[k] = 1;
      };
      auto plan_new_cells = [&]() {  // cells whose root the top plan newly refines
        for (size_t k = 0; k < ncells; ++k) {
          auto seed = planner.take_seed(uint32_t(k));
          if (!seed) continue;
          seeds[k] = std::move(seed);
          std::vector<Level> clv;
          std::vector<uint64_t> cleaf;
          cell_levels(cell_bin[k], clv, cleaf);
          replan(k, clv, cleaf);
        }
      };
      plan_new_cells();
      const int lmax = options.max_level > 0 ? options.max_level : L;
      // [depth][k]: where cell k's nodes of depth d > C start in lv[d].
      std::vector<std::vector<size_t>> off(static_cast<size_t>(L));
      // Leaves that passed, with the decoded value they passed with: top
      // ones by (depth, index), inner ones per cell by (depth, local index).
      struct Passed {
        int depth;
        uint32_t local;
        DecodedLeaf value;
      };
      auto passed_less = [](const Passed& a, const Passed& b) {
        return a.depth != b.depth ? a.depth < b.depth : a.local < b.local;
      };
      auto same_value = [](const DecodedLeaf& a, const DecodedLeaf& b) {
        return a.color == b.color &&
               std::bit_cast<uint32_t>(a.normal.x) == std::bit_cast<uint32_t>(b.normal.x) &&
               std::bit_cast<uint32_t>(a.normal.y) == std::bit_cast<uint32_t>(b.normal.y) &&
               std::bit_cast<uint32_t>(a.normal.z) == std::bit_cast<uint32_t>(b.normal.z);
      };
      std::vector<std::vector<Passed>> passed(ncells);
      std::map<std::pair<int, uint32_t>, DecodedLeaf> top_passed;
      EsvoOctree result;
      for (;;) {
        // The kept tree of this round.
        for (int d = C + 1; d < L; ++d) {
          lv[size_t(d)] = Level{};
          plan.leaf[size_t(d)].clear();
        }
        for (int d = C + 1; d <= L; ++d) plan.contour[size_t(d)].clear();
        leaf_values.clear();
        r.first_child.assign(ncells, 0);
        r.desc_below.assign(ncells, 0);
        r.values_below.assign(ncells, 0);
        for (int d = C + 1; d < L; ++d) off[size_t(d)].assign(ncells + 1, 0);
        for (size_t k = 0; k < ncells; ++k) {
          for (int d = C + 1; d < L; ++d) off[size_t(d)][k] = lv[size_t(d)].mask.size();
          if (has_seg[k] && !plan.leaf[size_t(C)][k])
            append_segment(k, segs[k], r.first_child, r.desc_below, r.values_below);
        }
        for (int d = C + 1; d < L; ++d) off[size_t(d)][ncells] = lv[size_t(d)].mask.size();
        planned_sizes(lv, plan, C - 1, 0);
        EsvoOctree octree = Layout(lv, leaf_values, options, &plan).run(grid);
        ++st.decoded_rounds;
        const std::vector<DecodedLeaf> leaves =
            decoded_leaves(octree, tree_view(lv, &leaf_values, 0, L - 1), lmax);

        // Which leaves each cell must test: the top leaf covering it (leaves
        // are disjoint, so at most one) and the leaves inside it. A leaf that
        // passed in an earlier round with the same decoded value passes
        // again (same voxels below it), so only leaves whose §5.5 block
        // changed are tested, and only the cells holding one are streamed.
        constexpr uint32_t kNone = UINT32_MAX;
        std::vector<uint32_t> top_leaf(ncells, kNone);
        std::vector<std::vector<uint32_t>> inner(ncells);
        std::vector<uint8_t> top_bad(leaves.size(), 0);
        std::vector<uint8_t> top_tested(leaves.size(), 0);
        for (size_t j = 0; j < leaves.size(); ++j) {
          const DecodedLeaf& l = leaves[j];
          if (l.depth <= C) {
            const auto hit = top_passed.find({l.depth, l.index});
            if (hit != top_passed.end() && same_value(hit->second, l)) continue;
            top_tested[j] = 1;
            // Its cells: [first, end) at depth C.
            size_t b0 = l.index, e0 = size_t(l.index) + 1;
            for (int d = l.depth; d < C; ++d) {
              const std::vector<uint32_t>& fc = lv[size_t(d)].first_child;
              b0 = fc[b0];
              e0 = e0 < fc.size() ? fc[e0] : lv[size_t(d) + 1].mask.size();
            }
            for (size_t k = b0; k < e0; ++k) top_leaf[k] = uint32_t(j);
          } else {
            const std::vector<size_t>& o = off[size_t(l.depth)];
            const size_t k =
                size_t(std::upper_bound(o.begin(), o.end(), size_t(l.index)) - o.begin() - 1);
            inner[k].push_back(uint32_t(j));
          }
        }
        std::vector<size_t> changed;  // cells re-planned this round
        for (size_t k = 0; k < ncells; ++k) {
          const bool test_top = top_leaf[k] != kNone && !top_bad[top_leaf[k]];
          // This round's inner leaves of cell k as (depth, local index), and
          // the ones not passed before with this value.
          std::vector<Passed> now;
          std::vector<uint32_t> todo;  // indices into now
          for (const uint32_t j : inner[k]) {
            const DecodedLeaf& l = leaves[j];
            const uint32_t local =
                segs[k].local[size_t(l.depth)][l.index - off[size_t(l.depth)][k]];
            const Passed q{l.depth, local, l};
            const std::vector<Passed>& pk = passed[k];
            const auto it = std::lower_bound(pk.begin(), pk.end(), q, passed_less);
            if (it == pk.end() || passed_less(q, *it) || !same_value(it->value, l))
              todo.push_back(uint32_t(now.size()));
            now.push_back(q);
          }
          if (!test_top && todo.empty()) {
            std::sort(now.begin(), now.end(), passed_less);
            passed[k] = std::move(now);
            continue;
          }
          std::vector<Level> clv;
          std::vector<uint64_t> cleaf;
          cell_levels(cell_bin[k], clv, cleaf);
          if (test_top) {
            const DecodedLeaf& l = leaves[top_leaf[k]];
            top_bad[top_leaf[k]] =
                detail::values_exceed(cleaf.data(), 0, cleaf.size(), l.color, l.normal, options);
          }
          const detail::TreeView ct = tree_view(clv, &cleaf, C, L - 1);
          std::vector<uint8_t> bad(todo.size(), 0);
          tbb::parallel_for(size_t(0), todo.size(), [&](size_t u) {
            const Passed& q = now[todo[u]];
            bad[u] = detail::attributes_exceed(ct, q.depth, q.local, q.value.color, q.value.normal,
                                               options);
          });
          std::vector<uint8_t> failed(now.size(), 0);
          for (size_t u = 0; u < todo.size(); ++u) {
            if (!bad[u]) continue;
            failed[todo[u]] = 1;
            forced[k].push_back({now[todo[u]].depth, now[todo[u]].local});
          }
          std::vector<Passed> keep;
          for (size_t u = 0; u < now.size(); ++u)
            if (!failed[u]) keep.push_back(now[u]);
          std::sort(keep.begin(), keep.end(), passed_less);
          passed[k] = std::move(keep);
          // Re-plan now, while its voxels are at hand.
          if (std::find(bad.begin(), bad.end(), 1) != bad.end())
            replan(k, clv, cleaf), changed.push_back(k), ++st.replanned_cells;
        }
        for (size_t j = 0; j < leaves.size(); ++j)
          if (top_tested[j] && !top_bad[j])
            top_passed[{leaves[j].depth, leaves[j].index}] = leaves[j];
        std::vector<std::pair<int, uint32_t>> bad_top;
        for (size_t j = 0; j < leaves.size(); ++j)
          if (top_bad[j]) bad_top.push_back({leaves[j].depth, leaves[j].index});
        if (bad_top.empty() && changed.empty()) {
          result = std::move(octree);
          break;
        }
        if (!bad_top.empty()) {
          st.forced_top_leaves += bad_top.size();
          planner.refine(bad_top);
          copy_top_plan();
          plan_new_cells();
        }
      }
      for (size_t k = 0; k < ncells; ++k) st.refined_cells += has_seg[k];
      bins = {};
      if (stats) *stats = st;
      return result;
    }
  }
  bins = {};
  if (progress && !attr_tolerance) progress->start_phase(1, 0);  // "layout"

  // Subtree sizes of the top levels from the cells', then the layout of the
  // kept tree (the decoded-value loop is not needed: raw leaves decode to
  // what the planner tested, and compressed ones without a color/normal
  // tolerance are not tested).
  planned_sizes(lv, plan, C - 1, 0);
  if (stats) *stats = st;
  return Layout(lv, leaf_values, options, &plan).run(grid);
}

}  // namespace voxcast::esvo
