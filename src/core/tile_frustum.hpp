#pragma once
// The tile frustum pass of the octree family (issue 10 item 4, "start deep,
// cull whole tiles"): for the pyramid (or prism) of a tile's or a pixel
// block's rays, the ordered list of the cubes those rays can touch, cut where
// a cube is about as wide as the beam at its distance, is a leaf, or could be
// a LOD stop. The packet caster then starts each ray at the first listed cube
// its ray enters instead of the root (core/frustum_packets.hpp), and a beam
// whose list is empty costs its rays nothing.
//
// The walk is the beam pass's (esvo §6.2, detail::beam_walk in
// core/octree_caster.hpp) with two differences:
//  * the eight children of a node are tested against the beam's four planes
//    at once, in the lanes of one vector register per quantity
//    (BeamClassifier::classify_children);
//  * it keeps the cubes themselves, in front-to-back order for one mirroring
//    octant (§6.1 "Alternate coordinate system"): the depth-first walk visits
//    the children of a node by decreasing mirrored slot index 7..0. Inside a
//    node the loop of cast_octree only ever ADVANCEs from a child to one whose
//    mirrored index has a subset of its bits (the step clears bits; a set bit
//    is a POP), so for every ray of that octant the loop meets disjoint cubes
//    in an order that agrees with the list's.
// The cut is conservative in the beam pass's sense (every voxel a ray of the
// beam can hit lies in a kept cube); a cube that could be a LOD stop for one
// of the rays is kept, never descended, so no ray can stop at an ancestor of
// a listed cube. A list for a pixel block can start from its tile's list
// (`within`): the tile's cubes are classified against the block's beam and
// descended further, in the same order.
#include <cstdint>

#include "core/beam_frustum.hpp"
#include "core/octree_caster.hpp"
#include "voxcast/octree_structure.hpp"
#include "voxcast/structure.hpp"

namespace voxcast::detail {

/// The frustum pass keeps cubes no wider than this times the beam's width at
/// their nearest point (BeamClassifier's stop fraction; the beam pass uses 2).
inline constexpr double kFrustumStopFraction = 2.0;

/// Fills *start with the list of `beam` for rays of mirroring octant `octant`
/// (BeamStart::nodes, region = their bounding box; empty = no ray of the beam
/// hits anything), starting from `within`'s list when it is one for the same
/// octant. A degenerate beam, or one so wide that the root is kept whole,
/// gives no information (valid = false). Counters (may be null): iterations =
/// nodes expanded, intersects = cubes classified; the policy counts fetches.
template <class P>
void frustum_walk(const OctreeWorld<P>& world, const BeamFrustum& beam, int octant,
                  const BeamStart* within, BeamStart* start, RayCounters* counters) {
  // Reset without giving up the list's storage (per-thread starts are reused).
  start->valid = false, start->empty = false, start->region = Aabb{}, start->octant = -1;
  start->nodes.clear();
  if (octant < 0 || octant > 7) return;
  BeamClassifier cls(beam, world.source.grid, kFrustumStopFraction);
  if (!cls.valid()) return;
  RayCounters& cnt = cls.counters;
  const P nodes(world.source);
  const uint32_t flip = uint32_t(octant ^ 7);  // mirrored index -> slot

  // A pending cube: kept (emitted when popped) or to be expanded.
  struct Item {
    FrustumNode cube;
    bool expand;
  };
  Item stack[8 * (kOctreeMaxScale + 2)];
  int top = 0;
  auto emit = [&](const FrustumNode& f) {
    start->nodes.push_back(f);
    start->region.extend({f.lo[0], f.lo[1], f.lo[2]});
    start->region.extend({f.lo[0] + f.side, f.lo[1] + f.side, f.lo[2] + f.side});  // exact
  };
  // Depth-first from `root`, children front to back (see the file comment).
  auto walk = [&](const Item& root) {
    stack[top++] = root;
    while (top > 0) {
      const Item it = stack[--top];
      if (!it.expand) {
        emit(it.cube);
        continue;
      }
      ++cnt.iterations;
      const FrustumNode& f = it.cube;
      const int child_scale = f.scale - 1;
      const auto desc = nodes.fetch(f.node, child_scale, cnt);
      const uint32_t first = nodes.children(desc, f.node, child_scale, cnt);
      const uint32_t present = nodes.mask(desc);
      uint32_t leaves = 0;
      for (uint32_t m = present; m != 0; m &= m - 1)
        if (nodes.leaf(desc, std::countr_zero(m), child_scale)) leaves |= 1u << std::countr_zero(m);
      const float hs = f.side * 0.5f;
      uint32_t keep, descend;
      cls.classify_children(f.lo, hs, present, leaves, &keep, &descend);
      // Pushed back to front, so that the front-most child is popped first.
      for (uint32_t mirrored = 0; mirrored < 8; ++mirrored) {
        const int c = int(mirrored ^ flip);
        if (((keep | descend) >> c & 1u) == 0) continue;
        Item child;
        child.expand = (descend >> c & 1u) != 0;
        FrustumNode& g = child.cube;
        g.lo[0] = f.lo[0] + ((c & 1) ? hs : 0.f);
        g.lo[1] = f.lo[1] + ((c & 2) ? hs : 0.f);
        g.lo[2] = f.lo[2] + ((c & 4) ? hs : 0.f);
        g.side = hs;
        g.parent = f.node;
        g.leaf = (leaves >> c & 1u) != 0;
        g.node = g.leaf ? 0u : nodes.child(desc, first, c, child_scale, cnt);
        g.scale = int8_t(child_scale);
        g.slot = uint8_t(c);
        if (child.expand) ++cnt.pushes;
        stack[top++] = child;
      }
    }
  };

  if (within != nullptr && within->valid && within->octant == octant) {
    if (!within->empty) {
      // The enclosing beam's cubes, in its order, against this beam.
      for (const FrustumNode& f : within->nodes) {
        const int what = cls.classify(f.lo, f.side, f.leaf);
        if (what == BeamClassifier::kKeep)
          emit(f);
        else if (what == BeamClassifier::kDescend)
          walk({f, true});
      }
    }
  } else {
    const float root_lo[3] = {1.f, 1.f, 1.f};
    const int what = cls.classify(root_lo, 1.f, false);
    if (what == BeamClassifier::kKeep) return;  // the whole octree: no information
    if (what == BeamClassifier::kDescend) {
      FrustumNode root{{1.f, 1.f, 1.f}, 1.f, 0u, nodes.root(), int8_t(kOctreeMaxScale), 0, false};
      walk({root, true});
    }
  }
  start->valid = true;
  start->octant = octant;
  start->empty = start->nodes.empty();
  if (counters != nullptr) *counters += cnt;
}

}  // namespace voxcast::detail

namespace voxcast {

template <class Self>
void OctreeStructure<Self>::frustum_start(const BeamFrustum& beam, int octant, TraceContext& ctx,
                                          BeamStart* start, const BeamStart* within) const {
  detail::frustum_walk(static_cast<const Self&>(*this).world(), beam, octant, within, start,
                       ctx.counting ? &ctx.counters : nullptr);
}

}  // namespace voxcast
