// Pinhole and orthographic cameras: parsing, printing, framing and primary
// rays (the camera contract is spelled out in camera.hpp).
#include "voxcast/camera.hpp"

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <numbers>
#include <vector>

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

// Comma-separated finite floats; `what` names the form in messages.
std::vector<float> parse_numbers(const std::string& text, const char* what) {
  std::vector<float> v;
  const char* s = text.c_str();
  while (true) {
    if (v.size() == 32) throw Error(std::string(what) + ": too many numbers in '" + text + "'");
    char* end = nullptr;
    errno = 0;
    const float x = std::strtof(s, &end);
    if (end == s)
      throw Error(std::string(what) + ": expected a number at '" + std::string(s) + "' in '" +
                  text + "'");
    if (errno == ERANGE || !std::isfinite(x))
      throw Error(std::string(what) + ": number out of range in '" + text + "'");
    v.push_back(x);
    while (*end == ' ') ++end;
    if (*end == '\0') break;
    if (*end != ',') throw Error(std::string(what) + ": expected ',' in '" + text + "'");
    s = end + 1;
  }
  return v;
}

void check_size(int width, int height) {
  if (width <= 0 || height <= 0) throw Error("camera: image size must be positive");
}

void check_bounds(const Aabb& bounds) {
  if (bounds.empty() || !is_finite(bounds.lo) || !is_finite(bounds.hi))
    throw Error("camera: cannot frame empty or non-finite bounds");
}

// The view basis of the camera contract.
struct Basis {
  Vec3 forward, right, true_up;
  Basis(Vec3 eye, Vec3 target, Vec3 up) : Basis(normalize(target - eye), up) {}
  Basis(Vec3 forward_unit, Vec3 up)
      : forward(forward_unit),
        right(normalize(cross(forward_unit, up))),
        true_up(cross(right, forward_unit)) {}
};

// The box corners relative to `origin` in the view basis: a = along right,
// b = along true_up, z = along forward. The framing below works on these
// points only, so a tighter point set (e.g. a convex hull) could replace them.
struct ViewPoint {
  double a, b, z;
};
std::vector<ViewPoint> corners_in_view(const Aabb& bounds, Vec3 origin, const Basis& basis) {
  std::vector<ViewPoint> out;
  for (int i = 0; i < 8; ++i) {
    const Vec3 p{(i & 1) ? bounds.hi.x : bounds.lo.x, (i & 2) ? bounds.hi.y : bounds.lo.y,
                 (i & 4) ? bounds.hi.z : bounds.lo.z};
    const Vec3 v = p - origin;
    out.push_back({double(dot(v, basis.right)), double(dot(v, basis.true_up)),
                   double(dot(v, basis.forward))});
  }
  return out;
}

// Distance from `target` (backwards along the view) at which a pinhole
// camera with this basis sees every corner at |sx|, |sy| <= kFrameFill:
// a corner at depth z0 relative to the target is at depth z0 + D from the
// eye, and |a| <= fill tan_h (z0 + D) <=> D >= |a| / (fill tan_h) - z0. The
// exact maximum over the corners, so the tightest corner touches the margin.
// The eye also stays in front of every corner by 5% of the box radius (so
// it is outside the box and no corner is at the eye plane), and a single
// point is framed from its own size (or 1) away.
double framing_distance(const Aabb& bounds, Vec3 target, const Basis& basis, float fovy_degrees,
                        int width, int height) {
  const double tan_v = std::tan(0.5 * double(fovy_degrees) * double(kDegToRad));
  const double tan_h = tan_v * double(width) / double(height);
  const double fill = Camera::kFrameFill;
  const double radius = 0.5 * double(length(bounds.extent()));
  double dist = 0;
  for (const ViewPoint& p : corners_in_view(bounds, target, basis)) {
    dist = std::fmax(dist, std::fabs(p.a) / (fill * tan_h) - p.z);
    dist = std::fmax(dist, std::fabs(p.b) / (fill * tan_v) - p.z);
    dist = std::fmax(dist, -p.z + 0.05 * radius);
  }
  if (!(dist > 0)) dist = radius > 0 ? radius : 1.0;
  // Round up to float so that the float eye is not closer than computed.
  return dist * (1.0 + 1e-6);
}

