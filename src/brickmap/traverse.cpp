// Brickmap ray casting (§3.3, §4.1): a 3-D DDA (Amanatides & Woo 1987) per
// level, occupancy layer -> brickgrid -> brick mask, in grid units (voxel
// (x, y, z) = [x, x+1] x [y, y+1] x [z, z+1]; t is the world distance, as the
// grid map p -> (p - origin) / voxel_size scales the direction with it).
//
// Consistency between levels: the t of a plane is always computed as
// (plane - o) * inv_d from the same float plane coordinate, whichever level
// asks, and every level breaks ties between axes the same way (argmin3), so
// when a finer walk leaves its parent cell through a plane, the parent's walk
// steps through exactly that plane at exactly that t. A finer walk starts in
// the cell holding the entry point, clamped into its parent (rounding of the
// entry point can only move it across a plane within float slack of it: a
// near tie in the oracle's sense, tests/support/dda_oracle.hpp).
#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cmath>
#include <limits>
#if defined(__AVX2__)
#include <immintrin.h>
#endif

#include "brickmap/brick_skip.hpp"
#include "brickmap/packet_walk.hpp"
#include "core/beam_frustum.hpp"
#include "voxcast/brickmap.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/isa.hpp"

namespace voxcast::brickmap {

namespace detail {
std::atomic<BrickSkip> brick_skip_mode{BrickSkip::Simd};
std::atomic<bool> brick_block_masks{true};
std::atomic<uint64_t> packet_lane_faults{0};
}  // namespace detail

namespace {

// Fixed tie break (x, then y, then z) shared by every level.
inline int argmin3(const float v[3]) {
  return v[0] <= v[1] ? (v[0] <= v[2] ? 0 : 2) : (v[1] <= v[2] ? 1 : 2);
}

struct GridRay {
  float o[3], d[3], inv[3];
  int step[3];  // +1 / -1: the side the ray moves to (the sign bit for a zero component)
  int up[3];    // 1 if step > 0: the exit plane of cell c is c + up
};

// The ray in grid units; false for non-finite input. Direction components
// below 2^-23 of the largest are replaced by +-2^-23 of it (sign kept, also
// for -0): such a ray cannot cross that axis's next plane inside a grid of
// fewer than 2^23 voxels, so it stays on the side its sign picks, and the
// arithmetic below stays finite.
// inv_vs: 1 / g.voxel_size, which trace_packets() divides once per call
// instead of once per ray (the same double).
[[gnu::always_inline]] inline bool to_grid(const GridTransform& g, double inv_vs, const Ray& ray,
                                           GridRay* r) {
  if (!is_finite(ray.origin) || !is_finite(ray.dir)) return false;
  float big = 0.f;
  for (int a = 0; a < 3; ++a) {
    r->o[a] = float((double(ray.origin[a]) - g.origin[a]) * inv_vs);
    r->d[a] = float(double(ray.dir[a]) * inv_vs);
    big = std::max(big, std::fabs(r->d[a]));  // finite inputs: no libm fmax call
  }
  if (!(big > 0.f) || !std::isfinite(big)) return false;
  const float tiny = big * 0x1p-23f;
  for (int a = 0; a < 3; ++a) {
    if (std::fabs(r->d[a]) < tiny) r->d[a] = std::copysign(tiny, r->d[a]);
    r->inv[a] = 1.f / r->d[a];
    r->step[a] = std::signbit(r->d[a]) ? -1 : 1;
    r->up[a] = r->step[a] > 0;
  }
  return true;
}
bool to_grid(const GridTransform& g, const Ray& ray, GridRay* r) {
  return to_grid(g, 1.0 / g.voxel_size, ray, r);
}

// std::nextafter(x, -INFINITY) for a finite x, from the bits (no libm call
// per beam-started ray).
inline float next_below(float x) {
  if (x == 0.f) return -std::numeric_limits<float>::denorm_min();
  const uint32_t b = std::bit_cast<uint32_t>(x);
  return std::bit_cast<float>(x > 0.f ? b - 1 : b + 1);
}
// std::nextafter(x, INFINITY) for a finite x.
inline float next_above(float x) {
  return -next_below(-x);
}

inline float plane_t(const GridRay& r, int a, float coord) {
  return (coord - r.o[a]) * r.inv[a];
}

// Cell of side 2^side_log2 (grid units) holding o + d t, ties towards the
// side the ray moves to, clamped to [lo[a], hi[a]].
inline void start_cell(const GridRay& r, float t, int side_log2, const int lo[3], const int hi[3],
                       int c[3]) {
  // 2^-side_log2 from its exponent bits: exact, and no division per descent.
  const float inv_side = std::bit_cast<float>(uint32_t(127 - side_log2) << 23);
  for (int a = 0; a < 3; ++a) {
    const float p = (r.o[a] + r.d[a] * t) * inv_side;
    const float f = r.up[a] ? std::floor(p) : std::ceil(p) - 1.f;
    const float clamped = std::min(std::max(f, float(lo[a])), float(hi[a]));
    c[a] = int(clamped);
  }
}

struct Found {
  float t;
  int face;   // entered face (axis * 2 + (outward normal negative ? 1 : 0))
  int level;  // cube level of the hit (grid.levels = a voxel)
  int c[3];   // the cube's coordinates at that level
  uint64_t ref;
};

// brick_slices()'s slack on axis a for a ray inside [0, t1]: the DDA's
// cell at t follows from plane t values (plane_t) and its start cell from a
// position (start_cell), each within a few ulps of |o| + |d| t (grid units)
// of the position o + d t the box test computes; 2^-16 of that bound is
// 128 ulps and more, and still a small fraction of a voxel in the grids
// below 2^13 voxels the bricks are built for.
inline float brick_slack(const GridRay& r, int a, float t1) {
  return (std::fabs(r.o[a]) + std::fabs(r.d[a]) * t1) * 0x1p-16f + 0x1p-16f;
}

inline int face_of(const GridRay& r, int axis) {
  return axis * 2 + (r.up[axis] ? 1 : 0);
}

// Solid bits of a 2x2x2 / 4x4x4 block of brick-local voxels at (x, y, z)
// (multiples of the side): true if any is solid.
inline bool block_solid(const Brick& b, int side, int x, int y, int z) {
  const uint64_t row = side == 2 ? 0x3u : 0xFu;
  uint64_t plane = 0;  // the block's x-y footprint within one z slice
  for (int dy = 0; dy < side; ++dy) plane |= row << ((y + dy) * 8 + x);
  for (int dz = 0; dz < side; ++dz)
    if (b.mask[z + dz] & plane) return true;
  return false;
}

enum class Step { Hit, Exit, Done };

// Three cube coordinates, passed by value so that a loop's own coordinates
// never escape to memory (the compiler keeps a DDA's state in registers).
struct Int3 {
  int v[3];
};

// One DDA over the children [lo, lo + span] of one cube at a child level
// (side `side` in grid units): the current child c, the t of its exit plane
// per axis, and the plane last crossed (t, axis; the entered face is
// face_of(axis)). Every member is accessed with constant indices only (the
// step is written once per axis, step_axis<A>), so a loop's Dda lives in
// registers; the variable-index version of this loop spilled c and n to the
// stack and reloaded them each step (BENCHMARKS.md, "Brickmap walk in
// registers").
struct Dda {
  int c[3];
  float n[3];
  int lo[3];
  uint32_t span[3];
  float side;
  float t;
  int axis;
  float exit() const { return std::min(std::min(n[0], n[1]), n[2]); }
  Int3 cell() const { return {{c[0], c[1], c[2]}}; }
};

enum : int { kExitParent = 3, kEndOfRay = 4 };

// Steps across the exit plane of axis A; returns A, or kExitParent when the
// ray leaves the parent cube, or kEndOfRay past t1 (one unsigned compare for
// the range, one for the end of the ray). `index` follows the child by
// `dstride[A]` (cells and nodes; null for voxels).
template <int A>
[[gnu::always_inline]] inline int step_axis(Dda& d, const GridRay& r, float t1, int64_t* index,
                                            const int64_t* dstride) {
  const float tn = d.n[A];
  const int cn = d.c[A] + r.step[A];
  d.t = tn;
  d.axis = A;
  d.c[A] = cn;
  if (uint32_t(cn - d.lo[A]) > d.span[A]) return kExitParent;
  if (tn > t1) return kEndOfRay;
  d.n[A] = plane_t(r, A, float(cn + r.up[A]) * d.side);
  if (index) *index += dstride[A];
  return A;
}

// The nearest exit plane with argmin3's tie break (x, then y, then z).
[[gnu::always_inline]] inline int advance(Dda& d, const GridRay& r, float t1,
                                          int64_t* index = nullptr,
                                          const int64_t* dstride = nullptr) {
  if (d.n[0] <= d.n[1])
    return d.n[0] <= d.n[2] ? step_axis<0>(d, r, t1, index, dstride)
                            : step_axis<2>(d, r, t1, index, dstride);
  return d.n[1] <= d.n[2] ? step_axis<1>(d, r, t1, index, dstride)
                          : step_axis<2>(d, r, t1, index, dstride);
}

inline Step end_of(int s) {
  return s == kExitParent ? Step::Exit : Step::Done;
}

// The walk over the level hierarchy (brickmap.hpp, BrickmapStructure): the
// pyramid levels (ratio 2; one level at a time while the footprint may stop
// there, else kPyramidStep levels per descent, child_level), the brickgrid
// (empty cubes of cells crossed in one step, jump), the cubes inside a brick
// and the voxels. Every level is a DDA of
// the same kind over the children of one cube of the level above. kAny
// (the any-hit walk of transmittance()): the same steps and decisions, so
// the same hit / miss answer, without recording the hit (Found untouched).
template <bool kCount, bool kAny>
struct Walker {
  const World& w;
  const GridRay& r;
  const LodFootprint& lod;
  TraceContext& ctx;
  float t1;  // end of the ray inside the grid
  int L;     // grid levels (voxel level)
  int B;     // brick level L - 3 (negative in grids below 8^3)
  float voxel_world_f;
  bool lod_on;     // false for a footprint of 0 (LOD 0): no cube side is <= it
  uint32_t* seen;  // per brick slot: frame of the last ray that entered it (or null)
  Found* f;
  // The t a beam-started walk begins at (NaN otherwise): begin() at this t
  // finds its start cell by plane comparisons (start_cell_exact).
  float start_t = NAN;
  // Per axis, a bound on how far (grid units) the positions computed in
  // brick_slices() can lie from the ones the DDA's plane crossings imply
  // (brick_slack).
  float slack[3] = {0.f, 0.f, 0.f};
  // The brickgrid's index strides per axis, and times the ray's step: the
  // same for every cell walk of the ray (set once per ray, not per descent).
  int64_t cell_stride[3] = {0, 0, 0}, cell_dstride[3] = {0, 0, 0};

