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
#include <immintrin.h>

#include <bit>
#include <cstddef>
#include <cstdint>
#include <cstring>
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

/// The kernels' input: lane start states, in structure-of-arrays form so
/// that refilled lanes are expand-loaded. Every ray starts as cast_octree
/// does after enter_root (at the root), or, when `deep` is set, where
/// parent/scale say: cast_octree's state at some later PUSH of the same ray
/// (t span, h, child position and slot, all of them the loop's own floats)
/// with the stack the loop had built by then (start_packets below fills it,
/// and so may a caller that found the start another way). The kernels
/// themselves are core/octree_packet_kernel.hpp.
struct alignas(64) PacketQueue {
  float cx[kPacketQueue], cy[kPacketQueue], cz[kPacketQueue];  // MirroredRay t coefficients
  float bx[kPacketQueue], by[kPacketQueue], bz[kPacketQueue];  // and biases
  float t_min[kPacketQueue], t_max[kPacketQueue], h[kPacketQueue];
  float px[kPacketQueue], py[kPacketQueue], pz[kPacketQueue];  // mirrored min corner of the child
  uint32_t flip[kPacketQueue];                                 // octant_mask ^ 7
  uint32_t idx[kPacketQueue];
  int32_t id[kPacketQueue];  // the ray's index in the caller's block (PacketOut, hit bytes)
  // Unmirrored directions (after avoid_tiny_components): the contour slab.
  float dx[kPacketQueue], dy[kPacketQueue], dz[kPacketQueue];
  // deep only: the start node, the scale of its children (the root's:
  // kOctreeMaxScale - 1), and the stack rows above it: for every scale s in
  // (scale, kOctreeMaxScale), the loop's (parent, t_max) saved at scale s
  // (start_packets, packet paths), or rows whose t_max ends the lane at a POP
  // out of the start node (the tile frustum pass, core/frustum_packets.hpp).
  uint32_t parent[kPacketQueue];
  int32_t scale[kPacketQueue];
  uint32_t stack_node[kOctreeMaxScale][kPacketQueue];
  float stack_tmax[kOctreeMaxScale][kPacketQueue];
  int count = 0;
  bool deep = false;  // some ray starts below the root (else parent/scale/stack are not read)
  // Idle lanes before the kernel refills them (0: all of them, whole
  // packets; paths need whole packets).
  int refill_lanes = 0;
  // Packet paths (set by packet_paths; path_width 0: none). Packet p = the
  // slots [p path_width, (p + 1) path_width), which the kernel of
  // path_width lanes refills as one packet. Its lanes, started at the root,
  // replay the path in the kernel's lanes before their first iteration
  // (core/octree_packet_kernel.hpp), each as far as the loop would PUSH
  // along it: cube j (side 2^-(j + 1), the root's child first) has the
  // unmirrored min corner path_lo[p][j] and node path_node[p][j].
  int path_width = 0;
  int8_t path_levels[kPacketQueue / 8];
  uint32_t path_node[kPacketQueue / 8][kOctreeMaxScale];
  float path_lo[kPacketQueue / 8][kOctreeMaxScale][3];
  uint32_t path_contour[kPacketQueue / 8][kOctreeMaxScale];  // if path_has_contour
  bool path_has_contour[kPacketQueue / 8][kOctreeMaxScale];
};

/// The kernel's output per ray: stop = 0 (CastStop::kMiss) unless the loop
/// stopped at a cube; then the loop state there (mirrored frame).
struct alignas(64) PacketOut {
  float t[kPacketQueue], px[kPacketQueue], py[kPacketQueue], pz[kPacketQueue];
  uint32_t parent[kPacketQueue], idx[kPacketQueue];
  int32_t scale[kPacketQueue], stop[kPacketQueue];
};

/// A first-hit kernel: casts q's rays through `nodes` (the scalar policy,
/// whose fields the kernel's vector policy reads), LOD terms as in
/// cast_octree.
template <class P>
using PacketKernel = void (*)(const P& nodes, const PacketQueue& q, float size_coef,
                              float size_bias, PacketOut* out);
