// Beam optimization (esvo §6.2) for the sparse voxel DAG: the coarse pass.
// The cube test and the start region are the ESVO's (core/beam_frustum.hpp);
// only the walk differs, over the DAG's node kinds (dag.hpp): interior nodes
// (header + one pointer per child), 64-bit 4^3 leaf masks whose byte c is the
// 2^3 sub-block in slot c, and inside a sub-block the leaf voxels. The fine
// rays then start at the region (DagStructure::trace_hinted, whose clipping
// is the ESVO caster's, so hits stay bit-identical).
//
// A DAG node is shared by many positions, but the pass walks the tree
// (positions), not the DAG: whether a cube lies in the beam depends on where
// it is, so visiting a shared node once per occurrence is inherent.
#include <bit>
#include <cstdint>

#include "core/beam_frustum.hpp"
#include "voxcast/dag.hpp"

namespace voxcast::dag {

void DagStructure::beam_start(const BeamFrustum& beam, BeamStart* start,
                              RayCounters* counters) const {
  *start = BeamStart{};
  const SparseVoxelDag& g = *dag_;
  ::voxcast::detail::BeamClassifier beam_cls(beam, g.grid);
  if (!beam_cls.valid()) return;  // no information
  using Cls = ::voxcast::detail::BeamClassifier;
  RayCounters& cnt = beam_cls.counters;
  const uint32_t* const words = g.words.data();
  const int L = g.levels();  // node levels 0..L-2, sub-blocks L-1, voxels L

  struct Node {
    uint32_t ref;  // word index; the sub-block's byte at level L-1
    int level;
    float lo[3];
    float s;  // cube side, octree units (2^-level)
  };
  Node stack[8 * (esvo::kMaxScale + 1)];  // depth-first: <= 7 pending siblings per level
  int top = 0;
  const float root_lo[3] = {1.f, 1.f, 1.f};
  switch (beam_cls.classify(root_lo, 1.f, false)) {
    case Cls::kKeep:
      beam_cls.keep(root_lo, 1.f);
      break;
    case Cls::kDescend:
      stack[top++] = {0, 0, {1.f, 1.f, 1.f}, 1.f};
      break;
    default:
      break;
  }
  while (top > 0) {
    const Node node = stack[--top];
    ++cnt.iterations;
    uint32_t child_mask;
    uint64_t leaf64 = 0;
    if (node.level < L - 2) {  // interior: header
      child_mask = words[node.ref] & 0xFFu;
      ++cnt.descriptor_fetches;
    } else if (node.level == L - 2) {  // 4^3 leaf mask: one child per non-zero byte
      leaf64 = uint64_t(words[node.ref]) | uint64_t(words[node.ref + 1]) << 32;
      ++cnt.descriptor_fetches;
      child_mask = 0;
      for (int c = 0; c < 8; ++c) child_mask |= uint32_t((leaf64 >> (8 * c)) & 0xFFu ? 1 : 0) << c;
    } else {  // 2^3 sub-block: the byte is the mask of its leaf voxels
      child_mask = node.ref;
    }
    const bool leaves = node.level == L - 1;
    const float hs = node.s * 0.5f;
    for (uint32_t m = child_mask; m != 0; m &= m - 1) {
      const int i = std::countr_zero(m);
      const float lo[3] = {node.lo[0] + ((i & 1) ? hs : 0.f), node.lo[1] + ((i & 2) ? hs : 0.f),
                           node.lo[2] + ((i & 4) ? hs : 0.f)};
      const int what = beam_cls.classify(lo, hs, leaves);
      if (what == Cls::kKeep) {
        beam_cls.keep(lo, hs);
      } else if (what == Cls::kDescend) {
        ++cnt.pushes;
        uint32_t ref;
        if (node.level < L - 2) {
          ref = words[node.ref + 1 + uint32_t(std::popcount(child_mask & ((1u << i) - 1)))];
          ++cnt.far_reads;
        } else {
          ref = uint32_t(leaf64 >> (8 * i)) & 0xFFu;
        }
        stack[top++] = {ref, node.level + 1, {lo[0], lo[1], lo[2]}, hs};
      }
    }
  }
  beam_cls.finish(start, counters);
}

void DagStructure::attributes_counted(const SurfaceHit& hit, Color* color, Vec3* normal,
                                      RayCounters* counters) const {
  attributes(hit, color, normal);
  // Raw: one 32-bit color and one 32-bit normal per voxel (dag.hpp);
  // compressed: the voxel's 24-byte esvo §5.5 block (as the ESVO counts it).
  // The index itself came with the traversal (prefix sums next to the pointers).
  if (counters != nullptr && dag_->has_attributes())
    counters->attribute_bytes += dag_->compressed_attributes() ? 24 : 8;
}

}  // namespace voxcast::dag
