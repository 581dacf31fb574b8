// Beam optimization (esvo §6.2): the pyramid of a block of pixels.
#include "render/beam.hpp"

#include <algorithm>
#include <cmath>

namespace voxcast::detail {

BeamFrustum block_beam(const CameraRays& cam, int x0, int y0, int x1, int y1,
                       const LodFootprint& lod) {
  // Camera contract (camera.hpp): pixel (x, y) looks along
  // forward + (2(x+0.5)/W - 1) tan (W/H) right + (1 - 2(y+0.5)/H) tan up;
  // the same map at pixel-edge coordinates X, Y, widened by one pixel.
  auto dir = [&](double X, double Y) {
    const double sx = (2.0 * X / cam.width - 1.0) * cam.tan_half * cam.aspect;
    const double sy = (1.0 - 2.0 * Y / cam.height) * cam.tan_half;
    double v[3];
    for (int k = 0; k < 3; ++k) v[k] = cam.forward[k] + cam.right[k] * sx + cam.true_up[k] * sy;
    const double len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    return Vec3{float(v[0] / len), float(v[1] / len), float(v[2] / len)};
  };
  const double X0 = x0 - 1.0, X1 = x1 + 1.0, Y0 = y0 - 1.0, Y1 = y1 + 1.0;
  BeamFrustum b;
  b.eye = cam.eye;
  b.edge[0] = dir(X0, Y0);
  b.edge[1] = dir(X1, Y0);
  b.edge[2] = dir(X1, Y1);
  b.edge[3] = dir(X0, Y1);
  // The widest angle of the pyramid is between opposite edges (a diagonal).
  auto angle = [](Vec3 a, Vec3 c) {
    const double d = double(a.x) * c.x + double(a.y) * c.y + double(a.z) * c.z;
    return std::acos(std::clamp(d, -1.0, 1.0));
  };
  b.angular_width = float(std::max(angle(b.edge[0], b.edge[2]), angle(b.edge[1], b.edge[3])));
  b.lod = lod;
  return b;
}

}  // namespace voxcast::detail