/// An any-hit kernel: hit[q.id[k]] = 1 for each ray k of q that the loop
/// stops at a cube (leaf or LOD), other entries untouched.
template <class P>
using AnyHitKernel = void (*)(const P& nodes, const PacketQueue& q, float size_coef,
                              float size_bias, uint8_t* hit);

/// A policy's kernels, one per ISA (core/packet_kernels.hpp declares them).
template <class P>
struct PacketKernels {
  PacketKernel<P> trace_avx2, trace_avx512;
  AnyHitKernel<P> anyhit_avx2, anyhit_avx512;
};

/// Checks that the CPU runs `isa` (voxcast::Error otherwise): `who` names
/// the caller in the message.
inline void require_isa(Isa isa, const char* who) {
  if (!cpu_supports(isa))
    throw Error(std::string(who) + ": this CPU does not support " + isa_name(isa));
}

/// Appends ray `id` (mirrored `ray`, direction `d` after avoid_tiny_components)
/// with the loop state `e` at the root, to q; returns its queue slot.
inline int queue_entry(PacketQueue* q, int32_t id, const MirroredRay& ray, Vec3 d,
                       const CastEntry& e, uint32_t root) {
  const int k = q->count++;
  q->cx[k] = ray.tx_coef, q->cy[k] = ray.ty_coef, q->cz[k] = ray.tz_coef;
  q->bx[k] = ray.tx_bias, q->by[k] = ray.ty_bias, q->bz[k] = ray.tz_bias;
  q->t_min[k] = e.t_min, q->t_max[k] = e.t_max, q->h[k] = e.h;
  q->px[k] = e.pos_x, q->py[k] = e.pos_y, q->pz[k] = e.pos_z;
  q->flip[k] = uint32_t(ray.octant_mask ^ 7);
  q->idx[k] = uint32_t(e.idx);
  q->id[k] = id;
  q->dx[k] = d.x, q->dy[k] = d.y, q->dz[k] = d.z;
  q->parent[k] = root;
  q->scale[k] = kOctreeMaxScale - 1;
  return k;
}

/// Queue slot q->count for `ray` (world space) in `frame`, started at the
/// root (clipped to `region` if set; cast_octree's set-up): false, and no
/// slot, if cast_octree would miss at once (non-finite input, empty span).
/// *origin: the ray's origin in octree space.
inline bool queue_ray(const OctreeFrame& frame, const Ray& r, const Aabb* region, uint32_t root,
                      int32_t id, PacketQueue* q, Vec3* origin) {
  const Vec3 p = frame.point(r.origin), d0 = frame.direction(r.dir);
  if (!(is_finite(p) && is_finite(d0))) return false;  // cast_octree: a miss
  const Vec3 d = avoid_tiny_components(d0);
  const MirroredRay ray(p, d);
  CastEntry e;
  if (!enter_root(ray, r.tmax, region, &e)) return false;
  queue_entry(q, id, ray, d, e, root);
  *origin = p;
  return true;
}