  // The cube side in world units: voxel_world 2^(L - level), exact in float
  // as in double (a power-of-two scale) and without a libm call per step.
  float side_world(int level) const { return voxel_world_f * float(1u << (L - level)); }
  bool lod_stop(int level, float exit) const {
    return lod_on && side_world(level) <= lod.size_at_origin + lod.size_per_t * exit;
  }

  // Occupancy of cube `c` at `level`; `cell`: the brickgrid cell holding it
  // (levels >= the brick level), `node`: its pyramid node (levels above).
  bool occupied(int level, Int3 c, uint32_t* cell, const PyramidNode** node) const {
    if (level < B) {
      const int k = B - level;
      if (uint32_t(c.v[1]) >= w.pyramid_dim_y(k)) return false;  // above a cut-off brickgrid
      *node = &w.pyramid_node(
          k, w.pyramid_index(k, uint32_t(c.v[0]), uint32_t(c.v[1]), uint32_t(c.v[2])));
      return (*node)->bricks != 0;
    }
    const int s = L - level;  // log2 of the cube's side in voxels (<= 3)
    if (uint32_t(c.v[1] << s >> kBrickLog2) >= w.dims()[1]) return false;
    *cell = w.cell(w.cell_index(uint32_t(c.v[0] << s >> kBrickLog2),
                                uint32_t(c.v[1] << s >> kBrickLog2),
                                uint32_t(c.v[2] << s >> kBrickLog2)));
    if (*cell == 0) return false;
    if (level <= std::max(B, 0) || cell_state(*cell) != kStateResident) return true;
    const Brick& b = w.brick(cell_brick(*cell));
    const int x = (c.v[0] << s) & 7, y = (c.v[1] << s) & 7, z = (c.v[2] << s) & 7;
    if (s == 0) return (b.mask[z] >> voxel_bit(uint32_t(x), uint32_t(y), 0)) & 1;
    return block_solid(b, 1 << s, x, y, z);
  }

  // An occupied cube the walk stops at (entered at t through the plane of
  // `axis`): a voxel, or an LOD answer.
  void stop(int level, Int3 c, uint32_t cell, const PyramidNode* node, float t, int axis) {
    if constexpr (kAny) return;
    uint64_t ref;
    // (A voxel only in a resident brick: a 1^3 grid's root is its voxel,
    // and a streamed world may not have its brick yet.)
    if (level == L && cell_state(cell) == kStateResident) {
      ref = uint64_t(cell_brick(cell)) << 9 |
            voxel_bit(uint32_t(c.v[0] & 7), uint32_t(c.v[1] & 7), uint32_t(c.v[2] & 7));
    } else if (level < B) {
      ref = uint64_t(1) << 63 | node->abgr;
    } else {
      ref = uint64_t(1) << 63 | (cell_state(cell) == kStateResident ? w.brick(cell_brick(cell)).lod
                                                                    : cell_lod_abgr(cell));
    }
    *f = {t, face_of(r, axis), level, {c.v[0], c.v[1], c.v[2]}, ref};
  }

  // The level the walk descends to from an occupied `level` cube it does not
  // stop at: the next level, or (when the footprint at the cube's exit is too
  // small for any level in between to stop at: the footprint only grows with
  // t, and the levels skipped have larger cubes than the last of them) a
  // level further down: above the brickgrid the pyramid levels B - j
  // kPyramidStep (a node has up to 2^(3 kPyramidStep) children, which costs
  // fewer descents than one level at a time through a surface where every
  // node is occupied), then the brickgrid, then the voxels.
  // From a brickgrid cell whose 2^3 blocks may stop but whose 4^3 ones
  // cannot, straight to the 2^3 blocks (visit_pairs).
  static constexpr int kPyramidStep = 3;
  int child_level(int level, float exit) const {
    if (level < B) {
      const int target = B - (B - level - 1) / kPyramidStep * kPyramidStep;
      return target == level + 1 || !lod_stop(target - 1, exit) ? target : level + 1;
    }
    if (!lod_stop(L - 1, exit)) return L;
    return level == B && !lod_stop(B + 1, exit) ? L - 1 : level + 1;
  }

  // The children at level `cl` of the cube (cl - ratio_log2, pc), from the
  // one holding the point at t (entered through the plane of `axis`).
  Dda begin(int cl, int ratio_log2, Int3 pc, float t, int axis) {
    Dda d;
    d.side = float(1 << (L - cl));
    d.t = t;
    d.axis = axis;
    const int top = (1 << cl) - 1;
    int hi[3];
    for (int a = 0; a < 3; ++a) {
      d.lo[a] = pc.v[a] << ratio_log2;
      hi[a] = std::min(top, d.lo[a] + (1 << ratio_log2) - 1);
      d.span[a] = uint32_t(hi[a] - d.lo[a]);
    }
    start_cell(r, t, L - cl, d.lo, hi, d.c);
    if (t == start_t) start_cell_exact(t, d.side, d.lo, hi, d.c);
    for (int a = 0; a < 3; ++a) d.n[a] = plane_t(r, a, float(d.c[a] + r.up[a]) * d.side);
    if constexpr (kCount) ++ctx.counters.pushes;
    return d;
  }

  // The cell the cell-by-cell walk is in just after t (every crossing at or
  // before t taken): per axis, the cell whose entry plane's t is <= t and
  // whose exit plane's t is > t, the same plane_t values the DDA compares.
  // The estimate from the position is off by at most a cell near a plane.
  void start_cell_exact(float t, float side, const int lo[3], const int hi[3], int c[3]) const {
    for (int a = 0; a < 3; ++a) {
      const int fwd = r.step[a] > 0 ? hi[a] : lo[a], back = r.step[a] > 0 ? lo[a] : hi[a];
      while (c[a] != fwd && plane_t(r, a, float(c[a] + r.up[a]) * side) <= t) c[a] += r.step[a];
      while (c[a] != back && plane_t(r, a, float(c[a] + 1 - r.up[a]) * side) > t) c[a] -= r.step[a];
    }
  }

  // The loops below are visit()'s general loop specialized per child level
  // (the same planes, t values and tie breaks, so the same hits): voxels of
  // a brick with its mask at hand, brickgrid cells and pyramid nodes with
  // their index stepped instead of recomputed.

