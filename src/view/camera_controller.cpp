// Orbit / fly camera control (camera_controller.hpp).
#include "view/camera_controller.hpp"

#include <algorithm>
#include <cmath>

namespace voxcast::view {

namespace {
constexpr float kDegToRad = 3.14159265358979f / 180.f;
}

void CameraController::reset(const Camera& camera, float scene_size) {
  base_ = camera;
  moved_ = false;
  target_ = camera.target;
  const Vec3 d = camera.eye - camera.target;
  distance_ = length(d);
  const Vec3 u = d / distance_;
  elevation_ = std::asin(std::clamp(u.y, -1.f, 1.f)) / kDegToRad;
  elevation_ = std::clamp(elevation_, -kMaxElevation, kMaxElevation);
  azimuth_ = std::atan2(u.x, u.z) / kDegToRad;
  speed_ = scene_size > 0 && std::isfinite(scene_size) ? 0.5f * scene_size : 1.f;
}

Vec3 CameraController::offset() const {
  const float az = azimuth_ * kDegToRad, el = elevation_ * kDegToRad;
  return Vec3{std::sin(az) * std::cos(el), std::sin(el), std::cos(az) * std::cos(el)} * distance_;
}

bool CameraController::update(const ControllerInput& in, int width, int height) {
  const Camera before = camera();
  const Vec3 eye = target_ + offset();
  if (in.rotate && (in.dx != 0 || in.dy != 0)) {
    // The same angles turn both modes: dragging right lowers the azimuth,
    // which in orbit mode moves the eye left around the target (the scene
    // turns right) and in fly mode turns the view right; the eye stays put
    // in fly mode, so the target swings around it.
    azimuth_ = std::remainder(azimuth_ - float(in.dx) * kDegreesPerPixel, 360.f);
    elevation_ =
        std::clamp(elevation_ + float(in.dy) * kDegreesPerPixel, -kMaxElevation, kMaxElevation);
    if (mode_ == CameraMode::Fly) target_ = eye - offset();
    moved_ = true;
  }
  const Vec3 forward = normalize(-offset());
  const Vec3 right = normalize(cross(forward, Vec3{0, 1, 0}));
  const Vec3 true_up = cross(right, forward);
  if (in.pan && (in.dx != 0 || in.dy != 0)) {
    // One pixel of mouse motion moves the target by one pixel footprint at
    // its distance, so the point under the cursor follows the cursor.
    const Camera c = camera();
    const float footprint = c.projection == Projection::Orthographic
                                ? c.ortho_width / float(std::max(width, 1))
                                : 2.f * distance_ * std::tan(0.5f * c.fovy_degrees * kDegToRad) /
                                      float(std::max(height, 1));
    target_ = target_ - right * (float(in.dx) * footprint) + true_up * (float(in.dy) * footprint);
    moved_ = true;
  }
  if (in.scroll != 0) {
    if (base_.projection == Projection::Orthographic) {
      base_.ortho_width *= std::pow(0.9f, float(in.scroll));
    } else if (mode_ == CameraMode::Orbit) {
      distance_ *= std::pow(0.9f, float(in.scroll));
    } else {
      target_ = target_ + forward * (0.1f * distance_ * float(in.scroll));
    }
    moved_ = true;
  }
  Vec3 move{0, 0, 0};
  if (in.forward) move += forward;
  if (in.back) move -= forward;
  if (in.right) move += right;
  if (in.left) move -= right;
  if (in.up) move += Vec3{0, 1, 0};
  if (in.down) move -= Vec3{0, 1, 0};
  if (length(move) > 0 && in.dt > 0) {
    target_ += normalize(move) * (speed_ * (in.fast ? 4.f : 1.f) * float(in.dt));
    moved_ = true;
  }
  const Camera after = camera();
  return after.eye.x != before.eye.x || after.eye.y != before.eye.y ||
         after.eye.z != before.eye.z || after.target.x != before.target.x ||
         after.target.y != before.target.y || after.target.z != before.target.z ||
         after.ortho_width != before.ortho_width;
}

Camera CameraController::camera() const {
  if (!moved_) return base_;
  Camera c = base_;
  c.target = target_;
  c.eye = target_ + offset();
  c.up = {0, 1, 0};
  return c;
}

}  // namespace voxcast::view
