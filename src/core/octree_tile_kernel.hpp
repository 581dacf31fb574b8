#pragma once
// The tile caster's walk (core/octree_tile_caster.hpp explains the order and
// why the hits are cast_octree's). Included only by the per-ISA kernel
// translation units (src/esvo/packet_kernel_*.cpp, src/dag/...), like
// core/octree_packet_kernel.hpp, whose lane types it uses: N = 16 lanes
// (AVX-512) or 8 (AVX2), one lane per pixel of a tile row, one vector per
// row and quantity.
//
// The walk is depth first over positions (a DAG node shared by several
// positions is visited once per position), children front to back. A node
// carries the rows of the tile whose rays it holds, as one lane mask per row;
// each present child is tested against those rays that have no hit yet, a
// row at a time: entry and exit t from the child's planes, the placement
// test, the LOD stop, the contour slab, then leaf hit or descent. A node
// whose rays all have their hits ends its loop, which culls everything
// behind the visible surface. Variants of that step, all with the same
// per-ray answers:
//  * a node with more than N rays, perspective, no contours: a child that
//    cannot be a LOD stop and is not a leaf gets no per-ray test, only the
//    rays its projected box covers (cull_children());
//  * a node with N rays or fewer: they are packed into row 0 of packed_
//    (pack_rays()) and the subtree works on that one register;
//  * a packed node without contours (visit_packed(), its children's t from
//    the node's three planes per axis, PackedPlanes) whose children are all
//    stops for its rays: bottom(), one branch-free pass; other packed nodes
//    without contours: packed_children(), all children's tests first, then
//    hits and descents;
//  * an unpacked node without contours: a child's row tests all first with
//    no branch per row, then the rows with stops, then one descent.
// The any-hit flavour (kAnyHit: occlusion, the parallel walks of
// core/octree_tile_caster.hpp "Parallel rays") only marks the rays that
// stop. docs/BENCHMARKS.md "Tile caster" and "Parallel walks for shadow
// rays" measure each step.
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <type_traits>

#include "core/octree_packet_kernel.hpp"
#include "core/octree_tile_caster.hpp"

namespace voxcast::detail {
namespace {

/// Rays in vector rows: the tile (row r = pixel row r, lane l = column
/// col0 + l) or, below a node that holds no more than N of them, those
/// rays packed into row 0 (id = the pixel, row * kTileCols + column).
template <int N>
struct TileRaySet {
  using L = Lanes<N>;
  using F = typename L::F;
  using I = typename L::I;
  F cx[kTileRows], cy[kTileRows], cz[kTileRows];
  F nbx[kTileRows], nby[kTileRows], nbz[kTileRows];
  F dx[kTileRows], dy[kTileRows], dz[kTileRows];
  I mirror_x[kTileRows], mirror_y[kTileRows], mirror_z[kTileRows];
  I id[kTileRows];
  uint32_t active[kTileRows];  // rays without a hit yet
  // The span [t_min, t_max] of each ray in the current node at each scale
  // (the root's at kOctreeMaxScale), as cast_octree carries it down.
  // Without contours a ray's span in any cube it is placed in is the
  // root's clipped to the cube's planes (core/octree_caster.hpp "Why a
  // start region gives bit-identical hits"), so only the root's row
  // (kOctreeMaxScale) is kept: span_level().
  F span_lo[kOctreeMaxScale + 1][kTileRows], span_hi[kOctreeMaxScale + 1][kTileRows];
  bool packed;
};

/// The walk's ray sets (~60 KB each with 16 lanes): per thread, not on the
/// stack; shared by the first-hit and any-hit walks.
template <int N>
struct TileStorage {
  TileRaySet<N> tile, packed;
};

template <class P, int N, bool kAnyHit>
class TileWalk {
  using L = Lanes<N>;
  using F = typename L::F;
  using I = typename L::I;
  using Index = typename P::Index;
  using Desc = typename P::Desc;
  static constexpr bool kIndexed = !std::is_same_v<Index, NoIndex>;
  static_assert(!P::kResidency, "the tile caster walks in-core trees");

  using RaySet = TileRaySet<N>;

  /// A child cube's entry and exit planes as MirroredRay sees them, per axis
  /// for a lane whose ray is mirrored (m) or not (u): the mirrored cube of
  /// [x, x + hs] is [3 - x - hs, 3 - x] (exact). span(): a row's tau =
  /// max(span start, entry planes), tc_max = min(exit planes), and each
  /// axis's exit-plane t (the contour slab's corner), each t as
  /// MirroredRay::tx computes it.
  struct ChildPlanes {
    ChildPlanes(const float* clo, float hs) {
      for (int a = 0; a < 3; ++a) {
        in_m[a] = L::template splat<F>(3.f - clo[a]), in_u[a] = L::template splat<F>(clo[a] + hs);
        out_m[a] = L::template splat<F>(3.f - clo[a] - hs), out_u[a] = L::template splat<F>(clo[a]);
      }
    }
    void span(const F* c, const F* nb, const I* mirrored, F t_lo, F* tau, F* tc_max,
              F* t_out) const {
      F t_in[3];
      for (int a = 0; a < 3; ++a) {
        t_in[a] = L::fma(mirrored[a] ? in_m[a] : in_u[a], c[a], nb[a]);
        t_out[a] = L::fma(mirrored[a] ? out_m[a] : out_u[a], c[a], nb[a]);
      }
      *tc_max = L::min(L::min(t_out[0], t_out[1]), t_out[2]);
      *tau = L::max(t_lo, L::max(L::max(t_in[0], t_in[1]), t_in[2]));
    }
    F in_m[3], in_u[3], out_m[3], out_u[3];
  };

