// GridTransform: placement of the power-of-two voxel grid (the octree root
// cube) around a mesh.
#include <fmt/format.h>

#include <bit>
#include <cmath>

#include "voxcast/error.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast {

namespace {

// Relative margin around the mesh: keeps vertices that lie exactly on the
// bounding box strictly inside the cube after float rounding of the origin.
constexpr double kMargin = 1e-3;

void check_bounds(const Aabb& b) {
  if (!is_finite(b.lo) || !is_finite(b.hi))
    throw Error("cannot fit a voxel grid: mesh bounds are not finite");
  if (b.empty()) throw Error("cannot fit a voxel grid: mesh bounds are empty");
}

double max_extent(const Aabb& b) {
  return std::max({double(b.hi.x) - b.lo.x, double(b.hi.y) - b.lo.y, double(b.hi.z) - b.lo.z});
}

}  // namespace

bool GridTransform::placement_is_valid() const {
  if (!(voxel_size > 0) || !std::isfinite(voxel_size) || !is_finite(origin)) return false;
  const double s = side();
  for (int a = 0; a < 3; ++a) {
    const float hi = float(double(origin[a]) + s);
    if (!(std::fabs(origin[a]) <= kMaxWorldCoordinate) || !(hi <= kMaxWorldCoordinate) ||
        !(hi > origin[a]))
      return false;
  }
  return true;
}

GridTransform GridTransform::fit(const Aabb& bounds, uint32_t resolution) {
  if (resolution == 0 || !std::has_single_bit(resolution) || resolution > (1u << kMaxGridLevels))
    throw Error(fmt::format("grid resolution {} is not a power of two between 1 and {}", resolution,
                            1u << kMaxGridLevels));
  check_bounds(bounds);

  double side = max_extent(bounds) * (1.0 + kMargin);
  if (!(side > 0)) {
    // A single point (all extents zero): any positive cube contains it; scale
    // it with the coordinates so that the voxel size stays above float ulp.
    double mag = std::max({std::fabs(double(bounds.lo.x)), std::fabs(double(bounds.lo.y)),
                           std::fabs(double(bounds.lo.z))});
    side = std::max(1.0, mag * kMargin);
  }
  if (!std::isfinite(side)) throw Error("cannot fit a voxel grid: mesh extent overflows");

  GridTransform g;
  g.resolution = resolution;
  g.levels = std::countr_zero(resolution);
  // Origin is stored as float: round it down so that lo stays inside, then make
  // sure hi is still covered (the cube may grow by a few ulps; the mesh stays
  // centered up to that rounding).
  for (int a = 0; a < 3; ++a) {
    double lo = bounds.lo[a], hi = bounds.hi[a];
    double o = 0.5 * (lo + hi) - 0.5 * side;
    float of = float(o);
    while (double(of) > lo - 0.25 * kMargin * side) of = std::nextafter(of, -INFINITY);
    g.origin[a] = of;
    double need = (hi - double(of)) * (1.0 + 0.25 * kMargin);
    side = std::max(side, need);
  }
  g.voxel_size = side / double(resolution);
  if (!(g.voxel_size > 0) || !std::isfinite(g.voxel_size))
    throw Error("cannot fit a voxel grid: voxel size underflows");
  return g;
}

GridTransform GridTransform::fit_voxel_size(const Aabb& bounds, double voxel_size) {
  if (!(voxel_size > 0) || !std::isfinite(voxel_size))
    throw Error(fmt::format("voxel size {} must be a positive finite number", voxel_size));
  check_bounds(bounds);
  double need = max_extent(bounds) * (1.0 + kMargin) / voxel_size;
  const double max_n = double(1u << kMaxGridLevels);
  if (!(need <= max_n))
    throw Error(fmt::format("voxel size {} needs {:.0f} voxels per axis, more than the maximum {}",
                            voxel_size, std::ceil(need), 1u << kMaxGridLevels));
  uint32_t n = std::bit_ceil(uint32_t(std::max(1.0, std::ceil(need))));
  GridTransform g = fit(bounds, n);
  // fit() may have grown the cube by a few ulps for float rounding of the
  // origin; one more doubling keeps the "at most voxel_size" promise.
  if (g.voxel_size > voxel_size) {
    if (n >= (1u << kMaxGridLevels))
      throw Error(fmt::format("voxel size {} needs more than {} voxels per axis", voxel_size,
                              1u << kMaxGridLevels));
    g = fit(bounds, n * 2);
  }
  return g;
}

}  // namespace voxcast
