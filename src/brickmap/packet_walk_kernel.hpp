#pragma once
// The brickmap lane walk (packet_walk.hpp), included only by the per-ISA
// translation units. Each lane runs traverse.cpp's Walker<false, false> for
// a footprint of 0 (no LOD stop: the levels below the root are fixed,
// PacketWorld::level) with the branches turned into lane masks, and the
// same float operations in the same order (-ffp-contract=off), so the same
// planes, t values, tie breaks and start cells:
//   test     the child the lane's DDA is in: pyramid node (bricks != 0, with
//            the cut-off in y), brickgrid cell (!= 0) or voxel bit (gathers);
//   hit      an occupied voxel: the lane ends with its Found;
//   push     an occupied node or resident cell: begin() of its children
//            (start_cell, start_cell_exact where t == start_t), after the
//            cell-box test of visit_cells (a lane that misses the box steps
//            on instead);
//   advance  step_axis (argmin3's tie break); a lane leaving its parent
//            pops to the parent's DDA (the parent's c from the child's lo,
//            its exit planes recomputed: plane_t of the same coordinates)
//            and advances again; past t1 or out of the root the lane misses.
//   jump     an empty cell with a clearance k > 1: Walker::jump, out of the
//            cube of radius k - 1 in one step (the crossings on the other
//            axes taken in (t, axis) order, lane loops until none is left).
// A not-resident cell ends the lane as kPacketScalar. The walk's brick-slice
// skip (brick_slices) is left out: an exact skip, the same hits without it.
// Lanes are filled 16 (8) rays at a time, a 4x4 (4x2) pixel block.
#include <immintrin.h>

#include <bit>
#include <cmath>
#include <cstring>

#include "brickmap/packet_walk.hpp"
#include "core/octree_packet_kernel.hpp"