  // §3.3, §4.1: a brick is one 512-bit mask, z slice k in mask[k] (bit
  // 8 y + x). The voxels of slice k the DDA visits between t0 and te lie in
  // the box of x and y the ray spans while its z is in [k, k + 1], each
  // range widened by the slack (the DDA decides by plane t values, the box
  // by positions: they differ by rounding only). Bit k is set when slice
  // k's box meets the slice's solid bits; the DDA finds no hit in a slice
  // whose bit is clear. A superset test, so the walk's hits do not depend
  // on it (0xFF: every slice may hold one). The eight slices are eight float
  // lanes (AVX2), the scalar loop is the reference (BrickmapSkip tests).
  uint32_t brick_slices(const Brick& b, Int3 pc, float t0, float te) const {
    float base[3];  // the ray origin relative to the brick's corner
    for (int a = 0; a < 3; ++a) base[a] = r.o[a] - float(pc.v[a] << kBrickLog2);
    const detail::BrickSkip mode = detail::brick_skip_mode.load(std::memory_order_relaxed);
#if defined(__AVX2__)
    if (mode == detail::BrickSkip::Simd) return brick_slices_avx2(b, base, t0, te);
#endif
    return mode == detail::BrickSkip::Off ? 0xFFu : brick_slices_scalar(b, base, t0, te);
  }

  uint32_t brick_slices_scalar(const Brick& b, const float base[3], float t0, float te) const {
    uint32_t slices = 0;
    for (int k = 0; k < 8; ++k) {
      const float ta = (float(k) - slack[2] - base[2]) * r.inv[2];
      const float tb = (float(k) + (1.f + slack[2]) - base[2]) * r.inv[2];
      const float lo = std::max(std::min(ta, tb), t0), hi = std::min(std::max(ta, tb), te);
      if (!(lo <= hi)) continue;
      int first[2], last[2];
      for (int a = 0; a < 2; ++a) {
        const float p0 = base[a] + r.d[a] * lo, p1 = base[a] + r.d[a] * hi;
        const float f = std::floor(std::min(p0, p1) - slack[a]);
        const float l = std::floor(std::max(p0, p1) + slack[a]);
        first[a] = int(std::min(std::max(f, 0.f), 7.f));
        last[a] = int(std::min(std::max(l, 0.f), 7.f));
      }
      const uint64_t row = (0xFFu << first[0]) & (0xFFu >> (7 - last[0]));
      const uint64_t rows = (~uint64_t(0) << 8 * first[1]) & (~uint64_t(0) >> 8 * (7 - last[1]));
      if (b.mask[k] & row * 0x0101010101010101u & rows) slices |= 1u << k;
    }
    return slices;
  }

#if defined(__AVX2__)
  // brick_slices_scalar() with the slices in lanes, each 64-bit slice as
  // its two 32-bit halves (rows 0-3, rows 4-7). Variable shifts of 32 or
  // more give 0, which drops the rows outside a half.
  uint32_t brick_slices_avx2(const Brick& b, const float base[3], float t0, float te) const {
    // Lane order of the mask's deinterleaved dwords (below): slices 0 1 4 5 2 3 6 7.
    const __m256 k = _mm256_setr_ps(0, 1, 4, 5, 2, 3, 6, 7);
    const __m256 oz = _mm256_set1_ps(base[2]), iz = _mm256_set1_ps(r.inv[2]);
    const __m256 ta =
        _mm256_mul_ps(_mm256_sub_ps(_mm256_sub_ps(k, _mm256_set1_ps(slack[2])), oz), iz);
    const __m256 tb =
        _mm256_mul_ps(_mm256_sub_ps(_mm256_add_ps(k, _mm256_set1_ps(1.f + slack[2])), oz), iz);
    const __m256 lo = _mm256_max_ps(_mm256_min_ps(ta, tb), _mm256_set1_ps(t0));
    const __m256 hi = _mm256_min_ps(_mm256_max_ps(ta, tb), _mm256_set1_ps(te));
    const __m256i valid = _mm256_castps_si256(_mm256_cmp_ps(lo, hi, _CMP_LE_OQ));
    __m256i first[2], last[2];
    for (int a = 0; a < 2; ++a) {
      const __m256 o = _mm256_set1_ps(base[a]), d = _mm256_set1_ps(r.d[a]);
      const __m256 e = _mm256_set1_ps(slack[a]);
      const __m256 p0 = _mm256_add_ps(o, _mm256_mul_ps(d, lo));
      const __m256 p1 = _mm256_add_ps(o, _mm256_mul_ps(d, hi));
      const __m256 zero = _mm256_setzero_ps(), seven = _mm256_set1_ps(7.f);
      const __m256 f = _mm256_floor_ps(_mm256_sub_ps(_mm256_min_ps(p0, p1), e));
      const __m256 l = _mm256_floor_ps(_mm256_add_ps(_mm256_max_ps(p0, p1), e));
      first[a] = _mm256_cvttps_epi32(_mm256_min_ps(_mm256_max_ps(f, zero), seven));
      last[a] = _mm256_cvttps_epi32(_mm256_min_ps(_mm256_max_ps(l, zero), seven));
    }
    const __m256i ff = _mm256_set1_epi32(0xFF), ones = _mm256_set1_epi32(-1);
    const __m256i seven = _mm256_set1_epi32(7), zero = _mm256_setzero_si256();
    // Bits first..last of x, in every byte of the lane.
    const __m256i row = _mm256_and_si256(_mm256_sllv_epi32(ff, first[0]),
                                         _mm256_srlv_epi32(ff, _mm256_sub_epi32(seven, last[0])));
    const __m256i spread = _mm256_setr_epi8(0, 0, 0, 0, 4, 4, 4, 4, 8, 8, 8, 8, 12, 12, 12, 12, 0,
                                            0, 0, 0, 4, 4, 4, 4, 8, 8, 8, 8, 12, 12, 12, 12);
    const __m256i xs = _mm256_and_si256(_mm256_shuffle_epi8(row, spread), valid);
    // Rows first..last of y in the low half (rows 0-3) and the high half.
    const __m256i y0 = _mm256_slli_epi32(first[1], 3), y1 = _mm256_slli_epi32(last[1], 3);
    const __m256i c24 = _mm256_set1_epi32(24), c32 = _mm256_set1_epi32(32),
                  c56 = _mm256_set1_epi32(56);
    const __m256i low = _mm256_and_si256(
        _mm256_sllv_epi32(ones, y0),
        _mm256_srlv_epi32(ones, _mm256_max_epi32(_mm256_sub_epi32(c24, y1), zero)));
    const __m256i high =
        _mm256_and_si256(_mm256_sllv_epi32(ones, _mm256_max_epi32(_mm256_sub_epi32(y0, c32), zero)),
                         _mm256_srlv_epi32(ones, _mm256_sub_epi32(c56, y1)));
    const __m256 m0 = _mm256_loadu_ps(reinterpret_cast<const float*>(b.mask));
    const __m256 m1 = _mm256_loadu_ps(reinterpret_cast<const float*>(b.mask + 4));
    const __m256i mlo = _mm256_castps_si256(_mm256_shuffle_ps(m0, m1, _MM_SHUFFLE(2, 0, 2, 0)));
    const __m256i mhi = _mm256_castps_si256(_mm256_shuffle_ps(m0, m1, _MM_SHUFFLE(3, 1, 3, 1)));
    const __m256i hits = _mm256_and_si256(
        xs, _mm256_or_si256(_mm256_and_si256(low, mlo), _mm256_and_si256(high, mhi)));
    // Lane bits (slices 0 1 4 5 2 3 6 7) to slice bits.
    const uint32_t lanes =
        ~uint32_t(_mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(hits, zero)))) & 0xFFu;
    return (lanes & 0xC3u) | (lanes & 0x0Cu) << 2 | (lanes & 0x30u) >> 2;
  }
#endif

  // The voxel DDA `d` moved on to the state advance() reaches when it
  // crosses into z slice `cz` ahead of it: the crossings come in (t, axis)
  // order (argmin3's tie break; jump()'s argument), so every x and y
  // crossing at or before that plane's t comes first. False when the ray
  // leaves the brick or ends (t1) before.
  // (The same for the 2^3 blocks' DDA of visit_pairs, slab cz of side 2.)
  bool enter_slice(Dda& d, int cz) const {
    const float tz = plane_t(r, 2, float(cz + 1 - r.up[2]) * d.side);
    if (tz > t1) return false;
    for (int b = 0; b < 2; ++b)
      while (d.n[b] <= tz) {
        d.c[b] += r.step[b];
        if (uint32_t(d.c[b] - d.lo[b]) > d.span[b]) return false;
        d.n[b] = plane_t(r, b, float(d.c[b] + r.up[b]) * d.side);
      }
    d.c[2] = cz;
    d.n[2] = plane_t(r, 2, float(cz + r.up[2]) * d.side);
    d.t = tz;
    d.axis = 2;
    return true;
  }

  // The DDA `d` over the 2^n slabs of a brick (z of brickgrid cell pcz; n =
  // 3: voxels, 2: 2^3 blocks) moved to the first slab ahead whose bit in
  // `slabs` is set (in the ray's z order, from its start slab): the cubes
  // it would visit before are empty. False when there is none, or the ray
  // leaves the brick or ends before it.
  bool enter_first_slab(Dda& d, uint32_t slabs, int n, int pcz) const {
    const int z0 = d.c[2] & ((1 << n) - 1);
    const uint32_t ahead = r.up[2] ? slabs >> z0 << z0 : slabs & ((2u << z0) - 1);
    if (ahead == 0) return false;
    const int k = r.up[2] ? std::countr_zero(ahead) : 31 - std::countl_zero(ahead);
    return k == z0 || enter_slice(d, (pcz << n) + k);
  }

