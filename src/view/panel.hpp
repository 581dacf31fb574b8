#pragma once
// The ImGui side panel: structure statistics, render settings, camera mode,
// path recording and playback, frame time and Mrays/s.
#include <string>
#include <vector>

#include "view/camera_controller.hpp"
#include "view/frame_source.hpp"

struct GLFWwindow;

namespace voxcast::view {

/// Facts about the loaded scene shown in the panel (filled once).
struct SceneStats {
  std::vector<std::pair<std::string, std::string>> rows;  // label, value
};

/// What the panel shows about the last frames.
struct FrameStatus {
  double frame_ms = 0;     // wall time of the last display frame that rendered
  double render_ms = 0;    // renderer's ray-cast time of the last pass
  double mrays = 0;        // primary rays per second of the last pass, millions
  double mrays_total = 0;  // primary + secondary
  int passes = 0, max_passes = 0;
  int preview_scale = 1;      // 1 = full resolution
  int width = 0, height = 0;  // rendered size of the last pass
  bool recording = false, playing = false;
  size_t recorded_keyframes = 0;
  Camera camera;
};

/// Buttons pressed this frame.
struct PanelActions {
  bool toggle_record = false, play = false, screenshot = false, reframe = false;
};

/// ImGui context with the GLFW and OpenGL 3 backends.
class Gui {
 public:
  explicit Gui(GLFWwindow* window);
  ~Gui();
  Gui(const Gui&) = delete;
  Gui& operator=(const Gui&) = delete;
  void begin_frame();
  /// Draws the panel (when `show_panel`) and the frame-time overlay.
  PanelActions panel(bool show_panel, const SceneStats& scene, ViewSettings* settings,
                     int* max_passes, CameraMode* mode, float* speed, const FrameStatus& status);
  /// Renders what begin_frame()..panel() built into the current framebuffer.
  void end_frame();
  bool wants_mouse() const;
  bool wants_keyboard() const;
};

/// The viewer's libraries for `voxcast --version`: GLFW (run time) and
/// Dear ImGui (header), one per line.
std::string view_library_versions();

}  // namespace voxcast::view
