// Beam optimization (esvo §6.2): the pyramid (pinhole camera) or prism
// (orthographic camera) of a block of pixels.
#include "render/beam.hpp"

#include <algorithm>
#include <cmath>

namespace voxcast::detail {

BeamFrustum block_beam(const CameraRays& cam, int x0, int y0, int x1, int y1,
                       const LodFootprint& lod) {
  // The camera contract (camera.hpp) at pixel-edge coordinates X, Y, widened
  // by one pixel, in double.
  const double X0 = x0 - 1.0, X1 = x1 + 1.0, Y0 = y0 - 1.0, Y1 = y1 + 1.0;
  auto sx = [&](double X) { return 2.0 * X / cam.width - 1.0; };
  auto sy = [&](double Y) { return 1.0 - 2.0 * Y / cam.height; };
  const double corner_x[4] = {X0, X1, X1, X0}, corner_y[4] = {Y0, Y0, Y1, Y1};
  BeamFrustum b;
  b.lod = lod;
  if (cam.ortho) {
    // Parallel rays along forward from the image plane: a prism around the
    // block's origin rectangle, referenced to the rectangle's center.
    const double cx = 0.5 * (sx(X0) + sx(X1)), cy = 0.5 * (sy(Y0) + sy(Y1));
    b.eye = cam.ortho_origin(float(cx), float(cy));
    double width2 = 0;
    for (int i = 0; i < 4; ++i) {
      const double u = (sx(corner_x[i]) - cx) * cam.half_width,
                   v = (sy(corner_y[i]) - cy) * cam.half_height;
      b.edge[i] = cam.forward;
      b.edge_origin[i] = Vec3{float(cam.right.x * u + cam.true_up.x * v),
                              float(cam.right.y * u + cam.true_up.y * v),
                              float(cam.right.z * u + cam.true_up.z * v)};
      width2 = std::max(width2, 4.0 * (u * u + v * v));  // the diagonal bounds every distance
    }
    // Float rounding of the rectangle and of b.eye is far below the one
    // pixel of widening; 1e-6 relative for the width itself.
    b.width = float(std::sqrt(width2) * (1.0 + 1e-6));
    b.angular_width = 0.f;
    return b;
  }
  auto dir = [&](double X, double Y) {
    const double px = sx(X) * cam.tan_half * cam.aspect, py = sy(Y) * cam.tan_half;
    double v[3];
    for (int k = 0; k < 3; ++k) v[k] = cam.forward[k] + cam.right[k] * px + cam.true_up[k] * py;
    const double len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    return Vec3{float(v[0] / len), float(v[1] / len), float(v[2] / len)};
  };
  b.eye = cam.eye;
  for (int i = 0; i < 4; ++i) b.edge[i] = dir(corner_x[i], corner_y[i]);
  // The widest angle of the pyramid is between opposite edges (a diagonal).
  auto angle = [](Vec3 a, Vec3 c) {
    const double d = double(a.x) * c.x + double(a.y) * c.y + double(a.z) * c.z;
    return std::acos(std::clamp(d, -1.0, 1.0));
  };
  b.angular_width = float(std::max(angle(b.edge[0], b.edge[2]), angle(b.edge[1], b.edge[3])));
  return b;
}

void PacketTile::frustum_blocks(const SurfaceQuery& q, const CameraRays& cam,
                                const LodFootprint& lod, int x0, int y0, int x1, int y1, int k,
                                TraceContext& ctx, const BeamStart& tile) {
  if (k >= x1 - x0 && k >= y1 - y0) {
    starts.clear();
    beams.assign(order.size(), &tile);
    return;
  }
  coarse_pass(x0, y0, x1, y1, k, [&](int bx, int by, BeamStart* start) {
    const int bx1 = std::min(bx + k, x1), by1 = std::min(by + k, y1);
    q.frustum_start(block_beam(cam, bx, by, bx1, by1, lod),
                    ray_octant(cam.ray((bx + bx1) / 2, (by + by1) / 2).dir), ctx, start, &tile);
  });
}

}  // namespace voxcast::detail
