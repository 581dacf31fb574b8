// Texture upload, framebuffer blit and read-back (gl_frame.hpp).
#define GLFW_INCLUDE_GLEXT
#include "view/gl_frame.hpp"

#include <GLFW/glfw3.h>

#include <algorithm>
#include <string>

#include "voxcast/error.hpp"

namespace voxcast::view {

namespace {

// OpenGL 1.1 (textures, pixels) is exported by libGL itself; the
// framebuffer-object calls (3.0) are not guaranteed to be, so they come from
// the context through glfwGetProcAddress.
struct FboFunctions {
  PFNGLGENFRAMEBUFFERSPROC gen = nullptr;
  PFNGLDELETEFRAMEBUFFERSPROC del = nullptr;
  PFNGLBINDFRAMEBUFFERPROC bind = nullptr;
  PFNGLFRAMEBUFFERTEXTURE2DPROC texture_2d = nullptr;
  PFNGLCHECKFRAMEBUFFERSTATUSPROC status = nullptr;
  PFNGLBLITFRAMEBUFFERPROC blit = nullptr;
};

const FboFunctions& fbo() {
  static const FboFunctions f = [] {
    FboFunctions r;
    r.gen = reinterpret_cast<PFNGLGENFRAMEBUFFERSPROC>(glfwGetProcAddress("glGenFramebuffers"));
    r.del =
        reinterpret_cast<PFNGLDELETEFRAMEBUFFERSPROC>(glfwGetProcAddress("glDeleteFramebuffers"));
    r.bind = reinterpret_cast<PFNGLBINDFRAMEBUFFERPROC>(glfwGetProcAddress("glBindFramebuffer"));
    r.texture_2d = reinterpret_cast<PFNGLFRAMEBUFFERTEXTURE2DPROC>(
        glfwGetProcAddress("glFramebufferTexture2D"));
    r.status = reinterpret_cast<PFNGLCHECKFRAMEBUFFERSTATUSPROC>(
        glfwGetProcAddress("glCheckFramebufferStatus"));
    r.blit = reinterpret_cast<PFNGLBLITFRAMEBUFFERPROC>(glfwGetProcAddress("glBlitFramebuffer"));
    return r;
  }();
  if (!f.gen || !f.del || !f.bind || !f.texture_2d || !f.status || !f.blit)
    throw Error("view: the OpenGL context has no framebuffer objects (OpenGL 3.0 needed)");
  return f;
}

}  // namespace

FrameTexture::FrameTexture() {
  const FboFunctions& f = fbo();
  glGenTextures(1, &texture_);
  f.gen(1, &framebuffer_);
}

FrameTexture::~FrameTexture() {
  if (framebuffer_) fbo().del(1, &framebuffer_);
  if (texture_) glDeleteTextures(1, &texture_);
}

void FrameTexture::upload(int width, int height, const std::vector<uint8_t>& rgb) {
  if (width <= 0 || height <= 0 || rgb.size() != size_t(width) * size_t(height) * 3)
    throw Error("view: frame of " + std::to_string(width) + "x" + std::to_string(height) +
                " holds " + std::to_string(rgb.size()) + " bytes");
  glBindTexture(GL_TEXTURE_2D, texture_);
  glPixelStorei(GL_UNPACK_ALIGNMENT, 1);  // RGB rows are not 4-byte aligned
  // Texture row 0 is the image's top row; blit() flips it into place.
  if (width != width_ || height != height_) {
    glTexImage2D(GL_TEXTURE_2D, 0, GL_RGB8, width, height, 0, GL_RGB, GL_UNSIGNED_BYTE, rgb.data());
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAX_LEVEL, 0);
    const FboFunctions& f = fbo();
    f.bind(GL_READ_FRAMEBUFFER, framebuffer_);
    f.texture_2d(GL_READ_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, texture_, 0);
    const GLenum status = f.status(GL_READ_FRAMEBUFFER);
    f.bind(GL_READ_FRAMEBUFFER, 0);
    if (status != GL_FRAMEBUFFER_COMPLETE)
      throw Error("view: cannot attach the frame texture to a framebuffer (status " +
                  std::to_string(status) + ")");
    width_ = width, height_ = height;
  } else {
    glTexSubImage2D(GL_TEXTURE_2D, 0, 0, 0, width, height, GL_RGB, GL_UNSIGNED_BYTE, rgb.data());
  }
  glBindTexture(GL_TEXTURE_2D, 0);
}

void FrameTexture::blit(int fb_width, int fb_height) const {
  const FboFunctions& f = fbo();
  f.bind(GL_DRAW_FRAMEBUFFER, 0);
  glViewport(0, 0, fb_width, fb_height);
  glDisable(GL_SCISSOR_TEST);  // ImGui leaves it on; it would clip the blit
  glClearColor(0.f, 0.f, 0.f, 1.f);
  glClear(GL_COLOR_BUFFER_BIT);
  if (width_ == 0) return;
  f.bind(GL_READ_FRAMEBUFFER, framebuffer_);
  // Destination rows reversed: the image's top row (texture row 0) lands at
  // the top of the window (GL's row fb_height - 1).
  f.blit(0, 0, width_, height_, 0, fb_height, fb_width, 0, GL_COLOR_BUFFER_BIT, GL_NEAREST);
  f.bind(GL_READ_FRAMEBUFFER, 0);
}

WindowPixels read_back_buffer(int fb_width, int fb_height) {
  WindowPixels p;
  p.width = fb_width, p.height = fb_height;
  std::vector<uint8_t> bottom_up(size_t(fb_width) * size_t(fb_height) * 3);
  while (glGetError() != GL_NO_ERROR) {
  }  // an error left by earlier calls would be blamed on the read-back
  fbo().bind(GL_READ_FRAMEBUFFER, 0);
  glReadBuffer(GL_BACK);
  glPixelStorei(GL_PACK_ALIGNMENT, 1);
  glReadPixels(0, 0, fb_width, fb_height, GL_RGB, GL_UNSIGNED_BYTE, bottom_up.data());
  if (const GLenum e = glGetError(); e != GL_NO_ERROR)
    throw Error("view: reading the window back failed (OpenGL error " + std::to_string(e) + ")");
  // GL returns the bottom row first; images here are top row first.
  p.rgb.resize(bottom_up.size());
  const size_t row = size_t(fb_width) * 3;
  for (int y = 0; y < fb_height; ++y)
    std::copy_n(bottom_up.data() + size_t(fb_height - 1 - y) * row, row,
                p.rgb.data() + size_t(y) * row);
  return p;
}

}  // namespace voxcast::view