  /// Row r of a ray set in registers (row 0 of a packed set) with its span
  /// at `level`, and a child's span on it (ChildPlanes::span; a packed
  /// node's children: PackedPlanes).
  struct Row {
    Row(const RaySet& rs, int level, int r)
        : c{rs.cx[r], rs.cy[r], rs.cz[r]},
          nb{rs.nbx[r], rs.nby[r], rs.nbz[r]},
          mirrored{rs.mirror_x[r], rs.mirror_y[r], rs.mirror_z[r]},
          t_lo(rs.span_lo[level][r]),
          t_max(rs.span_hi[level][r]) {}
    void span(const ChildPlanes& child, F* tau, F* tc_max, F* t_out) const {
      child.span(c, nb, mirrored, t_lo, tau, tc_max, t_out);
    }
    F c[3], nb[3];
    I mirrored[3];
    F t_lo, t_max;
  };

  /// A packed node's row against the planes of its cube and its children:
  /// per axis the t of the three planes lo, lo + hs, lo + 2 hs (mirrored per
  /// lane as MirroredRay: 3 - p; every such coordinate is exact), so that a
  /// child's entry and exit t per axis are selections instead of two fma
  /// per axis and child. The same fma on the same coordinates as
  /// ChildPlanes, so the same floats; child() takes max/min in its order.
  struct PackedPlanes {
    PackedPlanes(const Row& row, const float* lo, float hs) {
      for (int a = 0; a < 3; ++a) {
        const float p[3] = {lo[a], lo[a] + hs, lo[a] + hs + hs};
        const I m = row.mirrored[a];
        F u[3];
        for (int j = 0; j < 3; ++j)
          u[j] = L::fma(m ? L::template splat<F>(3.f - p[j]) : L::template splat<F>(p[j]), row.c[a],
                        row.nb[a]);
        // Half b of the node on axis a: planes p[b], p[b + 1]; a mirrored
        // lane enters at 3 - p[b].
        in[a][0] = m ? u[0] : u[1], out[a][0] = m ? u[1] : u[0];
        in[a][1] = m ? u[1] : u[2], out[a][1] = m ? u[2] : u[1];
        node_in[a] = m ? u[0] : u[2];
      }
    }
    /// Child c's span on the row (ChildPlanes::span).
    void child(int c, F t_lo, F* tau, F* tc_max) const {
      const int x = c & 1, y = c >> 1 & 1, z = c >> 2 & 1;
      *tc_max = L::min(L::min(out[0][x], out[1][y]), out[2][z]);
      *tau = L::max(t_lo, L::max(L::max(in[0][x], in[1][y]), in[2][z]));
    }
    /// The node's own entry t (Row::span of the node's cube).
    F entry(F t_lo) const {
      return L::max(t_lo, L::max(L::max(node_in[0], node_in[1]), node_in[2]));
    }
    F in[3][2], out[3][2], node_in[3];
  };

 public:
  using Storage = TileStorage<N>;

  TileWalk(const P& nodes, const TileRays& rays, int col0, float size_coef, float size_bias,
           TileOut* out, Storage* storage)
      : nodes_(nodes),
        rays_(rays),
        col0_(col0),
        size_coef_(L::template splat<F>(size_coef)),
        size_bias_(L::template splat<F>(size_bias)),
        contours_(may_narrow_spans(nodes)),
        lod_possible_(!(size_coef == 0.f && size_bias <= 0.f)),
        out_(out),
        tile_(storage->tile),
        packed_(storage->packed) {}

  void run() {
    RaySet& t = tile_;
    t.packed = false;
    packed_.packed = true;
    uint32_t rows = 0, mask[kTileRows] = {};  // (the 16-lane row helpers load all rows)
    for (int r = 0; r < rays_.rows; ++r) {
      const uint32_t live = (rays_.live[r] >> col0_) & L::kAll;
      t.active[r] = mask[r] = live;
      if (live != 0) rows |= 1u << r;
      t.cx[r] = load(rays_.cx[r]), t.cy[r] = load(rays_.cy[r]), t.cz[r] = load(rays_.cz[r]);
      t.nbx[r] = load(rays_.nbx[r]), t.nby[r] = load(rays_.nby[r]), t.nbz[r] = load(rays_.nbz[r]);
      t.dx[r] = load(rays_.dx[r]), t.dy[r] = load(rays_.dy[r]), t.dz[r] = load(rays_.dz[r]);
      t.mirror_x[r] = from_bits(rays_.mirror_x[r] >> col0_);
      t.mirror_y[r] = from_bits(rays_.mirror_y[r] >> col0_);
      t.mirror_z[r] = from_bits(rays_.mirror_z[r] >> col0_);
      t.id[r] = L::iota() + (r * kTileCols + col0_);
      t.span_lo[kOctreeMaxScale][r] = load(rays_.t_min[r]);
      t.span_hi[kOctreeMaxScale][r] = load(rays_.t_max[r]);
      const I miss = L::template splat<I>(-1);  // columns [col0, col0 + N) <= kTileCols
      std::memcpy(&out_->hit[r][col0_], &miss, sizeof miss);
    }
    if (rows != 0) {
      const float lo[3] = {1.f, 1.f, 1.f};
      visit(t, nodes_.root(), kOctreeMaxScale - 1, lo, rows, mask, Index{});
    }
  }

