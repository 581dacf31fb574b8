#pragma once
// Orbit and fly camera control for the viewer, free of any window system so
// that tests drive it with synthetic input.
//
// State: a target point, a distance and the view angles in Camera::orbit's
// convention (the eye sits at target + distance * (sin az cos el, sin el,
// cos az cos el)); up is +y. Orbit mode turns the eye around the target, fly
// mode turns the view around the eye; in both, WASD/QE move eye and target
// together.
#include "voxcast/camera.hpp"

namespace voxcast::view {

enum class CameraMode { Orbit, Fly };

/// One frame's input, in window pixels and seconds.
struct ControllerInput {
  double dx = 0, dy = 0;  // mouse motion since the last frame
  bool rotate = false;    // left button held: orbit / look around
  bool pan = false;       // right or middle button held: pan
  double scroll = 0;      // wheel steps (positive: closer)
  bool forward = false, back = false, left = false, right = false, up = false, down = false;
  bool fast = false;  // shift: 4x the speed
  double dt = 0;      // seconds since the last frame
};

class CameraController {
 public:
  /// Degrees of rotation per pixel of mouse motion.
  static constexpr float kDegreesPerPixel = 0.25f;
  /// The elevation stays within +-kMaxElevation so up (+y) never becomes
  /// parallel to the view.
  static constexpr float kMaxElevation = 89.f;

  /// Takes over `camera` (any valid one; a non-+y up is replaced by +y once
  /// the camera moves). `scene_size`: the occupied bounds' diagonal, which
  /// sets the WASD speed (half of it per second).
  void reset(const Camera& camera, float scene_size);
  /// Applies one frame's input for an image of width x height pixels (pan
  /// moves the target by the pixel footprint at the target's distance).
  /// Returns whether the camera changed.
  bool update(const ControllerInput& input, int width, int height);
  /// The current camera: exactly the one given to reset() until the first
  /// input that moves it.
  Camera camera() const;

  CameraMode mode() const { return mode_; }
  void set_mode(CameraMode mode) { mode_ = mode; }
  float azimuth() const { return azimuth_; }
  float elevation() const { return elevation_; }
  float distance() const { return distance_; }
  Vec3 target() const { return target_; }
  /// World units per second of WASD motion (before shift).
  float speed() const { return speed_; }
  void set_speed(float speed) { speed_ = speed; }

 private:
  Vec3 offset() const;  // eye - target
  Camera base_;         // the camera given to reset()
  bool moved_ = false;
  CameraMode mode_ = CameraMode::Orbit;
  Vec3 target_;
  float distance_ = 1.f, azimuth_ = 0.f, elevation_ = 0.f;
  float speed_ = 1.f;
};

}  // namespace voxcast::view
