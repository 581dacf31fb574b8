#pragma once
// Packets that start from a frustum pass's cube list (issue 10 item 4;
// core/tile_frustum.hpp makes the lists, core/octree_packet_caster.hpp is
// the packet driver this one extends). Each ray whose beam carries a list for
// its mirroring octant is traced in rounds: in a round it starts at the next
// listed cube its span enters (enter_root clipped to the cube; cubes it does
// not enter cost one box test and nothing else), and a lane that finds no
// hit inside that cube goes on to the next cube in the following round. Rays
// of an empty list are misses with no work at all.
//
// Where a lane starts. Without contours (the DAG; an ESVO without a contour
// attachment) at the listed cube C itself: the loop's state "current cube C
// in its parent P" (parent = P's node, scale = C's, position = C's mirrored
// corner, idx = C's slot), the span clipped to C, and a POP out of P ends the
// lane. That is the packet queue's one deep start (PacketQueue::deep: a start
// node, its scale and the stack rows above it, as the occlusion rays' deep
// start fills them): here the rows above P hold a t_max of -infinity, so that
// a POP out of P leaves the lane with an empty span, which the loop's early
// miss exit (taken without contours) ends at its next ADVANCE, before any
// PUSH or hit. With contours at the root, the span clipped to C
// (the beam pass's start region, one cube at a time): the slabs of C's
// ancestors narrow the span on the way down, which a deep start would skip.
//
// Why the hits are the scalar caster's, bit for bit. (0) Where planes tie,
// the loop's ray at parameter t is in the one cell whose crossed planes are
// exactly those with t(plane) <= t (cast_octree's tie rule), so it passes
// through a cube C for the t in [max(start, entry planes of C), min exit
// plane of C), half open; a cube only touched at an edge or a corner (the
// interval empty) is never on its path, and the driver skips such cubes
// (started there, a lane would not be in the loop's state). Let V be the first
// voxel the scalar loop hits (cast_octree's "Why a start region gives
// bit-identical hits": the first hit-able voxel in the loop's visiting
// order) and C_j the listed cube that contains it (the list is
// conservative: every voxel a ray of the beam can hit lies in a listed
// cube); the ray is in V on a non-empty interval, so in C_j too. (1) Started
// at C_j, the lane reaches C_j in exactly the scalar loop's state there: its
// t_max is min(E, exit of C_j) instead of min(E, exit of P), which decides
// nothing inside C_j (every span there is cut to C_j's exit anyway), and its
// t_min, the largest of C_j's entry-plane t values and the root's entry t, is
// the t at which the scalar loop enters C_j (it enters through the last of
// those planes it crosses); no ancestor of C_j is a possible LOD stop (the
// pass keeps those whole) and without contours no ancestor narrows the span.
// So the lane returns V with the same t, position and payload. From the root
// clipped to C_j the same follows from the start-region argument itself.
// (2) For a listed cube C_i before C_j that the ray passes through, the
// loop passes through C_i too, before V (the list's order is the loop's,
// tile_frustum.hpp), entering it in the lane's state (as in (1)), and finds
// nothing inside it (that would be its hit, not V): so neither does the
// lane, which misses in C_i or stops at a cube outside C_i (a
// one-point span at C_i's exit plane), which the driver rejects. (3) A ray
// that hits nothing misses in every cube. Rays of another octant than the
// list's start at the root within the list's bounding box (the beam pass).
#include <cstddef>
#include <cstdint>
#include <limits>
#include <optional>

#include "core/octree_caster.hpp"
#include "core/octree_packet_caster.hpp"
#include "voxcast/structure.hpp"

