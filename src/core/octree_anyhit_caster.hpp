#pragma once
// Any-hit packets of the octree family (issue 10 item 5): occlusion rays
// (shadow, AO) through the one caster's Appendix A loop on 16 AVX-512 lanes
// (8 with AVX2), each lane ending at its first occupied cube, optionally
// started deep (start_packets, core/octree_packet_caster.hpp: each ray at the deepest
// cube around its origin that the loop reaches by PUSHes alone, replaying
// the loop's own PUSHes down to it and filling its stack above the start on
// the way, so that rays leaving the start cube go on exactly as from the
// root), and, for rays
// that share an origin (the AO rays of one shading point), an optional cull
// of the point's ball, hemisphere and box.
//
// Split like the first-hit packet caster (core/octree_packet_caster.hpp):
// this header is compiled with the baseline flags (lane set-up, deep start,
// cull, the call of the active ISA's kernel); the kernel is the first-hit
// kernel's lane loop (core/octree_packet_kernel.hpp, anyhit_kernel),
// included only by the per-ISA kernel translation units.
//
// Why the cull gives the scalar caster's answer. Let N be a cube that
// contains every point p + t d, t in [0, tmax], of a group's rays with a
// margin (kDeepMargin) far above the rounding of the loop's t values. A
// ray's loop only reaches cubes its segment touches (within rounding, far
// below the margin), so if no present cube of N's subtree touches the
// region that holds every segment (their box, the ball of radius max tmax
// around the common origin and, given a normal n with dot(d, n) >= 0 for
// every ray, the half-space above the origin), every ray of the group
// misses; so does every ray whose segment lies in an empty child of a cube
// on the way down to N (it steps through it and out past tmax).
#include <bit>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string>

#include "core/octree_caster.hpp"
#include "core/octree_packet_caster.hpp"
#include "core/octree_ray.hpp"
#include "voxcast/error.hpp"
#include "voxcast/isa.hpp"
#include "voxcast/math.hpp"
#include "voxcast/occlusion_packets.hpp"
#include "voxcast/structure.hpp"

