#pragma once
// Any-hit packets of the octree family (issue 10 item 5): occlusion rays
// (shadow, AO) through the one caster's Appendix A loop on 16 AVX-512 lanes
// (8 with AVX2), each lane ending at its first occupied cube, and the AO
// "deep start": the rays of one shading point start at the deepest node whose
// cube contains all their segments, after a cull of that node's subtree by
// the rays' ball, hemisphere and box.
//
// Split like the first-hit packet caster (core/octree_packet_caster.hpp):
// this header is compiled with the baseline flags (lane set-up, deep start,
// cull, the call of the active ISA's kernel); core/octree_anyhit_kernel.hpp is
// included only by the per-ISA kernel translation units
// (src/esvo/anyhit_kernel_*.cpp, src/dag/anyhit_kernel_*.cpp).
//
// Why a deep start gives the scalar caster's answer. Let N be a cube that
// contains every point p + t d, t in [0, tmax], with a margin (kDeepMargin)
// far above the rounding of the loop's t values, reached from the root through
// present, non-leaf cubes without contours, at LOD 0. Started at the root, the
// scalar loop (core/octree_caster.hpp) descends along the cubes containing the
// ray's start (the margin decides every center-plane compare the same way the
// geometry does), so at the PUSH into N its state is: t_min = the root-entry
// t_min (no ADVANCE, no contour on the way), t_max = min(t_max0, tc_max(N))
// (a cube's exit t is <= its ancestors', fma being monotone), h = tc_max(N),
// the child of N selected by the same compares. The lane starts in exactly
// that state, so it evolves as the scalar loop until it POPs out of N. At
// that point t_min is an exit plane of N, >= tc_max(N) > t_max (checked per
// ray, strictly): from then on every span is empty (t_min only grows along
// the ray, t_max only shrinks), so the scalar loop can no longer hit anything
// and the lane ends as a miss. Rays whose check fails start at the root.
// The cull: a ray's loop only reaches cubes its segment touches (within
// rounding, far below the margin), so if no present cube of N's subtree
// touches the region that holds every segment (their box, the ball of radius
// max tmax around the common origin and, given a normal n with dot(d, n) >= 0
// for every ray, the half-space above the origin), every ray of the point
// misses.
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

/// The any-hit kernel's input: per ray, cast_octree's state at its start node
/// (the root, or a deep node), in structure-of-arrays form for expand-loads.
struct alignas(64) AnyHitQueue {
  float cx[kPacketQueue], cy[kPacketQueue], cz[kPacketQueue];  // MirroredRay t coefficients
  float bx[kPacketQueue], by[kPacketQueue], bz[kPacketQueue];  // and biases
  float t_min[kPacketQueue], t_max[kPacketQueue], h[kPacketQueue];
  float px[kPacketQueue], py[kPacketQueue], pz[kPacketQueue];  // mirrored min corner of the child
  uint32_t flip[kPacketQueue];                                 // octant_mask ^ 7
  uint32_t idx[kPacketQueue];
  uint32_t parent[kPacketQueue];  // the start node
  int32_t scale[kPacketQueue];    // scale of its children (the root's: kOctreeMaxScale - 1)
  int32_t stop[kPacketQueue];     // a POP to this scale or above ends the lane as a miss
  int32_t id[kPacketQueue];       // the ray's index in the caller's block
  float dx[kPacketQueue], dy[kPacketQueue], dz[kPacketQueue];  // unmirrored (contour slabs)
  int count = 0;
  bool deep = false;  // some ray starts below the root (else parent/scale/stop are the root's)
};

/// A kernel: hit[q.id[k]] = 1 for each ray k of q that the loop stops at a
/// cube (leaf or LOD), other entries untouched.
template <class P>
using AnyHitKernel = void (*)(const P& nodes, const AnyHitQueue& q, float size_coef,
                              float size_bias, uint8_t* hit);

/// Margin of the deep start and the cull, octree units (root side 1): far
/// above the rounding of any t compare in [1,2]^3 (~2^-22 in the same units,
/// core/octree_ray.hpp) and below a voxel of a 16K^3 grid (2^-14).
inline constexpr float kDeepMargin = 0x1p-17f;

/// Most nodes the cull may fetch per ray group (its stack is sized for it).
inline constexpr int kMaxCullBudget = 64;

/// Where a group's rays start: `node` at loop scale `scale` (its children's),
/// and the cubes from the root's child down to the node's own cube
/// (path[levels - 1]), each with its contour value if it has one.
struct DeepStart {
  struct Cube {
    Vec3 lo;  // unmirrored min corner
    float side;
    uint32_t contour;
    bool has_contour;
  };
  uint32_t node;
  int scale;
  int levels;
  bool culled;  // no ray of the group can hit anything
  Cube path[kOctreeMaxScale];
};