namespace voxcast::detail {

/// Whether any ray's beam carries a frustum list (BeamStart::octant >= 0).
inline bool has_frustum_lists(const BeamStart* const* beams, size_t n) {
  if (beams == nullptr) return false;
  for (size_t i = 0; i < n; ++i)
    if (beams[i] != nullptr && beams[i]->valid && beams[i]->octant >= 0) return true;
  return false;
}

/// The mirrored min corner of listed cube f for rays of mirroring octant
/// `octant` (exact: [x, x + s] mirrored is [3 - s - x, 3 - x]).
inline Vec3 mirror_corner(int octant, const FrustumNode& f) {
  return unmirror(octant, {f.lo[0], f.lo[1], f.lo[2]}, f.scale);
}

/// cast_packets (first hits) for rays whose beams may carry frustum lists
/// (see the file comment); hits bit-identical to OctreeWorld::trace.
template <class P>
void cast_frustum_packets(const OctreeWorld<P>& world, PacketKernel<P> kernel, const Ray* rays,
                          size_t n, const LodFootprint& lod, const BeamStart* const* beams,
                          SurfaceHit* hits, uint8_t* found) {
  const P nodes(world.source);
  const OctreeFrame& frame = world.frame;
  const float size_coef = frame.length(lod.size_per_t),
              size_bias = frame.length(lod.size_at_origin);
  const bool deep = !may_narrow_spans(nodes);
  thread_local PacketQueue q;
  thread_local PacketOut out;
  // Per ray of the chunk: the next list entry to try, and the entry of the
  // round in flight (-1: not a list ray); kDone once answered.
  constexpr int kDone = -2;
  int next[kPacketQueue], current[kPacketQueue];
  struct RaySetup {
    MirroredRay ray;
    Vec3 d;          // octree-space direction after avoid_tiny_components
    CastEntry root;  // the span in the root cube
    bool entered;    // the span is not empty
  };
  thread_local std::optional<RaySetup> setup[kPacketQueue];
  for (size_t base = 0; base < n; base += kPacketQueue) {
    const int m = int(n - base < size_t(kPacketQueue) ? n - base : size_t(kPacketQueue));
    for (int i = 0; i < m; ++i) found[base + size_t(i)] = 0, next[i] = 0, current[i] = -1;
    for (bool first_round = true;; first_round = false) {
      q.count = 0;
      q.deep = false;
      q.refill_lanes = 0, q.path_width = 0;  // whole packets, no packet paths
      for (int i = 0; i < m; ++i) {
        if (next[i] == kDone) continue;
        const Ray& r = rays[base + size_t(i)];
        const BeamStart* b = beams != nullptr ? beams[base + size_t(i)] : nullptr;
        if (first_round) {
          // The ray's set-up once per chunk (later rounds reuse it).
          const Vec3 p = frame.point(r.origin), d0 = frame.direction(r.dir);
          if ((b != nullptr && b->valid && b->empty) || !(is_finite(p) && is_finite(d0))) {
            next[i] = kDone;  // §6.2: nothing in the beam; cast_octree: a miss
            continue;
          }
          const Vec3 d = avoid_tiny_components(d0);
          setup[i].emplace(RaySetup{MirroredRay(p, d), d, {}, false});
          setup[i]->entered = enter_root(setup[i]->ray, r.tmax, nullptr, &setup[i]->root);
        }
        const MirroredRay& ray = setup[i]->ray;
        const Vec3 d = setup[i]->d;
        CastEntry e{};
        if (b == nullptr || !b->valid || b->octant != ray.octant_mask) {
          // No list for this ray: one root start, within the region if any.
          const Aabb* region = b != nullptr && b->valid ? &b->region : nullptr;
          if (!first_round || !enter_root(ray, r.tmax, region, &e)) {
            next[i] = kDone;
            continue;
          }
          queue_entry(&q, i, ray, d, e, nodes.root());
          out.stop[i] = 0;
          continue;
        }
        // The next listed cube the ray passes through (see (0) above): its
        // span [max(root span start, entry planes), min(exit planes)) clipped
        // to the root span's end, the same floats enter_root computes.
        if (!setup[i]->entered) {
          next[i] = kDone;  // misses the root cube
          continue;
        }
        const CastEntry& root = setup[i]->root;
        const int count = int(b->nodes.size());
        int k = next[i];
        for (; k < count; ++k) {
          const FrustumNode& f = b->nodes[size_t(k)];
          const Vec3 mc = mirror_corner(ray.octant_mask, f);
          const float t_in =
              vmax(vmax(ray.tx(mc.x + f.side), ray.ty(mc.y + f.side)), ray.tz(mc.z + f.side));
          const float t_out = vmin(vmin(ray.tx(mc.x), ray.ty(mc.y)), ray.tz(mc.z));
          const float t_min = vmax(root.t_min, t_in);
          if (t_min < t_out && t_min <= root.t_max) break;
        }
        if (k == count) {
          next[i] = kDone;  // no listed cube left on its way: a miss
          continue;
        }
        next[i] = k + 1, current[i] = k;
        {
          const FrustumNode& f = b->nodes[size_t(k)];
          const Aabb box{{f.lo[0], f.lo[1], f.lo[2]},
                         {f.lo[0] + f.side, f.lo[1] + f.side, f.lo[2] + f.side}};
          enter_root(ray, r.tmax, &box, &e);  // non-empty: checked above
        }
        const int slot = queue_entry(&q, i, ray, d, e, nodes.root());
        out.stop[i] = 0;
        if (deep) {
          const FrustumNode& f = b->nodes[size_t(k)];
          const Vec3 mc = mirror_corner(ray.octant_mask, f);
          q.px[slot] = mc.x, q.py[slot] = mc.y, q.pz[slot] = mc.z;
          q.idx[slot] = (float_bits(mc.x) >> f.scale & 1u) |
                        (float_bits(mc.y) >> f.scale & 1u) << 1 |
                        (float_bits(mc.z) >> f.scale & 1u) << 2;
          q.parent[slot] = f.parent;
          q.scale[slot] = f.scale;
          // Rows above the start: a POP out of P ends the lane (file comment).
          for (int s = f.scale + 1; s < kOctreeMaxScale; ++s) {
            q.stack_node[s][slot] = nodes.root();
            q.stack_tmax[s][slot] = -std::numeric_limits<float>::infinity();
          }
          q.deep = true;
        }
      }
      if (q.count == 0) break;
      kernel(nodes, q, size_coef, size_bias, &out);
      for (int k = 0; k < q.count; ++k) {
        const int i = q.id[k];
        const bool listed = current[i] >= 0;
        if (out.stop[i] == 0) {
          if (!listed) next[i] = kDone;  // list rays go on to their next cube
          continue;
        }
        if (listed) {
          // Only a hit inside the cube counts (see (2) in the file comment).
          const FrustumNode& f = beams[base + size_t(i)]->nodes[size_t(current[i])];
          const int octant = int(q.flip[k] ^ 7u);
          const Vec3 c = mirror_corner(octant, f);
          const bool inside = out.scale[i] <= f.scale && out.px[i] >= c.x &&
                              out.px[i] < c.x + f.side && out.py[i] >= c.y &&
                              out.py[i] < c.y + f.side && out.pz[i] >= c.z &&
                              out.pz[i] < c.z + f.side;
          if (!inside) continue;
        }
        next[i] = kDone;
        found[base + size_t(i)] = 1;
        packet_hit(world, nodes, q, k, out, rays[base + size_t(i)], &hits[base + size_t(i)]);
      }
    }
  }
}

/// A structure's trace_packets (`kernels`: its policy's kernels): the
/// frustum-list driver when some ray's beam carries a list, cast_packets
/// otherwise; the scalar caster for sources beyond the gathers' 32-bit
/// indices.
template <class P, class S>
void structure_trace_packets(const S& s, const typename P::Source& source, Isa isa,
                             const PacketKernels<P>& kernels, const Ray* rays, size_t n,
                             const LodFootprint& lod, const BeamStart* const* beams,
                             SurfaceHit* hits, uint8_t* found) {
  require_isa(isa, "packet caster");
  if (beyond_gathers(source)) {
    TraceContext ctx;
    for (size_t i = 0; i < n; ++i)
      found[i] = s.trace(rays[i], lod, ctx, &hits[i], beams != nullptr ? beams[i] : nullptr);
    return;
  }
  const PacketKernel<P> kernel = isa == Isa::Avx512 ? kernels.trace_avx512 : kernels.trace_avx2;
  if (has_frustum_lists(beams, n))
    cast_frustum_packets(OctreeWorld<P>(source), kernel, rays, n, lod, beams, hits, found);
  else
    cast_packets(OctreeWorld<P>(source), kernel, rays, n, lod, beams, hits, found);
}

}  // namespace voxcast::detail