/// queue_ray on rays[0, m) (m <= 8, ids id0, id0 + 1, ...), eight at a time
/// in the baseline ISA's 8-lane vectors: the same operations in the same
/// order as queue_ray (the build has -ffp-contract=off, so no product is
/// fused that queue_ray rounds), so every queued float is bit-identical.
/// Rays queue_ray would reject (non-finite, empty span) get no slot; the
/// others keep their order. origins[j]: the octree-space origin of the j-th
/// queued ray. Returns the number of rays queued.
inline int queue_rays8(const OctreeFrame& frame, const Ray* rays, int m, uint32_t root, int32_t id0,
                       PacketQueue* q, Vec3* origins) {
  typedef float F8 __attribute__((vector_size(32)));
  typedef int32_t I8 __attribute__((vector_size(32)));
  typedef uint32_t U8 __attribute__((vector_size(32)));
  static_assert(sizeof(Ray) == 7 * sizeof(float));
  F8 ox, oy, oz, dx, dy, dz, tm;
  if (m == 8) {  // the seven fields of eight rays: stride-7 gathers
    const float* f = &rays[0].origin.x;
    const __m256i at =
        _mm256_mullo_epi32(_mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7), _mm256_set1_epi32(7));
    auto field = [&](int k) {
      return (F8)_mm256_i32gather_ps(f, _mm256_add_epi32(at, _mm256_set1_epi32(k)), 4);
    };
    ox = field(0), oy = field(1), oz = field(2);
    dx = field(3), dy = field(4), dz = field(5), tm = field(6);
  } else {
    for (int i = 0; i < 8; ++i) {
      const Ray& r = rays[i < m ? i : m - 1];
      ox[i] = r.origin.x, oy[i] = r.origin.y, oz[i] = r.origin.z;
      dx[i] = r.dir.x, dy[i] = r.dir.y, dz[i] = r.dir.z, tm[i] = r.tmax;
    }
  }
  auto max = [](F8 a, F8 b) { return a > b ? a : b; };  // vmax
  auto min = [](F8 a, F8 b) { return a < b ? a : b; };  // vmin
  auto fabs = [](F8 a) { return (F8)((U8)a & 0x7FFFFFFFu); };
  auto finite = [](F8 a) { return ((U8)a & 0x7F800000u) != 0x7F800000u; };
  auto fma = [](F8 a, F8 b, F8 c) { return (F8)_mm256_fmadd_ps((__m256)a, (__m256)b, (__m256)c); };
  // OctreeFrame::point, direction.
  const float inv = frame.inv_side;
  const F8 px = (ox - frame.origin.x) * inv + 1.f, py = (oy - frame.origin.y) * inv + 1.f,
           pz = (oz - frame.origin.z) * inv + 1.f;
  dx = dx * inv, dy = dy * inv, dz = dz * inv;
  I8 ok = finite(px) & finite(py) & finite(pz) & finite(dx) & finite(dy) & finite(dz);
  // avoid_tiny_components.
  F8 eps = 0x1p-23f * max(fabs(dx), max(fabs(dy), fabs(dz)));
  eps = eps >= 0x1p-126f ? eps : F8{} + 0x1p-23f;
  auto tiny = [&](F8 d) {
    const F8 signed_eps = (F8)(((U8)d & 0x80000000u) | (U8)eps);
    return fabs(d) < eps ? signed_eps : d;
  };
  dx = tiny(dx), dy = tiny(dy), dz = tiny(dz);
  // MirroredRay.
  const F8 cx = 1.0f / -fabs(dx), cy = 1.0f / -fabs(dy), cz = 1.0f / -fabs(dz);
  F8 bx = cx * px, by = cy * py, bz = cz * pz;
  const I8 mx = dx > 0.0f, my = dy > 0.0f, mz = dz > 0.0f;
  bx = mx ? 3.0f * cx - bx : bx;
  by = my ? 3.0f * cy - by : by;
  bz = mz ? 3.0f * cz - bz : bz;
  const I8 octant = 7 ^ (mx & 1) ^ (my & 2) ^ (mz & 4);
  // enter_root (no region).
  auto t = [&](float x, F8 c, F8 b) { return fma(F8{} + x, c, -b); };
  F8 t_min = max(max(t(2.0f, cx, bx), t(2.0f, cy, by)), t(2.0f, cz, bz));
  F8 t_max = min(min(t(1.0f, cx, bx), t(1.0f, cy, by)), t(1.0f, cz, bz));
  const F8 h = t_max;
  t_min = max(t_min, F8{});
  t_max = min(t_max, tm);
  ok &= t_min <= t_max;
  const I8 ix = t(1.5f, cx, bx) > t_min, iy = t(1.5f, cy, by) > t_min, iz = t(1.5f, cz, bz) > t_min;
  const I8 idx = (ix & 1) | (iy & 2) | (iz & 4);
  const F8 one = F8{} + 1.0f, mid = F8{} + 1.5f;
  const F8 ex = ix ? mid : one, ey = iy ? mid : one, ez = iz ? mid : one;
  int queued = 0;
  if (m == 8 && _mm256_movemask_ps((__m256)ok) == 0xFF) {  // all eight: vector stores
    const int k = q->count;
    q->count += 8;
    auto put = [&](auto* dst, auto v) { std::memcpy(dst + k, &v, sizeof(v)); };
    put(q->cx, cx), put(q->cy, cy), put(q->cz, cz);
    put(q->bx, bx), put(q->by, by), put(q->bz, bz);
    put(q->t_min, t_min), put(q->t_max, t_max), put(q->h, h);
    put(q->px, ex), put(q->py, ey), put(q->pz, ez);
    put(q->flip, (U8)(octant ^ 7));
    put(q->idx, (U8)idx);
    put(q->id, I8{0, 1, 2, 3, 4, 5, 6, 7} + id0);
    put(q->dx, dx), put(q->dy, dy), put(q->dz, dz);
    put(q->parent, U8{} + root);
    put(q->scale, I8{} + (kOctreeMaxScale - 1));
    for (int i = 0; i < 8; ++i) origins[i] = {px[i], py[i], pz[i]};
    return 8;
  }
  for (int i = 0; i < m; ++i) {
    if (!ok[i]) continue;
    const int k = q->count++;
    q->cx[k] = cx[i], q->cy[k] = cy[i], q->cz[k] = cz[i];
    q->bx[k] = bx[i], q->by[k] = by[i], q->bz[k] = bz[i];
    q->t_min[k] = t_min[i], q->t_max[k] = t_max[i], q->h[k] = h[i];
    q->px[k] = ex[i], q->py[k] = ey[i], q->pz[k] = ez[i];
    q->flip[k] = uint32_t(octant[i] ^ 7);
    q->idx[k] = uint32_t(idx[i]);
    q->id[k] = id0 + i;
    q->dx[k] = dx[i], q->dy[k] = dy[i], q->dz[k] = dz[i];
    q->parent[k] = root;
    q->scale[k] = kOctreeMaxScale - 1;
    origins[queued++] = {px[i], py[i], pz[i]};
  }
  return queued;
}