 private:
  F load(const float (&row)[kTileCols]) const {
    F v;
    std::memcpy(&v, row + col0_, sizeof v);
    return v;
  }
  static I from_bits(uint32_t k) {
    const I v = L::template splat<I>(int32_t(k & L::kAll));
    return ((v >> L::iota()) & 1) != 0;
  }
  /// Where the spans of the rays in a node at `scale` are kept.
  int span_level(int scale) const { return contours_ ? scale : kOctreeMaxScale; }

  /// An unpacked node's row bookkeeping: mask[r] & active[r] for the rows r
  /// of `rows` (mask and active hold a lane mask per tile row). With 16
  /// lanes all 16 rows are one vector, no loop over the rows; the 8-lane
  /// kernel loops over the rows (the same as 64-byte vectors on AVX2
  /// measured 0.6-0.95x).
  static_assert(kTileRows == 16);
  /// The rays (lanes) in those rows.
  static int live_count(const uint32_t* mask, const uint32_t* active, uint32_t rows) {
    if constexpr (N == 16) {
      const __m512i live = live_rows_512(mask, active, rows);
      const __m256i w = _mm512_maskz_cvtepi32_epi16(0xFFFF, live);  // 16-bit masks
      uint64_t q[4];
      std::memcpy(q, &w, sizeof q);
      return std::popcount(q[0]) + std::popcount(q[1]) + std::popcount(q[2]) + std::popcount(q[3]);
    } else {
      int n = 0;
      for (uint32_t b = rows; b != 0; b &= b - 1) {
        const int r = std::countr_zero(b);
        n += std::popcount(mask[r] & active[r]);
      }
      return n;
    }
  }
  /// The rows of `rows` that still hold a ray.
  static uint32_t live_rows(const uint32_t* mask, const uint32_t* active, uint32_t rows) {
    if constexpr (N == 16) {
      const __m512i live = live_rows_512(mask, active, rows);
      return _mm512_test_epi32_mask(live, live);
    } else {
      uint32_t live = 0;
      for (uint32_t b = rows; b != 0; b &= b - 1) {
        const int r = std::countr_zero(b);
        live |= uint32_t((mask[r] & active[r]) != 0) << r;
      }
      return live;
    }
  }
  /// out[r] = mask[r] & active[r] & lanes for the rows r of `rows`; returns
  /// the rows where that is not zero. (Rows outside `rows`: zero with 16
  /// lanes, untouched with 8; the walk reads only the returned rows.)
  static uint32_t candidates(const uint32_t* mask, const uint32_t* active, uint32_t rows,
                             uint32_t lanes, uint32_t* out) {
    if constexpr (N == 16) {
      const __m512i c =
          _mm512_and_si512(live_rows_512(mask, active, rows), _mm512_set1_epi32(int32_t(lanes)));
      _mm512_storeu_si512(out, c);
      return _mm512_test_epi32_mask(c, c);
    } else {
      uint32_t child_rows = 0;
      for (uint32_t b = rows; b != 0; b &= b - 1) {
        const int r = std::countr_zero(b);
        out[r] = mask[r] & active[r] & lanes;
        if (out[r] != 0) child_rows |= 1u << r;
      }
      return child_rows;
    }
  }
  static __m512i live_rows_512(const uint32_t* mask, const uint32_t* active,
                               uint32_t rows) requires(N == 16) {
    return _mm512_maskz_and_epi32(__mmask16(rows), _mm512_loadu_si512(mask),
                                  _mm512_loadu_si512(active));
  }

  /// Lanes k of src, in order, into lanes [at, at + popcount(k)) of *dst
  /// (pack_rays of the 8-lane kernel).
  template <class V>
  static void pack(V src, uint32_t k, int at, V* dst) {
    for (uint32_t b = k; b != 0; b &= b - 1) (*dst)[at++] = src[std::countr_zero(b)];
  }