  // The voxels of the resident brick `brick_index` (brickgrid cell pc) the
  // ray crosses, from t to `exit` (the cell's exit t).
  Step visit_voxels(uint32_t brick_index, Int3 pc, float t, int axis, float exit) {
    const Brick& b = w.brick(brick_index);
    // A brick the ray crosses without touching a solid voxel is left without
    // its DDA (the caller steps across the cell's exit plane, as after the
    // DDA's own kExitParent; past t1 that step ends the ray, as kEndOfRay).
    const uint32_t slices = brick_slices(b, pc, t, std::min(exit, t1));
    if (slices == 0) return Step::Exit;
    Dda d = begin(L, kBrickLog2, pc, t, axis);
    // Straight to the first slice that may hold a hit.
    if (!enter_first_slab(d, slices, kBrickLog2, pc.v[2])) return Step::Exit;
    for (;;) {
      if constexpr (kCount) ++ctx.counters.iterations, ++ctx.counters.intersects;
      const uint32_t bit =
          voxel_bit(uint32_t(d.c[0] & 7), uint32_t(d.c[1] & 7), uint32_t(d.c[2] & 7));
      if (test_voxel(b, bit)) {
        if constexpr (!kAny)
          *f = {d.t,
                face_of(r, d.axis),
                L,
                {d.c[0], d.c[1], d.c[2]},
                uint64_t(brick_index) << 9 | bit};
        return Step::Hit;
      }
      const int s = advance(d, r, t1);
      if (s > 2) return end_of(s);
    }
  }

  // The 2^3 blocks of the resident brick of cell `pcell` (cell pc) when an
  // LOD footprint may stop at them but not at the 4^3 blocks (child_level):
  // visit_voxels' brick test and slice entry on the brick's mask dilated to
  // whole blocks (a block's 8 bits all set when one is), so a brick whose
  // occupied blocks the ray misses is left at once and the blocks before
  // the first slab (2 slices) ahead that may hold one are skipped; then
  // visit_blocks' DDA. The same hits as the blocks walked one by one
  // (BrickmapSkip.TheSameLodHitsWithAndWithoutTheBlockMasks).
  Step visit_pairs(uint32_t pcell, Int3 pc, float t, int axis, float exit) {
    uint64_t m[8];
    fold_blocks(w.brick(cell_brick(pcell)), 1, m);
    // Each block's bit (its corner's in the fold) spread to its 8 voxels.
    Brick blocks;
    for (int k = 0; k < 4; ++k) {
      uint64_t v = m[k] & 0x0055005500550055u;
      v |= v << 1;
      blocks.mask[2 * k] = blocks.mask[2 * k + 1] = v | v << 8;
    }
    const uint32_t slices = brick_slices(blocks, pc, t, std::min(exit, t1));
    if (slices == 0) return Step::Exit;
    Dda d = begin(L - 1, 2, pc, t, axis);
    // Slab j holds slices 2 j and 2 j + 1; the ray may meet one of them only.
    const uint32_t pairs = (slices | slices >> 1) & 0x55u;
    const uint32_t slabs = (pairs & 1) | (pairs >> 1 & 2) | (pairs >> 2 & 4) | (pairs >> 3 & 8);
    if (!enter_first_slab(d, slabs, 2, pc.v[2])) return Step::Exit;
    return walk_blocks(d, L - 1, m, pcell);
  }

  // The brickgrid cells (level B > 0) of the pyramid node (level, pc).
  Step visit_cells(int level, Int3 pc, float t, int axis) {
    // Most cell walks on a terrain cross an occupied node above its
    // non-empty cells (BENCHMARKS.md, "Brickmap beam pass in lanes"; 55-66 %
    // of them). A walk that meets no non-empty cell stops nowhere and
    // changes nothing (no stop, request or `seen` mark), so a ray that
    // misses the box of the node's non-empty cells (World::cell_box),
    // widened by the position slack (brick_slack: the DDA's cells follow
    // from plane t values and a start position, within that of the
    // positions here), leaves the node as the walk would, without it.
    if (B - level == World::kCellBoxLevel && !meets_cell_box(pc, t)) return Step::Exit;
    Dda d = begin(B, B - level, pc, t, axis);
    const uint32_t* cells = w.cells().data();
    const uint32_t dim_y = w.dims()[1];
    const int64_t* stride = cell_stride;
    const int64_t* dstride = cell_dstride;
    int64_t index = d.c[0] + stride[1] * d.c[1] + stride[2] * d.c[2];
    for (;;) {
      if constexpr (kCount) ++ctx.counters.iterations;
      const uint32_t cell = uint32_t(d.c[1]) < dim_y ? cells[index] : 0;  // above a cut-off grid
      if (cell != 0) {
        const bool resident = cell_state(cell) == kStateResident;
        if (seen && resident)
          std::atomic_ref<uint32_t>(seen[cell_brick(cell)])
              .store(ctx.frame, std::memory_order_relaxed);
        const float cexit = d.exit();
        if (lod_stop(B, cexit)) {
          stop(B, d.cell(), cell, nullptr, d.t, d.axis);
          return Step::Hit;
        }
        if (!resident) {
          // §3.2.1: the brick is needed; nearer is more urgent. Until it
          // arrives the cube answers with its LOD color.
          ctx.requests.push(BrickmapStructure::kRequestBrick, uint64_t(index), 1.f / (1.f + d.t));
          stop(B, d.cell(), cell, nullptr, d.t, d.axis);
          return Step::Hit;
        }
        // Straight to the brick's voxels when no LOD stop can come in between,
        // else to its blocks (visit()'s cases, without the call).
        const int bl = child_level(B, cexit);
        const bool masks = detail::brick_block_masks.load(std::memory_order_relaxed);
        const Step s = bl == L       ? visit_voxels(cell_brick(cell), d.cell(), d.t, d.axis, cexit)
                       : !masks      ? visit(B, d.cell(), cexit, cell, d.t, d.axis)
                       : bl == L - 1 ? visit_pairs(cell, d.cell(), d.t, d.axis, cexit)
                                     : visit_blocks(B, bl, d.cell(), cell, d.t, d.axis);
        if (s != Step::Exit) return s;
      }
      const int clear = cell == 0 && uint32_t(d.c[1]) < dim_y ? w.clearance(uint64_t(index)) : 0;
      const int s =
          clear > 1 ? jump(d, clear - 1, &index, stride) : advance(d, r, t1, &index, dstride);
      if (s > 2) return end_of(s);
    }
  }

  // Whether the ray between t and t1 may meet the box of the non-empty
  // cells of node pc (pyramid level kCellBoxLevel), widened by the slack.
  bool meets_cell_box(Int3 pc, float t) const {
    const uint32_t box = w.cell_box(w.pyramid_index(World::kCellBoxLevel, uint32_t(pc.v[0]),
                                                    uint32_t(pc.v[1]), uint32_t(pc.v[2])));
    float t0 = t, te = t1;
    for (int a = 0; a < 3; ++a) {
      const int cell0 = pc.v[a] << World::kCellBoxLevel;
      const float lo = float((cell0 + int(box >> (3 * a) & 7)) << kBrickLog2) - slack[a];
      const float hi = float((cell0 + int(box >> (9 + 3 * a) & 7) + 1) << kBrickLog2) + slack[a];
      const float ta = (lo - r.o[a]) * r.inv[a], tb = (hi - r.o[a]) * r.inv[a];
      t0 = std::max(t0, std::min(ta, tb));
      te = std::min(te, std::max(ta, tb));
    }
    return t0 <= te;
  }

  // An empty cell whose clearance says that the cube of `radius` cells
  // around it is empty: the DDA state after the crossing by which the ray
  // leaves that cube (clipped to the parent node), in one step instead of
  // one per cell. Exact, not approximate: plane crossings happen in (t,
  // axis) order (argmin3's tie break; a plane's t grows with its coordinate
  // on each axis), so the cube's first exit crossing is the argmin3 of its
  // exit planes, and on the other axes the cells entered before it are the
  // ones whose entry crossing comes first in that order. The same state, t
  // and axis as advance() reaching that crossing, so the same hits.
  int jump(Dda& d, int radius, int64_t* index, const int64_t stride[3]) {
    float tn[3];
    int tc[3];
    for (int a = 0; a < 3; ++a) {
      const int far = d.c[a] + r.step[a] * radius;
      tc[a] = std::min(std::max(far, d.lo[a]), d.lo[a] + int(d.span[a]));
      tn[a] = plane_t(r, a, float(tc[a] + r.up[a]) * d.side);
    }
    const int A = argmin3(tn);
    const int cn = tc[A] + r.step[A];
    d.t = tn[A];
    d.axis = A;
    if (uint32_t(cn - d.lo[A]) > d.span[A]) return kExitParent;
    if (tn[A] > t1) return kEndOfRay;
    for (int b = 0; b < 3; ++b) {
      if (b == A) continue;
      // Crossed before (t, A): t below, or equal on a lower axis.
      while (d.n[b] < d.t || (d.n[b] == d.t && b < A)) {
        d.c[b] += r.step[b];
        d.n[b] = plane_t(r, b, float(d.c[b] + r.up[b]) * d.side);
      }
    }
    d.c[A] = cn;
    d.n[A] = plane_t(r, A, float(cn + r.up[A]) * d.side);
    *index = d.c[0] + stride[1] * d.c[1] + stride[2] * d.c[2];
    return A;
  }