/// The mirrored min corner of the cube [lo, lo + side]^3 (exact).
inline Vec3 mirrored_corner(const MirroredRay& ray, Vec3 lo, float side) {
  return {(ray.octant_mask & 1) ? lo.x : 3.f - side - lo.x,
          (ray.octant_mask & 2) ? lo.y : 3.f - side - lo.y,
          (ray.octant_mask & 4) ? lo.z : 3.f - side - lo.z};
}

/// One ray of a deep group: replays the scalar loop's PUSHes along ds.path
/// (each cube's exit t, contour slab and child selection, the loop's own
/// floats) from the root state in *e. kDeep: *e is the loop's state at the
/// PUSH into the deep cube (t span, h, first child); kMiss: the loop cannot
/// hit anything (a contour emptied the span on the way); kRoot: this ray does
/// not fit the argument (its exit check or a child selection disagrees).
enum class Replay { kDeep, kMiss, kRoot };
inline Replay replay_deep_start(const MirroredRay& ray, Vec3 d, const DeepStart& ds, CastEntry* e) {
  const DeepStart::Cube& last = ds.path[ds.levels - 1];
  const Vec3 n = mirrored_corner(ray, last.lo, last.side);
  const float tc_n = vmin(vmin(ray.tx(n.x), ray.ty(n.y)), ray.tz(n.z));
  if (!(tc_n > e->t_max)) return Replay::kRoot;  // might step on past N within its span
  float t_min = e->t_min, t_max = e->t_max;
  // The root's child selection, then one PUSH per path cube.
  Vec3 pos{1.f, 1.f, 1.f};
  float half = 0.5f;
  for (int level = 0;; ++level) {
    if (ray.tx(pos.x + half) > t_min) pos.x += half;
    if (ray.ty(pos.y + half) > t_min) pos.y += half;
    if (ray.tz(pos.z + half) > t_min) pos.z += half;
    if (level == ds.levels) break;
    const DeepStart::Cube& cube = ds.path[level];
    const Vec3 m = mirrored_corner(ray, cube.lo, cube.side);
    if (!(pos.x == m.x && pos.y == m.y && pos.z == m.z)) return Replay::kRoot;
    const float tx = ray.tx(m.x), ty = ray.ty(m.y), tz = ray.tz(m.z);
    float tv_max = vmin(t_max, vmin(vmin(tx, ty), tz));
    if (cube.has_contour)
      contour_span(cube.contour, {ray.tx_coef, ray.ty_coef, ray.tz_coef}, d, tx, ty, tz, cube.side,
                   &t_min, &tv_max);
    if (!(t_min <= tv_max)) return Replay::kMiss;  // ADVANCE past t_max: nothing after
    t_max = tv_max;
    half = cube.side * 0.5f;
  }
  e->t_min = t_min, e->t_max = t_max, e->h = tc_n;
  e->pos_x = pos.x, e->pos_y = pos.y, e->pos_z = pos.z;
  e->idx = (pos.x != n.x ? 1 : 0) | (pos.y != n.y ? 2 : 0) | (pos.z != n.z ? 4 : 0);
  return Replay::kDeep;
}

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

