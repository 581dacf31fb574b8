#pragma once
// Coarse pass of the beam optimization (esvo §6.2), structure-independent
// part, shared by the octree family (ESVO octree, sparse voxel DAG): the
// beam's pyramid in octree space ([1,2]^3, esvo §6.1), the conservative cube
// test and the start region it accumulates. The node walk is
// detail::beam_walk (core/octree_caster.hpp) over each structure's node
// policy.
//
// The paper casts distance rays through the block corners and stops "as soon
// as we encounter a voxel that is not large enough to certainly cover at
// least one ray in the coarse grid". We do the conservative variant of the
// same idea as a frustum query: a depth-first walk of the hierarchy that
// drops every node whose cube lies outside the beam's pyramid (4 planes
// through the eye, slightly widened; for the parallel rays of an
// orthographic camera a prism: 4 planes through the edges of the block's
// origin rectangle, along the common direction, whose width is then
// constant), and keeps a node's whole cube, instead
// of descending, once it is a leaf, could be a LOD stop for some ray, or is
// no larger than the beam's width at its nearest point. The result is the
// bounding box R of the kept cubes. Every voxel a ray of the beam can hit
// lies in the pyramid, so R contains it (its cube or an ancestor's was kept),
// and the caster started at R's entry planes returns the same hit bit for bit
// (see the proof at detail::cast_octree, core/octree_caster.hpp). R's near faces are set by
// the nearest surface in the beam, which is where the paper's conservative
// distance would start.
//
// Contours (§6.2: "contour tests must be disabled in the coarse pass"): the
// pass only looks at whole cubes, which contain their contour-clipped
// volume, so it stays conservative with contours; the fine rays may
// then use contours, since a contour only narrows a voxel's span.
//
// Widening: the rays of a beam are at least one pixel inside the four edge
// directions (render/beam.cpp), and the caster's rounded rays stay within a
// few ulps of the octree coordinates (abs_tol) plus the direction change of
// the 2^-23 clamp of tiny direction components (ang_tol per unit distance).
#include <immintrin.h>

#include <algorithm>
#include <bit>
#include <cmath>

#include "core/octree_ray.hpp"
#include "voxcast/math.hpp"
#include "voxcast/structure.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast::detail {

class BeamClassifier {
 public:
  enum : int { kSkip = 0, kKeep = 1, kDescend = 2 };
  // Stop descending at cubes no wider than kStopFraction x the beam's width
  // at their nearest point. Any value is conservative; a coarser cut makes
  // the pass cheaper but starts the rays earlier. On the bunny at 2048^3,
  // 8x8 blocks: 0.5 -> 29 ms coarse pass per frame (1 core), 1 -> 17 ms,
  // 2 -> 11 ms, 4 -> 7 ms; 2 gave the fastest frames.
  static constexpr double kStopFraction = 2.0;