  // The pyramid nodes at level cl < B of the node (level, pc).
  Step visit_nodes(int level, int cl, Int3 pc, float t, int axis) {
    Dda d = begin(cl, cl - level, pc, t, axis);
    const int p = B - cl;
    const PyramidNode* nodes = &w.pyramid_node(p, 0);
    const uint32_t dim_y = w.pyramid_dim_y(p);
    const int64_t stride[3] = {1, int64_t(w.pyramid_dim(p)), int64_t(w.pyramid_dim(p)) * dim_y};
    const int64_t dstride[3] = {stride[0] * r.step[0], stride[1] * r.step[1],
                                stride[2] * r.step[2]};
    int64_t index = d.c[0] + stride[1] * d.c[1] + stride[2] * d.c[2];
    for (;;) {
      if constexpr (kCount) ++ctx.counters.iterations;
      // Nodes above a cut-off brickgrid are empty and not stored.
      if (uint32_t(d.c[1]) < dim_y && nodes[index].bricks != 0) {
        const float cexit = d.exit();
        if (lod_stop(cl, cexit)) {
          stop(cl, d.cell(), 0, &nodes[index], d.t, d.axis);
          return Step::Hit;
        }
        const Step s = visit(cl, d.cell(), cexit, 0, d.t, d.axis);
        if (s != Step::Exit) return s;
      }
      // (The same jump over node clearances was measured and does not pay:
      // BENCHMARKS.md, "Brickmap clearance jumps".)
      const int s = advance(d, r, t1, &index, dstride);
      if (s > 2) return end_of(s);
    }
  }

  // The cubes at level cl > B (side 2^s voxels, s = L - cl <= 2) of the
  // cube (level, pc) inside the resident brick of cell `pcell`: the cubes an
  // LOD footprint of 1 to 8 voxels may stop at (§4.1, §5.3). visit()'s
  // general loop asked occupied() per cube (cell load, state, brick, then a
  // block's rows slice by slice); here the brick's 512-bit mask (§3.3) is
  // folded once per call into one bit per cube: the OR of each slab of 2^s
  // z slices, then of 2^s neighbours in x and y, so bit (8 y + x) 2^s of
  // slab z says whether block (x, y, z) holds a solid voxel, as
  // block_solid() does. The same DDA, stops and descents, so the same hits
  // (BrickmapSkip.TheSameLodHitsWithAndWithoutTheBlockMasks).
  Step visit_blocks(int level, int cl, Int3 pc, uint32_t pcell, float t, int axis) {
    uint64_t m[8];
    fold_blocks(w.brick(cell_brick(pcell)), L - cl, m);
    Dda d = begin(cl, cl - level, pc, t, axis);
    return walk_blocks(d, cl, m, pcell);
  }

  // The brick's mask folded to blocks of 2^s voxels (s <= 2): m[k] holds slab
  // k (2^s slices ORed), block (x, y) at bit (8 y + x) 2^s.
  static void fold_blocks(const Brick& b, int s, uint64_t m[8]) {
    for (int k = 0; k < 8 >> s; ++k) {
      uint64_t v = 0;
      for (int j = 0; j < 1 << s; ++j) v |= b.mask[(k << s) + j];
      for (int i = 0; i < s; ++i) v |= v >> (1 << i), v |= v >> (8 << i);
      m[k] = v;
    }
  }

  // visit_blocks' DDA `d` over the level-cl cubes of the brick of cell
  // `pcell`, its mask folded to them in m (fold_blocks).
  Step walk_blocks(Dda& d, int cl, const uint64_t m[8], uint32_t pcell) {
    const int s = L - cl;
    const int mm = (8 >> s) - 1;  // a block's coordinate within the brick
    for (;;) {
      if constexpr (kCount) {
        ++ctx.counters.iterations;
        if (cl == L) ++ctx.counters.intersects;
      }
      const int bit = ((d.c[1] & mm) << s) * 8 + ((d.c[0] & mm) << s);
      if ((m[d.c[2] & mm] >> bit) & 1) {
        const float cexit = d.exit();
        if (cl == L || lod_stop(cl, cexit)) {
          stop(cl, d.cell(), pcell, nullptr, d.t, d.axis);
          return Step::Hit;
        }
        // visit()'s case for a cube inside a brick, without its frame.
        const Step st = visit_blocks(cl, child_level(cl, cexit), d.cell(), pcell, d.t, d.axis);
        if (st != Step::Exit) return st;
      }
      const int st = advance(d, r, t1);
      if (st > 2) return end_of(st);
    }
  }

  // Walks the children of the occupied cube (level, pc), entered at t
  // through the plane of `axis`; Exit when the ray leaves it (the caller
  // steps across its exit plane itself). `pcell`: its brickgrid cell when it
  // is a brick (level == max(B, 0)).
  Step visit(int level, Int3 pc, float exit, uint32_t pcell, float t, int axis) {
    const int cl = child_level(level, exit);
    if (cl == L && level == B && B >= 0) return visit_voxels(cell_brick(pcell), pc, t, axis, exit);
    if (cl < B) return visit_nodes(level, cl, pc, t, axis);
    if (cl == B) return visit_cells(level, pc, t, axis);
    if (B >= 0 && detail::brick_block_masks.load(std::memory_order_relaxed))
      return visit_blocks(level, cl, pc, pcell, t, axis);
    // The blocks inside a brick an LOD footprint may stop at, and grids
    // below 8^3 (B < 0): the general loop.
    Dda d = begin(cl, cl - level, pc, t, axis);
    for (;;) {
      if constexpr (kCount) {
        ++ctx.counters.iterations;
        if (cl == L) ++ctx.counters.intersects;
      }
      uint32_t cell = 0;
      const PyramidNode* node = nullptr;
      if (occupied(cl, d.cell(), &cell, &node)) {
        if (seen && cl == std::max(B, 0) && cell_state(cell) == kStateResident)
          std::atomic_ref<uint32_t>(seen[cell_brick(cell)])
              .store(ctx.frame, std::memory_order_relaxed);
        const float cexit = d.exit();
        if (cl == L || lod_stop(cl, cexit)) {
          stop(cl, d.cell(), cell, node, d.t, d.axis);
          return Step::Hit;
        }
        if (cl == std::max(B, 0) && cell_state(cell) != kStateResident) {
          ctx.requests.push(BrickmapStructure::kRequestBrick,
                            w.cell_index(uint32_t(d.c[0]), uint32_t(d.c[1]), uint32_t(d.c[2])),
                            1.f / (1.f + d.t));
          stop(cl, d.cell(), cell, node, d.t, d.axis);
          return Step::Hit;
        }
        const Step s = visit(cl, d.cell(), cexit, cell, d.t, d.axis);
        if (s != Step::Exit) return s;
      }
      const int s = advance(d, r, t1);
      if (s > 2) return end_of(s);
    }
  }
};