/// The deepest start of a region's rays (see the file comment): false if the
/// group must start at the root. Sets start->culled when the cull of the
/// subtree (at most `budget` <= kMaxCullBudget node fetches) finds no present
/// cube touching the region.
template <class P>
bool deep_start(const P& nodes, const SegmentRegion& r, int budget, DeepStart* start) {
  const float m = kDeepMargin;
  NoCounters cnt;
  [[maybe_unused]] typename P::Index index{};
  auto inside = [&](Vec3 lo, float side) {
    return r.lo.x - m > lo.x && r.lo.y - m > lo.y && r.lo.z - m > lo.z &&
           r.hi.x + m < lo.x + side && r.hi.y + m < lo.y + side && r.hi.z + m < lo.z + side;
  };
  Vec3 lo{1.f, 1.f, 1.f};
  float side = 1.f;
  if (!inside(lo, side)) return false;
  uint32_t node = nodes.root();
  int scale = kOctreeMaxScale - 1, levels = 0;
  for (;;) {
    const auto desc = nodes.fetch(node, scale, cnt);
    const float half = side * 0.5f;
    int c = 0;
    for (int a = 0; a < 3; ++a)
      if (r.lo[a] - m > lo[a] + half) c |= 1 << a;
    const Vec3 clo{lo.x + ((c & 1) ? half : 0.f), lo.y + ((c & 2) ? half : 0.f),
                   lo.z + ((c & 4) ? half : 0.f)};
    if (!inside(clo, half)) break;  // no child holds every segment: start at node
    if (!nodes.valid(desc, c)) {
      // Every segment lies in an empty cube: the loop steps through it and
      // out past t_max (the strict margin), a miss for every ray.
      start->culled = true;
      return true;
    }
    if (nodes.leaf(desc, c, scale)) break;  // the loop would hit it: leave that to the lanes
    DeepStart::Cube& cube = start->path[levels++];
    cube = {clo, half, 0u, false};
    if constexpr (P::kContours) cube.has_contour = nodes.contour(desc, node, c, &cube.contour);
    node = nodes.descend(desc, node, c, scale, index, cnt);
    lo = clo, side = half, --scale;
  }
  if (levels == 0) return false;  // the root itself: nothing gained
  start->node = node, start->scale = scale, start->levels = levels, start->culled = false;
  // The cull: a depth-first walk over the present cubes that touch the region.
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
    if (++fetches > budget) return true;  // undecided: trace the rays
    const auto desc = nodes.fetch(it.node, it.scale, cnt);
    const float half = it.side * 0.5f;
    for (uint32_t mask = nodes.mask(desc); mask != 0; mask &= mask - 1) {
      const int c = std::countr_zero(mask);
      const Vec3 clo{it.lo.x + ((c & 1) ? half : 0.f), it.lo.y + ((c & 2) ? half : 0.f),
                     it.lo.z + ((c & 4) ? half : 0.f)};
      if (!r.touches(clo, half)) continue;
      if (nodes.leaf(desc, c, it.scale) || top == 8 * kMaxCullBudget) return true;
      stack[top++] = {nodes.descend(desc, it.node, c, it.scale, index, cnt), it.scale - 1, clo,
                      half};
    }
  }
  start->culled = true;
  return true;
}

