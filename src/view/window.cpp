// GLFW window and context (window.hpp).
#include "view/window.hpp"

#include <GLFW/glfw3.h>

#include <cstdlib>

#include "voxcast/error.hpp"

namespace voxcast::view {

namespace {
// GLFW reports failures through a callback; the last message goes into the
// one-line error the CLI prints.
std::string g_glfw_error;
void record_error(int code, const char* description) {
  g_glfw_error = std::string(description ? description : "unknown error") + " (GLFW error " +
                 std::to_string(code) + ")";
}
}  // namespace

void scroll_callback(GLFWwindow* w, double, double dy) {
  auto* self = static_cast<Window*>(glfwGetWindowUserPointer(w));
  if (self) self->scroll_ += dy;
}

Window::Window(int width, int height, const std::string& title, bool vsync) {
  glfwSetErrorCallback(record_error);
  const char* display = std::getenv("DISPLAY");
  const char* wayland = std::getenv("WAYLAND_DISPLAY");
  const bool no_display = (!display || !*display) && (!wayland || !*wayland);
  if (!glfwInit()) {
    if (no_display)
      throw Error(
          "view: no display to open a window on (DISPLAY is not set; for a headless run use "
          "xvfb-run voxcast view ...)");
    throw Error("view: cannot open the display: " + g_glfw_error);
  }
  glfwWindowHint(GLFW_CONTEXT_VERSION_MAJOR, 3);
  glfwWindowHint(GLFW_CONTEXT_VERSION_MINOR, 3);
  glfwWindowHint(GLFW_OPENGL_PROFILE, GLFW_OPENGL_CORE_PROFILE);
  glfwWindowHint(GLFW_OPENGL_FORWARD_COMPAT, GLFW_TRUE);
  // The frame is shown exactly as rendered: 8 bits per channel, no sRGB
  // conversion by the framebuffer, no multisampling.
  glfwWindowHint(GLFW_RED_BITS, 8);
  glfwWindowHint(GLFW_GREEN_BITS, 8);
  glfwWindowHint(GLFW_BLUE_BITS, 8);
  glfwWindowHint(GLFW_SRGB_CAPABLE, GLFW_FALSE);
  glfwWindowHint(GLFW_SAMPLES, 0);
  glfwWindowHint(GLFW_RESIZABLE, GLFW_TRUE);
  window_ = glfwCreateWindow(width, height, title.c_str(), nullptr, nullptr);
  if (!window_) {
    const std::string why = g_glfw_error;
    glfwTerminate();
    throw Error("view: cannot open an OpenGL 3.3 core window: " + why);
  }
  glfwSetWindowUserPointer(window_, this);
  glfwSetScrollCallback(window_, scroll_callback);
  // A key or button tapped between two polls (frames can take a while to
  // render) still reads as pressed once.
  glfwSetInputMode(window_, GLFW_STICKY_KEYS, GLFW_TRUE);
  glfwSetInputMode(window_, GLFW_STICKY_MOUSE_BUTTONS, GLFW_TRUE);
  glfwMakeContextCurrent(window_);
  glfwSwapInterval(vsync ? 1 : 0);
}

Window::~Window() {
  if (window_) glfwDestroyWindow(window_);
  glfwTerminate();
}

bool Window::should_close() const {
  return glfwWindowShouldClose(window_);
}
void Window::request_close() {
  glfwSetWindowShouldClose(window_, GLFW_TRUE);
}
void Window::swap() {
  glfwSwapBuffers(window_);
}
void Window::framebuffer_size(int* width, int* height) const {
  glfwGetFramebufferSize(window_, width, height);
}
void Window::set_title(const std::string& title) {
  glfwSetWindowTitle(window_, title.c_str());
}

double Window::take_scroll() {
  const double s = scroll_;
  scroll_ = 0;
  return s;
}

bool Window::pressed(int key) {
  if (key < 0 || key >= 512) return false;
  const bool down = glfwGetKey(window_, key) == GLFW_PRESS;
  const bool edge = down && !key_down_[key];
  key_down_[key] = down;
  return edge;
}

}  // namespace voxcast::view