// The ray's span in the grid: [t0, t1] (t1 also clipped to tmax and to a
// beam's region), the axis of the face entered at t0, the t it leaves the
// grid at (exit), and start_t (NaN unless the ray starts at the region).
// False when the span is empty. walk() and the packet walk's set-up.
struct Span {
  float t0, t1, exit, start_t;
  int axis;
};
bool clip_ray(const World& w, const GridRay& r, float tmax, const float (*region)[3], Span* s) {
  const GridTransform& g = w.grid();
  const float n = float(g.resolution);
  // Clip to the grid box [0, N]^3. The plane t values are finite (finite
  // origin, clamped direction), so min / max need not handle NaN (no libm
  // fmin call per ray); a NaN tmax counts as no limit, as fmin gave.
  float t0 = 0.f, t1 = std::isnan(tmax) ? INFINITY : tmax;
  int axis = -1;
  float exit = INFINITY;
  for (int a = 0; a < 3; ++a) {
    const float ta = plane_t(r, a, r.up[a] ? 0.f : n), tb = plane_t(r, a, r.up[a] ? n : 0.f);
    if (ta > t0) t0 = ta, axis = a;
    t1 = std::min(t1, tb);
    exit = std::min(exit, tb);
  }
  if (!(t0 <= t1)) return false;
  if (axis < 0) {
    // The ray starts inside the box: the face the ray looks at.
    const float ad[3] = {-std::fabs(r.d[0]), -std::fabs(r.d[1]), -std::fabs(r.d[2])};
    axis = argmin3(ad);
  }
  // Beam start (esvo §6.2): every cube the walk can stop in lies in the
  // region R, so it is entered at a t >= R's entry t (the max of its near
  // planes' t, the same plane_t as the walk's: a cube inside R has its near
  // planes at or beyond R's) and <= R's exit t. The walk starts just before
  // R's entry, in the cells the walk from the grid's entry is in then
  // (start_cell_exact; no stop can happen in them), and ends at R's exit:
  // the same crossings after it, so the same hit, t and face.
  float start_t = NAN;
  if (region != nullptr) {
    float r0 = -INFINITY, r1 = INFINITY;
    for (int a = 0; a < 3; ++a) {
      r0 = std::max(r0, plane_t(r, a, r.up[a] ? region[0][a] : region[1][a]));
      r1 = std::min(r1, plane_t(r, a, r.up[a] ? region[1][a] : region[0][a]));
    }
    t1 = std::min(t1, r1);
    const float before = next_below(r0);
    if (before > t0) t0 = before, start_t = before;
    if (!(t0 <= t1)) return false;
  }
  *s = {t0, t1, exit, start_t, axis};
  return true;
}

// The walk; true with `f` filled (unless kAny) on a hit within [0, tmax].
// `region` (may be null): a beam's start region in grid units (lo, hi),
// holding every cube the walk can stop in for this ray (beam_start).
template <bool kCount, bool kAny = false>
bool walk(const World& w, const GridRay& r, float tmax, const LodFootprint& lod, TraceContext& ctx,
          uint32_t* seen, const float (*region)[3], Found* f) {
  const GridTransform& g = w.grid();
  Span span;
  if (!clip_ray(w, r, tmax, region, &span)) return false;
  const float t0 = span.t0, t1 = span.t1, exit = span.exit, start_t = span.start_t;
  const int axis = span.axis;
  const bool lod_on = lod.size_at_origin > 0.f || lod.size_per_t > 0.f;
  Walker<kCount, kAny> wk{
      w, r, lod, ctx, t1, g.levels, g.levels - kBrickLog2, float(g.voxel_size), lod_on, seen, f};
  wk.start_t = start_t;
  for (int a = 0; a < 3; ++a) wk.slack[a] = brick_slack(r, a, t1);
  wk.cell_stride[0] = 1;
  wk.cell_stride[1] = int64_t(w.dims()[0]);
  wk.cell_stride[2] = int64_t(w.dims()[0]) * w.dims()[1];
  for (int a = 0; a < 3; ++a) wk.cell_dstride[a] = wk.cell_stride[a] * r.step[a];
  const Int3 root{{0, 0, 0}};
  uint32_t cell = 0;
  const PyramidNode* node = nullptr;
  if constexpr (kCount) ++ctx.counters.iterations;
  if (!wk.occupied(0, root, &cell, &node)) return false;
  if (wk.B <= 0 && cell_state(cell) != kStateResident) {
    ctx.requests.push(BrickmapStructure::kRequestBrick, 0, 1.f / (1.f + t0));
    wk.stop(0, root, cell, node, t0, axis);
    return true;
  }
  if (g.levels == 0 || wk.lod_stop(0, exit)) {
    wk.stop(0, root, cell, node, t0, axis);
    return true;
  }
  return wk.visit(0, root, exit, cell, t0, axis) == Step::Hit;
}
// A beam's region (octree space [1, 2]^3, core/beam_frustum.hpp) in grid
// units: (p - 1) N, exact for the dyadic cube corners it is made of.
const float (*grid_region(const GridTransform& g, const Aabb& box, float out[2][3]))[3] {
  const float n = float(g.resolution);
  for (int a = 0; a < 3; ++a) out[0][a] = (box.lo[a] - 1.f) * n, out[1][a] = (box.hi[a] - 1.f) * n;
  return out;
}

Vec3 face_normal(int face) {
  Vec3 n{0, 0, 0};
  n[face >> 1] = (face & 1) ? -1.f : 1.f;
  return n;
}

// The SurfaceHit of the walk's Found (trace(), trace_packets()).
void fill_hit(const GridTransform& g, const Ray& ray, const Found& f, SurfaceHit* hit) {
  // voxel_size 2^(levels - level), exact (a power-of-two scale), no libm ldexp call.
  const double side = g.voxel_size * double(uint32_t(1) << (g.levels - f.level));
  hit->t = f.t;
  hit->voxel_size = float(side);
  hit->voxel_ref = f.ref;
  hit->child = uint32_t(f.face);
  hit->level = f.level;
  const Vec3 p = ray.origin + ray.dir * f.t;
  for (int a = 0; a < 3; ++a) {
    // Clamped into the cube [lo, hi) as the floats inside it (when the cube
    // holds any float at all), so that the position names the hit voxel.
    const double lo = double(g.origin[a]) + double(f.c[a]) * side;
    const double hi = double(g.origin[a]) + std::min(double(f.c[a] + 1) * side, g.side());
    // A position already in [lo, hi) is its own clamp (it is >= the
    // smallest float >= lo and <= the largest float < hi). Almost every
    // hit's is, so the rounding branches below, which go either way from
    // hit to hit (fill_hit was 10 % of the packet path's time, perf), run
    // only for the others.
    if (double(p[a]) >= lo && double(p[a]) < hi) {
      hit->position[a] = p[a];
      continue;
    }
    float lo_f = float(lo), hi_f = float(hi);
    if (double(lo_f) < lo) lo_f = next_above(lo_f);  // no libm call per hit
    if (double(hi_f) >= hi) hi_f = next_below(hi_f);
    hit->position[a] = std::max(std::min(p[a], hi_f), lo_f);  // p finite
  }
}

}  // namespace

void BrickmapStructure::beam_start(const BeamFrustum& beam, TraceContext& ctx,
                                   BeamStart* start) const {
  coarse_pass(beam, ctx, start, nullptr, false);
}

void BrickmapStructure::frustum_start(const BeamFrustum& beam, int octant, TraceContext& ctx,
                                      BeamStart* start, const BeamStart* within) const {
  (void)octant;  // the lane walk starts at the box's entry whatever the order of its cubes
  // A tile's list of this structure's cubes (a brickmap frustum_start:
  // octant -1, the cubes in nodes); anything else: the pass from the root.
  const bool from = within != nullptr && within->valid && within->octant == -1 &&
                    (within->empty || !within->nodes.empty());
  coarse_pass(beam, ctx, start, from ? within : nullptr, within == nullptr);
}