// ---- Deep start: packets below the root ------------------------------------

/// A descent from the root: the cubes from the root's child down
/// (cube[levels - 1] the deepest), each present, not a leaf, with its node
/// and its contour value if it has one (and the structure may narrow spans).
struct StartPath {
  struct Cube {
    Vec3 lo;  // unmirrored min corner
    float side;
    uint32_t node;  // the cube's own node (the parent of its children)
    uint32_t contour;
    bool has_contour;
  };
  int levels = 0;
  Cube cube[kOctreeMaxScale];
  // origin_path: the child below cube[levels - 1] where the walk ended (empty
  // or a leaf; end_side 0 if it ended otherwise).
  Vec3 end_lo{0.f, 0.f, 0.f};
  float end_side = 0.f;
};

/// The mirrored min corner of the cube [lo, lo + side]^3 (exact).
inline Vec3 mirrored_corner(int octant_mask, Vec3 lo, float side) {
  return {(octant_mask & 1) ? lo.x : 3.f - side - lo.x,
          (octant_mask & 2) ? lo.y : 3.f - side - lo.y,
          (octant_mask & 4) ? lo.z : 3.f - side - lo.z};
}

/// The path of point `o` (octree space): the cubes that contain it strictly,
/// from the root's child down through present non-leaf cubes, to the node
/// whose child holding o is empty or a leaf (or where o lies on a center
/// plane). Incremental: *path holds the previous point's path, and only the
/// part below the deepest cube that still contains o is walked again (no
/// fetch at all when o lies in the same final child), so the neighbouring
/// origins of a pixel block or the one origin of a point's AO rays share the
/// walk. Only a choice of where to start: replay_start checks every ray.
template <class P>
void origin_path(const P& nodes, Vec3 o, StartPath* path) {
  static_assert(!P::kResidency, "a deep start assumes every node is resident");
  auto strictly_inside = [&](Vec3 lo, float side) {
    return o.x > lo.x && o.y > lo.y && o.z > lo.z && o.x < lo.x + side && o.y < lo.y + side &&
           o.z < lo.z + side;
  };
  int keep = 0;
  while (keep < path->levels && strictly_inside(path->cube[keep].lo, path->cube[keep].side)) ++keep;
  if (keep == path->levels && path->end_side > 0.f && strictly_inside(path->end_lo, path->end_side))
    return;  // the same final child: the same path
  path->levels = keep;
  path->end_side = 0.f;
  if (keep == 0 && !strictly_inside({1.f, 1.f, 1.f}, 1.f)) return;
  NoCounters cnt;
  [[maybe_unused]] typename P::Index index{};
  const bool contours = may_narrow_spans(nodes);
  uint32_t node = keep > 0 ? path->cube[keep - 1].node : nodes.root();
  Vec3 clo = keep > 0 ? path->cube[keep - 1].lo : Vec3{1.f, 1.f, 1.f};
  float side = keep > 0 ? path->cube[keep - 1].side : 1.f;
  for (int scale = kOctreeMaxScale - 1 - keep; scale > 0; --scale) {
    const float half = side * 0.5f;
    int c = 0;
    for (int a = 0; a < 3; ++a) {
      const float mid = clo[a] + half;
      if (o[a] > mid)
        c |= 1 << a, clo[a] = mid;
      else if (!(o[a] < mid))
        return;  // on the center plane: the ray's direction decides
    }
    const auto desc = nodes.fetch(node, scale, cnt);
    if (!nodes.valid(desc, c) || nodes.leaf(desc, c, scale)) {
      path->end_lo = clo, path->end_side = half;
      return;
    }
    StartPath::Cube& cube = path->cube[path->levels++];
    cube = {clo, half, 0u, 0u, false};
    if constexpr (P::kContours)
      if (contours) cube.has_contour = nodes.contour(desc, node, c, &cube.contour);
    node = cube.node = nodes.descend(desc, node, c, scale, index, cnt);
    side = half;
  }
}

