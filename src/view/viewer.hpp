#pragma once
// `voxcast view`: the interactive viewer's main loop over a loaded scene.
#include <optional>
#include <string>

#include "view/camera_path.hpp"
#include "view/frame_source.hpp"
#include "voxcast/image.hpp"
#include "voxcast/scene_file.hpp"

namespace voxcast::view {

struct ViewerOptions {
  int width = 1024, height = 768;  // window size requested
  Camera camera;                   // the first camera (before any input or path)
  std::optional<CameraPath> path;  // replayed from the start (scripted) or on P
  /// Scripted mode: run this many frames, then close (-1: until the user
  /// closes the window). Scripted frames always render at full resolution,
  /// and path time advances 1/fps per frame (not with the wall clock), so a
  /// run is the same on any machine.
  int frames = -1;
  double fps = 30;
  bool screenshot_ui = false;  // the scripted screenshot includes panel and overlay
  bool show_panel = true;
  std::string record_path = "camera_path.json";  // where R saves a recording
  std::string screenshot_path;                   // F12 in interactive mode (empty: numbered)
  int max_passes = 16;
  ViewSettings settings;
  std::string title = "voxcast view";
};

struct ViewerReport {
  int frames = 0;
  /// The last frame as the window showed it (sRGB values in [0, 1], read
  /// back from the back buffer), when options.frames > 0.
  Image screenshot;
  Camera last_camera;
  int passes = 0;  // refinement passes averaged into the last frame
};

/// Opens the window and runs until closed or options.frames frames are done.
/// Throws voxcast::Error (no display, no OpenGL 3.3, I/O).
ViewerReport run_viewer(const LoadedScene& scene, const ViewerOptions& options);

}  // namespace voxcast::view
