#pragma once
// The ESVO's node-access policy (esvo/octree_nodes.hpp) in the lane form the
// packet kernel needs (core/octree_packet_kernel.hpp documents the
// interface): child descriptors fetched by gather, masks tested per lane,
// near/far child pointers (§5.1) followed per lane. Included only by the
// kernel translation units packet_kernel_avx2.cpp / _avx512.cpp.
#include "core/octree_packet_kernel.hpp"
#include "esvo/octree_nodes.hpp"
#include "voxcast/esvo.hpp"

namespace voxcast::detail {
namespace {

template <int kLanes>
struct EsvoPacketNodes {
  static constexpr int N = kLanes;
  using L = Lanes<N>;
  using I = typename L::I;
  using U = typename L::U;
  using Scalar = EsvoNodes;
  static constexpr bool kContours = Scalar::kContours;
  struct Desc {
    U w0, w1;
  };
  explicit EsvoPacketNodes(const EsvoNodes& n) : nodes(n), words(n.words) {}

  // Word index slot * 2 (+1): gathers take signed 32-bit indices, which
  // esvo/packet.cpp checks the octree's size against.
  void fetch(Desc* d, I m, U slot, I) const {
    const I w = (I)(slot * 2u);
    d->w0 = L::gather(words, w, m, d->w0);
    d->w1 = L::gather(words, w + 1, m, d->w1);
  }
  static I fetched(const Desc& d) { return (I)(d.w0 != 0u); }  // valid masks are never empty
  static void forget(Desc* d, I m) { d->w0 = m ? U{} : d->w0; }
  static I valid(const Desc& d, U c) {
    return (I)(((d.w0 >> (c + esvo::layout::ValidMask::lo)) & 1u) != 0u);
  }
  static I leaf(const Desc& d, U c, I) {
    return (I)(((d.w0 >> (c + esvo::layout::LeafMask::lo)) & 1u) != 0u);
  }
  static I contour_lanes(const Desc& d, U c) {
    return (I)(((d.w1 >> (c + esvo::layout::ContourMask::lo)) & 1u) != 0u);
  }
  /// Lane l's contour value (its bit is set): EsvoNodes::contour.
  uint32_t contour_value(const Desc& d, int l, uint32_t slot, uint32_t c) const {
    uint32_t value = 0;
    nodes.contour({d.w0[l], d.w1[l]}, slot, int(c), &value);
    return value;
  }
  /// EsvoNodes::descend: the first non-leaf child's slot (near pointer
  /// relative to `slot`, or a far pointer's 32-bit offset), then the rank of c
  /// among the non-leaf children.
  U descend(const Desc& d, U slot, U c, I, I m) const {
    using esvo::layout::ChildPointer, esvo::layout::FarBit, esvo::layout::ValidMask,
        esvo::layout::LeafMask;
    U rel = (d.w0 >> ChildPointer::lo) & ChildPointer::max;
    const I far = m & (I)((d.w0 & FarBit::mask) != 0u);
    if (L::bits(far) != 0) rel = L::gather(words, (I)((slot + rel) * 2u), far, rel);
    const U non_leaf = ((d.w0 >> ValidMask::lo) & ~(d.w0 >> LeafMask::lo)) & 0xFFu;
    return slot + rel + L::popcount8(non_leaf & (((U{} + 1u) << c) - 1u));
  }

  const EsvoNodes& nodes;
  const uint32_t* words;
};

}  // namespace
}  // namespace voxcast::detail