void BrickmapStructure::coarse_pass(const BeamFrustum& beam, TraceContext& ctx, BeamStart* start,
                                    const BeamStart* within, bool list) const {
  // The octree family's coarse pass (esvo §6.2, core/beam_frustum.hpp) over
  // the pyramid nodes and brickgrid cells: a cube outside the beam is
  // skipped, a cell (the walk's bricks, not-resident bricks and LOD stops
  // inside bricks all lie in it), a possible LOD stop or a cube narrower
  // than the beam is kept whole, others are descended. Cube (k, c) at
  // pyramid level k (0: a brickgrid cell): side 8 2^k voxels, in octree
  // space 1 + c side / N, exact (dyadic).
  // The start is reset field by field: the list keeps its capacity (a
  // tile's start is reused from tile to tile without allocating).
  start->valid = false, start->empty = false, start->region = Aabb{}, start->octant = -1;
  start->nodes.clear();
  const World& w = *world_;
  const GridTransform& g = w.grid();
  if (g.levels < kBrickLog2) return;  // a cell larger than the grid: no information
  if (within != nullptr && within->empty) {
    start->valid = start->empty = true;  // the tile's beam, which holds this one, meets nothing
    return;
  }
  // A tile's pass (the list its blocks start from) cuts at cubes as wide as
  // its beam (stop fraction 1 instead of 2): done once per tile, it leaves
  // the four block passes less to descend. Harness, packet+frustum, LOD 0 /
  // 1 px: medium 454-457 / 473-488 -> 441-444 / 458-462 cycles per ray,
  // distant 202-216 / 190-212 -> 196-200 / 183-186 (0.5: no better, 4: worse).
  constexpr double kTileStopFraction = 1.0;
  ::voxcast::detail::BeamClassifier cls(
      beam, g, list ? kTileStopFraction : ::voxcast::detail::BeamClassifier::kStopFraction);
  if (!cls.valid()) return;
  struct Item {
    int k;
    uint32_t c[3];
  };
  Item stack[8 * (kMaxGridLevels + 1)];  // depth-first: <= 7 pending siblings per level
  int top = 0;
  const float cell_side = float(kBrickSide) / float(g.resolution);
  auto keep = [&](const float lo[3], float side, int k) {
    cls.keep(lo, side);
    if (list) start->nodes.push_back({{lo[0], lo[1], lo[2]}, side, 0, 0, int8_t(k), 0, k == 0});
  };
  // A cube (k, c) classified whole: kept, or pushed to be descended.
  auto seed = [&](int k, const uint32_t c[3], const float lo[3], float side) {
    const int what = cls.classify(lo, side, k == 0);
    if (what == ::voxcast::detail::BeamClassifier::kKeep) keep(lo, side, k);
    if (what == ::voxcast::detail::BeamClassifier::kDescend) {
      ++cls.counters.pushes;
      stack[top++] = {k, {c[0], c[1], c[2]}};
    }
  };
  // The eight children (k - 1, 2 c + m) of each cube on the stack
  // classified at once in float lanes (BeamClassifier::classify_children,
  // as the tile frustum pass): a child is present when it is filled(). The
  // same plane test as classify() per child (as conservative); it also
  // skipped cubes already inside the region, but descending those adds
  // only cubes inside it. Any conservative region gives the same hits
  // (walk()), so the images do not depend on the cut
  // (BrickmapOracle.BeamStartGivesTheSameImages).
  auto descend = [&] {
    while (top > 0) {
      const Item item = stack[--top];
      ++cls.counters.iterations;
      const int k = item.k - 1;
      const uint32_t c0[3] = {2 * item.c[0], 2 * item.c[1], 2 * item.c[2]};
      // The children's words from the first child's index by strides (1 in
      // x, a row in y, a plane in z) instead of an index per child (the
      // eight look-ups were a quarter of the pass, perf); cubes above a
      // cut-off brickgrid are empty and not stored.
      const bool cell_level = k == 0;
      const uint64_t row = cell_level ? w.dims()[0] : w.pyramid_dim(k);
      const uint32_t dim_y = cell_level ? w.dims()[1] : w.pyramid_dim_y(k);
      const uint64_t plane = row * dim_y;
      const uint32_t* words = cell_level ? w.cells().data() : &w.pyramid_node(k, 0).bricks;
      const size_t step = cell_level ? 1 : sizeof(PyramidNode) / sizeof(uint32_t);
      const uint64_t first = c0[0] + row * (c0[1] + uint64_t(dim_y) * c0[2]);
      uint32_t present = 0;
      for (uint32_t m = 0; m < 8; ++m) {
        if (c0[1] + (m >> 1 & 1) >= dim_y) continue;
        const uint64_t at = first + (m & 1) + row * (m >> 1 & 1) + plane * (m >> 2);
        present |= words[at * step] != 0 ? 1u << m : 0u;
      }
      if (present == 0) continue;
      const float side = cell_side * float(1u << item.k), hs = 0.5f * side;
      const float lo[3] = {1.f + float(item.c[0]) * side, 1.f + float(item.c[1]) * side,
                           1.f + float(item.c[2]) * side};
      uint32_t kept, down;
      cls.classify_children(lo, hs, present, k == 0 ? present : 0u, &kept, &down);
      for (uint32_t m = kept; m != 0; m &= m - 1) {
        const int c = std::countr_zero(m);
        const float clo[3] = {lo[0] + ((c & 1) ? hs : 0.f), lo[1] + ((c & 2) ? hs : 0.f),
                              lo[2] + ((c & 4) ? hs : 0.f)};
        keep(clo, hs, k);
      }
      cls.counters.pushes += uint64_t(std::popcount(down));
      for (uint32_t m = down; m != 0; m &= m - 1) {
        const uint32_t c = uint32_t(std::countr_zero(m));
        stack[top++] = {k, {c0[0] + (c & 1), c0[1] + (c >> 1 & 1), c0[2] + (c >> 2)}};
      }
    }
  };
  if (within != nullptr) {
    // From the tile's cubes, each walked down before the next (the stack's
    // bound holds per cube); c from lo, exact (dyadic lo = 1 + c side).
    for (const FrustumNode& f : within->nodes) {
      const uint32_t c[3] = {uint32_t((f.lo[0] - 1.f) / f.side), uint32_t((f.lo[1] - 1.f) / f.side),
                             uint32_t((f.lo[2] - 1.f) / f.side)};
      seed(f.scale, c, f.lo, f.side);
      descend();
    }
  } else {
    // The root: the top pyramid level's one node (a brickgrid of one cell
    // when there is no pyramid), kept or descended as the children below.
    const int kr = w.pyramid_levels();
    const bool filled = kr == 0 ? w.dims()[1] > 0 && w.cell(0) != 0
                                : w.pyramid_dim_y(kr) > 0 && w.pyramid_node(kr, 0).bricks != 0;
    if (filled) {
      const uint32_t c[3] = {0, 0, 0};
      const float lo[3] = {1.f, 1.f, 1.f};
      seed(kr, c, lo, cell_side * float(1u << kr));
      descend();
    }
  }
  cls.finish(start, ctx.counting ? &ctx.counters : nullptr);
}

BrickmapStructure::BrickmapStructure(std::shared_ptr<const World> world,
                                     std::vector<uint32_t>* brick_seen)
    : world_(std::move(world)), seen_(brick_seen) {}

Aabb BrickmapStructure::bounds() const {
  const GridTransform& g = world_->grid();
  Aabb b;
  b.lo = g.origin;
  const float side = float(g.side());
  b.hi = g.origin + Vec3{side, side, side};
  return b;
}

bool BrickmapStructure::trace(const Ray& ray, const LodFootprint& lod, TraceContext& ctx,
                              SurfaceHit* hit, const BeamStart* beam) const {
  float region[2][3];
  const float(*rg)[3] = nullptr;
  if (beam != nullptr && beam->valid) {
    if (beam->empty) return false;
    rg = grid_region(world_->grid(), beam->region, region);
  }
  GridRay r;
  if (!to_grid(world_->grid(), ray, &r)) return false;
  Found f;
  uint32_t* seen = seen_ ? seen_->data() : nullptr;
  const bool found = ctx.counting ? walk<true>(*world_, r, ray.tmax, lod, ctx, seen, rg, &f)
                                  : walk<false>(*world_, r, ray.tmax, lod, ctx, seen, rg, &f);
  if (!found) return false;
  fill_hit(world_->grid(), ray, f, hit);
  return true;
}

float BrickmapStructure::transmittance(const Ray& ray, const LodFootprint& lod, TraceContext& ctx,
                                       const BeamStart* beam) const {
  float region[2][3];
  const float(*rg)[3] = nullptr;
  if (beam != nullptr && beam->valid) {
    if (beam->empty) return 1.f;
    rg = grid_region(world_->grid(), beam->region, region);
  }
  GridRay r;
  if (!to_grid(world_->grid(), ray, &r)) return 1.f;
  Found f;
  uint32_t* seen = seen_ ? seen_->data() : nullptr;
  const bool found = ctx.counting ? walk<true, true>(*world_, r, ray.tmax, lod, ctx, seen, rg, &f)
                                  : walk<false, true>(*world_, r, ray.tmax, lod, ctx, seen, rg, &f);
  return found ? 0.f : 1.f;
}

void BrickmapStructure::attributes(const SurfaceHit& hit, TraceContext& ctx, Color* color,
                                   Vec3* normal) const {
  const Vec3 face = face_normal(int(hit.child % 6));
  if (hit.voxel_ref >> 63) {
    if (color) *color = esvo::decode_color_abgr(uint32_t(hit.voxel_ref));
    if (normal) *normal = face;
    return;
  }
  const World& w = *world_;
  const Brick& b = w.brick(uint32_t(hit.voxel_ref >> 9));
  const uint32_t index = b.color + uint32_t(rank_below(b, uint32_t(hit.voxel_ref & 511)));
  if (color) *color = esvo::decode_color_abgr(w.color_of(b, index - b.color));
  if (normal) *normal = w.has_normals() ? esvo::decode_normal_cube(w.normals()[index]) : face;
  if (ctx.counting) ctx.counters.attribute_bytes += sizeof(Brick) + (w.has_normals() ? 8 : 4);
}

