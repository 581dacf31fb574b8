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
// from the queue by expand-loads (see refill_at). The first-hit kernel
// (trace_packets) and the any-hit kernel (occluded_packets,
// occluded_anyhit) are this one loop, lane_loop, with different hit sinks.
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

/// 0, 1, 2, ...: the queue slots a refill hands out.
constexpr std::array<int32_t, kPacketQueue> kSequence = [] {
  std::array<int32_t, kPacketQueue> a{};
  for (int i = 0; i < kPacketQueue; ++i) a[size_t(i)] = i;
  return a;
}();

/// The contour slabs (cast_octree's contour_span) of the lanes of `inside`
/// whose child c has one, narrowing t_min and tv_max lane by lane; shared by
/// lane loop (q: its queue, whose dx, dy, dz are the rays' unmirrored
/// directions).
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

/// The lane loop shared by the first-hit and the any-hit kernel:
/// cast_octree<P, false, false> on every ray of q (no region, no counters).
/// Each ray starts at its queue state: the root, or (q.deep) the node
/// q.parent at loop scale q.scale with its lane stack above that scale
/// copied from q.stack_node / q.stack_tmax, so that a POP past the start
/// node resumes exactly where the scalar loop would. `on_hit(l, slot, lod)`
/// is called for each lane l that stops at a cube (slot: its ray in q; lod:
/// a LOD stop rather than a leaf), with the loop state in the returned
/// references; the lane then ends (the any-hit early exit is this same
/// exit: an occlusion ray needs nothing after its first hit).
template <class VP, class OnHit>
[[gnu::always_inline]] inline void lane_loop(const typename VP::Scalar& nodes, const PacketQueue& q,
                                             float size_coef, float size_bias, OnHit&& on_hit) {
  constexpr int N = VP::N;
  constexpr int s_max = kOctreeMaxScale;
  using L = Lanes<N>;
  using F = typename L::F;
  using I = typename L::I;
  using U = typename L::U;
  const VP vp(nodes);
  const bool contours = may_narrow_spans(nodes);  // the loop's early miss exit when false
  // Refill the lanes from the queue, in order, once every lane is idle
  // (q.refill_lanes 0): the packet is then the queue's next 16 (8) rays, a
  // 4x4 (4x2) pixel block of camera or shadow rays, whose lanes read the
  // same nodes. Refilling lanes as they finish (after N/4 or N/2 idle
  // lanes) keeps more lanes busy but mixes rays at different depths, whose
  // gathers miss the caches independently: measured 10-25 % slower for
  // those rays (docs/BENCHMARKS.md "Packet casters", "Occlusion packets").
  // For the AO rays of one point per packet, whose lengths differ most, a
  // refill at N/4 idle lanes measured faster (q.refill_lanes,
  // docs/BENCHMARKS.md "Occlusion packets: the fold and the per-ray deep
  // start", "AO rays: refill at a quarter").
  const int refill_at = q.refill_lanes > 0 && q.refill_lanes < N ? q.refill_lanes : N;
  const I lane = L::iota();

  // Lane state (cast_octree's locals; idle lanes have slot < 0) and the
  // lanes' stacks, [scale][lane].
  F cx{}, cy{}, cz{}, bx{}, by{}, bz{};
  F px{}, py{}, pz{}, t_min{}, t_max{}, h{};
  F sexp = L::template splat<F>(0.5f);
  U parent{}, idx{}, flip{};
  I scale = L::template splat<I>(s_max - 1);
  I slot = L::template splat<I>(-1);  // the lane's ray in q
  typename VP::Desc desc{};
  alignas(64) uint32_t stack_node[(s_max + 1) * N];
  alignas(64) uint32_t stack_tmax[(s_max + 1) * N];  // float bits
  int next = 0;

  // PUSH in the lanes of m (cast_octree), after the stack write: into the
  // child the ray enters first (the upper half, mirrored, on each axis whose
  // center plane is not crossed yet at t_min), one scale down, the span
  // ending at tv_max, the child's node.
  auto push_lanes = [&](I m, F tv_max, U child) __attribute__((always_inline)) {
    const F half = sexp * 0.5f;
    const F ccx = px + half, ccy = py + half, ccz = pz + half;  // exact: dyadic
    const I mx = L::fma(ccx, cx, -bx) > t_min;
    const I my = L::fma(ccy, cy, -by) > t_min;
    const I mz = L::fma(ccz, cz, -bz) > t_min;
    idx = m ? ((U)mx & 1u) | ((U)my & 2u) | ((U)mz & 4u) : idx;
    px = (m & mx) ? ccx : px;
    py = (m & my) ? ccy : py;
    pz = (m & mz) ? ccz : pz;
    scale = m ? scale - 1 : scale;
    sexp = m ? half : sexp;
    t_max = m ? tv_max : t_max;
    parent = m ? child : parent;
  };

  for (;;) {
    uint32_t idle = L::bits(slot < 0);
    if (next < q.count && (std::popcount(idle) >= refill_at || idle == L::kAll)) {
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
      if (q.deep) {
        parent = L::expand(parent, idle, q.parent + next);
        scale = L::expand(scale, idle, q.scale + next);
        // exp2(scale - s_max), exact (the scalar loop's scale_exp2).
        sexp = fresh ? L::as_f((U)((scale - s_max + 127) << 23)) : sexp;
        // The stack rows above each lane's start: the scalar loop's PUSHes
        // on the way down (rows of shallower starts are subsets, so the
        // loop ends at the deepest start).
        for (int s = s_max - 1; s > 0; --s) {
          const I rows = fresh & (scale < s);
          if (L::bits(rows) == 0) break;
          U* node_row = reinterpret_cast<U*>(stack_node + s * N);
          U* tmax_row = reinterpret_cast<U*>(stack_tmax + s * N);
          *node_row = rows ? L::expand(U{}, idle, q.stack_node[s] + next) : *node_row;
          *tmax_row = rows ? L::as_u(L::expand(F{}, idle, q.stack_tmax[s] + next)) : *tmax_row;
        }
      } else {
        parent = fresh ? L::template splat<U>(nodes.root()) : parent;
        scale = fresh ? L::template splat<I>(s_max - 1) : scale;
        sexp = fresh ? L::template splat<F>(0.5f) : sexp;
        if (q.path_width == N) {
          // The packet's shared path (PacketQueue::path_*): the loop's PUSHes
          // along it, all lanes at once, each lane as long as the loop
          // itself would PUSH into the path's next cube (its child position,
          // no LOD stop, a span left non-empty by the cube and its contour;
          // the cubes are present, not leaves). No fetch: the path holds the
          // nodes and contour values.
          const int p = next / N;  // whole packets (refill_lanes 0): next is a multiple of N
          I follow = fresh;
          float side = 0.5f;
          for (int j = 0; j < q.path_levels[p]; ++j, side *= 0.5f) {
            const int s = s_max - 1 - j;  // the following lanes' scale
            const float* lo = q.path_lo[p][j];
            // The cube's mirrored min corner per lane (flip bit a: axis a mirrored).
            const F mx = (flip & 1u) != 0u ? L::template splat<F>(3.f - side - lo[0])
                                           : L::template splat<F>(lo[0]);
            const F my = (flip & 2u) != 0u ? L::template splat<F>(3.f - side - lo[1])
                                           : L::template splat<F>(lo[1]);
            const F mz = (flip & 4u) != 0u ? L::template splat<F>(3.f - side - lo[2])
                                           : L::template splat<F>(lo[2]);
            follow &= (px == mx) & (py == my) & (pz == mz);
            const F tx = L::fma(px, cx, -bx), ty = L::fma(py, cy, -by), tz = L::fma(pz, cz, -bz);
            const F tc_max = L::min(L::min(tx, ty), tz);
            F t_lo = t_min, tv_max = L::min(t_max, tc_max);
            follow &= (t_min <= t_max) & ~(tc_max * size_coef + size_bias >= sexp);
            if (q.path_has_contour[p][j])  // cast_octree's contour_span, lane by lane
              for (uint32_t b = L::bits(follow); b != 0; b &= b - 1) {
                const int l = std::countr_zero(b), k = slot[l];
                float tl = t_lo[l], tv = tv_max[l];
                contour_span(q.path_contour[p][j], {cx[l], cy[l], cz[l]},
                             {q.dx[k], q.dy[k], q.dz[k]}, tx[l], ty[l], tz[l], side, &tl, &tv);
                t_lo[l] = tl, tv_max[l] = tv;
              }
            follow &= t_lo <= tv_max;
            if (L::bits(follow) == 0) break;
            t_min = follow ? t_lo : t_min;
            U* node_row = reinterpret_cast<U*>(stack_node + s * N);
            U* tmax_row = reinterpret_cast<U*>(stack_tmax + s * N);
            *node_row = follow ? parent : *node_row;
            *tmax_row = follow ? L::as_u(t_max) : *tmax_row;
            h = follow ? tc_max : h;
            push_lanes(follow, tv_max, L::template splat<U>(q.path_node[p][j]));
          }
        }
      }
      vp.forget(&desc, fresh);
      next += std::popcount(idle);
    }
    const I active = slot >= 0;
    if (L::bits(active) == 0) return;

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
      done = lod | leaf;
      // Hits: the loop state at the cube (cast_octree's epilogue runs in
      // the caller).
      for (uint32_t b = L::bits(done); b != 0; b &= b - 1) {
        const int l = std::countr_zero(b);
        on_hit(l, slot[l], lod[l] != 0, t_min, px, py, pz, parent, idx, scale);
      }
      if (L::bits(push) != 0) {
        // PUSH, with the h threshold per lane.
        const I store = push & (tc_max < h);
        const I at = scale * N + lane;
        L::scatter(stack_node, at, store, parent);
        L::scatter(stack_tmax, at, store, L::as_u(t_max));
        h = push ? tc_max : h;
        push_lanes(push, tv_max, vp.descend(desc, parent, c, scale, push));
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
        const I left = pop & (top >= s_max);
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
      done |= miss;  // no on_hit: a miss
    }
    slot = done ? L::template splat<I>(-1) : slot;
  }
}

