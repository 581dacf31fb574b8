#pragma once
// Dense-grid emission–absorption oracle for volume queries (issue 9, item 7),
// ready for the first volume structure (GigaVoxels, a later issue): what a
// volume integrator must return for a ray through a grid of piecewise-
// constant cells, computed two independent ways in double precision.
//
// Model (front-to-back compositing, Max 1995 "Optical models for direct volume
// rendering", emission–absorption with a per-cell constant color): a cell of
// extinction σ and color c crossed over a length Δ (world distance) changes
// the accumulated color C and transmittance T by
//     C += T · (1 − exp(−σΔ)) · c,    T *= exp(−σΔ),
// starting from C = 0, T = 1. Over a whole ray this is the exact integral
//     C = ∫ T(s) σ(s) c(s) ds,  T(s) = exp(−∫_0^s σ),
// because both σ and c are constant inside a cell.
//
// Grid space: cell (x, y, z) is [x, x+1] × [y, y+1] × [z, z+1] of an
// nx × ny × nz grid; the ray is o + t d, and distances are |d| · Δt, so σ is
// per grid unit and d need not be normalized. Points outside the grid are
// empty (σ = 0).
#include <array>
#include <cstdint>
#include <vector>

#include "support/dda_oracle.hpp"

namespace voxcast::testing {

struct VolumeCell {
  double sigma = 0;                      // extinction per grid unit, >= 0
  std::array<double, 3> color{0, 0, 0};  // emitted linear RGB (premultiplied by nothing)
};

struct VolumeSample {
  std::array<double, 3> color{0, 0, 0};  // accumulated C
  double transmittance = 1;              // T after the segment
};

class DenseVolume {
 public:
  DenseVolume(int nx, int ny, int nz);
  int nx() const { return n_[0]; }
  int ny() const { return n_[1]; }
  int nz() const { return n_[2]; }
  VolumeCell& at(int x, int y, int z);
  const VolumeCell& at(int x, int y, int z) const;
  /// The cell containing grid point p (half-open cells), or null outside.
  const VolumeCell* cell_at(DVec3 p) const;

  /// Exact integration over [t0, t1]: the ray is cut at every cell boundary
  /// (slab walk in double precision) and each piece is composited with the
  /// closed form above.
  VolumeSample integrate_exact(DVec3 o, DVec3 d, double t0, double t1) const;
  /// The same by fine fixed steps of `dt` (in t) from t0, each sampling the
  /// cell at the step's midpoint (the last step is cut at t1). Converges to
  /// integrate_exact as dt -> 0 (only steps that straddle a boundary differ).
  VolumeSample integrate_fixed_step(DVec3 o, DVec3 d, double t0, double t1, double dt) const;

 private:
  int n_[3];
  std::vector<VolumeCell> cells_;
};

}  // namespace voxcast::testing