// Smallest orthographic width for which every corner projects to
// |sx|, |sy| <= kFrameFill around the view axis through `eye`.
double framing_ortho_width(const Aabb& bounds, Vec3 eye, const Basis& basis, int width,
                           int height) {
  double half_w = 0;
  for (const ViewPoint& p : corners_in_view(bounds, eye, basis)) {
    half_w = std::fmax(half_w, std::fabs(p.a) / Camera::kFrameFill);
    half_w = std::fmax(half_w, std::fabs(p.b) / Camera::kFrameFill * double(width) / height);
  }
  if (!(half_w > 0)) half_w = 0.5;  // a point on the axis: any width shows it
  return 2.0 * half_w * (1.0 + 1e-6);
}

// Eye at `dist` from the center of `bounds` in direction `back`; for an
// orthographic camera also the framing width.
Camera place(const Aabb& bounds, int width, int height, Vec3 back, Vec3 up, float dist,
             Projection projection) {
  check_bounds(bounds);
  check_size(width, height);
  Camera c;
  c.fovy_degrees = Camera::kDefaultFovy;
  c.up = up;
  c.target = bounds.center();
  const Basis basis(-back, c.up);
  if (!(dist > 0))
    dist = float(framing_distance(bounds, c.target, basis, c.fovy_degrees, width, height));
  c.eye = c.target + back * dist;
  // A distance lost in the target's float spacing: step out by the
  // coordinates' magnitude, which float can represent.
  if (c.eye.x == c.target.x && c.eye.y == c.target.y && c.eye.z == c.target.z)
    c.eye = c.target +
            back * (std::fabs(c.target.x) + std::fabs(c.target.y) + std::fabs(c.target.z) + 1.f);
  if (projection == Projection::Orthographic) c = c.orthographic(bounds, width, height);
  c.validate();
  return c;
}

}  // namespace

void Camera::validate() const {
  if (!is_finite(eye) || !is_finite(target) || !is_finite(up) || !std::isfinite(fovy_degrees) ||
      !std::isfinite(ortho_width))
    throw Error("camera: non-finite value");
  if (projection == Projection::Perspective) {
    if (!(fovy_degrees > 0.f && fovy_degrees < 180.f))
      throw Error("camera: fovy must be in (0, 180) degrees");
  } else if (!(ortho_width > 0.f)) {
    throw Error("camera: orthographic width must be > 0");
  }
  const Vec3 f = target - eye;
  if (!(length(f) > 0)) throw Error("camera: eye and target coincide");
  if (!std::isfinite(length(f)))  // (normalize would give no direction at all)
    throw Error("camera: eye and target too far apart for float arithmetic");
  if (nearly_parallel(normalize(f), up))
    throw Error("camera: up is parallel to the view direction");
}

Camera Camera::parse(const std::string& text) {
  Camera c;
  std::string numbers = text;
  const char* form = "ex,ey,ez,tx,ty,tz,ux,uy,uz,fovy";
  if (text.rfind("ortho,", 0) == 0) {
    c.projection = Projection::Orthographic;
    numbers = text.substr(6);
    form = "ortho,ex,ey,ez,tx,ty,tz,ux,uy,uz,width";
  }
  const std::vector<float> v = parse_numbers(numbers, "camera");
  if (v.size() != 10)
    throw Error(std::string("camera: expected exactly 10 numbers '") + form + "', got " +
                std::to_string(v.size()));
  c.eye = {v[0], v[1], v[2]};
  c.target = {v[3], v[4], v[5]};
  c.up = {v[6], v[7], v[8]};
  if (c.projection == Projection::Orthographic)
    c.ortho_width = v[9];
  else
    c.fovy_degrees = v[9];
  c.validate();
  return c;
}

std::string Camera::to_string() const {
  // %.9g: nine significant digits round-trip every float exactly.
  char buf[512];
  const bool ortho = projection == Projection::Orthographic;
  std::snprintf(buf, sizeof buf, "%s%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g",
                ortho ? "ortho," : "", eye.x, eye.y, eye.z, target.x, target.y, target.z, up.x,
                up.y, up.z, ortho ? ortho_width : fovy_degrees);
  return buf;
}