  /// Below a node that holds no more than N rays of the tile: those rays
  /// (lanes `mask` of rows `rows`), with their spans at scale s + 1, into
  /// row 0 of packed_; returns their lanes there.
  uint32_t pack_rays(int s, uint32_t rows, const uint32_t* mask) {
    RaySet& p = packed_;
    const int level = span_level(s + 1);
    int at = 0;
    if constexpr (N == 16) {
      // In registers: per row one lane map (the row's lanes k to lanes
      // [at, at + popcount(k))), then one merging permute per quantity
      // (pack() would compress and expand each through memory). Lanes past
      // the rays are zero.
      F cx{}, cy{}, cz{}, nbx{}, nby{}, nbz{}, dx{}, dy{}, dz{}, lo{}, hi{};
      I mirror_x{}, mirror_y{}, mirror_z{}, id{};
      const __m512i lane = (__m512i)L::iota();
      for (uint32_t b = rows; b != 0; b &= b - 1) {
        const int r = std::countr_zero(b);
        const uint32_t k = mask[r] & tile_.active[r];
        if (k == 0) continue;
        const __mmask16 to = __mmask16(((1u << std::popcount(k)) - 1) << at);
        const __m512i from =
            _mm512_maskz_expand_epi32(to, _mm512_maskz_compress_epi32(__mmask16(k), lane));
        auto put = [&](auto src, auto* dst) {
          using V = std::remove_reference_t<decltype(*dst)>;
          *dst = (V)_mm512_mask_permutexvar_ps((__m512)*dst, to, from, (__m512)src);
        };
        put(tile_.cx[r], &cx), put(tile_.cy[r], &cy), put(tile_.cz[r], &cz);
        put(tile_.nbx[r], &nbx), put(tile_.nby[r], &nby), put(tile_.nbz[r], &nbz);
        if (contours_) put(tile_.dx[r], &dx), put(tile_.dy[r], &dy), put(tile_.dz[r], &dz);
        put(tile_.mirror_x[r], &mirror_x), put(tile_.mirror_y[r], &mirror_y);
        put(tile_.mirror_z[r], &mirror_z), put(tile_.id[r], &id);
        put(tile_.span_lo[level][r], &lo), put(tile_.span_hi[level][r], &hi);
        at += std::popcount(k);
      }
      p.cx[0] = cx, p.cy[0] = cy, p.cz[0] = cz, p.nbx[0] = nbx, p.nby[0] = nby, p.nbz[0] = nbz;
      if (contours_) p.dx[0] = dx, p.dy[0] = dy, p.dz[0] = dz;
      p.mirror_x[0] = mirror_x, p.mirror_y[0] = mirror_y, p.mirror_z[0] = mirror_z, p.id[0] = id;
      p.span_lo[level][0] = lo, p.span_hi[level][0] = hi;
    } else {
      for (uint32_t b = rows; b != 0; b &= b - 1) {
        const int r = std::countr_zero(b);
        const uint32_t k = mask[r] & tile_.active[r];
        if (k == 0) continue;
        pack(tile_.cx[r], k, at, &p.cx[0]), pack(tile_.cy[r], k, at, &p.cy[0]);
        pack(tile_.cz[r], k, at, &p.cz[0]);
        pack(tile_.nbx[r], k, at, &p.nbx[0]), pack(tile_.nby[r], k, at, &p.nby[0]);
        pack(tile_.nbz[r], k, at, &p.nbz[0]);
        if (contours_) {
          pack(tile_.dx[r], k, at, &p.dx[0]), pack(tile_.dy[r], k, at, &p.dy[0]);
          pack(tile_.dz[r], k, at, &p.dz[0]);
        }
        pack(tile_.mirror_x[r], k, at, &p.mirror_x[0]);
        pack(tile_.mirror_y[r], k, at, &p.mirror_y[0]);
        pack(tile_.mirror_z[r], k, at, &p.mirror_z[0]);
        pack(tile_.id[r], k, at, &p.id[0]);
        pack(tile_.span_lo[level][r], k, at, &p.span_lo[level][0]);
        pack(tile_.span_hi[level][r], k, at, &p.span_hi[level][0]);
        at += std::popcount(k);
      }
    }
    const uint32_t lanes = (1u << at) - 1;  // at <= N <= 16
    p.active[0] = lanes;
    return lanes;
  }

  /// Takes the rays of lanes k of row r of `rs` out of the walk with their
  /// hit on child c of `node` at t: *rec is the TileHit of that cube and stop.
  void record(RaySet& rs, int r, uint32_t k, F t, uint32_t node, const Desc& desc, int c, int s,
              const float* clo, CastStop stop, const Index& index, int32_t* rec) {
    // Occlusion (kAnyHit) only asks whether the ray stops somewhere (any
    // stop it is placed in answers, core/octree_tile_caster.hpp "Parallel
    // rays"): no TileHit, no t, hit index 0.
    int32_t hit = 0;
    if constexpr (!kAnyHit) {
      if (*rec < 0) {
        TileHit h;
        h.node = node, h.child = int8_t(c), h.scale = int8_t(s), h.stop = uint8_t(stop);
        h.pos[0] = clo[0], h.pos[1] = clo[1], h.pos[2] = clo[2];
        if constexpr (kIndexed)
          h.index = uint64_t(nodes_.hit_index(index, desc, node, c, s));
        else
          h.index = 0;
        *rec = int32_t(out_->hits.size());
        out_->hits.push_back(h);
      }
      hit = *rec;
    }
    for (uint32_t b = k; b != 0; b &= b - 1) {
      const int l = std::countr_zero(b);
      const int id = rs.id[r][l], row = id / kTileCols, col = id % kTileCols;
      if constexpr (!kAnyHit) out_->t[row][col] = t[l];
      out_->hit[row][col] = hit;
      tile_.active[row] &= ~(1u << (col - col0_));
    }
    if (rs.packed) rs.active[r] &= ~k;
  }

