#pragma once
// Camera paths: keyframed cameras stored as JSON, recorded and replayed by
// `voxcast view` and rendered keyframe by keyframe by `voxcast render --path`.
//
// The file (README "Viewer", "Camera path JSON"):
//   {
//     "voxcast_camera_path": 1,
//     "keyframes": [
//       {"name": "front", "time": 0, "eye": [0, 0.5, 3], "target": [0, 0.5, 0],
//        "up": [0, 1, 0], "fovy": 40},
//       {"time": 2.5, "eye": [3, 1, 0], "target": [0, 0.5, 0],
//        "projection": "orthographic", "ortho_width": 2.2}
//     ]
//   }
// "time" (seconds, >= 0, strictly increasing), "eye" and "target" are
// required; "up" defaults to [0, 1, 0], "fovy" to 40 degrees, "projection"
// to "perspective" ("orthographic" needs "ortho_width"); "name" is optional
// and unique. Unknown keys are errors, so a misspelt key is never ignored.
#include <filesystem>
#include <string>
#include <vector>

#include "voxcast/camera.hpp"

namespace voxcast::view {

inline constexpr int kCameraPathVersion = 1;

struct CameraKeyframe {
  std::string name;  // may be empty
  double time = 0;   // seconds from the start of the path
  Camera camera;
};

struct CameraPath {
  std::vector<CameraKeyframe> keyframes;

  /// Parses the JSON text; throws voxcast::Error (one line, naming the
  /// keyframe and key) unless every rule of the format holds and every
  /// keyframe's camera passes Camera::validate().
  static CameraPath parse(const std::string& json_text);
  static CameraPath load(const std::filesystem::path& path);  // parse() of the file
  /// The JSON form (floats with enough digits to read back bit-exactly).
  std::string to_json() const;
  void save(const std::filesystem::path& path) const;  // atomic replace

  double start() const { return keyframes.empty() ? 0.0 : keyframes.front().time; }
  double end() const { return keyframes.empty() ? 0.0 : keyframes.back().time; }
  /// The camera at time t: a keyframe's camera exactly at its time (and
  /// before the first / after the last), in between the linear blend of
  /// eye, target, up, fovy and ortho width (the earlier keyframe's
  /// projection). Throws voxcast::Error on an empty path.
  Camera at(double t) const;
  /// Index of the keyframe named `key`, or with that decimal index; throws
  /// voxcast::Error naming the choices when there is none.
  size_t find(const std::string& key) const;
};

}  // namespace voxcast::view
