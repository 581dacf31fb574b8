#pragma once
// The lane-parallel any-hit loop (core/octree_anyhit_caster.hpp explains the
// split, the deep start and why the answers are the scalar caster's).
// Included only by the per-ISA kernel translation units; internal linkage.
//
// The loop body is the first-hit kernel's (core/octree_packet_kernel.hpp:
// the same lane types, vector policies, masks and float operations, so each
// lane computes exactly cast_octree's values), with what an occlusion ray
// does not need taken out and what a deep start needs added:
//  * a lane's start node, scale and exit scale come from the queue (a POP to
//    the exit scale ends the lane as a miss: it left its deep start cube);
//  * a hit only sets the ray's byte (no loop state is kept for an epilogue);
//  * lanes are refilled once every lane is idle, as in the first-hit kernel:
//    the packet is then the queue's next 16 (8) rays, one pixel block's
//    shadow rays or one point's AO rays; refilling as soon as half of the
//    lanes were idle measured no faster (docs/BENCHMARKS.md "Occlusion
//    packets").
#include <immintrin.h>

#include <bit>
#include <cstdint>

#include "core/octree_anyhit_caster.hpp"
#include "core/octree_packet_kernel.hpp"

namespace voxcast::detail {
namespace {

/// kDeep: lanes may start below the root (q.parent / q.scale / q.stop are
/// read); otherwise every lane starts at the root and the exit scale is the
/// constant s_max, which keeps a vector register free in the loop (the
/// deep-capable loop measured ~5 % slower on root-start rays).
template <class VP, bool kDeep>
void anyhit_loop(const typename VP::Scalar& nodes, const AnyHitQueue& q, float size_coef,
                 float size_bias, uint8_t* hit_out) {
  constexpr int N = VP::N;
  constexpr int s_max = kOctreeMaxScale;
  using L = Lanes<N>;
  using F = typename L::F;
  using I = typename L::I;
  using U = typename L::U;
  const VP vp(nodes);
  const bool contours = may_narrow_spans(nodes);  // the loop's early miss exit when false
  constexpr int kRefillLanes = N;                 // see the file comment
  const I lane = L::iota();

  F cx{}, cy{}, cz{}, bx{}, by{}, bz{};
  F px{}, py{}, pz{}, t_min{}, t_max{}, h{};
  F sexp = L::template splat<F>(0.5f);
  U parent{}, idx{}, flip{};
  I scale = L::template splat<I>(s_max - 1);
  [[maybe_unused]] I stop = L::template splat<I>(s_max);
  I slot = L::template splat<I>(-1);  // the lane's ray in q; idle lanes < 0
  typename VP::Desc desc{};
  alignas(64) uint32_t stack_node[(s_max + 1) * N];
  alignas(64) uint32_t stack_tmax[(s_max + 1) * N];  // float bits
  int next = 0;

  for (;;) {
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
      slot = L::expand(slot, idle, kSequence.data() + next);
      const I fresh = ((L::template splat<I>(1) << lane) & int32_t(idle)) != 0;
      if constexpr (kDeep) {
        parent = L::expand(parent, idle, q.parent + next);
        scale = L::expand(scale, idle, q.scale + next);
        stop = L::expand(stop, idle, q.stop + next);
        // exp2(scale - s_max), exact (the scalar loop's scale_exp2).
        sexp = fresh ? L::as_f((U)((scale - s_max + 127) << 23)) : sexp;
      } else {
        parent = fresh ? L::template splat<U>(nodes.root()) : parent;
        scale = fresh ? L::template splat<I>(s_max - 1) : scale;
        sexp = fresh ? L::template splat<F>(0.5f) : sexp;
      }
      vp.forget(&desc, fresh);
      next += std::popcount(idle);
    }
    const I active = slot >= 0;
    if (L::bits(active) == 0) return;

    const I stale = active & ~vp.fetched(desc);
    if (L::bits(stale) != 0) vp.fetch(&desc, stale, parent, scale);

    const F tx_corner = L::fma(px, cx, -bx);
    const F ty_corner = L::fma(py, cy, -by);
    const F tz_corner = L::fma(pz, cz, -bz);
    const F tc_max = L::min(L::min(tx_corner, ty_corner), tz_corner);

    const U c = idx ^ flip;
    const I valid = active & vp.valid(desc, c) & (t_min <= t_max);
    I push{}, done{};
    if (L::bits(valid) != 0) {
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
      for (uint32_t b = L::bits(done); b != 0; b &= b - 1)
        hit_out[q.id[slot[std::countr_zero(b)]]] = 1;
      if (L::bits(push) != 0) {
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
      if (!contours) miss = advance & (t_min > t_max);
      const I pop = advance & ~miss & ((idx & step) != 0u);
      if (L::bits(pop) != 0) {
        const U zero{};
        const U diff = (sx & pop ? L::as_u(px) ^ L::as_u(px + sexp) : zero) |
                       (sy & pop ? L::as_u(py) ^ L::as_u(py + sexp) : zero) |
                       (sz & pop ? L::as_u(pz) ^ L::as_u(pz + sexp) : zero);
        const F fdiff = __builtin_convertvector((I)diff, F);
        const I top = (I)(L::as_u(fdiff) >> 23) - 127;
        // Left the root, or the deep start's cube (nothing can be hit after).
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
      done |= miss;
    }
    slot = done ? L::template splat<I>(-1) : slot;
  }
}

/// The kernel: the root-start loop unless a ray of q starts deep.
template <class VP>
void anyhit_kernel(const typename VP::Scalar& nodes, const AnyHitQueue& q, float size_coef,
                   float size_bias, uint8_t* hit) {
  if (q.deep)
    anyhit_loop<VP, true>(nodes, q, size_coef, size_bias, hit);
  else
    anyhit_loop<VP, false>(nodes, q, size_coef, size_bias, hit);
}

}  // namespace
}  // namespace voxcast::detail