Vec3 Camera::auto_view_direction() {
  // Front-right-above: the usual three-quarter view of a +y-up model.
  return normalize(Vec3{1.0f, 0.6f, 1.4f});
}

Camera Camera::frame(const Aabb& bounds, int width, int height, Projection projection) {
  return place(bounds, width, height, auto_view_direction(), {0, 1, 0}, 0.f, projection);
}

Camera Camera::orbit(const Aabb& bounds, int width, int height, float azimuth_degrees,
                     float elevation_degrees, float distance, Projection projection) {
  if (!std::isfinite(azimuth_degrees) || !std::isfinite(elevation_degrees) ||
      !std::isfinite(distance))
    throw Error("orbit: non-finite value");
  if (!(elevation_degrees >= -90.f && elevation_degrees <= 90.f))
    throw Error("orbit: elevation must be in [-90, 90] degrees");
  const double az = double(azimuth_degrees) * std::numbers::pi / 180.0;
  const double el = double(elevation_degrees) * std::numbers::pi / 180.0;
  const Vec3 back{float(std::sin(az) * std::cos(el)), float(std::sin(el)),
                  float(std::cos(az) * std::cos(el))};
  // d(back)/d(el): perpendicular to the view, in the plane of +y whenever
  // |el| < 90 (so the same image as up = +y), and defined at the poles.
  const Vec3 up{float(-std::sin(az) * std::sin(el)), float(std::cos(el)),
                float(-std::cos(az) * std::sin(el))};
  return place(bounds, width, height, back, up, distance, projection);
}

Camera Camera::parse_orbit(const std::string& text, const Aabb& bounds, int width, int height,
                           Projection projection) {
  const std::vector<float> v = parse_numbers(text, "orbit");
  if (v.size() != 2 && v.size() != 3)
    throw Error("orbit: expected 'AZ,EL[,DIST]' (degrees, distance), got " +
                std::to_string(v.size()) + " numbers");
  if (v.size() == 3 && !(v[2] > 0)) throw Error("orbit: DIST must be > 0");
  return orbit(bounds, width, height, v[0], v[1], v.size() == 3 ? v[2] : 0.f, projection);
}

Camera Camera::parse_look_at(const std::string& text) {
  const std::vector<float> v = parse_numbers(text, "look-at");
  if (v.size() != 6 && v.size() != 9 && v.size() != 10)
    throw Error("look-at: expected 'ex,ey,ez,tx,ty,tz[,ux,uy,uz[,fovy]]', got " +
                std::to_string(v.size()) + " numbers");
  Camera c;
  c.eye = {v[0], v[1], v[2]};
  c.target = {v[3], v[4], v[5]};
  c.up = v.size() >= 9 ? Vec3{v[6], v[7], v[8]} : Vec3{0, 1, 0};
  c.fovy_degrees = v.size() == 10 ? v[9] : kDefaultFovy;
  c.validate();
  return c;
}

Camera Camera::orthographic(const Aabb& bounds, int width, int height, float width_world) const {
  Camera c = *this;
  c.projection = Projection::Orthographic;
  if (width_world > 0) {
    c.ortho_width = width_world;
  } else {
    check_bounds(bounds);
    check_size(width, height);
    validate();  // the basis below needs a usable eye, target and up
    c.ortho_width = float(framing_ortho_width(bounds, eye, Basis(eye, target, up), width, height));
  }
  c.validate();
  return c;
}

CameraRays::CameraRays(const Camera& camera, int width_, int height_)
    : width(width_), height(height_) {
  camera.validate();
  check_size(width_, height_);
  eye = camera.eye;
  const Basis basis(camera.eye, camera.target, camera.up);
  forward = basis.forward;
  right = basis.right;
  true_up = basis.true_up;
  aspect = float(width_) / float(height_);
  if (camera.projection == Projection::Orthographic) {
    ortho = true;
    half_width = 0.5f * camera.ortho_width;
    half_height = half_width / aspect;  // square pixels
  } else {
    tan_half = std::tan(0.5f * camera.fovy_degrees * kDegToRad);
  }
}

}  // namespace voxcast
