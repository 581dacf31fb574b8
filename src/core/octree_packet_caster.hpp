#pragma once
// The packet caster of the octree family (issue 10 item 3): the Appendix A
// loop of core/octree_caster.hpp run on 16 rays at once (AVX-512; 8 with
// AVX2), one ray per vector lane, over the same node-access policy.
//
// Split in two so that the vector code never shares a function with the
// baseline build (an inline function emitted by an AVX-512 translation unit
// could be the copy the linker keeps for everyone):
//  * this header, compiled with the library's baseline flags: the ray set-up
//    (cast_octree's own enter_root on each ray, packed into a queue of lane
//    states), the call of the kernel of the active ISA, and the hit epilogue
//    (cast_octree's unmirroring, entered face, and the policy's payload found
//    by walking down to the hit cube);
//  * core/octree_packet_kernel.hpp, included only by the per-ISA kernel
//    translation units (src/esvo/packet_kernel_*.cpp, src/dag/...): the
//    lane-parallel loop.
// Why the hits are bit-identical to cast_octree's: every lane runs exactly
// the scalar loop's float operations (the same fma per plane, the same
// compares and tie rules, the same float-bit POP); PUSH/ADVANCE/POP are
// selected per lane by masks instead of branches, which changes no value.
// The loop carries no payload (the DAG's voxel rank): a cube's path from the
// root is fixed by its position, so the epilogue finds the payload by
// descending to the hit cube with the policy's own descend() and hit_index(),
// which add the same integers the loop would have added.
#include <bit>
#include <cstddef>
#include <cstdint>
#include <string>
#include <type_traits>

#include "core/octree_caster.hpp"
#include "core/octree_ray.hpp"
#include "voxcast/error.hpp"
#include "voxcast/isa.hpp"
#include "voxcast/math.hpp"
#include "voxcast/structure.hpp"