  /// The eight children (side hs, slot c at lo + hs per set bit of c) of an
  /// unpacked node, for a perspective camera, in one vector pass (the
  /// children are the lanes; a scalar pass per child was ~12 % of a frame):
  ///  * rows[c] / lanes[c]: the rows and lanes whose rays may pass through
  ///    child c: its box in the camera frame projected to X/Z and Y/Z,
  ///    widened by kMargin pixels on each side for rounding (the exact test
  ///    decides every ray it keeps; this only has to keep every ray that may
  ///    be placed in the cube); all rows and lanes where the box reaches
  ///    behind the eye (nothing culled);
  ///  * bit c of *may_stop: whether child c may be a LOD stop for some ray:
  ///    its exit t is at most the distance of the cube's farthest point from
  ///    the eye (world units = octree units x side), and the LOD test is
  ///    monotone in t. A 1/1024 slack keeps rounding on the safe side (the
  ///    exact test decides).
  /// Every lane computes what the scalar formula would for its child, with
  /// the same operations in the same order (no contraction: -ffp-contract=off).
  static constexpr float kMargin = 0.0625f;
  using V8 = float __attribute__((vector_size(32)));
  using I8 = int32_t __attribute__((vector_size(32)));
  struct ChildCull {
    uint32_t rows[8], lanes[8], may_stop = 0;
  };
  void cull_children(const float* lo, float hs, ChildCull* out) const {
    const TileRays& t = rays_;
    const float h = hs * 0.5f;
    const I8 slot = {0, 1, 2, 3, 4, 5, 6, 7};
    const V8 zero = {}, side = zero + hs;
    // The child's center minus the eye: (child lo + h) - eye, child lo =
    // lo + (hs or +0), as the scalar code rounds it.
    const V8 qx = (lo[0] + ((slot & 1) != 0 ? side : zero) + h) - t.eye.x;
    const V8 qy = (lo[1] + ((slot & 2) != 0 ? side : zero) + h) - t.eye.y;
    const V8 qz = (lo[2] + ((slot & 4) != 0 ? side : zero) + h) - t.eye.z;
    const V8 x = qx * t.right.x + qy * t.right.y + qz * t.right.z;
    const V8 y = qx * t.up.x + qy * t.up.y + qz * t.up.z;
    const V8 z = qx * t.forward.x + qy * t.forward.y + qz * t.forward.z;
    const float ex = h * t.abs_right, ey = h * t.abs_up, ez = h * t.abs_forward;
    const V8 z_near = z - ez, z_far = z + ez;
    const V8 abs_z = (V8)((I8)z & 0x7fffffff);
    const I8 in_front = z_near > 1e-6f * (abs_z + ez);
    // Pixel index k passes at base + k step (step may be negative).
    auto range = [&](V8 c, float e, float base, float step, int n, uint32_t all) {
      const V8 a = c - e, b = c + e;
      const V8 lo_r = a / (a >= 0.f ? z_far : z_near), hi_r = b / (b >= 0.f ? z_near : z_far);
      const V8 k0 = (lo_r - base) / step, k1 = (hi_r - base) / step;
      const I8 swap = k0 > k1;
      const V8 first_k = swap ? k1 : k0, last_k = swap ? k0 : k1;
      I8 none = ~(last_k >= -1.f) | ~(first_k <= float(n));
      // max(0, ceil(k0 - kMargin)), min(n - 1, floor(k1 + kMargin)), clamped
      // in floats (the same integers wherever the scalar conversion is defined).
      V8 f = (V8)_mm256_ceil_ps((__m256)(first_k - kMargin));
      V8 l = (V8)_mm256_floor_ps((__m256)(last_k + kMargin));
      f = f > 0.f ? f : zero;
      f = f < float(n) ? f : zero + float(n);
      l = l < float(n - 1) ? l : zero + float(n - 1);
      l = l > -1.f ? l : zero - 1.f;
      const I8 first = __builtin_convertvector(f, I8), last = __builtin_convertvector(l, I8);
      none |= first > last;
      // n <= 16: the run's length is below 32.
      const I8 ones = (I8{} + 1) << (last - first + 1);
      const I8 run = (ones - 1) << first;
      return none ? I8{} : (run & int32_t(all));
    };
    const I8 rows = range(y, ey, t.v0, t.dv, kTileRows, ~0u);
    const I8 lanes = range(x, ex, t.u0 + float(col0_) * t.du, t.du, N, L::kAll);
    for (int c = 0; c < 8; ++c) {
      out->rows[c] = in_front[c] ? uint32_t(rows[c]) : ~0u;
      out->lanes[c] = in_front[c] ? uint32_t(lanes[c]) : uint32_t(L::kAll);
    }
    // (|q| + h sqrt 3) world_side (1 + 1/1024), as length(q) rounds it.
    const V8 len = (V8)_mm256_sqrt_ps((__m256)(qx * qx + qy * qy + qz * qz));
    const V8 far = (len + h * 1.7320509f) * t.world_side * 1.0009765625f;
    const I8 stop = far * size_coef_[0] + size_bias_[0] >= hs * 0.9990234375f;
    out->may_stop = uint32_t(_mm256_movemask_ps((__m256)stop));
  }

  /// visit() of a packed node whose children are all stops for the rays k:
  /// each ray's hit is the first child, front to back, it is placed in. No
  /// branch per child and ray: the children's tests run in turn on the
  /// rays still without a hit, and the hits are written once at the end.
  void bottom(RaySet& rs, const Row& row, const PackedPlanes& planes, const Desc& desc,
              uint32_t node, int s, const float* lo, uint32_t k, int flip, uint32_t present,
              const Index& index) {
    const float hs = scale_side(s);
    const F side = L::template splat<F>(hs);
    I open = from_bits(k);
    F hit_t = row.t_lo;
    I hit_c = L::template splat<I>(-1), hit_lod = L::template splat<I>(0);
    for (uint32_t b = front_to_back(present, flip); b != 0; b &= b - 1) {
      const int c = std::countr_zero(b) ^ 7 ^ flip;
      F tau, tc_max;
      planes.child(c, row.t_lo, &tau, &tc_max);
      const I placed = open & (tau < tc_max) & (tau <= row.t_max);
      hit_t = placed ? tau : hit_t;
      hit_c = placed ? L::template splat<I>(c) : hit_c;
      hit_lod = placed ? (tc_max * size_coef_ + size_bias_ >= side) : hit_lod;
      open &= ~placed;
    }
    const uint32_t hits = L::bits(hit_c >= 0);
    if (hits == 0) return;
    int32_t rec[8][2];
    for (int c = 0; c < 8; ++c) rec[c][0] = rec[c][1] = -1;
    for (uint32_t b = hits; b != 0; b &= b - 1) {
      const int l = std::countr_zero(b), c = hit_c[l], lod = hit_lod[l] != 0;
      const float clo[3] = {lo[0] + ((c & 1) ? hs : 0.f), lo[1] + ((c & 2) ? hs : 0.f),
                            lo[2] + ((c & 4) ? hs : 0.f)};
      record(rs, 0, 1u << l, hit_t, node, desc, c, s, clo, lod ? CastStop::kLod : CastStop::kLeaf,
             index, &rec[c][lod]);
    }
  }

