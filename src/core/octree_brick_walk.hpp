#pragma once
// The last three octree levels of a ray inside one 512-bit brick (issue 10
// item 4): where the lane loop (core/octree_packet_kernel.hpp) would PUSH a
// lane into a cube of 8^3 leaf voxels, the lane's first hit in that cube is
// found from the cube's occupancy (8 x 64 bits, the DAG's bricks, dag.hpp)
// with a few vector compares instead of the loop's PUSH / ADVANCE / POP
// iterations and node gathers through three levels. Included only by the
// kernel translation units (internal linkage: each ISA compiles its own
// copy; the 16-wide vectors are one zmm with AVX-512, two ymm with AVX2).
//
// Why the hit is the scalar loop's, bit for bit (cast_octree's own argument,
// "Why a start region gives bit-identical hits", made exact for one cube).
// Mirrored frame: every direction component is negative, plane t(c) =
// fma(c, coef, -bias) is non-increasing in c; the cube's planes on axis a are
// P(m) = p_a + m v, m = 0..8 (v the leaf side, exact dyadic), voxel m spans
// [P(m), P(m+1)], entered at en(m) = t(P(m+1)), left at ex(m) = t(P(m)).
// The loop enters the cube at s = t_min with span end T = tv_max (<= the
// cube's exit X). Assume s < X and en(m) < ex(m) on every axis (the planes'
// t strictly ordered; else the lane keeps the plain loop). Then the loop's
// t_min runs through s and the distinct plane crossings in (s, X) in order,
// each ADVANCE crossing every plane of that t at once, descents placing the
// ray in the cell whose crossed planes are those with t <= t_min; so the
// leaf cells it stands in are exactly the C with
//   max(s, en_x, en_y, en_z)(C) < min(ex_x, ex_y, ex_z)(C)             (1)
// (C's t_min: the left side; its ancestors are entered no later and left no
// earlier, so the loop reaches C whenever C's subtree is present), and it
// stops at the first occupied one with t_min <= T (the span test; the early
// miss exit and POPs only end the cube past T). Those cells form a chain in
// the product order of mirrored coordinates (each step lowers at least one
// coordinate and raises none), so the first one is the extreme one on every
// axis: found by bit scans, slice by slice in z, whatever the mirroring.
// The hit t is C's t_min = max(s, en_x, en_y, en_z)(C) (every other t_min
// of C is <= it and it is a crossing the loop made, or s), the same fma as
// the loop's. (1) with <= T is a conjunction of pairwise compares, each of
// at most two axes: per axis pair an 8 x 8 matrix (x-y: 64 bits; x-z and
// y-z: one row per z slice), per axis an 8-bit mask.
//
// The caller keeps the plain loop for lanes whose footprint could stop (LOD)
// at any cube inside (the loop tests LOD before the span), and lanes with
// s == X or coincident plane t values (extreme distances), where (1) would
// not describe the loop's walk.
#include <immintrin.h>

#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>

// The 16-wide vectors pass through inlined functions of internal linkage
// only; the AVX2 translation units (the only includers besides AVX-512's)
// would otherwise warn of the 64-byte vector ABI where templates using them
// are instantiated, so the warning stays off for the rest of the unit.
#pragma GCC diagnostic ignored "-Wpsabi"