/// Moves queue slot k (started at the root by queue_ray) down `path` as far
/// as cast_octree itself would go by PUSHes alone: at each level the loop's
/// own floats (corner t, LOD test, contour slab, child selection) decide
/// whether it PUSHes into the path's next cube, and the replay stops at the
/// first level where it would not (another child, an empty span, a LOD
/// stop). The slot then holds the loop's state at that iteration, and its
/// stack rows the (parent, t_max) the loop saved on the way (saved whatever
/// the h threshold: the loop skips a write only where the row is never read,
/// a child sharing its parent's exit). Returns the levels descended.
inline int replay_start(const StartPath& path, float size_coef, float size_bias, int k,
                        PacketQueue* q, uint32_t root) {
  constexpr int s_max = kOctreeMaxScale;
  const float cx = q->cx[k], cy = q->cy[k], cz = q->cz[k];
  const float bx = q->bx[k], by = q->by[k], bz = q->bz[k];
  const int octant_mask = int(q->flip[k] ^ 7u);
  float t_min = q->t_min[k], t_max = q->t_max[k], h = q->h[k];
  Vec3 pos{q->px[k], q->py[k], q->pz[k]};
  uint32_t parent = root, idx = q->idx[k];
  int scale = s_max - 1, level = 0;
  float sexp = 0.5f;
  for (; level < path.levels; ++level) {
    const StartPath::Cube& cube = path.cube[level];
    const Vec3 m = mirrored_corner(octant_mask, cube.lo, cube.side);
    if (!(pos.x == m.x && pos.y == m.y && pos.z == m.z)) break;
    const float tx = std::fma(pos.x, cx, -bx), ty = std::fma(pos.y, cy, -by),
                tz = std::fma(pos.z, cz, -bz);
    const float tc_max = vmin(vmin(tx, ty), tz);
    if (!(t_min <= t_max) || tc_max * size_coef + size_bias >= sexp) break;
    float t_lo = t_min, tv_max = vmin(t_max, tc_max);
    if (cube.has_contour)
      contour_span(cube.contour, {cx, cy, cz}, {q->dx[k], q->dy[k], q->dz[k]}, tx, ty, tz, sexp,
                   &t_lo, &tv_max);
    if (!(t_lo <= tv_max)) break;
    // PUSH into the cube.
    q->stack_node[scale][k] = parent;
    q->stack_tmax[scale][k] = t_max;
    h = tc_max;
    t_min = t_lo;
    const float half = sexp * 0.5f;
    const float ccx = pos.x + half, ccy = pos.y + half, ccz = pos.z + half;  // exact: dyadic
    idx = 0;
    if (std::fma(ccx, cx, -bx) > t_min) idx ^= 1, pos.x = ccx;
    if (std::fma(ccy, cy, -by) > t_min) idx ^= 2, pos.y = ccy;
    if (std::fma(ccz, cz, -bz) > t_min) idx ^= 4, pos.z = ccz;
    --scale;
    sexp = half;
    t_max = tv_max;
    parent = cube.node;
  }
  if (level == 0) return 0;
  q->parent[k] = parent;
  q->scale[k] = scale;
  q->t_min[k] = t_min, q->t_max[k] = t_max, q->h[k] = h;
  q->px[k] = pos.x, q->py[k] = pos.y, q->pz[k] = pos.z;
  q->idx[k] = idx;
  q->deep = true;
  return level;
}