namespace {

// The lane walk's view of `w` and `lod` (packet_walk.hpp); false when the
// walk does not apply: grids below 2^7 voxels (the root's children could be
// cells) or a pyramid of another height.
bool packet_world(const World& w, const LodFootprint& lod, detail::PacketWorld* pw) {
  const GridTransform& g = w.grid();
  const int L = g.levels, B = L - kBrickLog2;
  if (B < 4 || B > detail::kPacketMaxLevels || w.pyramid_levels() != B) return false;
  if (w.clearances().size() < 4 || w.node_clearances().size() < 4) return false;
  pw->cells = w.cells().data();
  pw->bricks = reinterpret_cast<const uint32_t*>(w.bricks().data());
  pw->cell_box = w.cell_boxes().data();
  pw->clearance = w.clearances().data();
  pw->clearance_last = int32_t(w.clearances().size() - 4);
  pw->node_clearance = w.node_clearances().data();
  pw->node_clearance_last = int32_t(w.node_clearances().size() - 4);
  for (int a = 0; a < 3; ++a) pw->dims[a] = w.dims()[a];
  pw->L = L, pw->B = B;
  for (int p = 1; p <= B; ++p) {
    pw->nodes[p] = reinterpret_cast<const uint32_t*>(&w.pyramid_node(p, 0));
    pw->node_dim[p] = w.pyramid_dim(p), pw->node_dim_y[p] = w.pyramid_dim_y(p);
  }
  pw->slice_skip =
      detail::brick_skip_mode.load(std::memory_order_relaxed) != detail::BrickSkip::Off;
  pw->lod_on = lod.size_at_origin > 0.f || lod.size_per_t > 0.f;
  pw->voxel_world = float(g.voxel_size);
  pw->lod_size0 = lod.size_at_origin, pw->lod_per_t = lod.size_per_t;
  return true;
}

// The packet walk's rays (PacketRays), per thread, grown once.
struct PacketBuffers {
  static constexpr size_t kChunk = 256;
  alignas(64) float f[16][kChunk];  // o, d, inv, slack (x, y, z each), t0, t1, start_t, exit
  alignas(64) int32_t axis[kChunk];
  uint32_t id[kChunk];
  int32_t region_of[kChunk];  // beam regions for the set-up in lanes
  float regions[kChunk][8];
  uint8_t status[kChunk];
  detail::PacketFound out[kChunk];
};

}  // namespace

void BrickmapStructure::trace_packets(const Ray* rays, size_t n, const LodFootprint& lod,
                                      TraceContext& ctx, SurfaceHit* hits, uint8_t* found, Isa isa,
                                      const BeamStart* const* beams) const {
  if (!cpu_supports(isa))
    throw Error(std::string("brickmap trace_packets: this CPU does not support ") + isa_name(isa));
  const World& w = *world_;
  const GridTransform& g = w.grid();
  detail::PacketWorld pw;
  if (ctx.counting || seen_ != nullptr || !packet_world(w, lod, &pw)) {
    for (size_t i = 0; i < n; ++i)
      found[i] = trace(rays[i], lod, ctx, &hits[i], beams ? beams[i] : nullptr);
    return;
  }
  const bool root = w.pyramid_node(w.pyramid_levels(), 0).bricks != 0;
  thread_local std::unique_ptr<PacketBuffers> buffers;
  if (!buffers) buffers = std::make_unique<PacketBuffers>();
  PacketBuffers& q = *buffers;
  detail::PacketRays pr;
  for (int a = 0; a < 3; ++a)
    pr.o[a] = q.f[a], pr.d[a] = q.f[3 + a], pr.inv[a] = q.f[6 + a], pr.slack[a] = q.f[9 + a];
  float *t0 = q.f[12], *t1 = q.f[13], *start = q.f[14], *exit = q.f[15];
  pr.t0 = t0, pr.t1 = t1, pr.start_t = start, pr.exit = exit, pr.axis = q.axis;
  // The root's LOD stop (walk()): a grid narrower than the footprint.
  const float root_side = float(g.voxel_size) * float(1u << g.levels);
  const double inv_vs = 1.0 / g.voxel_size;
  // The set-up in lanes (packet_walk.hpp).
  const bool lanes_setup = isa == Isa::Avx512;
  detail::PacketSetupIn in;
  float* fs[16];
  if (lanes_setup) {
    for (int a = 0; a < 3; ++a) in.origin[a] = double(g.origin[a]);
    in.inv_vs = inv_vs, in.n = float(g.resolution);
    in.lod_on = pw.lod_on, in.root_side = root_side;
    in.lod_size0 = lod.size_at_origin, in.lod_per_t = lod.size_per_t;
    for (int j = 0; j < 16; ++j) fs[j] = q.f[j];
  }
  for (size_t b0 = 0; b0 < n; b0 += PacketBuffers::kChunk) {
    const size_t m = std::min(PacketBuffers::kChunk, n - b0);
    int count = 0;
    if (lanes_setup) {
      std::fill(found + b0, found + b0 + m, uint8_t(0));
      if (root) {
        uint32_t scalar[PacketBuffers::kChunk];
        int n_scalar = 0;
        in.rays = rays + b0, in.count = int(m);
        if (beams != nullptr) {
          // Each beam's region once (consecutive rays share their beam).
          const BeamStart* last = nullptr;
          int e = -1;
          for (size_t i = 0; i < m; ++i) {
            const BeamStart* beam = beams[b0 + i];
            if (beam != last || e < 0) {
              last = beam, ++e;
              float* r = q.regions[e];
              uint32_t kind = detail::kRegionNone;
              if (beam != nullptr && beam->valid) {
                kind = beam->empty ? detail::kRegionEmpty : detail::kRegionClip;
                float region[2][3];
                grid_region(g, beam->region, region);
                for (int a = 0; a < 3; ++a) r[a] = region[0][a], r[3 + a] = region[1][a];
              }
              r[6] = std::bit_cast<float>(kind);
            }
            q.region_of[i] = e;
          }
          in.region_of = q.region_of, in.regions = &q.regions[0][0];
        }
        count = detail::packet_setup_avx512(in, uint32_t(b0), fs, q.axis, q.id, scalar, &n_scalar);
        for (int k = 0; k < n_scalar; ++k)
          found[scalar[k]] = trace(rays[scalar[k]], lod, ctx, &hits[scalar[k]],
                                   beams ? beams[scalar[k]] : nullptr);
      }
    }
    for (size_t i = b0; i < b0 + m && !lanes_setup; ++i) {
      found[i] = 0;
      const BeamStart* beam = beams ? beams[i] : nullptr;
      float region[2][3];
      const float(*rg)[3] = nullptr;
      if (beam != nullptr && beam->valid) {
        if (beam->empty) continue;
        rg = grid_region(g, beam->region, region);
      }
      GridRay r;
      Span s;
      if (!root || !to_grid(g, inv_vs, rays[i], &r) || !clip_ray(w, r, rays[i].tmax, rg, &s))
        continue;
      if (pw.lod_on && root_side <= lod.size_at_origin + lod.size_per_t * s.exit) {
        found[i] = trace(rays[i], lod, ctx, &hits[i], beam);
        continue;
      }
      for (int a = 0; a < 3; ++a) {
        q.f[a][count] = r.o[a], q.f[3 + a][count] = r.d[a], q.f[6 + a][count] = r.inv[a];
        q.f[9 + a][count] = brick_slack(r, a, s.t1);
      }
      t0[count] = s.t0, t1[count] = s.t1, start[count] = s.start_t, exit[count] = s.exit;
      q.axis[count] = s.axis;
      q.id[count] = uint32_t(i);
      ++count;
    }
    // Padding up to a whole packet (lanes the walk leaves idle).
    const int padded = std::min(int(PacketBuffers::kChunk), (count + 15) & ~15);
    for (int k = count; k < padded; ++k) {
      for (int j = 0; j < 12; ++j) q.f[j][k] = 1.f;
      t0[k] = t1[k] = exit[k] = 0.f, start[k] = NAN, q.axis[k] = 0;
    }
    pr.count = count;
    std::fill(q.status, q.status + count, detail::kPacketMiss);
    if (isa == Isa::Avx512)
      detail::packet_walk_avx512(pw, pr, q.status, q.out);
    else
      detail::packet_walk_avx2(pw, pr, q.status, q.out);
    for (int k = 0; k < count; ++k) {
      const size_t i = q.id[k];
      if (q.status[k] == detail::kPacketHit) {
        const detail::PacketFound& o = q.out[k];
        const Found f{o.t, o.face, o.level, {o.c[0], o.c[1], o.c[2]}, o.ref};
        fill_hit(g, rays[i], f, &hits[i]);
        found[i] = 1;
      } else if (q.status[k] >= detail::kPacketScalar) {
        if (q.status[k] == detail::kPacketFault)
          detail::packet_lane_faults.fetch_add(1, std::memory_order_relaxed);
        found[i] = trace(rays[i], lod, ctx, &hits[i], beams ? beams[i] : nullptr);
      }
    }
  }
}

void BrickmapStructure::occluded_packets(const Ray* rays, size_t n, const LodFootprint& lod,
                                         TraceContext& ctx, uint8_t* occluded, Isa isa) const {
  if (!cpu_supports(isa))
    throw Error(std::string("brickmap occluded_packets: this CPU does not support ") +
                isa_name(isa));
  for (size_t i = 0; i < n; ++i) occluded[i] = this->occluded(rays[i], lod, ctx);
}

}  // namespace voxcast::brickmap