/// The first-hit kernel: out's stop/t/scale/parent/idx/pos of each ray of q
/// that stopped at a cube (CastStop: kLeaf = 1, kLod = 2); other rays' stop
/// stays as the caller set it (0, a miss).
template <class VP>
void packet_kernel(const typename VP::Scalar& nodes, const PacketQueue& q, float size_coef,
                   float size_bias, PacketOut* out) {
  lane_loop<VP>(
      nodes, q, size_coef, size_bias,
      [&](int l, int k, bool lod, const auto& t_min, const auto& px, const auto& py, const auto& pz,
          const auto& parent, const auto& idx, const auto& scale) __attribute__((always_inline)) {
        const int i = q.id[k];
        out->t[i] = t_min[l];
        out->px[i] = px[l], out->py[i] = py[l], out->pz[i] = pz[l];
        out->parent[i] = parent[l];
        out->idx[i] = idx[l];
        out->scale[i] = scale[l];
        out->stop[i] = lod ? int32_t(CastStop::kLod) : int32_t(CastStop::kLeaf);
      });
}

/// The any-hit kernel: hit[q.id[k]] = 1 for each ray k of q that stops at a
/// cube (leaf or LOD), other entries untouched; no loop state is kept.
template <class VP>
void anyhit_kernel(const typename VP::Scalar& nodes, const PacketQueue& q, float size_coef,
                   float size_bias, uint8_t* hit) {
  lane_loop<VP>(
      nodes, q, size_coef, size_bias,
      [&](int, int k, bool, const auto&, const auto&, const auto&, const auto&, const auto&,
          const auto&, const auto&) __attribute__((always_inline)) { hit[q.id[k]] = 1; });
}

}  // namespace

/// Defines the kernels name_packet_kernel_isa and name_anyhit_kernel_isa
/// (core/packet_kernels.hpp) of scalar policy Nodes over vector policy VP:
/// one line in each kernel translation unit.
#define VOXCAST_DEFINE_PACKET_KERNELS(name, isa, Nodes, VP)                                  \
  void name##_packet_kernel_##isa(const Nodes& nodes, const PacketQueue& q, float size_coef, \
                                  float size_bias, PacketOut* out) {                         \
    packet_kernel<VP>(nodes, q, size_coef, size_bias, out);                                  \
  }                                                                                          \
  void name##_anyhit_kernel_##isa(const Nodes& nodes, const PacketQueue& q, float size_coef, \
                                  float size_bias, uint8_t* hit) {                           \
    anyhit_kernel<VP>(nodes, q, size_coef, size_bias, hit);                                  \
  }

}  // namespace voxcast::detail
