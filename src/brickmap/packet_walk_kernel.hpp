#pragma once
// The brickmap lane walk (packet_walk.hpp), included only by the per-ISA
// translation units. Each lane runs traverse.cpp's Walker<false, false>
// with the branches turned into lane masks, and the same float operations
// in the same order (-ffp-contract=off), so the same planes, t values, tie
// breaks, start cells and LOD decisions. A lane's state is one DDA (the
// children at level lv of a cube) and `chain`, a bit per level of the cubes
// it is inside: the parent is the highest level in it, so a pop needs no
// stack of DDAs.
//   test     the child the lane's DDA is in: pyramid node (bricks != 0, with
//            the cut-off in y; one masked gather per level present), brickgrid
//            cell (!= 0), or inside a brick the bits of the voxel or (LOD)
//            2^s block (block_solid: one mask word per z slice);
//   stop     an occupied voxel, or an occupied cube whose side fits the
//            footprint at its exit (lod_stop): the lane ends with its Found
//            (a node's, the brick's or the cell's LOD color);
//   push     an occupied node, resident cell or block: begin() of its
//            children at child_level() (start_cell, start_cell_exact where
//            t == start_t), after the cell-box test of visit_cells (a lane
//            that misses the box steps on instead);
//   advance  step_axis (argmin3's tie break); a lane leaving its parent
//            pops to the parent's DDA (the parent's c from the child's lo,
//            its exit planes recomputed: plane_t of the same coordinates)
//            and advances again; past t1 or out of the root the lane misses.
//   jump     an empty cell (or node of level B - 3: World::node_clearance)
//            with a clearance k > 1: Walker::jump, out of the
//            cube of radius k - 1 in one step (the crossings on the other
//            axes taken in (t, axis) order, lane loops until none is left).
//   slices   a push into a brick's voxels: visit_voxels' brick-slice test
//            (brick_slices: a brick's 8 slices in 8 lanes, two lanes' rays
//            per 16-lane pass) and slice entry (enter_slice): a lane
//            whose ray meets no solid voxel of the brick steps on, the
//            others start at the first slice ahead that may hold a hit.
//            The same for a push into a brick's 2^3 blocks (visit_pairs:
//            the mask dilated to whole blocks, slabs of 2 slices).
// A not-resident cell (no LOD stop) ends the lane as kPacketScalar, a lane
// found outside the grid (a fault of the walk) as kPacketFault. Lanes
// are filled 16 (8) rays at a time, a 4x4 (4x2) pixel block.
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
  // Variable shifts per lane; a count of 32 or more gives 0 (vpsllvd,
  // vpsrlvd), which the slice test's row masks rely on.
  static U sllv(U v, I n) {
    if constexpr (N == 16)
      return (U)_mm512_maskz_sllv_epi32(
          0xFFFF, (__m512i)v, (__m512i)n);  // maskz: no undefined source (-Wmaybe-uninitialized)
    else
      return (U)_mm256_sllv_epi32((__m256i)v, (__m256i)n);
  }
  static U srlv(U v, I n) {
    if constexpr (N == 16)
      return (U)_mm512_maskz_srlv_epi32(0xFFFF, (__m512i)v, (__m512i)n);
    else
      return (U)_mm256_srlv_epi32((__m256i)v, (__m256i)n);
  }
  /// traverse.cpp's argmin3 in lanes: the nearest of three exit plane t
  /// with its tie break (x, then y, then z), as the axis masks, the t and
  /// the axis index. One place for the rule the jump and the advance share.
  struct Nearest {
    I on[3];
    F t;
    I axis;
  };
  [[gnu::always_inline]] static Nearest nearest(const F v[3]) {
    const I x_le_y = v[0] <= v[1];
    const I a0 = x_le_y & (v[0] <= v[2]);
    const I a1 = ~x_le_y & (v[1] <= v[2]);
    return {
        {a0, a1, ~(a0 | a1)}, a0 ? v[0] : (a1 ? v[1] : v[2]), a0 ? I{} : (a1 ? I{} + 1 : I{} + 2)};
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
  const int BL = w.B, LL = w.L;
  auto load = [](const float* p) {
    F v;
    std::memcpy(&v, p, sizeof v);
    return v;
  };
  // 2^k and 2^-k as floats from the exponent bits (k in lanes), exact.
  auto pow2 = [](I k) { return L::as_f((U)((k + 127) << 23)); };
  // The highest set bit of each lane (values below 2^24: exact in float).
  auto high_bit = [](I v) { return (I)(L::as_u(__builtin_convertvector(v, F)) >> 23) - 127; };
  auto to_f = [](I v) { return __builtin_convertvector(v, F); };
  // Walker::lod_stop(level, exit) in lanes: side_world(level) <= footprint.
  auto lod_stop = [&](I level, F exit) {
    if (!w.lod_on) return I{};
    const F sw = w.voxel_world * pow2(LL - level);
    return (I)(sw <= w.lod_size0 + w.lod_per_t * exit);
  };
  // The color of the pyramid node (level, c) (PyramidNode's second word).
  auto node_color = [&](int level, int32_t x, int32_t y, int32_t z) {
    const int p = BL - level;
    const int32_t idx = x + int32_t(w.node_dim[p]) * (y + int32_t(w.node_dim_y[p]) * z);
    return w.nodes[p][idx * 2 + 1];
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
    // The t at which a lane leaves child cc (side sd) along axis a: the
    // plane of its far face (plane_t of traverse.cpp, the same operations).
    auto exit_t = [&](int a, I cc, F sd) { return (to_f(cc + up[a]) * sd - o[a]) * inv[a]; };
    const F t1 = load(q.t1 + base), start_t = load(q.start_t + base);
    const F exit0 = load(q.exit + base);
    const I octant = up[0] | up[1] << 1 | up[2] << 2;  // World::node_clearance's octant
    F t = load(q.t0 + base);
    I axis;
    std::memcpy(&axis, q.axis + base, sizeof axis);
    // The lane's DDA (Dda of traverse.cpp): children at level lv of the
    // cube at the highest level in `chain` (a bit per level of the cubes
    // the lane is inside, the root's bit 0 always set), the child c. Before
    // the first push: "inside" nothing, at the root cube (level 0, c = 0).
    I c[3] = {}, lo[3] = {}, span[3] = {};
    F n[3] = {};
    I lv{}, chain{}, brick{};

    // brick_slices (traverse.cpp) for the rays of lanes la and lb (16
    // lanes; 8 lanes: la's only, lb == la): bit k (la) and bit 8 + k (lb)
    // set when z slice k of the lane's brick may hold a solid voxel the ray
    // meets between t and te (the same boxes and slack: a superset test).
    // Lane j takes slice j & 7 of la's brick (j < 8) or lb's, and both
    // half words of the slice (rows 0-3 and 4-7); the ray's values come to
    // the lanes by permutes. One pass for two rays (one for one with 8
    // lanes), instead of a pass per ray with a lane per half word.
    auto brick_slices = [&](int la, int lb, F te, I dil) {
      const I sel = lane < 8 ? I{} + la : I{} + lb;
      const auto pick = [&](auto v) {
        using V = decltype(v);
        if constexpr (N == 16)
          return (V)_mm512_maskz_permutexvar_epi32(0xFFFF, (__m512i)sel, (__m512i)v);
        else
          return (V)_mm256_permutevar8x32_epi32((__m256i)v, (__m256i)sel);
      };
      const F k = to_f(lane & 7);
      F b3[3];  // the ray origin relative to the brick's corner
      for (int a = 0; a < 3; ++a) b3[a] = pick(o[a]) - to_f(pick(c[a]) << 3);
      const F sz = pick(slack[2]), iz = pick(inv[2]);
      const F ta = (k - sz - b3[2]) * iz;
      const F tb = (k + (1.f + sz) - b3[2]) * iz;
      const F lo = L::max(L::min(ta, tb), pick(t)), hi = L::min(L::max(ta, tb), pick(te));
      I first[2], last[2];
      for (int a = 0; a < 2; ++a) {
        const F da = pick(d[a]), sa = pick(slack[a]);
        const F p0 = b3[a] + da * lo, p1 = b3[a] + da * hi;
        const F f = L::template round<_MM_FROUND_TO_NEG_INF>(L::min(p0, p1) - sa);
        const F g = L::template round<_MM_FROUND_TO_NEG_INF>(L::max(p0, p1) + sa);
        first[a] = __builtin_convertvector(L::min(L::max(f, F{}), F{} + 7.f), I);
        last[a] = __builtin_convertvector(L::min(L::max(g, F{}), F{} + 7.f), I);
      }
      // Bits first..last of x in every row byte; rows first..last of y in
      // the low half word (rows 0-3) and the high one (rows 4-7); shifts of
      // 32 or more give 0.
      const U row =
          ((U{} + 0xFFu) << (U)first[0] & (U{} + 0xFFu) >> (U)(7 - last[0])) * 0x01010101u;
      const I y0 = first[1] * 8, y1 = 24 - last[1] * 8;
      const U rows_lo =
          L::sllv(U{} + ~0u, y0 < 0 ? I{} : y0) & L::srlv(U{} + ~0u, y1 < 0 ? I{} : y1);
      const I z0 = y0 - 32, z1 = y1 + 32;
      const U rows_hi =
          L::sllv(U{} + ~0u, z0 < 0 ? I{} : z0) & L::srlv(U{} + ~0u, z1 < 0 ? I{} : z1);
      // The slices' half words (slice k: words 2 k, 2 k + 1 of the brick).
      U wlo, whi;
      if constexpr (N == 16) {
        const __m512i wa = _mm512_loadu_si512(w.bricks + size_t(uint32_t(brick[la])) * 18);
        const __m512i wb = _mm512_loadu_si512(w.bricks + size_t(uint32_t(brick[lb])) * 18);
        const I at = (lane & 8) * 2 + (lane & 7) * 2;  // 16 + 2 k: wb's
        wlo = (U)_mm512_permutex2var_epi32(wa, (__m512i)at, wb);
        whi = (U)_mm512_permutex2var_epi32(wa, (__m512i)(at + 1), wb);
      } else {
        const uint32_t* wp = w.bricks + size_t(uint32_t(brick[la])) * 18;
        const __m256i wa = _mm256_loadu_si256((const __m256i*)wp);
        const __m256i wb = _mm256_loadu_si256((const __m256i*)(wp + 8));
        const __m256i ev = (__m256i)((lane & 3) * 2), od = (__m256i)((lane & 3) * 2 + 1);
        wlo = (U)_mm256_blend_epi32(_mm256_permutevar8x32_epi32(wa, ev),
                                    _mm256_permutevar8x32_epi32(wb, ev), 0xF0);
        whi = (U)_mm256_blend_epi32(_mm256_permutevar8x32_epi32(wa, od),
                                    _mm256_permutevar8x32_epi32(wb, od), 0xF0);
      }
      // 2-voxel blocks: every voxel of an occupied block set (the pair of
      // slices, of rows and of columns ORed), so the test is the blocks'.
      const I dl = pick(dil);
      if (L::bits(dl)) {
        const I pair = lane ^ 1;
        U zlo, zhi;
        if constexpr (N == 16) {
          zlo = (U)_mm512_maskz_permutexvar_epi32(0xFFFF, (__m512i)pair, (__m512i)wlo);
          zhi = (U)_mm512_maskz_permutexvar_epi32(0xFFFF, (__m512i)pair, (__m512i)whi);
        } else {
          zlo = (U)_mm256_permutevar8x32_epi32((__m256i)wlo, (__m256i)pair);
          zhi = (U)_mm256_permutevar8x32_epi32((__m256i)whi, (__m256i)pair);
        }
        auto dilate = [](U v) {
          v |= (v >> 8 & 0x00FF00FFu) | (v << 8 & 0xFF00FF00u);
          const U e = (v | v >> 1) & 0x55555555u;
          return e | e << 1;
        };
        wlo = dl ? dilate(wlo | zlo) : wlo;
        whi = dl ? dilate(whi | zhi) : whi;
      }
      const U any = (wlo & row & rows_lo) | (whi & row & rows_hi);
      return L::bits((lo <= hi) & (any != 0u));
    };
    // begin() of the children at level nl of the lanes' cubes c (level lv).
    auto push = [&](I m, I nl) __attribute__((always_inline)) {
      const I ratio = nl - lv, ntop = ((I{} + 1) << nl) - 1;
      const F nside = pow2(LL - nl), ninv = pow2(nl - LL);
      I nlo[3], nhi[3], nc[3];
      for (int a = 0; a < 3; ++a) {
        nlo[a] = c[a] << ratio;
        const I h = nlo[a] + ((I{} + 1) << ratio) - 1;
        nhi[a] = ntop < h ? ntop : h;
        // start_cell: floor (or ceil - 1) of the position, clamped.
        const F p = (o[a] + d[a] * t) * ninv;
        const F f = up[a] != 0 ? L::template round<_MM_FROUND_TO_NEG_INF>(p)
                               : L::template round<_MM_FROUND_TO_POS_INF>(p) - 1.f;
        const F flo = to_f(nlo[a]), fhi = to_f(nhi[a]);
        const F mx = f < flo ? flo : f;
        nc[a] = __builtin_convertvector(fhi < mx ? fhi : mx, I);
      }
      // start_cell_exact where the lane starts at its beam's region, in
      // lanes (a loop per lane was ~8 % of the beam-started walk's time, perf):
      // per axis forward while the child's exit plane's t is <= t, then back
      // while its entry plane's t is > t (the same plane_t values).
      const I exact = m & (t == start_t);
      if (L::bits(exact)) {
        for (int a = 0; a < 3; ++a) {
          const I fwd = up[a] != 0 ? nhi[a] : nlo[a], back = up[a] != 0 ? nlo[a] : nhi[a];
          for (I k = exact;;) {
            k &= (nc[a] != fwd) & (exit_t(a, nc[a], nside) <= t);
            if (!L::bits(k)) break;
            nc[a] = k ? nc[a] + stp[a] : nc[a];
          }
          for (I k = exact;;) {
            k &= (nc[a] != back) & ((to_f(nc[a] + 1 - up[a]) * nside - o[a]) * inv[a] > t);
            if (!L::bits(k)) break;
            nc[a] = k ? nc[a] - stp[a] : nc[a];
          }
        }
      }
      for (int a = 0; a < 3; ++a) {
        const F nn = exit_t(a, nc[a], nside);
        n[a] = m ? nn : n[a];
        c[a] = m ? nc[a] : c[a];
        lo[a] = m ? nlo[a] : lo[a];
        span[a] = m ? nhi[a] - nlo[a] : span[a];
      }
      chain = m ? chain | (I{} + 1) << lv : chain;
      lv = m ? nl : lv;
    };
    // Walker::child_level(level, exit) in lanes.
    auto child_level = [&](I level, F exit) {
      const I target = BL - ((BL - level - 1) * 43 >> 7) * 3;  // x / 3 for x < 64
      const I node = target == level + 1 ? I{} - 1 : ~lod_stop(target - 1, exit);
      const I below = lod_stop(I{} + (LL - 1), exit);
      // From a cell: straight to the 2-voxel blocks when the 4-voxel ones
      // cannot stop (their side exceeds the footprint at the cell's exit).
      const I first =
          level == BL ? (lod_stop(I{} + (BL + 1), exit) ? level + 1 : I{} + (LL - 1)) : level + 1;
      return level < BL ? (node ? target : level + 1) : (below ? first : I{} + LL);
    };
    push(active, child_level(I{}, exit0));

    while (L::bits(active)) {
      // A lane outside the grid (its cube's coordinates beyond the level's
      // 2^lv per axis) can only come from a fault of this walk; it would
      // read outside the arrays. It retires as kPacketFault (the caller
      // counts it and asks trace()) instead of crashing.
      const U top = (U)((I{} + 1) << lv);
      const I fault = active & (((U)c[0] >= top) | ((U)c[1] >= top) | ((U)c[2] >= top));
      if (L::bits(fault)) [[unlikely]] {
        for (uint32_t b = L::bits(fault); b != 0; b &= b - 1)
          status[base + std::countr_zero(b)] = kPacketFault;
        active &= ~fault;
        if (!L::bits(active)) break;
      }
      // ---- test the lanes' current children ----
      I occ{};
      U cellv{};  // the cell
      // The cell box and the clearance of a node of level B - 3 and the
      // clearance of a cell are gathered with the node and the cell, before
      // it is known whether they are needed (an occupied node, an empty node
      // or cell): the loop waits on gathers, and these no longer wait on
      // the first. clr: the clearance of the lanes' child (0: none), empty:
      // the lanes whose child is an empty cell or node of level B - 3.
      U box{};
      I clr{}, empty{};
      // The byte at index idx of a clearance array in the lanes of m (a
      // 4-byte gather from at most the array's last 4 bytes).
      auto clearance = [&](const uint8_t* base, int32_t last, I idx, I m) {
        const I at = idx < last ? idx : I{} + last;
        const U word = L::gather_bytes(base, at, m, U{});
        return m ? (I)((word >> (U)((idx - at) * 8)) & 0xFFu) : clr;
      };
      const I is_node = active & (lv < BL);
      for (uint32_t mn = L::bits(is_node); mn != 0;) {
        // One masked gather per pyramid level present in the lanes.
        const int level = lv[std::countr_zero(mn)], p = BL - level;
        const I mk = is_node & (lv == level);
        mn &= ~L::bits(mk);
        const I in = mk & ((U)c[1] < w.node_dim_y[p]);
        const I idx = c[0] + int32_t(w.node_dim[p]) * (c[1] + int32_t(w.node_dim_y[p]) * c[2]);
        const U g = L::gather(w.nodes[p], idx * 2, in, U{});
        occ |= in & (g != 0);
        if (level == BL - 3) {  // World::cell_box and node_clearance share this index
          box = L::gather(w.cell_box, idx, in, U{});
          clr = clearance(w.node_clearance, w.node_clearance_last, idx * 8 + octant, in);
          empty |= in & (g == 0);
        }
      }
      const I is_cell = active & (lv == BL);
      const I mc = is_cell & ((U)c[1] < w.dims[1]);
      if (L::bits(mc)) {
        const I idx = c[0] + int32_t(w.dims[0]) * (c[1] + int32_t(w.dims[1]) * c[2]);
        cellv = L::gather(w.cells, idx, mc, U{});
        clr = clearance(w.clearance, w.clearance_last, idx, mc);
        empty |= mc & (cellv == 0u);
        occ |= mc & (cellv != 0);
      }
      // Inside a brick: a voxel's bit, or (LOD) a 2^s block's bits, s =
      // L - lv, rows of one half-slice word per z slice of the block.
      const I in_brick = active & (lv > BL);
      I bit{};
      if (L::bits(in_brick)) {
        const I s = LL - lv;
        const I x = c[0] << s & 7, y = c[1] << s & 7, z = c[2] << s & 7;
        const I sidev = (I{} + 1) << s;
        // The block's rows in its half word: side bits from x, side rows from y & 3.
        const I rowrep = sidev == 4 ? I{} + 0x01010101 : (sidev == 2 ? I{} + 0x101 : I{} + 1);
        const U plane = (U)((((I{} + 1) << sidev) - 1) * rowrep) << (U)((y & 3) * 8 + x);
        bit = x | y << 3 | z << 6;
        I solid{};
        for (int dz = 0; dz < 4; ++dz) {
          const I m = in_brick & (dz < sidev);
          if (!L::bits(m)) break;
          const U word = L::gather(w.bricks, brick * 18 + (z + dz) * 2 + (y >> 2), m, U{});
          solid |= m & ((word & plane) != 0u);
        }
        occ |= solid;
      }
      const F cexit = L::min(L::min(n[0], n[1]), n[2]);
      // LOD stops: an occupied node, cell or block whose side fits the
      // footprint at its exit; any occupied voxel.
      const I stop = occ & ((lv == LL) | lod_stop(lv, cexit));
      if (L::bits(stop)) {
        U lodc{};
        const I resident = (I)(cellv >> 30 == 1u);
        lodc = (stop & is_cell) ? (resident ? L::gather(w.bricks, (I)(cellv & 0xFFFFFFu) * 18 + 17,
                                                        stop & is_cell & resident, U{})
                                            : (cellv & 0xFFFFFFu) | 0xFF000000u)
                                : lodc;
        const I sub = stop & in_brick & (lv < LL);
        if (L::bits(sub)) lodc = sub ? L::gather(w.bricks, brick * 18 + 17, sub, U{}) : lodc;
        for (uint32_t b = L::bits(stop); b != 0; b &= b - 1) {
          const int l = std::countr_zero(b);
          const int ax = axis[l];
          uint64_t ref;
          if (lv[l] == LL)
            ref = uint64_t(uint32_t(brick[l])) << 9 | uint32_t(bit[l]);
          else if (lv[l] < BL)  // an LOD stop at a node: its color, read here (once per ray)
            ref = uint64_t(1) << 63 | node_color(lv[l], c[0][l], c[1][l], c[2][l]);
          else
            ref = uint64_t(1) << 63 | lodc[l];
          status[base + l] = kPacketHit;
          out[base + l] = {t[l], ax * 2 + up[ax][l], lv[l], {c[0][l], c[1][l], c[2][l]}, ref};
        }
        active &= ~stop;
        occ &= ~stop;
      }
      // A not-resident brick: the scalar walk answers (requests, LOD color).
      const I scalar = occ & is_cell & ((cellv >> 30) != 1u);
      for (uint32_t b = L::bits(scalar); b != 0; b &= b - 1)
        status[base + std::countr_zero(b)] = kPacketScalar;
      active &= ~scalar;
      occ &= ~scalar;
      const I nl = child_level(lv, cexit);
      // visit_cells' cell-box test (World::cell_box) before the cells of a
      // node of level B - kCellBoxLevel: a lane missing the box steps on.
      const I boxed = occ & (lv == BL - 3) & (nl == BL);
      if (L::bits(boxed)) {
        F t0 = t, te = t1;
        for (int a = 0; a < 3; ++a) {
          const I cell0 = c[a] << 3;
          const F blo = to_f((cell0 + (I)(box >> (3 * a) & 7u)) << 3) - slack[a];
          const F bhi = to_f((cell0 + (I)(box >> (9 + 3 * a) & 7u) + 1) << 3) + slack[a];
          const F ta = (blo - o[a]) * inv[a], tb = (bhi - o[a]) * inv[a];
          const F mn = tb < ta ? tb : ta, mx = ta < tb ? tb : ta;
          t0 = t0 < mn ? mn : t0;
          te = mx < te ? mx : te;
        }
        occ &= ~(boxed & ~(t0 <= te));
      }
      brick = is_cell & occ ? (I)(cellv & 0xFFFFFFu) : brick;
      // visit_voxels' brick-slice test: a lane whose ray meets no solid
      // voxel in the brick it would descend into steps on instead.
      I slices{};
      uint32_t vox = 0;
      if (w.slice_skip) {
        uint32_t skip = 0;
        vox = L::bits(occ & is_cell & (nl >= LL - 1));
        const F te = L::min(cexit, t1);
        for (uint32_t b = vox; b != 0;) {
          const int la = std::countr_zero(b);
          b &= b - 1;
          int lb = la;  // 16 lanes: the next lane's ray in the same pass
          if (N == 16 && b != 0) lb = std::countr_zero(b), b &= b - 1;
          const uint32_t h = brick_slices(la, lb, te, nl == LL - 1);
          const uint32_t ha = h & 0xFFu, hb = N == 16 ? h >> 8 : ha;
          slices[la] = int32_t(ha), slices[lb] = int32_t(hb);
          skip |= (ha == 0 ? 1u << la : 0u) | (hb == 0 ? 1u << lb : 0u);
        }
        vox &= ~skip;
        occ &= ((I{} + int32_t(skip)) >> lane & 1) - 1;  // 0 in the skipped lanes
      }
      I adv = active & ~occ;
      F side = pow2(LL - lv);
      // visit_cells' jump: an empty cell of clearance k > 1 leaves the
      // cube of radius k - 1 around it (clipped to the parent) in one step;
      // the same for an empty node of level B - 3 with its node clearance
      // (the scalar walk steps node by node; the crossing reached is the
      // same, Walker::jump's argument).
      I leave_jump{};
      if (L::bits(empty)) {
        const I radius = clr - 1;
        const I jump = empty & (radius > 0);
        if (L::bits(jump)) {
          F tn[3];
          I tc[3];
          for (int a = 0; a < 3; ++a) {
            const I far = c[a] + stp[a] * radius, hi = lo[a] + span[a];
            const I mx = far < lo[a] ? lo[a] : far;
            tc[a] = hi < mx ? hi : mx;
            tn[a] = exit_t(a, tc[a], side);
          }
          const typename L::Nearest nj = L::nearest(tn);
          const F tj = nj.t;
          const I aj = nj.axis;
          const I ax[3] = {nj.on[0] & jump, nj.on[1] & jump, nj.on[2] & jump};
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
              n[b] = m ? exit_t(b, c[b], side) : n[b];
            }
          }
          for (int a = 0; a < 3; ++a) {
            const I m = ok & ax[a];
            c[a] = m ? cn[a] : c[a];
            n[a] = m ? exit_t(a, cn[a], side) : n[a];
          }
          adv &= ~jump;
        }
      }
      if (L::bits(occ)) push(occ, nl);
      // visit_voxels' slice entry: the voxels before the first slice ahead
      // that may hold a hit are empty, so the lane goes straight to that
      // slice's entry plane, or leaves the brick when there is none or the
      // ray leaves the brick (or ends) before it. Walker::enter_slice in
      // lanes: the state the voxel DDA reaches when it crosses into z slice
      // cz, every x and y crossing at or before that plane's t taken first.
      if (vox != 0) {
        const I vm = ((I{} + int32_t(vox)) >> lane & 1) * -1;
        // 2-voxel blocks (lv == L - 1): slab j of the block DDA holds slices
        // 2 j and 2 j + 1 (the ray may meet one of the two only).
        const I blk = lv != LL;
        const I sl = (slices | slices >> 1) & 0x55;
        const I slabs = blk ? (sl & 1) | (sl >> 1 & 2) | (sl >> 2 & 4) | (sl >> 3 & 8) : slices;
        const I z0 = c[2] & (blk ? I{} + 3 : I{} + 7);
        const I ahead = up[2] != 0 ? slabs >> z0 << z0 : slabs & (((I{} + 2) << z0) - 1);
        // The first slice ahead: the lowest set bit upwards, the highest downwards.
        const I k = high_bit(up[2] != 0 ? ahead & -ahead : ahead);
        I fail = vm & (ahead == 0);
        I go = vm & ~fail & (k != z0);
        const I cz = lo[2] + k;
        // The cube side: exit_t's products with it are exact (x * 1 = x).
        const F cside = blk ? F{} + 2.f : F{} + 1.f;
        const F tz = (to_f(cz + 1 - up[2]) * cside - o[2]) * inv[2];
        fail |= go & (tz > t1);
        go &= ~(tz > t1);
        for (int a = 0; a < 2; ++a)
          for (I m = go;;) {
            m &= n[a] <= tz;
            if (!L::bits(m)) break;
            c[a] = m ? c[a] + stp[a] : c[a];
            const I out = m & ((U)(c[a] - lo[a]) > (U)span[a]);
            fail |= out, go &= ~out, m &= ~out;
            n[a] = m ? exit_t(a, c[a], cside) : n[a];
          }
        c[2] = go ? cz : c[2];
        n[2] = go ? exit_t(2, cz, cside) : n[2];
        t = go ? tz : t;
        axis = go ? I{} + 2 : axis;
        leave_jump |= fail;
      }
      // ---- advance (and pop) the other lanes ----
      while (L::bits(adv | leave_jump)) {
        const typename L::Nearest na = L::nearest(n);
        t = adv ? na.t : t;
        axis = adv ? na.axis : axis;
        const I ax[3] = {na.on[0] & adv, na.on[1] & adv, na.on[2] & adv};
        I leave{};
        for (int a = 0; a < 3; ++a) {
          c[a] = ax[a] ? c[a] + stp[a] : c[a];
          leave |= ax[a] & ((U)(c[a] - lo[a]) > (U)span[a]);
        }
        const I end = adv & ~leave & (na.t > t1);
        const I ok = adv & ~leave & ~end;
        leave |= leave_jump;
        leave_jump = I{};
        for (int a = 0; a < 3; ++a) {
          const I m = ok & ax[a];
          n[a] = m ? exit_t(a, c[a], side) : n[a];  // no branch: the axis is data dependent
        }
        // Past t1, or out of the root's children: a miss.
        active &= ~(end | (leave & (chain == 1)));
        const I pop = leave & (chain != 1);
        adv = pop;
        if (!L::bits(pop)) break;
        // The parent's DDA: children at the highest level in chain, of the
        // cube at the next one; its child c is the one the lane's lo came from.
        const I pl = high_bit(chain);
        const I gchain = chain & ~((I{} + 1) << pl);
        const I gl = high_bit(gchain);
        const I ratio = lv - pl, pratio = pl - gl, ptop = ((I{} + 1) << pl) - 1;
        const F pside = pow2(LL - pl);
        for (int a = 0; a < 3; ++a) {
          const I pc = lo[a] >> ratio;
          const I plo = pc >> pratio << pratio;
          const I h = plo + ((I{} + 1) << pratio) - 1;
          const I phi = ptop < h ? ptop : h;
          c[a] = pop ? pc : c[a];
          lo[a] = pop ? plo : lo[a];
          span[a] = pop ? phi - plo : span[a];
          n[a] = pop ? exit_t(a, pc, pside) : n[a];
        }
        lv = pop ? pl : lv, chain = pop ? gchain : chain;
        side = pop ? pside : side;
      }
    }
  }
}

