#include "support/sat_oracle.hpp"

#include <algorithm>
#include <cmath>

#include "voxcast/math.hpp"
#include "voxcast/morton.hpp"

namespace voxcast::testing {

namespace {

// The engine's one vector type in double (math.hpp): its arithmetic is
// plain componentwise code, nothing of the voxelizer's under test.
using D3 = Vec3d;
D3 sub(D3 a, D3 b) {
  return a - b;
}

// Separated along `axis` iff the triangle's projection interval and the box's
// projection [-r, r] (box centered at the origin, half size h) are disjoint.
// A zero axis projects everything to 0 and never separates.
bool separated(D3 axis, const D3 v[3], double h) {
  double p0 = dot(axis, v[0]), p1 = dot(axis, v[1]), p2 = dot(axis, v[2]);
  double r = h * (std::fabs(axis.x) + std::fabs(axis.y) + std::fabs(axis.z));
  double mn = std::min({p0, p1, p2}), mx = std::max({p0, p1, p2});
  return mn > r || mx < -r;
}

}  // namespace

bool sat_triangle_box_overlap(const double tri[3][3], const double lo[3], double size) {
  const double h = 0.5 * size;
  const D3 c{lo[0] + h, lo[1] + h, lo[2] + h};
  // Move the box center to the origin.
  const D3 v[3] = {sub({tri[0][0], tri[0][1], tri[0][2]}, c),
                   sub({tri[1][0], tri[1][1], tri[1][2]}, c),
                   sub({tri[2][0], tri[2][1], tri[2][2]}, c)};
  const D3 e[3] = {sub(v[1], v[0]), sub(v[2], v[1]), sub(v[0], v[2])};
  const D3 axes[3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  // 9 cross-product axes.
  for (const D3& ed : e)
    for (const D3& a : axes)
      if (separated(cross(a, ed), v, h)) return false;
  // 3 box normals (the triangle's bounding box against the box).
  for (const D3& a : axes)
    if (separated(a, v, h)) return false;
  // Triangle normal.
  if (separated(cross(e[0], e[1]), v, h)) return false;
  return true;
}

std::vector<uint64_t> sat_triangle_voxels(const double tri[3][3], uint32_t n) {
  int lo[3], hi[3];
  for (int a = 0; a < 3; ++a) {
    double mn = std::min({tri[0][a], tri[1][a], tri[2][a]});
    double mx = std::max({tri[0][a], tri[1][a], tri[2][a]});
    // One voxel of margin beyond the bounding box: the SAT decides, not this.
    lo[a] = std::max(0, int(std::floor(std::clamp(mn, -2.0, double(n) + 2))) - 1);
    hi[a] = std::min(int(n) - 1, int(std::floor(std::clamp(mx, -2.0, double(n) + 2))) + 1);
  }
  std::vector<uint64_t> out;
  for (int z = lo[2]; z <= hi[2]; ++z)
    for (int y = lo[1]; y <= hi[1]; ++y)
      for (int x = lo[0]; x <= hi[0]; ++x) {
        const double b[3] = {double(x), double(y), double(z)};
        if (sat_triangle_box_overlap(tri, b, 1.0)) out.push_back(morton_encode(x, y, z));
      }
  std::sort(out.begin(), out.end());
  return out;
}

}  // namespace voxcast::testing
