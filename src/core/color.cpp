// sRGB transfer functions (image.hpp): core, since the mesh (texture
// sampling), I/O and render modules all use them.
#include <cmath>

#include "voxcast/image.hpp"

namespace voxcast {

float srgb_to_linear(float c) {
  if (c <= 0.04045f) return c / 12.92f;
  return std::pow((c + 0.055f) / 1.055f, 2.4f);
}

float linear_to_srgb(float c) {
  if (c <= 0.0031308f) return c * 12.92f;
  return 1.055f * std::pow(c, 1.0f / 2.4f) - 0.055f;
}

}  // namespace voxcast