  /// visit() of a packed node without contours, in two passes: first every
  /// child's test on the rays k (no branch per child; the children's block,
  /// prefetched when the node was fetched, arrives meanwhile), then, front
  /// to back, the hits and descents on the rays still without a hit (a
  /// subtree visited first may have taken some).
  void packed_children(RaySet& rs, const Row& row, const PackedPlanes& planes, const Desc& desc,
                       uint32_t node, int s, const float* lo, uint32_t k, int flip,
                       uint32_t present, const Index& index) {
    const float hs = scale_side(s);
    const F side = L::template splat<F>(hs);
    F tau[8];
    uint32_t placed[8], lod[8];
    int slot[8], n = 0;
    for (uint32_t b = front_to_back(present, flip); b != 0; b &= b - 1) {
      const int c = std::countr_zero(b) ^ 7 ^ flip;
      F tc_max;
      planes.child(c, row.t_lo, &tau[n], &tc_max);
      placed[n] = k & L::bits((tau[n] < tc_max) & (tau[n] <= row.t_max));
      lod[n] = L::bits(tc_max * size_coef_ + size_bias_ >= side);
      slot[n++] = c;
    }
    for (int j = 0; j < n; ++j) {
      const uint32_t now = placed[j] & rs.active[0];
      if (now == 0) continue;
      const int c = slot[j];
      const float clo[3] = {lo[0] + ((c & 1) ? hs : 0.f), lo[1] + ((c & 2) ? hs : 0.f),
                            lo[2] + ((c & 4) ? hs : 0.f)};
      int32_t rec_lod = -1, rec_leaf = -1;
      const uint32_t stop = now & lod[j];
      if (stop != 0)
        record(rs, 0, stop, tau[j], node, desc, c, s, clo, CastStop::kLod, index, &rec_lod);
      const uint32_t rest = now & ~stop;
      if (rest == 0) continue;
      if (nodes_.leaf(desc, c, s)) {
        record(rs, 0, rest, tau[j], node, desc, c, s, clo, CastStop::kLeaf, index, &rec_leaf);
      } else {
        Index child_index = index;
        const uint32_t child = nodes_.descend(desc, node, c, s, child_index, cnt_);
        visit_packed(child, s - 1, clo, rest, child_index);
      }
    }
  }

  /// The next level's fetches, started when a node is fetched (a
  /// depth-first walk has one node in flight otherwise): the policy's
  /// optional hook.
  void prefetch_below(const Desc& desc, uint32_t node, int s) const {
    if constexpr (requires { nodes_.prefetch_below(desc, node, s); })
      nodes_.prefetch_below(desc, node, s);
  }
  /// Front to back (core/octree_tile_caster.hpp "Order") in the node of
  /// side 2 hs at lo: slot bit a of the first child is the eye's half on
  /// axis a; children come in the order m ^ flip, m = 7 ... 0.
  int child_order(const float* lo, float hs) const {
    int flip = 0;
    if (rays_.perspective) {
      if (!(rays_.eye.x >= lo[0] + hs)) flip |= 1;
      if (!(rays_.eye.y >= lo[1] + hs)) flip |= 2;
      if (!(rays_.eye.z >= lo[2] + hs)) flip |= 4;
    } else {
      if (!(rays_.forward.x < 0.f)) flip |= 1;
      if (!(rays_.forward.y < 0.f)) flip |= 2;
      if (!(rays_.forward.z < 0.f)) flip |= 4;
    }
    return flip;
  }

  /// The present children in the walk's order (m ^ flip for m = 7 ... 0) as
  /// a mask to iterate from its lowest bit: bit i is child i ^ 7 ^ flip's
  /// (bit c of `present` moved to c ^ 7 ^ flip by three fixed swaps), so a
  /// loop visits only the present children, with no branch per slot.
  static uint32_t front_to_back(uint32_t present, int flip) {
    const int g = 7 ^ flip;
    uint32_t x = present;
    if (g & 1) x = (x & 0x55u) << 1 | (x & 0xAAu) >> 1;
    if (g & 2) x = (x & 0x33u) << 2 | (x & 0xCCu) >> 2;
    if (g & 4) x = (x & 0x0Fu) << 4 | (x & 0xF0u) >> 4;
    return x;
  }

