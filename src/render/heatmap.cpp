// Iteration-count heat maps (esvo §6.2 Figure 16, Figure 32): the paper
// shows 0..64 iterations as black..white; we use the perceptually uniform
// "inferno" ramp (monotone lightness, black to pale yellow), which keeps the
// paper's dark = cheap, bright = expensive reading and separates more levels.
#include <algorithm>
#include <cmath>

#include "voxcast/error.hpp"
#include "voxcast/render.hpp"

namespace voxcast {
namespace {

// matplotlib's inferno sampled at 0, 0.1, ..., 1 (sRGB, 8 bit); piecewise
// linear in sRGB between the stops.
constexpr unsigned char kInferno[11][3] = {
    {0x00, 0x00, 0x04}, {0x16, 0x0b, 0x39}, {0x42, 0x0a, 0x68}, {0x6a, 0x17, 0x6e},
    {0x93, 0x26, 0x67}, {0xbc, 0x37, 0x54}, {0xdd, 0x51, 0x3a}, {0xf3, 0x78, 0x19},
    {0xfc, 0xa5, 0x0a}, {0xf6, 0xd7, 0x46}, {0xfc, 0xff, 0xa4}};

}  // namespace

Image iteration_heatmap(const Image& iterations, float max_iterations) {
  if (!(max_iterations > 0.f) || !std::isfinite(max_iterations))
    throw Error("heatmap: the maximum must be a positive number");
  if (iterations.channels != 1) throw Error("heatmap: expected a 1-channel iteration image");
  Image out(iterations.width, iterations.height, 3);
  for (int y = 0; y < iterations.height; ++y) {
    for (int x = 0; x < iterations.width; ++x) {
      const float v = *iterations.at(x, y);
      const float u = std::clamp(std::isfinite(v) ? v / max_iterations : 1.f, 0.f, 1.f) * 10.f;
      const int i = std::min(int(u), 9);
      const float f = u - float(i);
      float* o = out.at(x, y);
      for (int k = 0; k < 3; ++k) {
        const float srgb =
            (float(kInferno[i][k]) * (1.f - f) + float(kInferno[i + 1][k]) * f) / 255.f;
        o[k] = srgb_to_linear(srgb);
      }
    }
  }
  return out;
}

}  // namespace voxcast
