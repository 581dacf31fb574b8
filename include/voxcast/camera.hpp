#pragma once
// Pinhole and orthographic cameras with the project's camera contract
// (README "Camera contract"):
// forward = normalize(target - eye), right = normalize(cross(forward, up)),
// true_up = cross(right, forward); with sx = 2(x+0.5)/W - 1 and
// sy = 1 - 2(y+0.5)/H (pixel (x, y), y = 0 the top row):
//  * perspective: the ray from eye along
//    normalize(forward + sx tan(fovy/2) (W/H) right + sy tan(fovy/2) true_up);
//  * orthographic (parallel rays): the ray along forward from
//    eye + sx (ortho_width/2) right + sy (ortho_width/2) (H/W) true_up.
#include <string>

#include "voxcast/math.hpp"

namespace voxcast {

enum class Projection { Perspective, Orthographic };

struct Camera {
  Vec3 eye{0, 0, 1};
  Vec3 target{0, 0, 0};
  Vec3 up{0, 1, 0};
  float fovy_degrees = 45.f;  // perspective: full vertical angle
  Projection projection = Projection::Perspective;
  float ortho_width = 0.f;  // orthographic: world-space width of the image (> 0)

  /// The vertical field of view of automatic and --look-at cameras.
  static constexpr float kDefaultFovy = 40.f;
  /// Share of the half image a framed model may fill along each axis (the
  /// rest is the margin): every corner of the framed box projects to
  /// |sx|, |sy| <= kFrameFill.
  static constexpr float kFrameFill = 0.95f;

  /// Parses "ex,ey,ez,tx,ty,tz,ux,uy,uz,fovy" (perspective) or
  /// "ortho,ex,ey,ez,tx,ty,tz,ux,uy,uz,width" (orthographic); throws voxcast::Error.
  static Camera parse(const std::string& text);
  /// The same comma forms, with enough digits to round-trip floats.
  std::string to_string() const;
  /// Throws voxcast::Error unless the camera is usable (finite, eye != target,
  /// up not parallel to the view, fovy in (0, 180), ortho width > 0).
  void validate() const;

  /// The automatic camera: looking at the center of `bounds` from the
  /// front-right-above (direction kAutoView from the target), fovy
  /// kDefaultFovy, at the distance that keeps all 8 corners of `bounds` in
  /// the image with the kFrameFill margin, for this aspect ratio.
  static Camera frame(const Aabb& bounds, int width, int height,
                      Projection projection = Projection::Perspective);
  /// Direction from the target to the eye of the automatic camera.
  static Vec3 auto_view_direction();
  /// Orbit around the center of `bounds`: the eye in direction
  /// (sin az cos el, sin el, cos az cos el) from it (az = 0, el = 0: from +z;
  /// az = 90: from +x; el = 90: from above), up = the direction of increasing
  /// elevation (+y whenever |el| < 90), fovy kDefaultFovy; distance <= 0 = the
  /// framing distance of frame(). Orthographic: the framing width too.
  static Camera orbit(const Aabb& bounds, int width, int height, float azimuth_degrees,
                      float elevation_degrees, float distance = 0.f,
                      Projection projection = Projection::Perspective);
  /// Parses "AZ,EL[,DIST]" (degrees; DIST > 0 or absent) and calls orbit().
  static Camera parse_orbit(const std::string& text, const Aabb& bounds, int width, int height,
                            Projection projection = Projection::Perspective);
  /// Parses "ex,ey,ez,tx,ty,tz[,ux,uy,uz[,fovy]]" (up defaults to 0,1,0, fovy
  /// to kDefaultFovy); a perspective camera.
  static Camera parse_look_at(const std::string& text);

  /// This camera made orthographic with the same eye, target and up, and
  /// width `ortho_width` or (<= 0) the smallest width that keeps the 8
  /// corners of `bounds` in the image with the kFrameFill margin.
  Camera orthographic(const Aabb& bounds, int width, int height, float ortho_width = 0.f) const;
};

/// Precomputed basis for generating primary rays quickly.
struct CameraRays {
  Vec3 eye, forward, right, true_up;
  float tan_half = 0, aspect = 0;  // perspective: tan(fovy/2), W/H
  bool ortho = false;
  float half_width = 0, half_height = 0;  // orthographic: half the view in world units
  int width, height;
  /// Where in its pixel a ray passes, in pixel units from the pixel's
  /// top-left corner: (0.5, 0.5) = the center (the camera contract above);
  /// antialiasing moves it (render.hpp RenderOptions::spp).
  Vec2 sample{0.5f, 0.5f};
  CameraRays(const Camera& camera, int width, int height);
  CameraRays(const Camera& camera, int width, int height, Vec2 sample_offset)
      : CameraRays(camera, width, height) {
    sample = sample_offset;
  }
  /// Unit direction of pixel (x, y)'s ray (forward for every orthographic ray).
  Vec3 direction(int x, int y) const {
    return ortho ? forward
                 : perspective_direction(screen_x(float(x) + sample.x),
                                         screen_y(float(y) + sample.y));
  }
  /// Origin of pixel (x, y)'s ray (the eye for a perspective camera).
  Vec3 origin(int x, int y) const {
    return ortho ? ortho_origin(screen_x(float(x) + sample.x), screen_y(float(y) + sample.y)) : eye;
  }
  Ray ray(int x, int y) const { return {origin(x, y), direction(x, y), INFINITY}; }
  /// Pixel footprint = pixel_size() + pixel_angle() * t at distance t along
  /// a ray: perspective 0 + 2 tan(fovy/2)/H per unit distance (the center
  /// pixel's), orthographic the constant pixel side and 0.
  float pixel_angle() const { return ortho ? 0.f : 2.f * tan_half / float(height); }
  float pixel_size() const { return ortho ? 2.f * half_height / float(height) : 0.f; }

  /// Screen coordinates in [-1, 1] of pixel-space position X (0 = left image
  /// edge, W = right edge) and Y (0 = top edge).
  float screen_x(float X) const { return 2.f * X / float(width) - 1.f; }
  float screen_y(float Y) const { return 1.f - 2.f * Y / float(height); }
  Vec3 perspective_direction(float sx, float sy) const {
    return normalize(forward + right * (sx * tan_half * aspect) + true_up * (sy * tan_half));
  }
  Vec3 ortho_origin(float sx, float sy) const {
    return eye + right * (sx * half_width) + true_up * (sy * half_height);
  }
};

}  // namespace voxcast
