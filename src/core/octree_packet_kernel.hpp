#pragma once
// The lane-parallel Appendix A loop (core/octree_packet_caster.hpp explains
// the split and why the hits are bit-identical). Included only by the per-ISA
// kernel translation units (*_avx2.cpp, *_avx512.cpp); everything here has
// internal linkage, so each of them compiles its own copy with its own flags.
//
// One lane = one ray, N = 16 (AVX-512) or 8 (AVX2) lanes, GCC vector types
// (element-wise operators; comparisons yield -1/0 lane masks). Per iteration
// every active lane evaluates the loop body of cast_octree with the branches
// turned into lane masks: fetch (gather) where the cached descriptor is
// stale, the three corner t values, then PUSH lanes, ADVANCE lanes and, of
// those, POP lanes. The stack is per lane in L1, laid out [scale][lane] so
// that a level's entries of all lanes share a cache line. Lanes are refilled
// from the queue by expand-loads (see kRefillLanes).
//
// A vector policy VP (src/esvo/packet_nodes.hpp, src/dag/packet_nodes.hpp)
// provides, for lane masks m:
//   N, F/I/U (vector types), Scalar (the scalar policy), kContours
//   Desc; fetch(&desc, m, parent, scale); I fetched(desc); forget(&desc, m)
//   I valid(desc, c); I leaf(desc, c, scale); U descend(desc, parent, c, scale, m)
//   kContours: I contour_lanes(desc, c), uint32_t contour_value(desc, lane, parent, c)
#include <immintrin.h>

#include <array>
#include <bit>
#include <cstdint>

#include "core/octree_caster.hpp"
#include "core/octree_packet_caster.hpp"

namespace voxcast::detail {
namespace {

// The vector types of each width (GCC does not take a template-dependent
// vector_size).
template <int N>
struct LaneTypes;
template <>
struct LaneTypes<8> {
  typedef float F __attribute__((vector_size(32)));
  typedef int32_t I __attribute__((vector_size(32)));
  typedef uint32_t U __attribute__((vector_size(32)));
};
template <>
struct LaneTypes<16> {
  typedef float F __attribute__((vector_size(64)));
  typedef int32_t I __attribute__((vector_size(64)));
  typedef uint32_t U __attribute__((vector_size(64)));
};

template <int N>
struct Lanes {
  using F = typename LaneTypes<N>::F;
  using I = typename LaneTypes<N>::I;
  using U = typename LaneTypes<N>::U;

  static constexpr uint32_t kAll = N == 32 ? ~0u : (1u << N) - 1;

  static I iota() {
    I v;
    for (int i = 0; i < N; ++i) v[i] = i;
    return v;
  }
  template <class V, class S>
  static V splat(S s) {
    return V{} + s;
  }
  /// Bit i = lane i of mask m.
  static uint32_t bits(I m) {
    if constexpr (N == 16)
      return _mm512_movepi32_mask((__m512i)m);
    else
      return uint32_t(_mm256_movemask_ps((__m256)m));
  }
  static F fma(F a, F b, F c) {
    if constexpr (N == 16)
      return (F)_mm512_fmadd_ps((__m512)a, (__m512)b, (__m512)c);
    else
      return (F)_mm256_fmadd_ps((__m256)a, (__m256)b, (__m256)c);
  }
  // vmin/vmax of octree_ray.hpp, lane-wise (the same select on a < b).
  static F min(F a, F b) { return a < b ? a : b; }
  static F max(F a, F b) { return a > b ? a : b; }
  static U as_u(F f) { return (U)f; }
  static F as_f(U u) { return (F)u; }