namespace voxcast::brickmap::detail {
namespace {

template <int N>
struct WalkLanes : ::voxcast::detail::Lanes<N> {
  using L0 = ::voxcast::detail::Lanes<N>;
  using F = typename L0::F;
  using I = typename L0::I;
  using U = typename L0::U;
  /// The 4 bytes at base + idx in the lanes of m, src elsewhere.
  static U gather_bytes(const uint8_t* base, I idx, I m, U src) {
    if constexpr (N == 16)
      return (U)_mm512_mask_i32gather_epi32((__m512i)src, L0::bits(m), (__m512i)idx, base, 1);
    else
      return (U)_mm256_mask_i32gather_epi32((__m256i)src, (const int*)base, (__m256i)idx,
                                            (__m256i)m, 1);
  }
  // floor (kMode _MM_FROUND_TO_NEG_INF) or ceil (_MM_FROUND_TO_POS_INF).
  template <int kMode>
  static F round(F x) {
    if constexpr (N == 16)
      return (F)_mm512_mask_roundscale_ps((__m512)x, 0xFFFF, (__m512)x, kMode | _MM_FROUND_NO_EXC);
    else
      return (F)_mm256_round_ps((__m256)x, kMode | _MM_FROUND_NO_EXC);
  }
};

template <int N>
void packet_walk(const PacketWorld& w, const PacketRays& q, uint8_t* status, PacketFound* out) {
  using L = WalkLanes<N>;
  using F = typename L::F;
  using I = typename L::I;
  using U = typename L::U;
  const I lane = L::iota();
  const int D = w.depths;
  // Per depth: the child level, the ratio to the parent level, the child's
  // side in grid units and its 1 / side (exact powers of two), the top
  // coordinate of its level.
  int ratio_of[kPacketMaxDepth], top_of[kPacketMaxDepth];
  float side_of[kPacketMaxDepth], inv_side_of[kPacketMaxDepth];
  for (int k = 0; k < D; ++k) {
    ratio_of[k] = w.level[k] - (k ? w.level[k - 1] : 0);
    top_of[k] = (1 << w.level[k]) - 1;
    side_of[k] = float(1 << (w.L - w.level[k]));
    inv_side_of[k] = std::bit_cast<float>(uint32_t(127 - (w.L - w.level[k])) << 23);
  }
  auto load = [](const float* p) {
    F v;
    std::memcpy(&v, p, sizeof v);
    return v;
  };
  for (int base = 0; base < q.count; base += N) {
    I active = lane < (q.count - base);
    F o[3], d[3], inv[3], slack[3];
    I up[3], stp[3];
    for (int a = 0; a < 3; ++a) {
      o[a] = load(q.o[a] + base), d[a] = load(q.d[a] + base);
      inv[a] = load(q.inv[a] + base), slack[a] = load(q.slack[a] + base);
      up[a] = d[a] < 0.f ? I{} : I{} + 1;  // d is never 0 (to_grid)
      stp[a] = up[a] * 2 - 1;
    }
    const F t1 = load(q.t1 + base), start_t = load(q.start_t + base);
    F t = load(q.t0 + base);
    I axis;
    std::memcpy(&axis, q.axis + base, sizeof axis);
    // The lane's DDA (Dda of traverse.cpp) at depth dep (-1: the root, the
    // cube the first push starts from).
    I c[3] = {}, lo[3] = {}, span[3] = {};
    F n[3] = {};
    I dep = I{} - 1, lv{}, ratio{}, brick{};
    F side{};

    // begin() of the children at depth dep + 1 of the lane's cube c.
    auto push = [&](I m) __attribute__((always_inline)) {
      const I nd = dep + 1;
      I nlv{}, nratio{}, ntop{};
      F nside{}, ninv{};
      for (int k = 0; k < D; ++k) {
        const I mk = m & (nd == k);
        if (!L::bits(mk)) continue;
        nlv = mk ? w.level[k] : nlv, nratio = mk ? ratio_of[k] : nratio;
        ntop = mk ? top_of[k] : ntop;
        nside = mk ? side_of[k] : nside, ninv = mk ? inv_side_of[k] : ninv;
      }
      I nlo[3], nhi[3], nc[3];
      for (int a = 0; a < 3; ++a) {
        nlo[a] = c[a] << nratio;
        const I h = nlo[a] + ((I{} + 1) << nratio) - 1;
        nhi[a] = ntop < h ? ntop : h;
        // start_cell: floor (or ceil - 1) of the position, clamped.
        const F p = (o[a] + d[a] * t) * ninv;
        const F f = up[a] != 0 ? L::template round<_MM_FROUND_TO_NEG_INF>(p)
                               : L::template round<_MM_FROUND_TO_POS_INF>(p) - 1.f;
        const F flo = __builtin_convertvector(nlo[a], F), fhi = __builtin_convertvector(nhi[a], F);
        const F mx = f < flo ? flo : f;
        nc[a] = __builtin_convertvector(fhi < mx ? fhi : mx, I);
      }
      // start_cell_exact where the lane starts at its beam's region.
      for (uint32_t b = L::bits(m & (t == start_t)); b != 0; b &= b - 1) {
        const int l = std::countr_zero(b);
        for (int a = 0; a < 3; ++a) {
          const int s = stp[a][l], u = up[a][l];
          const int fwd = s > 0 ? nhi[a][l] : nlo[a][l], back = s > 0 ? nlo[a][l] : nhi[a][l];
          const float oa = o[a][l], ia = inv[a][l], sd = nside[l], tl = t[l];
          int cc = nc[a][l];
          while (cc != fwd && (float(cc + u) * sd - oa) * ia <= tl) cc += s;
          while (cc != back && (float(cc + 1 - u) * sd - oa) * ia > tl) cc -= s;
          nc[a][l] = cc;
        }
      }
      for (int a = 0; a < 3; ++a) {
        const F nn = (__builtin_convertvector(nc[a] + up[a], F) * nside - o[a]) * inv[a];
        n[a] = m ? nn : n[a];
        c[a] = m ? nc[a] : c[a];
        lo[a] = m ? nlo[a] : lo[a];
        span[a] = m ? nhi[a] - nlo[a] : span[a];
      }
      dep = m ? nd : dep, lv = m ? nlv : lv, ratio = m ? nratio : ratio;
      side = m ? nside : side;
    };
    push(active);

    while (L::bits(active)) {
      // ---- test the lanes' current children ----
      I occ{};
      U cellv{};
      for (int k = 0; k < D; ++k) {
        if (w.level[k] >= w.B) break;
        const I mk = active & (dep == k) & ((U)c[1] < w.node_dim_y[k]);
        if (!L::bits(mk)) continue;
        const I idx = c[0] + int32_t(w.node_dim[k]) * (c[1] + int32_t(w.node_dim_y[k]) * c[2]);
        const U g = L::gather(w.nodes[k], idx * 2, mk, U{});
        occ |= mk & (g != 0);
      }
      const I is_cell = active & (lv == w.B);
      const I mc = is_cell & ((U)c[1] < w.dims[1]);
      if (L::bits(mc)) {
        const I idx = c[0] + int32_t(w.dims[0]) * (c[1] + int32_t(w.dims[1]) * c[2]);
        cellv = L::gather(w.cells, idx, mc, U{});
        occ |= mc & (cellv != 0);
      }
      const I is_vox = active & (lv == w.L);
      if (L::bits(is_vox)) {
        const I x = c[0] & 7, y = c[1] & 7, z = c[2] & 7;
        const U word = L::gather(w.bricks, brick * 18 + z * 2 + (y >> 2), is_vox, U{});
        const I solid = is_vox & (((word >> (U)(x + (y & 3) * 8)) & 1u) != 0);
        for (uint32_t b = L::bits(solid); b != 0; b &= b - 1) {
          const int l = std::countr_zero(b);
          const int ax = axis[l];
          status[base + l] = kPacketHit;
          out[base + l] = {
              t[l],
              ax * 2 + up[ax][l],
              {c[0][l], c[1][l], c[2][l]},
              uint64_t(uint32_t(brick[l])) << 9 | uint32_t(x[l] | y[l] << 3 | z[l] << 6)};
        }
        active &= ~solid;
        occ &= ~is_vox;
      }
      // A not-resident brick: the scalar walk answers (requests, LOD color).
      const I scalar = occ & is_cell & ((cellv >> 30) != 1u);
      for (uint32_t b = L::bits(scalar); b != 0; b &= b - 1)
        status[base + std::countr_zero(b)] = kPacketScalar;
      active &= ~scalar;
      occ &= ~scalar;
      // visit_cells' cell-box test (World::cell_box) before the cells of a
      // node of level B - kCellBoxLevel: a lane missing the box steps on.
      const I boxed = occ & (lv == w.B - 3) & (dep + 1 < D);
      if (L::bits(boxed)) {
        const I idx =
            c[0] + int32_t(w.dims[0] >> 3) * (c[1] + int32_t((w.dims[1] + 7) >> 3) * c[2]);
        const U box = L::gather(w.cell_box, idx, boxed, U{});
        F t0 = t, te = t1;
        for (int a = 0; a < 3; ++a) {
          const I cell0 = c[a] << 3;
          const F blo =
              __builtin_convertvector((cell0 + (I)(box >> (3 * a) & 7u)) << 3, F) - slack[a];
          const F bhi =
              __builtin_convertvector((cell0 + (I)(box >> (9 + 3 * a) & 7u) + 1) << 3, F) +
              slack[a];
          const F ta = (blo - o[a]) * inv[a], tb = (bhi - o[a]) * inv[a];
          const F mn = tb < ta ? tb : ta, mx = ta < tb ? tb : ta;
          t0 = t0 < mn ? mn : t0;
          te = mx < te ? mx : te;
        }
        occ &= ~(boxed & ~(t0 <= te));
      }
      brick = is_cell & occ ? (I)(cellv & 0xFFFFFFu) : brick;
      I adv = active & ~occ;
      // visit_cells' jump: an empty cell of clearance k > 1 leaves the
      // cube of radius k - 1 around it (clipped to the parent) in one step.
      I leave_jump{};
      const I empty = mc & (cellv == 0u);
      if (L::bits(empty)) {
        const I idx = c[0] + int32_t(w.dims[0]) * (c[1] + int32_t(w.dims[1]) * c[2]);
        const I at = idx < w.clearance_last ? idx : I{} + w.clearance_last;
        const U word = L::gather_bytes(w.clearance, at, empty, U{});
        const I radius = (I)((word >> (U)((idx - at) * 8)) & 0xFFu) - 1;
        const I jump = empty & (radius > 0);
        if (L::bits(jump)) {
          F tn[3];
          I tc[3];
          for (int a = 0; a < 3; ++a) {
            const I far = c[a] + stp[a] * radius, hi = lo[a] + span[a];
            const I mx = far < lo[a] ? lo[a] : far;
            tc[a] = hi < mx ? hi : mx;
            tn[a] = (__builtin_convertvector(tc[a] + up[a], F) * side - o[a]) * inv[a];
          }
          const I x_le_y = tn[0] <= tn[1];
          const I a0 = x_le_y & (tn[0] <= tn[2]);
          const I a1 = ~x_le_y & (tn[1] <= tn[2]);
          const I ax[3] = {a0 & jump, a1 & jump, ~(a0 | a1) & jump};
          const F tj = a0 ? tn[0] : (a1 ? tn[1] : tn[2]);
          const I aj = a0 ? I{} : (a1 ? I{} + 1 : I{} + 2);
          t = jump ? tj : t;
          axis = jump ? aj : axis;
          I cn[3];
          for (int a = 0; a < 3; ++a) {
            cn[a] = tc[a] + stp[a];
            leave_jump |= ax[a] & ((U)(cn[a] - lo[a]) > (U)span[a]);
          }
          const I end = jump & ~leave_jump & (tj > t1);
          const I ok = jump & ~leave_jump & ~end;
          active &= ~end;
          for (int b = 0; b < 3; ++b) {
            // The cells crossed before (t, A) on the other axes.
            for (I m = ok & ~ax[b];;) {
              m &= (n[b] < t) | ((n[b] == t) & (aj > b));
              if (!L::bits(m)) break;
              c[b] = m ? c[b] + stp[b] : c[b];
              n[b] = m ? (__builtin_convertvector(c[b] + up[b], F) * side - o[b]) * inv[b] : n[b];
            }
          }
          for (int a = 0; a < 3; ++a) {
            const I m = ok & ax[a];
            c[a] = m ? cn[a] : c[a];
            n[a] = m ? (__builtin_convertvector(cn[a] + up[a], F) * side - o[a]) * inv[a] : n[a];
          }
          adv &= ~jump;
        }
      }
      if (L::bits(occ)) push(occ);
      // ---- advance (and pop) the other lanes ----
      while (L::bits(adv | leave_jump)) {
        const I x_le_y = n[0] <= n[1];
        const I a0 = x_le_y & (n[0] <= n[2]);
        const I a1 = ~x_le_y & (n[1] <= n[2]);
        const I a2 = ~(a0 | a1);
        const F tn = a0 ? n[0] : (a1 ? n[1] : n[2]);
        t = adv ? tn : t;
        axis = adv ? (a0 ? I{} : (a1 ? I{} + 1 : I{} + 2)) : axis;
        const I ax[3] = {a0 & adv, a1 & adv, a2 & adv};
        I leave{};
        for (int a = 0; a < 3; ++a) {
          c[a] = ax[a] ? c[a] + stp[a] : c[a];
          leave |= ax[a] & ((U)(c[a] - lo[a]) > (U)span[a]);
        }
        const I end = adv & ~leave & (tn > t1);
        const I ok = adv & ~leave & ~end;
        leave |= leave_jump;
        leave_jump = I{};
        for (int a = 0; a < 3; ++a) {
          const I m = ok & ax[a];
          if (L::bits(m))
            n[a] = m ? (__builtin_convertvector(c[a] + up[a], F) * side - o[a]) * inv[a] : n[a];
        }
        // Past t1, or out of the root's children: a miss.
        active &= ~(end | (leave & (dep == 0)));
        const I pop = leave & (dep > 0);
        adv = pop;
        if (!L::bits(pop)) break;
        // The parent's DDA: its child c is the one the lane's lo came from.
        const I pd = dep - 1;
        I plv{}, pratio{}, ptop{};
        F pside{};
        for (int k = 0; k < D; ++k) {
          const I mk = pop & (pd == k);
          if (!L::bits(mk)) continue;
          plv = mk ? w.level[k] : plv, pratio = mk ? ratio_of[k] : pratio;
          ptop = mk ? top_of[k] : ptop, pside = mk ? side_of[k] : pside;
        }
        for (int a = 0; a < 3; ++a) {
          const I pc = lo[a] >> ratio;
          const I plo = pc >> pratio << pratio;
          const I h = plo + ((I{} + 1) << pratio) - 1;
          const I phi = ptop < h ? ptop : h;
          c[a] = pop ? pc : c[a];
          lo[a] = pop ? plo : lo[a];
          span[a] = pop ? phi - plo : span[a];
          n[a] = pop ? (__builtin_convertvector(pc + up[a], F) * pside - o[a]) * inv[a] : n[a];
        }
        dep = pop ? pd : dep, lv = pop ? plv : lv, ratio = pop ? pratio : ratio;
        side = pop ? pside : side;
      }
    }
  }
}

}  // namespace
}  // namespace voxcast::brickmap::detail
