#pragma once
// The DAG's node-access policy (dag/octree_nodes.hpp) in the lane form the
// packet kernel needs (core/octree_packet_kernel.hpp documents the
// interface): headers and 64-bit leaf masks fetched by gather, the node kind
// chosen per lane from its scale. The voxel rank is not carried (the packet
// caster finds it after the hit, core/octree_packet_caster.hpp). Included
// only by the kernel translation units packet_kernel_avx2.cpp / _avx512.cpp.
#include "core/octree_packet_kernel.hpp"
#include "dag/octree_nodes.hpp"
#include "voxcast/dag.hpp"

namespace voxcast::detail {
namespace {

template <int kLanes>
struct DagPacketNodes {
  static constexpr int N = kLanes;
  using L = Lanes<N>;
  using I = typename L::I;
  using U = typename L::U;
  using Scalar = DagNodes;
  static constexpr bool kContours = false;
  struct Desc {
    U mask;    // present children
    U lo, hi;  // the 4^3 mask of a leaf-mask node
  };
  explicit DagPacketNodes(const DagNodes& n)
      : words(n.words), leaf_scale(n.leaf_scale), mask_scale(n.mask_scale) {}

  /// DagNodes::fetch per lane: a header's child mask above the leaf-mask
  /// level, the 64-bit mask and its byte mask at it, the sub-block byte
  /// (the node itself) below.
  void fetch(Desc* d, I m, U node, I scale) const {
    const I header = m & (scale > mask_scale);
    const I leafmask = m & (scale == mask_scale);
    const I below = m & (scale < mask_scale);
    const U w = L::gather(words, (I)node, header | leafmask, U{});
    if (L::bits(leafmask) != 0) {
      const U w1 = L::gather(words, (I)(node + 1u), leafmask, U{});
      d->lo = leafmask ? w : d->lo;
      d->hi = leafmask ? w1 : d->hi;
    }
    using dag::layout::ChildMask;
    U mask = header ? (w >> ChildMask::lo) & ChildMask::max : d->mask;
    mask = leafmask ? byte_bits(w) | (byte_bits(d->hi) << 4) : mask;
    d->mask = below ? node : mask;
  }
  static I fetched(const Desc& d) { return (I)(d.mask != 0u); }  // masks are never empty
  static void forget(Desc* d, I m) { d->mask = m ? U{} : d->mask; }
  static I valid(const Desc& d, U c) { return (I)(((d.mask >> c) & 1u) != 0u); }
  I leaf(const Desc&, U, I scale) const { return scale == leaf_scale; }
  /// DagNodes::descend without the index: the pointer word behind the
  /// header, or sub-block c of the leaf mask.
  U descend(const Desc& d, U node, U c, I scale, I m) const {
    const I header = m & (scale > mask_scale);
    const U rank = L::popcount8(d.mask & (((U{} + 1u) << c) - 1u));
    const U child = L::gather(words, (I)(node + 1u + rank), header, U{});
    // dag::layout::LeafMaskBytes: byte c of the 64-bit mask (lo = bytes 0-3).
    const U half = c < 4u ? d.lo : d.hi;
    const U sub = (half >> ((c & 3u) * 8u)) & 0xFFu;
    return header ? child : sub;
  }

  /// Bit j set iff byte j of each lane's word is non-zero (byte_mask of
  /// dag/octree_nodes.hpp on 32 bits).
  static U byte_bits(U v) {
    v |= v >> 4;
    v |= v >> 2;
    v |= v >> 1;
    v &= 0x01010101u;
    return (v | (v >> 7) | (v >> 14) | (v >> 21)) & 0xFu;
  }

  const uint32_t* words;
  int leaf_scale, mask_scale;
};

}  // namespace
}  // namespace voxcast::detail