  /// base[idx] in the lanes of m, src elsewhere (masked: no read elsewhere).
  static U gather(const uint32_t* base, I idx, I m, U src) {
    if constexpr (N == 16)
      return (U)_mm512_mask_i32gather_epi32((__m512i)src, bits(m), (__m512i)idx, base, 4);
    else
      return (U)_mm256_mask_i32gather_epi32((__m256i)src, (const int*)base, (__m256i)idx,
                                            (__m256i)m, 4);
  }
  /// base[idx] = v in the lanes of m (distinct indices).
  static void scatter(uint32_t* base, I idx, I m, U v) {
    if constexpr (N == 16) {
      _mm512_mask_i32scatter_epi32(base, bits(m), (__m512i)idx, (__m512i)v, 4);
    } else {
      for (uint32_t b = bits(m); b != 0; b &= b - 1) {
        const int l = std::countr_zero(b);
        base[idx[l]] = v[l];
      }
    }
  }
  /// Lanes of bit mask k take src[0], src[1], ... in lane order (the queue's
  /// next rays); other lanes keep v.
  static U expand(U v, uint32_t k, const uint32_t* src) {
    if constexpr (N == 16) {
      return (U)_mm512_mask_expandloadu_epi32((__m512i)v, __mmask16(k), src);
    } else {
      for (int j = 0; k != 0; k &= k - 1) v[std::countr_zero(k)] = src[j++];
      return v;
    }
  }
  static F expand(F v, uint32_t k, const float* src) {
    return as_f(expand(as_u(v), k, reinterpret_cast<const uint32_t*>(src)));
  }
  static I expand(I v, uint32_t k, const int32_t* src) {
    return (I)expand((U)v, k, reinterpret_cast<const uint32_t*>(src));
  }
  /// Population count of each lane's low 8 bits (child masks).
  static U popcount8(U v) {
    v = v - ((v >> 1) & 0x55u);
    v = (v & 0x33u) + ((v >> 2) & 0x33u);
    return (v + (v >> 4)) & 0x0Fu;
  }
};

/// cast_octree<P, false, false> on every ray of q (no region, no counters):
/// out's stop/t/scale/parent/idx/pos of each ray that stopped at a cube.
/// 0, 1, 2, ...: the queue slots a refill hands out.
constexpr std::array<int32_t, kPacketQueue> kSequence = [] {
  std::array<int32_t, kPacketQueue> a{};
  for (int i = 0; i < kPacketQueue; ++i) a[size_t(i)] = i;
  return a;
}();

/// The contour slabs (cast_octree's contour_span) of the lanes of `inside`
/// whose child c has one, narrowing t_min and tv_max lane by lane; shared by
/// the first-hit and the any-hit kernel (q: its queue, whose dx, dy, dz are
/// the rays' unmirrored directions).
template <class VP, class Q, class D, class F, class I, class U>
[[gnu::always_inline]] inline void lane_contours(const VP& vp, const Q& q, const D& desc, I inside,
                                                 U c, U parent, I slot, F cx, F cy, F cz,
                                                 F tx_corner, F ty_corner, F tz_corner, F sexp,
                                                 F* t_min, F* tv_max) {
  const I contoured = inside & vp.contour_lanes(desc, c);
  for (uint32_t b = Lanes<VP::N>::bits(contoured); b != 0; b &= b - 1) {
    const int l = std::countr_zero(b);
    const int k = slot[l];
    float tl = (*t_min)[l], tv = (*tv_max)[l];
    contour_span(vp.contour_value(desc, l, parent[l], c[l]), {cx[l], cy[l], cz[l]},
                 {q.dx[k], q.dy[k], q.dz[k]}, tx_corner[l], ty_corner[l], tz_corner[l], sexp[l],
                 &tl, &tv);
    (*t_min)[l] = tl, (*tv_max)[l] = tv;
  }
}

/// kDeep: lanes may start below the root (q.parent / q.scale / q.stop, the
/// tile frustum pass's start cubes, core/tile_frustum.hpp); otherwise every
/// lane starts at the root (as in the any-hit kernel, the deep-capable loop
/// costs a few per cent on root-start rays).
template <class VP, bool kDeep>
void packet_loop(const typename VP::Scalar& nodes, const PacketQueue& q, float size_coef,
                 float size_bias, PacketOut* out) {
  constexpr int N = VP::N;
  constexpr int s_max = kOctreeMaxScale;
  using L = Lanes<N>;
  using F = typename L::F;
  using I = typename L::I;
  using U = typename L::U;
  const VP vp(nodes);
  const bool contours = may_narrow_spans(nodes);  // the loop's early miss exit when false
  constexpr int kRefillLanes = N;

  const I lane = L::iota();

  // A packet: lane state (cast_octree's locals; idle lanes have slot < 0)
  // and the lanes' stacks.
  struct Packet {
    F cx{}, cy{}, cz{}, bx{}, by{}, bz{};
    F px{}, py{}, pz{}, t_min{}, t_max{}, h{};
    F sexp = L::template splat<F>(0.5f);
    U parent{}, idx{}, flip{};
    I scale = L::template splat<I>(s_max - 1);
    [[maybe_unused]] I stop = L::template splat<I>(s_max);  // kDeep: POP to here = left the start
    I slot = L::template splat<I>(-1);                      // the lane's ray in q
    typename VP::Desc desc{};
    alignas(64) uint32_t stack_node[(s_max + 1) * N];
    alignas(64) uint32_t stack_tmax[(s_max + 1) * N];  // float bits
  };
  int next = 0;

  // One iteration of the loop on packet pk; false once it has no ray left.
  auto step = [&](Packet & pk) __attribute__((always_inline)) {
    F &cx = pk.cx, &cy = pk.cy, &cz = pk.cz, &bx = pk.bx, &by = pk.by, &bz = pk.bz;
    F &px = pk.px, &py = pk.py, &pz = pk.pz, &t_min = pk.t_min, &t_max = pk.t_max, &h = pk.h;
    F& sexp = pk.sexp;
    U &parent = pk.parent, &idx = pk.idx, &flip = pk.flip;
    I &scale = pk.scale, &slot = pk.slot;
    [[maybe_unused]] I& stop = pk.stop;
    typename VP::Desc& desc = pk.desc;
    uint32_t* stack_node = pk.stack_node;
    uint32_t* stack_tmax = pk.stack_tmax;
    // Refill the lanes from the queue, in order, once every lane is idle:
    // the packet is then the queue's next 16 (8) rays, a 4x4 (4x2) pixel
    // block of camera rays whose lanes read the same nodes. Refilling lanes
    // as they finish (after N/4 or N/2 idle lanes) keeps more lanes busy but
    // mixes rays at different depths, whose gathers miss the caches
    // independently: measured 10-25 % slower (docs/BENCHMARKS.md).
    uint32_t idle = L::bits(slot < 0);
    if (next < q.count && (std::popcount(idle) >= kRefillLanes || idle == L::kAll)) {
      const int avail = q.count - next;
      if (std::popcount(idle) > avail) idle = _pdep_u32((1u << avail) - 1, idle);
      cx = L::expand(cx, idle, q.cx + next), cy = L::expand(cy, idle, q.cy + next);
      cz = L::expand(cz, idle, q.cz + next);
      bx = L::expand(bx, idle, q.bx + next), by = L::expand(by, idle, q.by + next);
      bz = L::expand(bz, idle, q.bz + next);
      px = L::expand(px, idle, q.px + next), py = L::expand(py, idle, q.py + next);
      pz = L::expand(pz, idle, q.pz + next);
      t_min = L::expand(t_min, idle, q.t_min + next);
      t_max = L::expand(t_max, idle, q.t_max + next);
      h = L::expand(h, idle, q.h + next);
      flip = L::expand(flip, idle, q.flip + next);
      idx = L::expand(idx, idle, q.idx + next);
      // The lanes refilled, as a lane mask, and their queue slots next, next + 1, ...
      const I fresh = ((L::template splat<I>(1) << lane) & int32_t(idle)) != 0;
      slot = L::expand(slot, idle, kSequence.data() + next);
      if constexpr (kDeep) {
        parent = L::expand(parent, idle, q.parent + next);
        scale = L::expand(scale, idle, q.scale + next);
        stop = L::expand(stop, idle, q.stop + next);
        sexp = fresh ? L::as_f((U)((scale - s_max + 127) << 23)) : sexp;  // exact exp2
      } else {
        parent = fresh ? L::template splat<U>(nodes.root()) : parent;
        scale = fresh ? L::template splat<I>(s_max - 1) : scale;
        sexp = fresh ? L::template splat<F>(0.5f) : sexp;
      }
      vp.forget(&desc, fresh);
      next += std::popcount(idle);
    }
    const I active = slot >= 0;
    if (L::bits(active) == 0) return false;

    // Fetch the parent where the cached copy is stale (ADVANCE keeps it).
    const I stale = active & ~vp.fetched(desc);
    if (L::bits(stale) != 0) vp.fetch(&desc, stale, parent, scale);

    // Maximum t of the cube: the planes through its exit corner.
    const F tx_corner = L::fma(px, cx, -bx);
    const F ty_corner = L::fma(py, cy, -by);
    const F tz_corner = L::fma(pz, cz, -bz);
    const F tc_max = L::min(L::min(tx_corner, ty_corner), tz_corner);

    const U c = idx ^ flip;
    const I valid = active & vp.valid(desc, c) & (t_min <= t_max);
    I push{}, done{};
    if (L::bits(valid) != 0) {
      // LOD termination (the same mul and add as the scalar loop).
      const I lod = valid & (tc_max * size_coef + size_bias >= sexp);
      const I inside = valid & ~lod;
      F tv_max = L::min(t_max, tc_max);
      if constexpr (VP::kContours)
        if (contours)
          lane_contours(vp, q, desc, inside, c, parent, slot, cx, cy, cz, tx_corner, ty_corner,
                        tz_corner, sexp, &t_min, &tv_max);
      const I intersect = inside & (t_min <= tv_max);
      const I leaf = intersect & vp.leaf(desc, c, scale);
      push = intersect & ~leaf;
      const I hit = lod | leaf;
      if (const uint32_t hb = L::bits(hit); hb != 0) {
        // Hits: the loop state at the cube (cast_octree's epilogue runs in
        // the caller). CastStop: kLeaf = 1, kLod = 2.
        for (uint32_t b = hb; b != 0; b &= b - 1) {
          const int l = std::countr_zero(b);
          const int i = q.id[slot[l]];
          out->t[i] = t_min[l];
          out->px[i] = px[l], out->py[i] = py[l], out->pz[i] = pz[l];
          out->parent[i] = parent[l];
          out->idx[i] = idx[l];
          out->scale[i] = scale[l];
          out->stop[i] = lod[l] ? int32_t(CastStop::kLod) : int32_t(CastStop::kLeaf);
        }
        done = hit;
      }
      if (L::bits(push) != 0) {
        // PUSH, with the h threshold per lane.
        const I store = push & (tc_max < h);
        const I at = scale * N + lane;
        L::scatter(stack_node, at, store, parent);
        L::scatter(stack_tmax, at, store, L::as_u(t_max));
        h = push ? tc_max : h;
        const U child = vp.descend(desc, parent, c, scale, push);
        const F half = sexp * 0.5f;
        const F ccx = px + half, ccy = py + half, ccz = pz + half;  // exact: dyadic
        const I mx = L::fma(ccx, cx, -bx) > t_min;
        const I my = L::fma(ccy, cy, -by) > t_min;
        const I mz = L::fma(ccz, cz, -bz) > t_min;
        const U nidx = ((U)mx & 1u) | ((U)my & 2u) | ((U)mz & 4u);
        idx = push ? nidx : idx;
        px = (push & mx) ? ccx : px;
        py = (push & my) ? ccy : py;
        pz = (push & mz) ? ccz : pz;
        scale = push ? scale - 1 : scale;
        sexp = push ? half : sexp;
        t_max = push ? tv_max : t_max;
        parent = push ? child : parent;
        vp.forget(&desc, push);
      }
    }

    // ADVANCE: step to the next sibling along the ray.
    const I advance = active & ~push & ~done;
    if (L::bits(advance) != 0) {
      const I sx = advance & (tx_corner <= tc_max);
      const I sy = advance & (ty_corner <= tc_max);
      const I sz = advance & (tz_corner <= tc_max);
      const U step = ((U)sx & 1u) | ((U)sy & 2u) | ((U)sz & 4u);
      px = sx ? px - sexp : px;
      py = sy ? py - sexp : py;
      pz = sz ? pz - sexp : pz;
      t_min = advance ? tc_max : t_min;
      idx ^= step;
      I miss{};
      // Past the end of the span: a miss (cast_octree: without contours only).
      if (!contours) miss = advance & (t_min > t_max);
      const I pop = advance & ~miss & ((idx & step) != 0u);
      if (L::bits(pop) != 0) {
        // Highest differing bit between the old and new positions = new
        // scale. Its index is the exponent of the (exact, < 2^24) int ->
        // float conversion; larger values only say "left the root".
        const U zero{};
        const U diff = (sx & pop ? L::as_u(px) ^ L::as_u(px + sexp) : zero) |
                       (sy & pop ? L::as_u(py) ^ L::as_u(py + sexp) : zero) |
                       (sz & pop ? L::as_u(pz) ^ L::as_u(pz + sexp) : zero);
        const F fdiff = __builtin_convertvector((I)diff, F);
        const I top = (I)(L::as_u(fdiff) >> 23) - 127;
        // Left the root, or (kDeep) the lane's start cube's parent.
        I left;
        if constexpr (kDeep)
          left = pop & (top >= stop);
        else
          left = pop & (top >= s_max);
        miss |= left;
        const I in = pop & ~left;
        scale = in ? top : scale;
        sexp = in ? L::as_f((U)((scale - s_max + 127) << 23)) : sexp;
        const I at = scale * N + lane;
        parent = L::gather(stack_node, at, in, parent);
        t_max = L::as_f(L::gather(stack_tmax, at, in, L::as_u(t_max)));
        const U sh = (U)scale;
        const U shx = L::as_u(px) >> sh, shy = L::as_u(py) >> sh, shz = L::as_u(pz) >> sh;
        px = in ? L::as_f(shx << sh) : px;
        py = in ? L::as_f(shy << sh) : py;
        pz = in ? L::as_f(shz << sh) : pz;
        idx = in ? (shx & 1u) | ((shy & 1u) << 1) | ((shz & 1u) << 2) : idx;
        h = in ? F{} : h;
        vp.forget(&desc, in);
      }
      done |= miss;  // out->stop stays 0
    }
    slot = done ? L::template splat<I>(-1) : slot;
    return true;
  };

  // One packet at a time: two packets in turn (one computing while the
  // other waits for its gathers) measured no faster (docs/BENCHMARKS.md).
  Packet packet;
  while (step(packet)) {
  }
}

/// The kernel: the root-start loop unless a ray of q starts deep.
template <class VP>
void packet_kernel(const typename VP::Scalar& nodes, const PacketQueue& q, float size_coef,
                   float size_bias, PacketOut* out) {
  if (q.deep)
    packet_loop<VP, true>(nodes, q, size_coef, size_bias, out);
  else
    packet_loop<VP, false>(nodes, q, size_coef, size_bias, out);
}

}  // namespace
}  // namespace voxcast::detail