  /// visit() of a packed node without contours (the rays of lanes `mask`
  /// of packed_): bottom() or packed_children(). Its own function, small,
  /// for the walk's most frequent visits (no frame of the unpacked loop).
  void visit_packed(uint32_t node, int s, const float* lo, uint32_t mask, const Index& index) {
    RaySet& rs = packed_;
    const uint32_t k = mask & rs.active[0];
    if (k == 0) return;
    const Desc desc = nodes_.fetch(node, s, cnt_);
    const uint32_t present = P::mask(desc);
    const float hs = scale_side(s);
    prefetch_below(desc, node, s);
    const int flip = child_order(lo, hs);
    // Every child a stop for every ray: a LOD stop wherever the ray is
    // placed (the test is monotone in t, and a child's tc_max > its tau >=
    // the node's entry t: the node's entry planes come first on every
    // axis), or a leaf. (A ray not placed in the node is placed in none
    // of its children.)
    const Row row(rs, kOctreeMaxScale, 0);  // span_level() without contours
    const PackedPlanes planes(row, lo, hs);
    bool stops = false;
    if (lod_possible_) {
      const F side = L::template splat<F>(hs);
      stops = (k & ~L::bits(planes.entry(row.t_lo) * size_coef_ + size_bias_ >= side)) == 0;
    }
    if (!stops) {
      stops = true;
      for (uint32_t b = present; b != 0 && stops; b &= b - 1)
        stops = nodes_.leaf(desc, std::countr_zero(b), s);
    }
    if (stops) {
      bottom(rs, row, planes, desc, node, s, lo, k, flip, present, index);
      return;
    }
    packed_children(rs, row, planes, desc, node, s, lo, k, flip, present, index);
  }

  /// The children (scale s) of `node`, whose cube has min corner lo, for the
  /// rays of `rs` in `mask` (rows `rows`); their spans are rs.span_*[s + 1].
  void visit(RaySet& rs, uint32_t node, int s, const float* lo, uint32_t rows, const uint32_t* mask,
             const Index& index) {
    if (!rs.packed) {
      const int n = live_count(mask, rs.active, rows);
      if (n <= N) {
        if (n == 0) return;
        const uint32_t lanes = pack_rays(s, rows, mask);
        visit(packed_, node, s, lo, 1u, &lanes, index);
        return;
      }
    }
    if (rs.packed && !contours_) {
      visit_packed(node, s, lo, mask[0], index);
      return;
    }
    const Desc desc = nodes_.fetch(node, s, cnt_);
    const uint32_t present = P::mask(desc);
    const float hs = scale_side(s);
    prefetch_below(desc, node, s);
    const int flip = child_order(lo, hs);
    const F* parent_hi = rs.span_hi[span_level(s + 1)];
    const F side = L::template splat<F>(hs);
    uint32_t child_mask[kTileRows] = {};  // (the 16-lane row helpers load all rows)
    // A big node's children against the tile's pixels (cull_children).
    const bool culls = !rs.packed && rays_.perspective;
    ChildCull cull;
    if (culls) cull_children(lo, hs, &cull);
    for (uint32_t b = front_to_back(present, flip); b != 0; b &= b - 1) {
      const int c = std::countr_zero(b) ^ 7 ^ flip;
      // The rows whose rays still look for their hit.
      // (mask holds a row per tile row for an unpacked node, only row 0 for
      // a packed one.)
      if (rs.packed) {
        rows = (mask[0] & rs.active[0]) != 0 ? rows : 0u;  // rows = 1
      } else {
        rows = live_rows(mask, rs.active, rows);
      }
      if (rows == 0) return;

      const float clo[3] = {lo[0] + ((c & 1) ? hs : 0.f), lo[1] + ((c & 2) ? hs : 0.f),
                            lo[2] + ((c & 4) ? hs : 0.f)};
      const ChildPlanes planes(clo, hs);
      // Row r's span in the child (its span start is the node's).
      auto row_span = [&](int r, F* tau, F* tc_max, F* t_out) {
        Row(rs, span_level(s + 1), r).span(planes, tau, tc_max, t_out);
      };
      // A big node's rows: skip those its child cannot reach.
      uint32_t test_rows = rows, test_lanes = L::kAll;
      if (culls && (!contours_ || std::popcount(rows) > 2)) {
        test_rows &= cull.rows[c], test_lanes = cull.lanes[c];
        if (test_rows == 0 || test_lanes == 0) continue;
      }
      const bool leaf = nodes_.leaf(desc, c, s);
      if (culls && !contours_ && !leaf && (cull.may_stop >> c & 1u) == 0) {
        // No ray can stop in this child: no per-ray test; its candidates
        // are the node's live rays its rectangle keeps, and the tests below
        // it decide (their spans need nothing from here).
        const uint32_t child_rows = candidates(mask, rs.active, test_rows, test_lanes, child_mask);
        if (child_rows != 0) {
          Index child_index = index;
          const uint32_t child = nodes_.descend(desc, node, c, s, child_index, cnt_);
          visit(rs, child, s - 1, clo, child_rows, child_mask, child_index);
        }
        continue;
      }
      bool contoured = false;
      uint32_t contour = 0;
      if constexpr (P::kContours) {
        if (contours_) contoured = nodes_.contour(desc, node, c, &contour);
      }
      uint32_t child_rows = 0;
      int32_t rec_lod = -1, rec_leaf = -1;
      if (!contours_) {
        // Without contours (spans are the root's: span_level): every row's test first, with no
        // branch per row (which rays a child keeps is data the branch predictor cannot learn), then
        // the rows with stops, then one descent: the same placements, records in the same order as
        // the loop below.
        uint32_t stop_rows = 0, lod_mask[kTileRows], stop_mask[kTileRows];
        for (uint32_t b = test_rows; b != 0; b &= b - 1) {
          const int r = std::countr_zero(b);
          const uint32_t k = mask[r] & rs.active[r] & test_lanes;
          F tau, tc_max, t_out[3];
          row_span(r, &tau, &tc_max, t_out);
          const uint32_t placed = k & L::bits((tau < tc_max) & (tau <= parent_hi[r]));
          const uint32_t lod =
              lod_possible_ ? placed & L::bits(tc_max * size_coef_ + size_bias_ >= side) : 0u;
          lod_mask[r] = lod;
          stop_mask[r] = leaf ? placed : lod;
          child_mask[r] = leaf ? 0u : placed & ~lod;
          stop_rows |= uint32_t(stop_mask[r] != 0) << r;
          child_rows |= uint32_t(child_mask[r] != 0) << r;
        }
        for (uint32_t b = stop_rows; b != 0; b &= b - 1) {
          const int r = std::countr_zero(b);
          F tau{};
          if constexpr (!kAnyHit) {  // the hit's t, as the test above computed it
            F tc_max, t_out[3];
            row_span(r, &tau, &tc_max, t_out);
          }
          if (lod_mask[r] != 0)
            record(rs, r, lod_mask[r], tau, node, desc, c, s, clo, CastStop::kLod, index, &rec_lod);
          const uint32_t leaves = stop_mask[r] & ~lod_mask[r];
          if (leaves != 0)
            record(rs, r, leaves, tau, node, desc, c, s, clo, CastStop::kLeaf, index, &rec_leaf);
        }
        if (child_rows != 0) {
          Index child_index = index;
          const uint32_t child = nodes_.descend(desc, node, c, s, child_index, cnt_);
          visit(rs, child, s - 1, clo, child_rows, child_mask, child_index);
        }
        continue;
      }
      for (uint32_t b = test_rows; b != 0; b &= b - 1) {
        const int r = std::countr_zero(b);
        const uint32_t k = mask[r] & rs.active[r] & test_lanes;
        if (k == 0) continue;
        F tau, tc_max, t_out[3];
        row_span(r, &tau, &tc_max, t_out);
        const F t_max = parent_hi[r];
        const uint32_t placed = k & L::bits((tau < tc_max) & (tau <= t_max));
        if (placed == 0) continue;
        // LOD termination (cast_octree): before the cube's own contour.
        const uint32_t lod = placed & L::bits(tc_max * size_coef_ + size_bias_ >= side);
        if (lod != 0)
          record(rs, r, lod, tau, node, desc, c, s, clo, CastStop::kLod, index, &rec_lod);
        uint32_t rest = placed & ~lod;
        if (rest == 0) continue;
        F t_min = tau, tv_max = L::min(t_max, tc_max);
        if (contoured) {
          const F cx = rs.cx[r], cy = rs.cy[r], cz = rs.cz[r];
          const F dx = rs.dx[r], dy = rs.dy[r], dz = rs.dz[r];
          for (uint32_t q = rest; q != 0; q &= q - 1) {
            const int l = std::countr_zero(q);
            float a = t_min[l], e = tv_max[l];
            contour_span(contour, {cx[l], cy[l], cz[l]}, {dx[l], dy[l], dz[l]}, t_out[0][l],
                         t_out[1][l], t_out[2][l], hs, &a, &e);
            t_min[l] = a, tv_max[l] = e;
          }
          rest &= L::bits(t_min <= tv_max);
          if (rest == 0) continue;
        }
        if (leaf) {
          record(rs, r, rest, t_min, node, desc, c, s, clo, CastStop::kLeaf, index, &rec_leaf);
        } else {
          child_mask[r] = rest;
          if (contours_) rs.span_lo[s][r] = t_min, rs.span_hi[s][r] = tv_max;
          child_rows |= 1u << r;
        }
      }
      if (child_rows != 0) {
        Index child_index = index;
        const uint32_t child = nodes_.descend(desc, node, c, s, child_index, cnt_);
        visit(rs, child, s - 1, clo, child_rows, child_mask, child_index);
      }
    }
  }

