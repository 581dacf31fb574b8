#pragma once
// Pinhole camera with the project's camera contract (README "Camera contract"):
// forward = normalize(target - eye), right = normalize(cross(forward, up)),
// true_up = cross(right, forward); pixel (x, y), y = 0 the top row, gets the ray
// from eye along normalize(forward + (2(x+0.5)/W - 1) tan(fovy/2) (W/H) right
//                                  + (1 - 2(y+0.5)/H) tan(fovy/2) true_up).
#include <string>

#include "voxcast/math.hpp"

namespace voxcast {

struct Camera {
  Vec3 eye{0, 0, 1};
  Vec3 target{0, 0, 0};
  Vec3 up{0, 1, 0};
  float fovy_degrees = 45.f;

  /// Parses "ex,ey,ez,tx,ty,tz,ux,uy,uz,fovy"; throws voxcast::Error.
  static Camera parse(const std::string& text);
  /// The same comma form, with enough digits to round-trip floats.
  std::string to_string() const;
  /// A camera looking at `bounds` from the front-right-above, framing it.
  static Camera frame(const Aabb& bounds, int width, int height);
};

/// Precomputed basis for generating primary rays quickly.
struct CameraRays {
  Vec3 eye, forward, right, true_up;
  float tan_half, aspect;
  int width, height;
  CameraRays(const Camera& camera, int width, int height);
  Vec3 direction(int x, int y) const;  // unit length
  Ray ray(int x, int y) const { return {eye, direction(x, y), INFINITY}; }
  /// World-space width of one pixel's footprint per unit distance along a ray.
  float pixel_angle() const { return 2.f * tan_half / float(height); }
};

}  // namespace voxcast