namespace voxcast::detail {

/// Rays per kernel call: a queue the lanes refill from, in the caller's
/// order (4x4 pixel blocks for camera rays, so a packet starts coherent).
inline constexpr int kPacketQueue = 256;

/// The kernel's input: lane start states (cast_octree after enter_root), in
/// structure-of-arrays form so that refilled lanes are expand-loaded.
struct alignas(64) PacketQueue {
  float cx[kPacketQueue], cy[kPacketQueue], cz[kPacketQueue];  // MirroredRay t coefficients
  float bx[kPacketQueue], by[kPacketQueue], bz[kPacketQueue];  // and biases
  float t_min[kPacketQueue], t_max[kPacketQueue], h[kPacketQueue];
  float px[kPacketQueue], py[kPacketQueue], pz[kPacketQueue];
  uint32_t flip[kPacketQueue];  // octant_mask ^ 7
  uint32_t idx[kPacketQueue];
  int32_t id[kPacketQueue];  // the ray's index in PacketOut
  // Unmirrored directions (after avoid_tiny_components): the contour slab.
  float dx[kPacketQueue], dy[kPacketQueue], dz[kPacketQueue];
  // Where the lane starts (read only when `deep`): the loop's parent node,
  // the scale of its current cube (the root's children: kOctreeMaxScale - 1)
  // and the scale a POP to which ends the lane as a miss (kOctreeMaxScale:
  // left the root). Set by the tile frustum pass (core/tile_frustum.hpp).
  uint32_t parent[kPacketQueue];
  int32_t scale[kPacketQueue], stop[kPacketQueue];
  int count = 0;
  bool deep = false;  // some lane starts below the root
};

/// Appends ray `id` (mirrored `ray`, direction `d` after avoid_tiny_components)
/// with the loop state `e` at the root, to q; returns its queue slot.
inline int queue_ray(PacketQueue* q, int id, const MirroredRay& ray, Vec3 d, const CastEntry& e,
                     uint32_t root) {
  const int k = q->count++;
  q->cx[k] = ray.tx_coef, q->cy[k] = ray.ty_coef, q->cz[k] = ray.tz_coef;
  q->bx[k] = ray.tx_bias, q->by[k] = ray.ty_bias, q->bz[k] = ray.tz_bias;
  q->t_min[k] = e.t_min, q->t_max[k] = e.t_max, q->h[k] = e.h;
  q->px[k] = e.pos_x, q->py[k] = e.pos_y, q->pz[k] = e.pos_z;
  q->flip[k] = uint32_t(ray.octant_mask ^ 7);
  q->idx[k] = uint32_t(e.idx);
  q->id[k] = id;
  q->dx[k] = d.x, q->dy[k] = d.y, q->dz[k] = d.z;
  q->parent[k] = root, q->scale[k] = kOctreeMaxScale - 1, q->stop[k] = kOctreeMaxScale;
  return k;
}

/// The kernel's output per ray: stop = 0 (CastStop::kMiss) unless the loop
/// stopped at a cube; then the loop state there (mirrored frame).
struct alignas(64) PacketOut {
  float t[kPacketQueue], px[kPacketQueue], py[kPacketQueue], pz[kPacketQueue];
  uint32_t parent[kPacketQueue], idx[kPacketQueue];
  int32_t scale[kPacketQueue], stop[kPacketQueue];
};

/// A kernel: casts q's rays through `nodes` (the scalar policy, whose fields
/// the kernel's vector policy reads), LOD terms as in cast_octree.
template <class P>
using PacketKernel = void (*)(const P& nodes, const PacketQueue& q, float size_coef,
                              float size_bias, PacketOut* out);

/// The kernel of `isa`; throws voxcast::Error if the CPU cannot run it.
template <class P>
PacketKernel<P> packet_kernel_for(Isa isa, PacketKernel<P> avx2, PacketKernel<P> avx512) {
  if (!cpu_supports(isa))
    throw Error(std::string("packet caster: this CPU does not support ") + isa_name(isa));
  return isa == Isa::Avx512 ? avx512 : avx2;
}

/// The policy's payload of the cube at unmirrored min corner `pos`, `scale`:
/// the descent from the root through the cubes containing it (the loop's own
/// path, fixed by the position), with the policy's descend() and hit_index().
template <class P>
typename P::Index payload_at(const P& nodes, Vec3 pos, int scale) {
  typename P::Index index{};
  NoCounters cnt;
  uint32_t node = nodes.root();
  for (int s = kOctreeMaxScale - 1;; --s) {
    const auto desc = nodes.fetch(node, s, cnt);
    // Mantissa bit s of a coordinate in [1, 2) is its half at scale s.
    const int c = int((float_bits(pos.x) >> s & 1u) | (float_bits(pos.y) >> s & 1u) << 1 |
                      (float_bits(pos.z) >> s & 1u) << 2);
    if (s == scale) return nodes.hit_index(index, desc, node, c, s);
    node = nodes.descend(desc, node, c, s, index, cnt);
  }
}

/// cast_octree's epilogue on the final state of q's ray k (ray r, out's entry
/// q.id[k]): *hit as OctreeWorld::trace fills it.
template <class P>
void packet_hit(const OctreeWorld<P>& world, const P& nodes, const PacketQueue& q, int k,
                const PacketOut& out, const Ray& r, SurfaceHit* hit) {
  const OctreeFrame& frame = world.frame;
  const int i = q.id[k];
  const Vec3 p = frame.point(r.origin), d0 = frame.direction(r.dir);
  OctreeCast<typename P::Index> c;
  c.hit = true;
  c.stop = CastStop(out.stop[i]);
  c.t = out.t[i];
  c.scale = out.scale[i];
  c.node = out.parent[i];
  c.child = int(out.idx[i] ^ q.flip[k]);
  const Vec3 mpos{out.px[i], out.py[i], out.pz[i]};
  const int octant_mask = int(q.flip[k] ^ 7u);
  if constexpr (P::kEnteredFace) {
    const Vec3 d{q.dx[k], q.dy[k], q.dz[k]};
    c.face = entered_face(MirroredRay(p, d), d, mpos, c.scale);
  }
  c.pos = unmirror(octant_mask, mpos, c.scale);
  if constexpr (!std::is_same_v<typename P::Index, NoIndex>)
    c.index = payload_at(nodes, c.pos, c.scale);
  frame.hit_to_world(p, d0, c.t, c.pos, c.scale, hit);
  P::name_hit(c, hit);
}

/// The OctreeWorld::trace / occluded answers for rays[0, n) (world space),
/// bit-identical, via `kernel`. any_hit: only found[i] (occluded), hits unused.
/// beams (may be null): per ray, the coarse-pass result of its block (or
/// null), as the beam argument of OctreeWorld::trace: an empty beam is a miss,
/// a region is where the ray starts and ends (bit-identical hits).
template <class P>
void cast_packets(const OctreeWorld<P>& world, PacketKernel<P> kernel, const Ray* rays, size_t n,
                  const LodFootprint& lod, const BeamStart* const* beams, bool any_hit,
                  SurfaceHit* hits, uint8_t* found) {
  const P nodes(world.source);
  const OctreeFrame& frame = world.frame;
  const float size_coef = frame.length(lod.size_per_t),
              size_bias = frame.length(lod.size_at_origin);
  // OctreeWorld::occluded uses the closest-hit loop where any-hit skips
  // nothing; either way the loop is the same and only `hit` is read.
  thread_local PacketQueue q;
  thread_local PacketOut out;
  for (size_t base = 0; base < n; base += kPacketQueue) {
    const int m = int(n - base < size_t(kPacketQueue) ? n - base : size_t(kPacketQueue));
    q.count = 0;
    q.deep = false;
    for (int i = 0; i < m; ++i) {
      const Ray& r = rays[base + size_t(i)];
      found[base + size_t(i)] = 0;
      out.stop[i] = 0;
      const Aabb* region = nullptr;
      if (beams != nullptr && beams[base + size_t(i)] != nullptr) {
        const BeamStart& b = *beams[base + size_t(i)];
        if (b.valid && b.empty) continue;  // §6.2: no ray of the beam hits anything
        if (b.valid) region = &b.region;
      }
      const Vec3 p = frame.point(r.origin), d0 = frame.direction(r.dir);
      if (!(is_finite(p) && is_finite(d0))) continue;  // cast_octree: a miss
      const Vec3 d = avoid_tiny_components(d0);
      const MirroredRay ray(p, d);
      CastEntry e;
      if (!enter_root(ray, r.tmax, region, &e)) continue;
      queue_ray(&q, i, ray, d, e, nodes.root());
    }
    if (q.count > 0) kernel(nodes, q, size_coef, size_bias, &out);
    for (int k = 0; k < q.count; ++k) {
      const int i = q.id[k];
      if (out.stop[i] == 0) continue;
      found[base + size_t(i)] = 1;
      if (!any_hit)
        packet_hit(world, nodes, q, k, out, rays[base + size_t(i)], &hits[base + size_t(i)]);
    }
  }
}

/// A structure's trace_packets (any_hit false) or occluded_packets (true):
/// `kernels` = the AVX2 and the AVX-512 kernel of its policy. Sources of
/// 2^31 words or more (beyond the gathers' signed 32-bit indices) take the
/// scalar caster.
template <class P, class S>
void structure_packets(const S& s, const typename P::Source& source, Isa isa, PacketKernel<P> avx2,
                       PacketKernel<P> avx512, const Ray* rays, size_t n, const LodFootprint& lod,
                       const BeamStart* const* beams, bool any_hit, SurfaceHit* hits,
                       uint8_t* found) {
  const PacketKernel<P> kernel = packet_kernel_for<P>(isa, avx2, avx512);
  if (source.words.size() >= (size_t(1) << 31)) {
    TraceContext ctx;
    for (size_t i = 0; i < n; ++i) {
      const BeamStart* beam = beams != nullptr ? beams[i] : nullptr;
      found[i] =
          any_hit ? s.occluded(rays[i], lod, ctx) : s.trace(rays[i], lod, ctx, &hits[i], beam);
    }
    return;
  }
  cast_packets(OctreeWorld<P>(source), kernel, rays, n, lod, beams, any_hit, hits, found);
}

}  // namespace voxcast::detail
