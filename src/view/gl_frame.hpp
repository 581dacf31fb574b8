#pragma once
// The CPU frame on the GPU: an RGB8 texture holding the renderer's image and
// a framebuffer blit that puts it in the window, plus the read-back of what
// the window shows. Needs a current OpenGL >= 3.0 context (the viewer's is
// 3.3 core); the framebuffer-object entry points are looked up through GLFW.
#include <cstdint>
#include <vector>

namespace voxcast::view {

/// The pixels read back from the window's back buffer: RGB8, top row first.
struct WindowPixels {
  int width = 0, height = 0;
  std::vector<uint8_t> rgb;
};

class FrameTexture {
 public:
  /// Throws voxcast::Error if the context lacks framebuffer objects.
  FrameTexture();
  ~FrameTexture();
  FrameTexture(const FrameTexture&) = delete;
  FrameTexture& operator=(const FrameTexture&) = delete;

  /// Replaces the texture with a width x height RGB8 image (rows top to
  /// bottom, what png_bytes() returns).
  void upload(int width, int height, const std::vector<uint8_t>& rgb);
  /// Clears the window's back buffer to black and copies the texture over the whole framebuffer of
  /// fb_width x fb_height, scaled by nearest neighbour: with equal sizes every pixel is copied
  /// unchanged (no filtering, blending or color conversion on the way).
  void blit(int fb_width, int fb_height) const;
  int width() const { return width_; }
  int height() const { return height_; }

 private:
  unsigned texture_ = 0, framebuffer_ = 0;
  int width_ = 0, height_ = 0;
};

/// Reads the back buffer of the current context (fb_width x fb_height).
WindowPixels read_back_buffer(int fb_width, int fb_height);

}  // namespace voxcast::view
