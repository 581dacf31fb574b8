// Pinhole camera: parsing, printing, automatic framing and primary rays
// (the camera contract is spelled out in camera.hpp).
#include "voxcast/camera.hpp"

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <numbers>

#include "voxcast/error.hpp"

namespace voxcast {
namespace {

constexpr float kDegToRad = float(std::numbers::pi / 180.0);

// Forward and up must span a plane, or right = cross(forward, up) is undefined.
bool nearly_parallel(Vec3 forward_unit, Vec3 up) {
  const float lu = length(up);
  if (!(lu > 0)) return true;
  return length(cross(forward_unit, up / lu)) < 1e-6f;
}

void check_camera(const Camera& c) {
  if (!is_finite(c.eye) || !is_finite(c.target) || !is_finite(c.up) ||
      !std::isfinite(c.fovy_degrees))
    throw Error("camera: non-finite value");
  if (!(c.fovy_degrees > 0.f && c.fovy_degrees < 180.f))
    throw Error("camera: fovy must be in (0, 180) degrees");
  const Vec3 f = c.target - c.eye;
  if (!(length(f) > 0)) throw Error("camera: eye and target coincide");
  if (nearly_parallel(normalize(f), c.up))
    throw Error("camera: up is parallel to the view direction");
}

}  // namespace

Camera Camera::parse(const std::string& text) {
  float v[10];
  const char* s = text.c_str();
  int n = 0;
  while (true) {
    if (n == 10)
      throw Error(
          "camera: expected exactly 10 numbers 'ex,ey,ez,tx,ty,tz,ux,uy,uz,fovy', got more");
    char* end = nullptr;
    errno = 0;
    const float x = std::strtof(s, &end);
    if (end == s)
      throw Error("camera: expected a number at '" + std::string(s) + "' in '" + text + "'");
    if (errno == ERANGE || !std::isfinite(x))
      throw Error("camera: number out of range in '" + text + "'");
    v[n++] = x;
    while (*end == ' ') ++end;
    if (*end == '\0') break;
    if (*end != ',') throw Error("camera: expected ',' in '" + text + "'");
    s = end + 1;
  }
  if (n != 10)
    throw Error("camera: expected exactly 10 numbers 'ex,ey,ez,tx,ty,tz,ux,uy,uz,fovy', got " +
                std::to_string(n));
  Camera c;
  c.eye = {v[0], v[1], v[2]};
  c.target = {v[3], v[4], v[5]};
  c.up = {v[6], v[7], v[8]};
  c.fovy_degrees = v[9];
  check_camera(c);
  return c;
}

std::string Camera::to_string() const {
  // %.9g: nine significant digits round-trip every float exactly.
  char buf[512];
  std::snprintf(buf, sizeof buf, "%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g", eye.x, eye.y,
                eye.z, target.x, target.y, target.z, up.x, up.y, up.z, fovy_degrees);
  return buf;
}

Camera Camera::frame(const Aabb& bounds, int width, int height) {
  if (bounds.empty() || !is_finite(bounds.lo) || !is_finite(bounds.hi))
    throw Error("camera: cannot frame empty or non-finite bounds");
  if (width <= 0 || height <= 0) throw Error("camera: image size must be positive");
  Camera c;
  c.fovy_degrees = 40.f;
  c.up = {0, 1, 0};
  c.target = bounds.center();
  // Front-right-above: the usual three-quarter view of a +y-up model.
  const Vec3 back = normalize(Vec3{1.0f, 0.6f, 1.4f});  // from target towards the eye
  const Vec3 forward = -back;
  const Vec3 right = normalize(cross(forward, c.up));
  const Vec3 true_up = cross(right, forward);
  const float tan_v = std::tan(0.5f * c.fovy_degrees * kDegToRad);
  const float tan_h = tan_v * float(width) / float(height);
  // Fit the ellipsoid inscribed in the box (semi-axes = half extents) with a
  // 5% margin. Fitting the box corners or the bounding sphere leaves most of
  // the frame empty for real models, which seldom reach their box corners
  // (the bunny covered 17% of the image with a corner fit, ~35% like this).
  // The ellipsoid's half width along a unit screen axis u is
  // sqrt(sum (e_i u_i)^2); a sphere of radius r fits a cone of half angle a
  // at distance r / sin(a), which we use per screen axis.
  const Vec3 e = bounds.extent() * 0.5f;
  // The ellipsoid is grown by 12%: real shapes poke out of it near the box
  // edges (bunny ears, truck corners) and should not be clipped much.
  auto half_width = [&](Vec3 u) { return 1.12f * length(e * u); };
  auto dist_for = [](float r, float tan_half) {
    const float t = tan_half * 0.95f;
    return r * std::sqrt(1.f + 1.f / (t * t));  // r / sin(atan(t))
  };
  float dist = std::fmax(dist_for(half_width(right), tan_h), dist_for(half_width(true_up), tan_v));
  // Keep the eye outside the ellipsoid along the view direction.
  dist = std::fmax(dist, 1.05f * half_width(forward));
  const float radius = length(e);
  if (!(dist > 0)) dist = radius > 0 ? radius : 1.f;  // a point: any distance works
  c.eye = c.target + back * dist;
  if (c.eye.x == c.target.x && c.eye.y == c.target.y && c.eye.z == c.target.z)
    c.eye = c.target +
            back * (std::fabs(c.target.x) + std::fabs(c.target.y) + std::fabs(c.target.z) + 1.f);
  return c;
}

CameraRays::CameraRays(const Camera& camera, int width_, int height_)
    : width(width_), height(height_) {
  check_camera(camera);
  if (width_ <= 0 || height_ <= 0) throw Error("camera: image size must be positive");
  eye = camera.eye;
  forward = normalize(camera.target - camera.eye);
  right = normalize(cross(forward, camera.up));
  true_up = cross(right, forward);
  tan_half = std::tan(0.5f * camera.fovy_degrees * kDegToRad);
  aspect = float(width_) / float(height_);
}

Vec3 CameraRays::direction(int x, int y) const {
  const float sx = (2.f * (float(x) + 0.5f) / float(width) - 1.f) * tan_half * aspect;
  const float sy = (1.f - 2.f * (float(y) + 0.5f) / float(height)) * tan_half;
  return normalize(forward + right * sx + true_up * sy);
}

}  // namespace voxcast
