#pragma once
// The film an integrator writes: one image per AOV (arbitrary output
// variable), allocated for the AOVs asked for. Written once for every
// integrator (surface, volume, AO, GI); a tile writes only its own pixels, so
// tiles run in parallel without locks.
#include <cstdint>
#include <vector>

#include "voxcast/image.hpp"

namespace voxcast {

/// AOV bits.
enum Aov : uint32_t {
  kAovColor = 1u << 0,       // 3 channels, linear RGB
  kAovDepth = 1u << 1,       // 1 channel, world distance (+inf on a miss)
  kAovNormal = 1u << 2,      // 3 channels, n * 0.5 + 0.5 (0.5 on a miss)
  kAovIterations = 1u << 3,  // 1 channel, caster iterations per pixel (profiling)
  kAovAo = 1u << 4,          // 1 channel, ambient occlusion in [0,1] (1 on a miss)
  kAovShadow = 1u << 5,      // 1 channel, light visibility in [0,1] (1 on a miss)
  kAovAlpha = 1u << 6,       // 1 channel, accumulated opacity (volumes; 1 on a surface hit)
};

struct Film {
  int width = 0, height = 0;
  uint32_t aovs = 0;
  Image color, depth, normal, iterations, ao, shadow, alpha;
  /// esvo §6.3: per-pixel filter radius code (render.hpp encode_filter_radius)
  /// for the post-filter; allocated with `want_filter_radius`.
  std::vector<uint8_t> filter_radius;

  Film() = default;
  Film(int w, int h, uint32_t aov_bits, bool want_filter_radius = false)
      : width(w), height(h), aovs(aov_bits) {
    if (aovs & kAovColor) color = Image(w, h, 3);
    if (aovs & kAovDepth) depth = Image(w, h, 1);
    if (aovs & kAovNormal) normal = Image(w, h, 3);
    if (aovs & kAovIterations) iterations = Image(w, h, 1);
    if (aovs & kAovAo) ao = Image(w, h, 1), ao.pixels.assign(ao.pixels.size(), 1.f);
    if (aovs & kAovShadow) shadow = Image(w, h, 1), shadow.pixels.assign(shadow.pixels.size(), 1.f);
    if (aovs & kAovAlpha) alpha = Image(w, h, 1);
    if (want_filter_radius) filter_radius.assign(size_t(w) * size_t(h), 0);
  }
  bool has(uint32_t aov) const { return (aovs & aov) == aov; }
};

}  // namespace voxcast