namespace voxcast::detail {
namespace {

typedef float BrickF __attribute__((vector_size(64)));
typedef int32_t BrickI __attribute__((vector_size(64)));

/// Bit i = lane i of a 16-lane compare mask.
[[gnu::always_inline]] inline uint32_t brick_bits(BrickI m) {
#ifdef __AVX512F__
  return _mm512_movepi32_mask((__m512i)m);
#else
  __m256 lo, hi;
  std::memcpy(&lo, &m, 32);
  std::memcpy(&hi, reinterpret_cast<const char*>(&m) + 32, 32);
  return uint32_t(_mm256_movemask_ps(lo)) | uint32_t(_mm256_movemask_ps(hi)) << 8;
#endif
}

/// a * b + c rounded once (the loop's plane t), lane by lane.
[[gnu::always_inline]] inline BrickF brick_fma(BrickF a, BrickF b, BrickF c) {
#ifdef __AVX512F__
  return (BrickF)_mm512_fmadd_ps((__m512)a, (__m512)b, (__m512)c);
#else
  __m256 a0, a1, b0, b1, c0, c1;
  std::memcpy(&a0, &a, 32), std::memcpy(&a1, reinterpret_cast<const char*>(&a) + 32, 32);
  std::memcpy(&b0, &b, 32), std::memcpy(&b1, reinterpret_cast<const char*>(&b) + 32, 32);
  std::memcpy(&c0, &c, 32), std::memcpy(&c1, reinterpret_cast<const char*>(&c) + 32, 32);
  const __m256 r0 = _mm256_fmadd_ps(a0, b0, c0), r1 = _mm256_fmadd_ps(a1, b1, c1);
  BrickF r;
  std::memcpy(&r, &r0, 32), std::memcpy(reinterpret_cast<char*>(&r) + 32, &r1, 32);
  return r;
#endif
}

/// Plane multipliers m (planes P(m) = p + m v) per lane, unmirrored voxel
/// order u (m = 7 - u on a mirrored axis, f = 1): [f][lane] for the entry
/// (m + 1) and exit (m) planes of voxel u = lane & 7 (rows), and of voxel
/// u = 2 g + lane / 8 (columns of group g).
struct BrickPlanes {
  alignas(64) float en_row[2][16], ex_row[2][16];
  alignas(64) float en_col[2][4][16], ex_col[2][4][16];
};
constexpr BrickPlanes kBrickPlanes = [] {
  BrickPlanes p{};
  for (int f = 0; f < 2; ++f)
    for (int q = 0; q < 16; ++q) {
      const int ur = q & 7, mr = f ? 7 - ur : ur;
      p.en_row[f][q] = float(mr + 1), p.ex_row[f][q] = float(mr);
      for (int g = 0; g < 4; ++g) {
        const int uc = 2 * g + (q >> 3), mc = f ? 7 - uc : uc;
        p.en_col[f][g][q] = float(mc + 1), p.ex_col[f][g][q] = float(mc);
      }
    }
  return p;
}();

/// One lane's ray and cube: mirrored t coefficients and biases, the cube's
/// mirrored min corner, its leaf side v, flip (bit a: axis a mirrored), the
/// span [s, T] and the cube's exit X (the loop's t_min, tv_max, tc_max).
struct BrickRay {
  float cx, cy, cz, bx, by, bz;
  float px, py, pz, v;
  uint32_t flip;
  float s, T, X;
};

/// The first hit: t, the leaf's mirrored min corner and mirrored slot in its
/// 2^3 sub-block, and its brick-local unmirrored coordinates.
struct BrickHit {
  float t, px, py, pz;
  uint32_t idx;
  int u, w, r;
};

enum class BrickWalk { kHit, kMiss, kPlain };

/// The first occupied leaf of the cube on the ray (see above), or kMiss, or
/// kPlain where the lane must keep the plain loop. occ: slice[z] bit x + 8 y,
/// brick-local unmirrored coordinates.
[[gnu::always_inline]] inline BrickWalk brick_walk(const uint64_t* occ, const BrickRay& b,
                                                   BrickHit* hit) {
  if (!(b.s < b.X)) return BrickWalk::kPlain;
  constexpr uint64_t kRep = 0x0101010101010101ull;
  const uint32_t fx = b.flip & 1u, fy = b.flip >> 1 & 1u, fz = b.flip >> 2 & 1u;
  auto load = [](const float* p) {
    BrickF r;
    std::memcpy(&r, p, 64);
    return r;
  };
  const BrickF v = BrickF{} + b.v, S = BrickF{} + b.s, T = BrickF{} + b.T;
  // t of planes P(K) on one axis (K v and p + K v are exact: dyadic).
  auto plane_t = [&](BrickF K, float p, float c, float bias) {
    return brick_fma(K * v + p, BrickF{} + c, -(BrickF{} + bias));
  };
  const BrickPlanes& kp = kBrickPlanes;
  // Rows: x in lanes 0-7, y in lanes 8-15 (per-axis masks, x-z and y-z).
  BrickI lo8;
  for (int q = 0; q < 16; ++q) lo8[q] = q < 8 ? -1 : 0;
  const BrickF pxy = lo8 ? BrickF{} + b.px : BrickF{} + b.py;
  const BrickF cxy = lo8 ? BrickF{} + b.cx : BrickF{} + b.cy;
  const BrickF nbxy = -(lo8 ? BrickF{} + b.bx : BrickF{} + b.by);
  const BrickF en_xy =
      brick_fma((lo8 ? load(kp.en_row[fx]) : load(kp.en_row[fy])) * v + pxy, cxy, nbxy);
  const BrickF ex_xy =
      brick_fma((lo8 ? load(kp.ex_row[fx]) : load(kp.ex_row[fy])) * v + pxy, cxy, nbxy);
  const BrickF en_z = plane_t(load(kp.en_row[fz]), b.pz, b.cz, b.bz);
  const BrickF ex_z = plane_t(load(kp.ex_row[fz]), b.pz, b.cz, b.bz);
  if ((brick_bits(en_xy < ex_xy) & brick_bits(en_z < ex_z)) != 0xFFFFu) return BrickWalk::kPlain;
  const uint32_t ok_xy = brick_bits((S < ex_xy) & (en_xy <= T));
  const uint32_t ok_z = brick_bits((S < ex_z) & (en_z <= T)) & 0xFFu;
  if ((ok_xy & 0xFFu) == 0 || (ok_xy >> 8) == 0 || ok_z == 0) return BrickWalk::kMiss;
  // Most cubes a ray enters it leaves without a hit (a thin surface): the
  // ray's x-y bounding rectangle, then its x-y path, against the brick's x-y
  // projection (of the slices its z range meets) reject many cheaply.
  const uint64_t rect = (ok_xy & 0xFFu) * kRep & _pdep_u64(ok_xy >> 8, kRep) * 0xFFu;
  uint64_t occ_xy = 0;
  for (int r = 0; r < 8; ++r) occ_xy |= ok_z >> r & 1u ? occ[r] : 0u;
  if ((rect & occ_xy) == 0) return BrickWalk::kMiss;

  // x-y: bit u + 8 w.
  const BrickF en_x = plane_t(load(kp.en_row[fx]), b.px, b.cx, b.bx);
  const BrickF ex_x = plane_t(load(kp.ex_row[fx]), b.px, b.cx, b.bx);
  uint64_t xy = 0;
  for (int g = 0; g < 4; ++g) {
    const BrickF en_y = plane_t(load(kp.en_col[fy][g]), b.py, b.cy, b.by);
    const BrickF ex_y = plane_t(load(kp.ex_col[fy][g]), b.py, b.cy, b.by);
    xy |= uint64_t(brick_bits((en_x < ex_y) & (en_y < ex_x))) << (16 * g);
  }
  xy &= rect & occ_xy;
  if (xy == 0) return BrickWalk::kMiss;

  // z slices front to back (mirrored z descending), x-z and y-z per slice.
  alignas(64) float zen[16], zex[16];
  std::memcpy(zen, &en_z, 64), std::memcpy(zex, &ex_z, 64);
  for (int i = 0; i < 8; ++i) {
    const int r = fz ? i : 7 - i;
    if (!(ok_z >> r & 1u) || (xy & occ[r]) == 0) continue;
    const uint32_t m = brick_bits((en_xy < BrickF{} + zex[r]) & (ex_xy > BrickF{} + zen[r]));
    const uint64_t path = xy & (m & 0xFFu) * kRep & _pdep_u64(m >> 8, kRep) * 0xFFu;
    const uint64_t h = path & occ[r];
    if (h == 0) continue;
    // The extreme y row, then the extreme x bit in it (mirrored maximum).
    const int w = fy ? std::countr_zero(h) >> 3 : (63 - std::countl_zero(h)) >> 3;
    const uint32_t row = uint32_t(h >> (8 * w)) & 0xFFu;
    const int u = fx ? std::countr_zero(row) : 31 - std::countl_zero(row);
    const int mx = fx ? 7 - u : u, my = fy ? 7 - w : w, mz = fz ? 7 - r : r;
    hit->px = b.px + float(mx) * b.v, hit->py = b.py + float(my) * b.v;
    hit->pz = b.pz + float(mz) * b.v;
    const float tx = std::fma(hit->px + b.v, b.cx, -b.bx);
    const float ty = std::fma(hit->py + b.v, b.cy, -b.by);
    const float tz = std::fma(hit->pz + b.v, b.cz, -b.bz);
    float t = b.s;
    if (tx > t) t = tx;
    if (ty > t) t = ty;
    if (tz > t) t = tz;
    hit->t = t;
    hit->idx = uint32_t(mx & 1) | uint32_t(my & 1) << 1 | uint32_t(mz & 1) << 2;
    hit->u = u, hit->w = w, hit->r = r;
    return BrickWalk::kHit;
  }
  return BrickWalk::kMiss;
}

/// The 8-bit mask of the 2^3 sub-block holding brick voxel (u, w, r) (the
/// DAG's node at the leaf level, whose bit c is child slot c).
inline uint32_t brick_sub_block(const uint64_t* occ, int u, int w, int r) {
  uint32_t m = 0;
  for (int c = 0; c < 8; ++c) {
    const int x = (u & ~1) + (c & 1), y = (w & ~1) + (c >> 1 & 1), z = (r & ~1) + (c >> 2 & 1);
    m |= uint32_t(occ[z] >> (x + 8 * y) & 1u) << c;
  }
  return m;
}

}  // namespace
}  // namespace voxcast::detail