  const P& nodes_;
  const TileRays& rays_;
  const int col0_;
  const F size_coef_, size_bias_;
  const bool contours_;
  // False when no cube can be a LOD stop: a zero coefficient and a bias of
  // at most 0 (LodFootprint{}, LOD 0), since the test is side <= exit t *
  // coef + bias with side > 0; the LOD tests are then skipped.
  const bool lod_possible_;
  TileOut* out_;
  NoCounters cnt_;
  RaySet& tile_;
  RaySet& packed_;
};

template <class P, int N>
void tile_kernel(const P& nodes, const TileRays& rays, int col0, float size_coef, float size_bias,
                 bool any_hit, TileOut* out) {
  thread_local TileStorage<N> storage;
  if (any_hit) {
    TileWalk<P, N, true>(nodes, rays, col0, size_coef, size_bias, out, &storage).run();
  } else {
    TileWalk<P, N, false>(nodes, rays, col0, size_coef, size_bias, out, &storage).run();
  }
}

}  // namespace

#define VOXCAST_DEFINE_TILE_KERNEL(name, isa, Nodes, N)                                         \
  void name##_tile_kernel_##isa(const Nodes& nodes, const TileRays& rays, int col0,             \
                                float size_coef, float size_bias, bool any_hit, TileOut* out) { \
    tile_kernel<Nodes, N>(nodes, rays, col0, size_coef, size_bias, any_hit, out);               \
  }

}  // namespace voxcast::detail
