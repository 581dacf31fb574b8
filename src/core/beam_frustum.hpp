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
// through the eye, slightly widened), and keeps a node's whole cube, instead
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
#include <algorithm>
#include <cmath>

#include "core/octree_ray.hpp"
#include "voxcast/math.hpp"
#include "voxcast/structure.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast::detail {

class BeamClassifier {
 public:
  enum : int { kSkip = 0, kKeep = 1, kDescend = 2 };

  /// `grid`: the structure's grid (octree space p' = (p - origin)/side + 1).
  BeamClassifier(const BeamFrustum& beam, const GridTransform& grid) {
    const OctreeFrame frame(grid);
    // Eye in octree space, the same float the caster starts from.
    const Vec3 pf = frame.point(beam.eye);
    if (!is_finite(pf)) return;  // no information
    const double e[3] = {pf.x, pf.y, pf.z};
    // Side planes through the eye: unit normals pointing into the beam. The
    // octree transform is a uniform scale + shift, so world directions serve.
    double n[4][3];
    double sum[3] = {0, 0, 0};
    for (const Vec3& c : beam.edge) sum[0] += c.x, sum[1] += c.y, sum[2] += c.z;
    for (int i = 0; i < 4; ++i) {
      const Vec3 a = beam.edge[i], b = beam.edge[(i + 1) & 3];
      double v[3] = {double(a.y) * b.z - double(a.z) * b.y, double(a.z) * b.x - double(a.x) * b.z,
                     double(a.x) * b.y - double(a.y) * b.x};
      const double len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
      if (!(len > 0) || !std::isfinite(len)) return;  // degenerate beam: no information
      const double sgn = (v[0] * sum[0] + v[1] * sum[1] + v[2] * sum[2]) < 0 ? -1.0 : 1.0;
      for (int k = 0; k < 3; ++k) n[i][k] = v[k] * sgn / len;
    }
    const double emax = std::max({std::fabs(e[0]), std::fabs(e[1]), std::fabs(e[2]), 2.0});
    const double abs_tol = 0x1p-18 * emax;
    const double ang_tol = 0x1p-21 * grid.side() + 1e-6;
    // Stop descending at cubes no wider than kStopFraction x the beam's width
    // at their nearest point. Any value is conservative; a coarser cut makes
    // the pass cheaper but starts the rays earlier. On the bunny at 2048^3,
    // 8x8 blocks: 0.5 -> 29 ms coarse pass per frame (1 core), 1 -> 17 ms,
    // 2 -> 11 ms, 4 -> 7 ms; 2 gave the fastest frames.
    constexpr double kStopFraction = 2.0;
    width2_ = double(beam.angular_width) * beam.angular_width * kStopFraction * kStopFraction;
    // LOD (§6.1): the caster stops at a cube of side <= size_coef * tc_max +
    // size_bias, both octree units (size_coef = size_per_t / side, tc_max in
    // world units), and tc_max <= the world distance to the cube's far corner,
    // so side <= size_per_t * far (octree units) + bias; 1/64 of slack for rounding.
    lod_coef_ = double(beam.lod.size_per_t) * (1.0 + 0x1p-6);
    lod_bias_ = double(beam.lod.size_at_origin) * frame.inv_side * (1.0 + 0x1p-6);
    // Plane normals as float lanes (the 4-plane test vectorizes); float
    // rounding here is < 2^-20 of the distances involved and is covered by
    // float_tol below (an angular widening of ~1e-6 rad, far below a pixel).
    for (int i = 0; i < 4; ++i) {
      nx_[i] = float(n[i][0]), ny_[i] = float(n[i][1]), nz_[i] = float(n[i][2]);
      n1_[i] = std::fabs(nx_[i]) + std::fabs(ny_[i]) + std::fabs(nz_[i]);
    }
    ex_ = float(e[0]), ey_ = float(e[1]), ez_ = float(e[2]);
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
    const float far_bound = std::fabs(cx) + std::fabs(cy) + std::fabs(cz) + 3.f * h;
    const float tol = abs_tol_ + ang_tol_ * far_bound;
    bool outside = false;
    for (int i = 0; i < 4; ++i)
      outside |= nx_[i] * cx + ny_[i] * cy + nz_[i] * cz + h * n1_[i] < -tol;
    if (outside) return kSkip;
    if (lo[0] >= region.lo.x && lo[1] >= region.lo.y && lo[2] >= region.lo.z &&
        lo[0] + s <= region.hi.x && lo[1] + s <= region.hi.y && lo[2] + s <= region.hi.z)
      return kSkip;  // adds nothing: its voxels are inside R already
    if (leaf) return kKeep;
    const float dx = vmax(std::fabs(cx) - h, 0.f), dy = vmax(std::fabs(cy) - h, 0.f),
                dz = vmax(std::fabs(cz) - h, 0.f);
    if (double(s) * s <= width2_ * (dx * dx + dy * dy + dz * dz))
      return kKeep;  // narrower than the beam there
    if (lod_coef_ > 0 || lod_bias_ > 0) {
      const double far =
          std::sqrt(double(cx) * cx + double(cy) * cy + double(cz) * cz) + h * 1.7320508075688772;
      if (s <= lod_coef_ * (far + tol) + lod_bias_) return kKeep;  // may be a LOD stop
    }
    return kDescend;
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
  double width2_ = 0, lod_coef_ = 0, lod_bias_ = 0;
  float nx_[4] = {}, ny_[4] = {}, nz_[4] = {}, n1_[4] = {};
  float ex_ = 0, ey_ = 0, ez_ = 0, abs_tol_ = 0, ang_tol_ = 0;
};

}  // namespace voxcast::detail