template <int N>
int packet_setup(const PacketSetupIn& in, uint32_t id0, float* const f[16], int32_t* axis_out,
                 uint32_t* id, uint32_t* scalar, int* n_scalar) {
  static_assert(N == 16, "compress stores: AVX-512 only");
  using L = WalkLanes<N>;
  using F = typename L::F;
  using I = typename L::I;
  using U = typename L::U;
  typedef double D __attribute__((vector_size(N * 8)));
  const I lane = L::iota();
  const auto fabs_ = [](F x) { return L::as_f(L::as_u(x) & 0x7FFFFFFFu); };
  const auto finite = [&](F x) { return (I)(fabs_(x) <= F{} + 3.40282347e38f); };  // NaN: false
  const auto to_d = [](F x) { return __builtin_convertvector(x, D); };
  const auto to_f = [](D x) { return __builtin_convertvector(x, F); };
  const F inf = F{} + INFINITY;
  const uint32_t* raw = reinterpret_cast<const uint32_t*>(in.rays);
  static_assert(sizeof(Ray) == 7 * sizeof(float), "Ray: origin, dir, tmax");
  int out = 0;
  for (int b = 0; b < in.count; b += N) {
    const I live = lane < (in.count - b);
    const I at = (lane + b) * 7;
    F v[7];
    for (int k = 0; k < 7; ++k) v[k] = L::as_f(L::gather(raw, at + k, live, U{}));
    // to_grid (traverse.cpp)
    I ok = live;
    for (int k = 0; k < 6; ++k) ok &= finite(v[k]);
    F o[3], d[3], inv[3];
    I up[3];
    F big{};
    for (int a = 0; a < 3; ++a) {
      o[a] = to_f((to_d(v[a]) - in.origin[a]) * in.inv_vs);
      d[a] = to_f(to_d(v[3 + a]) * in.inv_vs);
      const F ad = fabs_(d[a]);
      big = big < ad ? ad : big;
    }
    ok &= (big > 0.f) & finite(big);
    const F tiny = big * 0x1p-23f;
    for (int a = 0; a < 3; ++a) {
      const F signed_tiny = L::as_f((L::as_u(d[a]) & 0x80000000u) | L::as_u(tiny));
      d[a] = fabs_(d[a]) < tiny ? signed_tiny : d[a];
      inv[a] = 1.f / d[a];
      up[a] = (I)(L::as_u(d[a]) >> 31) == 0;
    }
    // clip_ray without a region
    F t0{}, t1 = v[6] != v[6] ? inf : v[6], ex = inf;
    I ax = I{} - 1;
    for (int a = 0; a < 3; ++a) {
      const F ta = ((up[a] ? F{} : F{} + in.n) - o[a]) * inv[a];
      const F tb = ((up[a] ? F{} + in.n : F{}) - o[a]) * inv[a];
      const I gt = ta > t0;
      t0 = gt ? ta : t0;
      ax = gt ? I{} + a : ax;
      t1 = tb < t1 ? tb : t1;
      ex = tb < ex ? tb : ex;
    }
    ok &= t0 <= t1;
    F start_t = F{} + NAN;
    if (in.region_of != nullptr) {
      // clip_ray's beam start: the region's entry and exit t, start just
      // before the entry (next_below from the bits).
      const uint32_t* rg = reinterpret_cast<const uint32_t*>(in.regions);
      const I e =
          (I)L::gather(reinterpret_cast<const uint32_t*>(in.region_of), lane + b, live, U{}) * 8;
      const U kind = L::gather(rg, e + 6, live, U{});
      ok &= (I)(kind != kRegionEmpty);
      const I has = (I)(kind == kRegionClip);
      F r0 = F{} - INFINITY, r1 = F{} + INFINITY;
      for (int a = 0; a < 3; ++a) {
        const F lo = L::as_f(L::gather(rg, e + a, has, U{}));
        const F hi = L::as_f(L::gather(rg, e + 3 + a, has, U{}));
        const F pa = ((up[a] ? lo : hi) - o[a]) * inv[a];
        const F pb = ((up[a] ? hi : lo) - o[a]) * inv[a];
        r0 = r0 < pa ? pa : r0;
        r1 = pb < r1 ? pb : r1;
      }
      t1 = has & (r1 < t1) ? r1 : t1;
      const U rb = L::as_u(r0);
      const U nb = r0 == 0.f ? U{} + 0x80000001u : (r0 > 0.f ? rb - 1 : rb + 1);
      const F before = L::as_f(nb);
      const I adv = has & (before > t0);
      t0 = adv ? before : t0;
      start_t = adv ? before : start_t;
      ok &= t0 <= t1;
    }
    const F nd[3] = {-fabs_(d[0]), -fabs_(d[1]), -fabs_(d[2])};
    ax = ax < 0 ? L::nearest(nd).axis : ax;  // inside the box: argmin3 of -|d|
    if (in.lod_on) {
      const I rs = ok & (F{} + in.root_side <= in.lod_size0 + in.lod_per_t * ex);
      for (uint32_t m = L::bits(rs); m != 0; m &= m - 1)
        scalar[(*n_scalar)++] = id0 + uint32_t(b + std::countr_zero(m));
      ok &= ~rs;
    }
    const __mmask16 k = L::bits(ok);
    F slack[3];
    for (int a = 0; a < 3; ++a)
      slack[a] = (fabs_(o[a]) + fabs_(d[a]) * t1) * 0x1p-16f + 0x1p-16f;  // brick_slack
    const F vals[16] = {o[0],   o[1],     o[2],     d[0],     d[1], d[2], inv[0],  inv[1],
                        inv[2], slack[0], slack[1], slack[2], t0,   t1,   start_t, ex};
    for (int j = 0; j < 16; ++j) _mm512_mask_compressstoreu_ps(f[j] + out, k, (__m512)vals[j]);
    _mm512_mask_compressstoreu_epi32(axis_out + out, k, (__m512i)ax);
    _mm512_mask_compressstoreu_epi32(id + out, k, (__m512i)(lane + int32_t(id0) + b));
    out += std::popcount(uint32_t(k));
  }
  return out;
}

}  // namespace
}  // namespace voxcast::brickmap::detail