namespace voxcast::detail {

/// Margin of the cull, octree units (root side 1): far
/// above the rounding of any t compare in [1,2]^3 (~2^-22 in the same units,
/// core/octree_ray.hpp) and below a voxel of a 16K^3 grid (2^-14).
inline constexpr float kDeepMargin = 0x1p-17f;

/// Most nodes the cull may fetch per ray group (its stack is sized for it).
inline constexpr int kMaxCullBudget = 64;

/// The region every segment of a group lies in (octree space, with margins).
struct SegmentRegion {
  Vec3 lo, hi;        // box of the segments
  Vec3 center;        // the common origin
  float radius;       // max t * |d|
  bool half = false;  // the half-space dot(x - center, normal) >= -margin holds too
  Vec3 normal;
  /// A cube [c, c + s]^3 may touch the region.
  bool touches(Vec3 c, float s) const {
    const float m = kDeepMargin;
    float d2 = 0.f, top = -INFINITY;
    for (int a = 0; a < 3; ++a) {
      if (c[a] > hi[a] + m || c[a] + s < lo[a] - m) return false;
      const float q = vmax(c[a], vmin(center[a], c[a] + s)) - center[a];
      d2 += q * q;
    }
    if (d2 > (radius + m) * (radius + m)) return false;
    if (!half) return true;
    for (int k = 0; k < 8; ++k) {
      const Vec3 v{c.x + ((k & 1) ? s : 0.f), c.y + ((k & 2) ? s : 0.f), c.z + ((k & 4) ? s : 0.f)};
      top = vmax(top, dot(v - center, normal));
    }
    return top >= -m;
  }
};

/// The cull of a group's rays (see the file comment): true if no ray whose
/// segment lies in region `r` can hit anything, decided with at most
/// `budget` <= kMaxCullBudget node fetches below the deepest cube that holds
/// the region; false if undecided.
template <class P>
bool cull_region(const P& nodes, const SegmentRegion& r, int budget) {
  const float m = kDeepMargin;
  NoCounters cnt;
  [[maybe_unused]] typename P::Index index{};
  auto inside = [&](Vec3 lo, float side) {
    return r.lo.x - m > lo.x && r.lo.y - m > lo.y && r.lo.z - m > lo.z &&
           r.hi.x + m < lo.x + side && r.hi.y + m < lo.y + side && r.hi.z + m < lo.z + side;
  };
  Vec3 lo{1.f, 1.f, 1.f};
  float side = 1.f;
  if (budget <= 0 || !inside(lo, side)) return false;
  uint32_t node = nodes.root();
  int scale = kOctreeMaxScale - 1;
  for (;;) {
    const auto desc = nodes.fetch(node, scale, cnt);
    const float half = side * 0.5f;
    int c = 0;
    for (int a = 0; a < 3; ++a)
      if (r.lo[a] - m > lo[a] + half) c |= 1 << a;
    const Vec3 clo{lo.x + ((c & 1) ? half : 0.f), lo.y + ((c & 2) ? half : 0.f),
                   lo.z + ((c & 4) ? half : 0.f)};
    if (!inside(clo, half)) break;                 // no child holds every segment: cull below node
    if (!nodes.valid(desc, c)) return true;        // every segment lies in an empty cube
    if (nodes.leaf(desc, c, scale)) return false;  // the loop may hit it: leave that to the lanes
    node = nodes.descend(desc, node, c, scale, index, cnt);
    lo = clo, side = half, --scale;
  }
  // A depth-first walk over the present cubes that touch the region.
  struct Item {
    uint32_t node;
    int scale;
    Vec3 lo;
    float side;
  };
  Item stack[8 * kMaxCullBudget];
  int top = 0, fetches = 0;
  stack[top++] = {node, scale, lo, side};
  while (top > 0) {
    const Item it = stack[--top];
    if (++fetches > budget) return false;  // undecided: trace the rays
    const auto desc = nodes.fetch(it.node, it.scale, cnt);
    const float half = it.side * 0.5f;
    for (uint32_t mask = nodes.mask(desc); mask != 0; mask &= mask - 1) {
      const int c = std::countr_zero(mask);
      const Vec3 clo{it.lo.x + ((c & 1) ? half : 0.f), it.lo.y + ((c & 2) ? half : 0.f),
                     it.lo.z + ((c & 4) ? half : 0.f)};
      if (!r.touches(clo, half)) continue;
      if (nodes.leaf(desc, c, it.scale) || top == 8 * kMaxCullBudget) return false;
      stack[top++] = {nodes.descend(desc, it.node, c, it.scale, index, cnt), it.scale - 1, clo,
                      half};
    }
  }
  return true;
}

/// The region of group rays [i0, i1) (octree space), which share rays[i0]'s
/// origin; false if they do not (or a ray is not finite). normal (may be
/// null): dot(dir, normal) >= 0 for every ray makes the half-space part of
/// the region.
inline bool group_region(const OctreeFrame& frame, const Ray* rays, size_t i0, size_t i1,
                         const Vec3* normal, SegmentRegion* reg) {
  const Ray& r0 = rays[i0];
  const Vec3 p = frame.point(r0.origin);
  *reg = SegmentRegion{p, p, p, 0.f, false, Vec3{0, 0, 0}};
  if (!is_finite(p)) return false;
  bool half = normal != nullptr && is_finite(*normal);
  for (size_t i = i0; i < i1; ++i) {
    const Ray& r = rays[i];
    if (!(r.origin.x == r0.origin.x && r.origin.y == r0.origin.y && r.origin.z == r0.origin.z &&
          std::isfinite(r.tmax) && r.tmax >= 0.f))
      return false;
    const Vec3 d = frame.direction(r.dir);
    if (!is_finite(d)) return false;
    const Vec3 e = p + d * r.tmax;
    for (int a = 0; a < 3; ++a)
      reg->lo[a] = vmin(reg->lo[a], e[a]), reg->hi[a] = vmax(reg->hi[a], e[a]);
    reg->radius = vmax(reg->radius, length(d * r.tmax));
    half = half && dot(r.dir, *normal) >= 0.f;
  }
  if (half) reg->half = true, reg->normal = *normal;
  return true;
}

/// occluded(rays[i], lod) for i < n into hit[i] (0/1), bit-identical to the
/// scalar caster, via `kernel` of `width` lanes, started as `start` says
/// (DeepStart, voxcast/occlusion_packets.hpp: per ray, start_packets; per
/// packet, packet_paths with `path_share`). group > 0: rays [k group, (k + 1) group) share an
/// origin (checked) and, if `normals` is set, dot(dir, normals[k]) >= 0 (checked); with cull_budget
/// > 0 such groups are first offered the cull (at LOD 0). stats (may be null) accumulates.
template <class P>
void anyhit_packets(const OctreeWorld<P>& world, AnyHitKernel<P> kernel, int width, const Ray* rays,
                    size_t n, const LodFootprint& lod, int group, const Vec3* normals,
                    DeepStart start, float path_share, int cull_budget, uint8_t* hit,
                    AnyHitStats* stats) {
  cull_budget = cull_budget < 0 ? 0 : (cull_budget > kMaxCullBudget ? kMaxCullBudget : cull_budget);
  const P nodes(world.source);
  const OctreeFrame& frame = world.frame;
  const float size_coef = frame.length(lod.size_per_t),
              size_bias = frame.length(lod.size_at_origin);
  const bool lod0 = size_coef == 0.f && size_bias == 0.f;
  thread_local PacketQueue q;
  thread_local Vec3 origins[kPacketQueue];
  AnyHitStats st;
  size_t base = 0;
  // The queued rays: deep start, then the kernel.
  auto flush = [&] {
    if (q.count == 0) return;
    if (start == DeepStart::PerRay) {
      const uint64_t before = st.depth_sum;
      st.depth_sum += start_packets(nodes, origins, 0, size_coef, size_bias, &q);
      if (st.depth_sum != before)
        for (int k = 0; k < q.count; ++k) st.deep_rays += q.scale[k] < kOctreeMaxScale - 1;
    } else if (start == DeepStart::Packet) {
      packet_paths(nodes, origins, width, path_share, &q);
      for (int p = 0; p * width < q.count; ++p) st.path_levels += uint64_t(q.path_levels[p]);
    }
    st.rays += uint64_t(q.count);
    // Packets of one point's AO rays: refill once a quarter of the lanes
    // is idle (measured faster for them than at half, 1.08-1.15x on the
    // bunny's AO rays, docs/BENCHMARKS.md "AO rays: refill at a quarter";
    // whole packets are faster for a pixel block's rays).
    q.refill_lanes = group > 0 && q.path_width == 0 ? width / 4 : 0;
    kernel(nodes, q, size_coef, size_bias, hit + base);
    q.count = 0, q.deep = false, q.path_width = 0;
  };
  // Groups never straddle a queue: a block holds whole groups when it can.
  const size_t g = group > 0 ? size_t(group) : 1;
  const size_t block = g <= size_t(kPacketQueue) ? (size_t(kPacketQueue) / g) * g : g;
  for (; base < n; base += block) {
    const size_t m = n - base < block ? n - base : block;
    q.count = 0, q.deep = false, q.path_width = 0;
    for (size_t i = 0; i < m; ++i) hit[base + i] = 0;
    // Queues rays [i0, i1) of the block, eight at a time while they fit
    // (queue_rays8: the same floats as queue_ray, in vectors).
    auto queue_range = [&](size_t i0, size_t i1) {
      for (size_t i = i0; i < i1;) {
        if (kPacketQueue - q.count >= 8) {
          const int k = i1 - i < 8 ? int(i1 - i) : 8;
          queue_rays8(frame, rays + base + i, k, nodes.root(), int32_t(i), &q, &origins[q.count]);
          i += size_t(k);
        } else {
          queue_ray(frame, rays[base + i], nullptr, nodes.root(), int32_t(i), &q,
                    &origins[q.count]);
          ++i;
        }
        if (q.count == kPacketQueue) flush();  // a group larger than the queue
      }
    };
    if (!(group > 0 && cull_budget > 0 && lod0)) {
      queue_range(0, m);
    } else {
      for (size_t g0 = 0; g0 < m; g0 += g) {
        const size_t g1 = g0 + g < m ? g0 + g : m;
        SegmentRegion reg;
        const Vec3* nrm = normals != nullptr ? &normals[(base + g0) / g] : nullptr;
        if (group_region(frame, rays + base, g0, g1, nrm, &reg)) {
          ++st.points;
          if (cull_region(nodes, reg, cull_budget)) {
            ++st.culled;
            continue;  // every ray of the group misses: hit stays 0
          }
        }
        queue_range(g0, g1);
      }
    }
    flush();
  }
  if (stats != nullptr) {
    stats->points += st.points, stats->culled += st.culled;
    stats->rays += st.rays, stats->deep_rays += st.deep_rays;
    stats->depth_sum += st.depth_sum, stats->path_levels += st.path_levels;
  }
}

/// A structure's any-hit packets: its policy's kernels; sources of 2^31
/// words or more (beyond the gathers' indices) take the scalar caster.
template <class P, class S>
void structure_anyhit(const S& s, const typename P::Source& source, Isa isa,
                      const PacketKernels<P>& kernels, const Ray* rays, size_t n,
                      const LodFootprint& lod, int group, const Vec3* normals, DeepStart start,
                      float path_share, int cull_budget, uint8_t* hit, AnyHitStats* stats) {
  require_isa(isa, "any-hit packets");
  if (beyond_gathers(source)) {
    TraceContext ctx;
    for (size_t i = 0; i < n; ++i) hit[i] = s.occluded(rays[i], lod, ctx);
    return;
  }
  anyhit_packets(
      OctreeWorld<P>(source), isa == Isa::Avx512 ? kernels.anyhit_avx512 : kernels.anyhit_avx2,
      packet_width(isa), rays, n, lod, group, normals, start, path_share, cull_budget, hit, stats);
}

/// A structure's SurfaceQuery::transmittance_batch: `occluded(rays, m, hit)`
/// (the structure's packet caster) in chunks, 0/1 transmittances; the scalar
/// caster while ctx.counting, so that the counters stay the loop's. The
/// structures pass occluded_packets (the any-hit packets with their default
/// options: no cull, which did not pay, docs/BENCHMARKS.md "Occlusion
/// packets"), so `group` and `normals` are not used.
template <class S, class Occluded>
void structure_transmittance_batch(const S& s, const Occluded& occluded, const Ray* rays, size_t n,
                                   const LodFootprint& lod, TraceContext& ctx, float* out) {
  if (ctx.counting) {
    for (size_t i = 0; i < n; ++i) out[i] = s.transmittance(rays[i], lod, ctx);
    return;
  }
  constexpr size_t kChunk = 4096;
  uint8_t hit[kChunk];
  for (size_t b = 0; b < n; b += kChunk) {
    const size_t m = n - b < kChunk ? n - b : kChunk;
    occluded(rays + b, m, hit);
    for (size_t i = 0; i < m; ++i) out[b + i] = hit[i] ? 0.f : 1.f;
  }
}

}  // namespace voxcast::detail
