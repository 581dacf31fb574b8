// Running mean of the refinement passes (progressive.hpp).
#include "view/progressive.hpp"

namespace voxcast::view {

void Accumulator::add(const Image& color) {
  if (passes_ == 0 || color.width != sum_.width || color.height != sum_.height ||
      color.channels != sum_.channels) {
    sum_ = color;
    mean_ = color;
    passes_ = 1;
    return;
  }
  ++passes_;
  const float inv = 1.f / float(passes_);
  for (size_t i = 0; i < sum_.pixels.size(); ++i) {
    sum_.pixels[i] += color.pixels[i];
    mean_.pixels[i] = sum_.pixels[i] * inv;
  }
}

}  // namespace voxcast::view
