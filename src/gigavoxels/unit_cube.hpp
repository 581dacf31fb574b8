#pragma once
// The ray interval inside the unit cube, shared by the volumes that march in
// unit-cube coordinates (GigaVoxels, RecursiveVolume).
#include <algorithm>
#include <utility>

#include "voxcast/math.hpp"

namespace voxcast::giga::detail {

/// Clips [*t0, *t1] to where o + d t lies in [0, 1]^3; false when empty.
inline bool clip_unit_cube(Vec3 o, Vec3 d, float* t0, float* t1) {
  for (int a = 0; a < 3; ++a) {
    if (d[a] == 0.f) {
      if (!(o[a] >= 0.f && o[a] <= 1.f)) return false;
      continue;
    }
    float ta = -o[a] / d[a], tb = (1.f - o[a]) / d[a];
    if (ta > tb) std::swap(ta, tb);
    *t0 = std::max(*t0, ta), *t1 = std::min(*t1, tb);
  }
  return *t1 > *t0;
}

/// The point-location walk both volumes share: from t0 to t1, each cell is
/// located from a point slightly past its entry (so that the walk never
/// picks the cell the ray just left; progress is at least eps), its exit
/// found, and the interval handed on. locate(t, x, foot) gets the entry t,
/// the located point x (clamped into the cube) and the pixel cone's width
/// at t, and returns the cell's exit; emit(t, te) returns false to stop.
template <class Locate, class Emit>
void walk_cells(Vec3 o, Vec3 d, float t0, float t1, float eps, float size_at_origin,
                float size_per_t, Locate&& locate, Emit&& emit) {
  float t = t0;
  while (t < t1) {
    const float tp = std::min(t + eps, 0.5f * (t + t1));
    float x[3];
    for (int a = 0; a < 3; ++a) x[a] = std::clamp(o[a] + d[a] * tp, 0.f, 1.f);
    float te = locate(t, x, size_at_origin + size_per_t * t);
    if (!(te > t)) te = std::min(t1, t + eps);
    if (!emit(t, te)) return;
    t = te;
  }
}

}  // namespace voxcast::giga::detail
