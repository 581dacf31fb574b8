#pragma once
// The viewer's window: GLFW with an OpenGL 3.3 core context, and the input
// state the viewer polls once per frame.
#include <string>

struct GLFWwindow;

namespace voxcast::view {

class Window {
 public:
  /// Opens a width x height window. Throws voxcast::Error with one line when
  /// there is no display (no DISPLAY / WAYLAND_DISPLAY, or the server refuses)
  /// or no OpenGL 3.3 core context can be had.
  Window(int width, int height, const std::string& title, bool vsync);
  ~Window();
  Window(const Window&) = delete;
  Window& operator=(const Window&) = delete;

  GLFWwindow* handle() const { return window_; }
  bool should_close() const;
  void request_close();
  void swap();
  /// Size of the drawable in pixels (may differ from the window size on
  /// high-DPI screens).
  void framebuffer_size(int* width, int* height) const;
  void set_title(const std::string& title);
  /// Wheel steps since the last call (the scroll callback accumulates them).
  double take_scroll();
  /// Whether `key` (a GLFW_KEY_*) went down since the last call for it.
  bool pressed(int key);

 private:
  GLFWwindow* window_ = nullptr;
  double scroll_ = 0;
  bool key_down_[512] = {};
  friend void scroll_callback(GLFWwindow*, double, double);
};

}  // namespace voxcast::view