/// occluded(rays[i], lod) for i < n into hit[i] (0/1), bit-identical to the
/// scalar caster, via `kernel`. group > 0: rays [k group, (k + 1) group)
/// share an origin (checked) and, if `normals` is set, dot(dir, normals[k])
/// >= 0 (checked); such groups take the deep start (at LOD 0). `deep` false:
/// every ray starts at the root. stats (may be null) accumulates.
template <class P>
void anyhit_packets(const OctreeWorld<P>& world, AnyHitKernel<P> kernel, const Ray* rays, size_t n,
                    const LodFootprint& lod, int group, const Vec3* normals, bool deep,
                    int cull_budget, uint8_t* hit, AnyHitStats* stats) {
  cull_budget = cull_budget < 0 ? 0 : (cull_budget > kMaxCullBudget ? kMaxCullBudget : cull_budget);
  const P nodes(world.source);
  const OctreeFrame& frame = world.frame;
  const float size_coef = frame.length(lod.size_per_t),
              size_bias = frame.length(lod.size_at_origin);
  const bool lod0 = size_coef == 0.f && size_bias == 0.f;
  constexpr int s_max = kOctreeMaxScale;
  thread_local AnyHitQueue q;
  AnyHitStats st;
  // Groups never straddle a queue: a block holds whole groups when it can.
  const size_t g = group > 0 ? size_t(group) : 1;
  const size_t block = g <= size_t(kPacketQueue) ? (size_t(kPacketQueue) / g) * g : g;
  for (size_t base = 0; base < n; base += block) {
    const size_t m = n - base < block ? n - base : block;
    q.count = 0;
    q.deep = false;
    for (size_t i = 0; i < m; ++i) hit[base + i] = 0;
    for (size_t g0 = 0; g0 < m; g0 += g) {
      const size_t g1 = g0 + g < m ? g0 + g : m;
      // The group's deep start, if it has one.
      DeepStart ds;
      bool use_deep = false;
      if (deep && group > 0 && lod0) {
        const Ray& r0 = rays[base + g0];
        const Vec3 p = frame.point(r0.origin);
        SegmentRegion reg{p, p, p, 0.f, false, Vec3{0, 0, 0}};
        bool ok = is_finite(p);
        const Vec3* nrm = normals != nullptr ? &normals[(base + g0) / g] : nullptr;
        bool half = nrm != nullptr && is_finite(*nrm);
        for (size_t i = g0; i < g1 && ok; ++i) {
          const Ray& r = rays[base + i];
          ok = r.origin.x == r0.origin.x && r.origin.y == r0.origin.y &&
               r.origin.z == r0.origin.z && std::isfinite(r.tmax) && r.tmax >= 0.f;
          const Vec3 d = frame.direction(r.dir);
          ok = ok && is_finite(d);
          if (!ok) break;
          const Vec3 e = p + d * r.tmax;
          for (int a = 0; a < 3; ++a)
            reg.lo[a] = vmin(reg.lo[a], e[a]), reg.hi[a] = vmax(reg.hi[a], e[a]);
          reg.radius = vmax(reg.radius, length(d * r.tmax));
          half = half && dot(r.dir, *nrm) >= 0.f;
        }
        if (ok) {
          if (half) reg.half = true, reg.normal = *nrm;
          ++st.points;
          use_deep = deep_start(nodes, reg, cull_budget, &ds);
          if (use_deep) {
            ++st.deep_points;
            if (ds.culled) {
              ++st.culled;
              continue;  // every ray of the group misses: hit stays 0
            }
            st.depth_sum += uint64_t(ds.levels);
          }
        }
      }
      for (size_t i = g0; i < g1; ++i) {
        const Ray& r = rays[base + i];
        const Vec3 p = frame.point(r.origin), d0 = frame.direction(r.dir);
        if (!(is_finite(p) && is_finite(d0))) continue;  // cast_octree: a miss
        const Vec3 d = avoid_tiny_components(d0);
        const MirroredRay ray(p, d);
        CastEntry e;
        if (!enter_root(ray, r.tmax, nullptr, &e)) continue;
        const int k = q.count++;
        uint32_t parent = nodes.root();
        int scale = s_max - 1, stop = s_max;
        if (use_deep) {
          const Replay how = replay_deep_start(ray, d, ds, &e);
          if (how == Replay::kMiss) {
            --q.count;
            continue;
          }
          if (how == Replay::kDeep)
            parent = ds.node, scale = ds.scale, stop = ds.scale + 1, q.deep = true;
          else
            ++st.root_rays;
        }
        q.cx[k] = ray.tx_coef, q.cy[k] = ray.ty_coef, q.cz[k] = ray.tz_coef;
        q.bx[k] = ray.tx_bias, q.by[k] = ray.ty_bias, q.bz[k] = ray.tz_bias;
        q.t_min[k] = e.t_min, q.t_max[k] = e.t_max, q.h[k] = e.h;
        q.px[k] = e.pos_x, q.py[k] = e.pos_y, q.pz[k] = e.pos_z;
        q.flip[k] = uint32_t(ray.octant_mask ^ 7);
        q.idx[k] = uint32_t(e.idx);
        q.parent[k] = parent;
        q.scale[k] = scale;
        q.stop[k] = stop;
        q.id[k] = int32_t(i);
        q.dx[k] = d.x, q.dy[k] = d.y, q.dz[k] = d.z;
        if (q.count == kPacketQueue) {  // a group larger than the queue
          kernel(nodes, q, size_coef, size_bias, hit + base);
          q.count = 0, q.deep = false;
        }
      }
    }
    if (q.count > 0) kernel(nodes, q, size_coef, size_bias, hit + base);
  }
  if (stats != nullptr) {
    stats->points += st.points, stats->deep_points += st.deep_points;
    stats->depth_sum += st.depth_sum, stats->culled += st.culled;
    stats->root_rays += st.root_rays;
  }
}

/// A structure's any-hit packets: its AVX2 / AVX-512 kernels; sources of
/// 2^31 words or more (beyond the gathers' indices) take the scalar caster.
template <class P, class S>
void structure_anyhit(const S& s, const typename P::Source& source, Isa isa, AnyHitKernel<P> avx2,
                      AnyHitKernel<P> avx512, const Ray* rays, size_t n, const LodFootprint& lod,
                      int group, const Vec3* normals, bool deep, int cull_budget, uint8_t* hit,
                      AnyHitStats* stats) {
  if (!cpu_supports(isa))
    throw Error(std::string("any-hit packets: this CPU does not support ") + isa_name(isa));
  if (source.words.size() >= (size_t(1) << 31)) {
    TraceContext ctx;
    for (size_t i = 0; i < n; ++i) hit[i] = s.occluded(rays[i], lod, ctx);
    return;
  }
  anyhit_packets(OctreeWorld<P>(source), isa == Isa::Avx512 ? avx512 : avx2, rays, n, lod, group,
                 normals, deep, cull_budget, hit, stats);
}

/// A structure's SurfaceQuery::transmittance_batch: `occluded(rays, m, hit)`
/// (the structure's packet caster) in chunks, 0/1 transmittances; the scalar
/// caster while ctx.counting, so that the counters stay the loop's. The
/// structures pass occluded_packets, the first-hit kernel: on the same rays
/// it measured 2-5 % faster than occluded_anyhit for AO and the same for
/// shadow rays (docs/BENCHMARKS.md "Occlusion packets"), and the groups'
/// deep start did not pay, so `group` and `normals` are not used.
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