/// The deep start of queue slots [first, q->count): each ray replays the
/// path of its origin (origin_path; origins[k]: slot k's, octree space), so
/// that it starts at the deepest cube containing its origin that the loop
/// reaches by PUSHes alone (shadow rays of a pixel block, AO rays of a
/// point: the neighbouring origins share most of the walk). Returns the
/// levels of descent skipped, summed over the rays.
template <class P>
uint64_t start_packets(const P& nodes, const Vec3* origins, int first, float size_coef,
                       float size_bias, PacketQueue* q) {
  uint64_t levels = 0;
  StartPath path;
  for (int k = first; k < q->count; ++k) {
    origin_path(nodes, origins[k], &path);
    levels += uint64_t(replay_start(path, size_coef, size_bias, k, q, nodes.root()));
  }
  return levels;
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

/// A packet's shared path (PacketQueue::path_*) for each run of `width`
/// queue slots: from the root, the child that holds the origins of at least
/// `share` of the lanes still on the path (origins[k]: slot k's, octree
/// space; lanes with an origin outside the root or on the center plane
/// leave it), as long as that child is present and not a leaf (with its
/// contour value, if the structure may narrow spans). A lane off the path
/// simply stops replaying there: where to start is only a choice, the
/// kernel's replay checks every lane with the loop's own floats.
template <class P>
void packet_paths(const P& nodes, const Vec3* origins, int width, float share, PacketQueue* q) {
  static_assert(!P::kResidency, "a deep start assumes every node is resident");
  NoCounters cnt;
  [[maybe_unused]] typename P::Index index{};
  const bool contours = may_narrow_spans(nodes);
  q->path_width = width;
  for (int k0 = 0, p = 0; k0 < q->count; k0 += width, ++p) {
    const int k1 = k0 + width < q->count ? k0 + width : q->count;
    uint32_t on = 0;  // lanes still on the path
    for (int k = k0; k < k1; ++k) {
      const Vec3 o = origins[k];
      if (o.x > 1.f && o.y > 1.f && o.z > 1.f && o.x < 2.f && o.y < 2.f && o.z < 2.f)
        on |= 1u << (k - k0);
    }
    const int need = int(std::ceil(share * float(std::popcount(on))));
    int levels = 0;
    uint32_t node = nodes.root();
    Vec3 clo{1.f, 1.f, 1.f};
    float side = 1.f;
    for (int scale = kOctreeMaxScale - 1; scale > 0 && on != 0; --scale) {
      const float half = side * 0.5f;
      uint32_t in_child[8] = {};
      for (uint32_t b = on; b != 0; b &= b - 1) {
        const int l = std::countr_zero(b);
        const Vec3 o = origins[k0 + l];
        int c = 0;
        for (int a = 0; a < 3; ++a) {
          const float mid = clo[a] + half;
          if (o[a] > mid)
            c |= 1 << a;
          else if (!(o[a] < mid))
            c = -1;
          if (c < 0) break;
        }
        if (c >= 0) in_child[c] |= 1u << l;
      }
      int best = 0;
      for (int c = 1; c < 8; ++c)
        if (std::popcount(in_child[c]) > std::popcount(in_child[best])) best = c;
      if (std::popcount(in_child[best]) < (need > 1 ? need : 1)) break;
      const auto desc = nodes.fetch(node, scale, cnt);
      if (!nodes.valid(desc, best) || nodes.leaf(desc, best, scale)) break;
      q->path_has_contour[p][levels] = false;
      if constexpr (P::kContours)
        if (contours)
          q->path_has_contour[p][levels] =
              nodes.contour(desc, node, best, &q->path_contour[p][levels]);
      for (int a = 0; a < 3; ++a)
        if (best >> a & 1) clo[a] += half;
      node = nodes.descend(desc, node, best, scale, index, cnt);
      q->path_node[p][levels] = node;
      q->path_lo[p][levels][0] = clo.x, q->path_lo[p][levels][1] = clo.y;
      q->path_lo[p][levels][2] = clo.z;
      ++levels;
      side = half;
      on = in_child[best];
    }
    q->path_levels[p] = int8_t(levels);
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
  P::name_hit(world.source, c, hit);
}

/// The OctreeWorld::trace answers for rays[0, n) (world space),
/// bit-identical, via `kernel`: found[i], and hits[i] where found.
/// beams (may be null): per ray, the coarse-pass result of its block (or
/// null), as the beam argument of OctreeWorld::trace: an empty beam is a miss,
/// a region is where the ray starts and ends (bit-identical hits).
template <class P>
void cast_packets(const OctreeWorld<P>& world, PacketKernel<P> kernel, const Ray* rays, size_t n,
                  const LodFootprint& lod, const BeamStart* const* beams, SurfaceHit* hits,
                  uint8_t* found) {
  const P nodes(world.source);
  const OctreeFrame& frame = world.frame;
  const float size_coef = frame.length(lod.size_per_t),
              size_bias = frame.length(lod.size_at_origin);
  thread_local PacketQueue q;
  thread_local PacketOut out;
  for (size_t base = 0; base < n; base += kPacketQueue) {
    const int m = int(n - base < size_t(kPacketQueue) ? n - base : size_t(kPacketQueue));
    q.count = 0;
    q.deep = false;
    for (int i = 0; i < m; ++i) {
      found[base + size_t(i)] = 0;
      out.stop[i] = 0;
      const Aabb* region = nullptr;
      if (beams != nullptr && beams[base + size_t(i)] != nullptr) {
        const BeamStart& b = *beams[base + size_t(i)];
        if (b.valid && b.empty) continue;  // §6.2: no ray of the beam hits anything
        if (b.valid) region = &b.region;
      }
      Vec3 origin;
      queue_ray(frame, rays[base + size_t(i)], region, nodes.root(), i, &q, &origin);
    }
    if (q.count > 0) kernel(nodes, q, size_coef, size_bias, &out);
    for (int k = 0; k < q.count; ++k) {
      const int i = q.id[k];
      if (out.stop[i] == 0) continue;
      found[base + size_t(i)] = 1;
      packet_hit(world, nodes, q, k, out, rays[base + size_t(i)], &hits[base + size_t(i)]);
    }
  }
}

/// Whether a structure's source is too large for the kernels' gathers
/// (signed 32-bit word indices): such structures take the scalar caster.
template <class Source>
bool beyond_gathers(const Source& source) {
  return source.words.size() >= (size_t(1) << 31);
}

}  // namespace voxcast::detail