  /// `grid`: the structure's grid (octree space p' = (p - origin)/side + 1).
  /// `stop_fraction`: keep (instead of descending) cubes no wider than this
  /// times the beam's width at their nearest point (kStopFraction below).
  BeamClassifier(const BeamFrustum& beam, const GridTransform& grid,
                 double stop_fraction = kStopFraction) {
    const OctreeFrame frame(grid);
    const float inv_side = frame.inv_side;
    // Eye in octree space, the same float the caster starts from (for a
    // parallel beam: a reference point on the origins' plane).
    const Vec3 pf = frame.point(beam.eye);
    if (!is_finite(pf)) return;  // no information
    const double e[3] = {pf.x, pf.y, pf.z};
    // Pinhole: four planes through the eye, each spanned by two adjacent
    // edges. Parallel (orthographic): each plane through two adjacent origin
    // corners, containing the common direction. Unit normals point into the
    // beam. The octree transform is a uniform scale + shift, so world
    // directions serve, and offsets from the eye scale by 1/side.
    bool pinhole = true, parallel = true;
    for (int i = 0; i < 4; ++i) {
      const Vec3 o = beam.edge_origin[i], d = beam.edge[i] - beam.edge[0];
      pinhole &= o.x == 0 && o.y == 0 && o.z == 0;
      parallel &= d.x == 0 && d.y == 0 && d.z == 0;
    }
    if (!pinhole && !parallel) return;  // not a beam the contract knows: no information
    double off[4][3];                   // edge origins - eye, octree units
    double off_mean[3] = {0, 0, 0}, off_max = 0;
    for (int i = 0; i < 4; ++i) {
      const Vec3 o = beam.edge_origin[i];
      off[i][0] = double(o.x) * inv_side, off[i][1] = double(o.y) * inv_side,
      off[i][2] = double(o.z) * inv_side;
      if (!std::isfinite(off[i][0]) || !std::isfinite(off[i][1]) || !std::isfinite(off[i][2]))
        return;
      for (int k = 0; k < 3; ++k) off_mean[k] += 0.25 * off[i][k];
      off_max = std::max(off_max, std::sqrt(off[i][0] * off[i][0] + off[i][1] * off[i][1] +
                                            off[i][2] * off[i][2]));
    }
    double n[4][3], dist[4];
    double sum[3] = {0, 0, 0};
    for (const Vec3& c : beam.edge) sum[0] += c.x, sum[1] += c.y, sum[2] += c.z;
    for (int i = 0; i < 4; ++i) {
      const int j = (i + 1) & 3;
      double a[3], b[3];
      if (pinhole) {
        a[0] = beam.edge[i].x, a[1] = beam.edge[i].y, a[2] = beam.edge[i].z;
        b[0] = beam.edge[j].x, b[1] = beam.edge[j].y, b[2] = beam.edge[j].z;
      } else {
        for (int k = 0; k < 3; ++k) a[k] = off[j][k] - off[i][k];
        b[0] = beam.edge[0].x, b[1] = beam.edge[0].y, b[2] = beam.edge[0].z;
      }
      double v[3] = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                     a[0] * b[1] - a[1] * b[0]};
      const double len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
      if (!(len > 0) || !std::isfinite(len)) return;  // degenerate beam: no information
      // Inward: towards a point inside the beam (pinhole: along the mean
      // edge; parallel: towards the origins' center, n is normal to the edges).
      double inward = 0;
      for (int k = 0; k < 3; ++k) inward += v[k] * (pinhole ? sum[k] : off_mean[k] - off[i][k]);
      const double sgn = inward < 0 ? -1.0 : 1.0;
      for (int k = 0; k < 3; ++k) n[i][k] = v[k] * sgn / len;
      // The plane holds the ray origins' corner i: n . (p - eye) >= n . off_i.
      dist[i] = n[i][0] * off[i][0] + n[i][1] * off[i][1] + n[i][2] * off[i][2];
    }
    double emax = std::max({std::fabs(e[0]), std::fabs(e[1]), std::fabs(e[2]), 2.0});
    emax += off_max;  // the ray origins' coordinates are within off_max of the eye's
    double abs_tol = 0x1p-18 * emax;
    if (!pinhole) {
      // Each ray of a parallel beam computes its own float origin (a few
      // rounding steps at the magnitude of the world coordinates, then
      // origin - grid.origin); the pinhole rays all share the eye's float.
      auto amax = [](Vec3 v) { return std::max({std::fabs(v.x), std::fabs(v.y), std::fabs(v.z)}); };
      abs_tol += 0x1p-20 * (double(amax(beam.eye)) + amax(grid.origin) + beam.width) * inv_side;
    }
    const double ang_tol = 0x1p-21 * grid.side() + 1e-6;
    width2_ = double(beam.angular_width) * beam.angular_width * stop_fraction * stop_fraction;
    // A parallel beam's width is constant: its origins' spread (octree units).
    width0_ = double(beam.width) * inv_side * stop_fraction;
    if (!std::isfinite(width0_) || width0_ < 0) return;
    // LOD (§6.1): the caster stops at a cube of side <= size_coef * tc_max +
    // size_bias, both octree units (size_coef = size_per_t / side, tc_max in
    // world units), and tc_max <= the world distance from the ray's origin to
    // the cube's far corner <= (the distance from the eye + off_max) * side,
    // so side <= size_per_t * far (octree units) + bias; 1/64 of slack for rounding.
    lod_coef_ = double(beam.lod.size_per_t) * (1.0 + 0x1p-6);
    lod_bias_ = double(beam.lod.size_at_origin) * inv_side * (1.0 + 0x1p-6);
    // Plane normals as float lanes (the 4-plane test vectorizes); float
    // rounding here is < 2^-20 of the distances involved and is covered by
    // float_tol below (an angular widening of ~1e-6 rad, far below a pixel).
    for (int i = 0; i < 4; ++i) {
      nx_[i] = float(n[i][0]), ny_[i] = float(n[i][1]), nz_[i] = float(n[i][2]);
      n1_[i] = std::fabs(nx_[i]) + std::fabs(ny_[i]) + std::fabs(nz_[i]);
      d_[i] = float(dist[i]);
    }
    ex_ = float(e[0]), ey_ = float(e[1]), ez_ = float(e[2]);
    off_max_ = float(off_max);
    abs_tol_ = float(abs_tol);
    ang_tol_ = float(ang_tol) + 0x1p-18f;  // + float_tol
    valid_ = true;
  }

  /// False: the beam is degenerate or the eye not finite; no information.
  bool valid() const { return valid_; }

  /// Classifies the cube [lo, lo + s] (octree space): kSkip = outside the
  /// beam or already inside the region, kKeep = keep whole (leaf, possible
  /// LOD stop, or narrower than the beam there), kDescend.
  int classify(const float lo[3], float s, bool leaf) {
    ++counters.intersects;
    const float h = 0.5f * s;
    const float cx = lo[0] + h - ex_, cy = lo[1] + h - ey_, cz = lo[2] + h - ez_;
    // Upper bound of the distance to the cube's far corner without a sqrt
    // (the L1 norm bounds the L2 norm); it only scales the tiny ang_tol.
    const float far_bound = std::fabs(cx) + std::fabs(cy) + std::fabs(cz) + 3.f * h + off_max_;
    const float tol = abs_tol_ + ang_tol_ * far_bound;
    bool outside = false;
    for (int i = 0; i < 4; ++i)
      outside |= nx_[i] * cx + ny_[i] * cy + nz_[i] * cz + h * n1_[i] - d_[i] < -tol;
    if (outside) return kSkip;
    if (lo[0] >= region.lo.x && lo[1] >= region.lo.y && lo[2] >= region.lo.z &&
        lo[0] + s <= region.hi.x && lo[1] + s <= region.hi.y && lo[2] + s <= region.hi.z)
      return kSkip;  // adds nothing: its voxels are inside R already
    if (leaf) return kKeep;
    const float dx = vmax(std::fabs(cx) - h, 0.f), dy = vmax(std::fabs(cy) - h, 0.f),
                dz = vmax(std::fabs(cz) - h, 0.f);
    // s <= kStopFraction * (width + angular_width * distance); width = 0 for a pinhole.
    const double narrow = double(s) - width0_;
    if (narrow <= 0 || narrow * narrow <= width2_ * (dx * dx + dy * dy + dz * dz))
      return kKeep;  // narrower than the beam there
    if (lod_coef_ > 0 || lod_bias_ > 0) {
      const double far = std::sqrt(double(cx) * cx + double(cy) * cy + double(cz) * cz) +
                         h * 1.7320508075688772 + off_max_;
      if (s <= lod_coef_ * (far + tol) + lod_bias_) return kKeep;  // may be a LOD stop
    }
    return kDescend;
  }

  /// classify() of the eight children of the cube [lo, lo + 2 hs], all at
  /// once in 8 float lanes (one AVX2 register per quantity), without the
  /// "inside the region" skip: bit c of *keep / *descend for each child c of
  /// `present` (children in `leaves` are kept, not descended). The same
  /// float tests as classify() for the planes, so as conservative; the width
  /// and LOD cuts in float, the LOD cut with classify()'s 1/64 slack (far
  /// above float rounding), so a possible LOD stop is never descended.
  void classify_children(const float lo[3], float hs, uint32_t present, uint32_t leaves,
                         uint32_t* keep, uint32_t* descend) {
    typedef float F8 __attribute__((vector_size(32)));
    typedef int32_t I8 __attribute__((vector_size(32)));
    counters.intersects += uint64_t(std::popcount(present));
    const I8 c = {0, 1, 2, 3, 4, 5, 6, 7};
    const float h = 0.5f * hs;
    const F8 zero{}, hv = zero + h;
    // Child centers minus the eye (the child's lo + h, as classify()).
    const F8 cx = ((c & 1) != 0 ? zero + (lo[0] + hs) : zero + lo[0]) + hv - ex_;
    const F8 cy = ((c & 2) != 0 ? zero + (lo[1] + hs) : zero + lo[1]) + hv - ey_;
    const F8 cz = ((c & 4) != 0 ? zero + (lo[2] + hs) : zero + lo[2]) + hv - ez_;
    auto fabs8 = [](F8 v) { return (F8)((I8)v & 0x7FFFFFFF); };
    const F8 ax = fabs8(cx), ay = fabs8(cy), az = fabs8(cz);
    const F8 far_bound = ax + ay + az + 3.f * h + off_max_;
    const F8 tol = abs_tol_ + ang_tol_ * far_bound;
    I8 outside{};
    for (int i = 0; i < 4; ++i)
      outside |= nx_[i] * cx + ny_[i] * cy + nz_[i] * cz + h * n1_[i] - d_[i] < -tol;
    const F8 dx = ax - h > zero ? ax - h : zero, dy = ay - h > zero ? ay - h : zero,
             dz = az - h > zero ? az - h : zero;
    const float narrow = float(double(hs) - width0_);
    I8 keep_whole = (zero + narrow <= zero) |
                    (zero + narrow * narrow <= float(width2_) * (dx * dx + dy * dy + dz * dz));
    if (lod_coef_ > 0 || lod_bias_ > 0) {
      // sqrt bounds from above in float: the slack covers its rounding.
      // One vector sqrt (the same correctly rounded values as 8 scalar
      // std::sqrt calls, which were a tenth of the brickmap coarse pass at LOD 1).
      const F8 dist2 = cx * cx + cy * cy + cz * cz;
      F8 far = (F8)_mm256_sqrt_ps((__m256)dist2);
      far += h * 1.7320508f + off_max_;
      keep_whole |= hs <= float(lod_coef_) * (far + tol) + float(lod_bias_);
    }
    // The lane masks' sign bits as child bits.
    const uint32_t out = uint32_t(_mm256_movemask_ps((__m256)outside));
    const uint32_t whole = uint32_t(_mm256_movemask_ps((__m256)keep_whole));
    const uint32_t in = present & ~out;
    *keep = in & (leaves | whole);
    *descend = in & ~*keep;
  }

  /// Adds the cube [lo, lo + s] to the region.
  void keep(const float lo[3], float s) {
    region.extend({lo[0], lo[1], lo[2]});
    region.extend({lo[0] + s, lo[1] + s, lo[2] + s});  // exact: dyadic coordinates in [1, 2]
  }

  /// Fills `start` from the region (valid, empty iff nothing was kept) and
  /// adds the pass's counters to `out` (if set).
  void finish(BeamStart* start, RayCounters* out) const {
    start->valid = true;
    start->empty = region.empty();
    start->region = region;
    if (out != nullptr) *out += counters;
  }

  Aabb region;           // octree space; empty until a cube is kept
  RayCounters counters;  // iterations = nodes visited, intersects = cubes classified

 private:
  bool valid_ = false;
  double width2_ = 0, width0_ = 0, lod_coef_ = 0, lod_bias_ = 0;
  float nx_[4] = {}, ny_[4] = {}, nz_[4] = {}, n1_[4] = {}, d_[4] = {};
  float ex_ = 0, ey_ = 0, ez_ = 0, off_max_ = 0, abs_tol_ = 0, ang_tol_ = 0;
};

}  // namespace voxcast::detail
