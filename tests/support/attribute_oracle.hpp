#pragma once
// Attribute helpers for the compression and variable-depth tests, written
// from the esvo.hpp encodings (not from the codec under test), and a shared
// mesh with smooth procedural colors so that color tolerances have work.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <string>

#include "support/test_data.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/mesh.hpp"

namespace voxcast::testing {

/// Angle between two unit vectors in radians (chord formula: accurate near 0).
inline double angle(Vec3 a, Vec3 b) {
  const double dx = double(a.x) - b.x, dy = double(a.y) - b.y, dz = double(a.z) - b.z;
  return 2.0 * std::asin(std::min(1.0, 0.5 * std::sqrt(dx * dx + dy * dy + dz * dz)));
}
inline constexpr double kDeg = 3.14159265358979323846 / 180.0;

/// An 8-bit sRGB color (R, G, B).
struct Rgb8 {
  int c[3];
};
inline Rgb8 to8(const Color& linear) {
  const uint32_t abgr = esvo::encode_color_abgr(linear);
  return {{int(abgr & 0xFF), int(abgr >> 8 & 0xFF), int(abgr >> 16 & 0xFF)}};
}
inline int max_channel_diff(const Rgb8& a, const Rgb8& b) {
  return std::max(
      {std::abs(a.c[0] - b.c[0]), std::abs(a.c[1] - b.c[1]), std::abs(a.c[2] - b.c[2])});
}

/// A shipped test mesh (tests/data/meshes/NAME) with smooth procedural vertex
/// colors (waves across the bounding box, a few periods per axis).
inline Mesh load_mesh_with_wave_colors(const char* name) {
  Mesh m = load_mesh(test_mesh(name));
  const Aabb b = m.bounds();
  const Vec3 e = b.hi - b.lo;
  const float s = std::max({e.x, e.y, e.z});
  m.colors.clear();
  for (const Vec3& q : m.positions) {
    const Vec3 u = (q - b.lo) / s;
    m.colors.push_back({0.5f + 0.5f * std::sin(19.f * u.x),
                        0.5f + 0.5f * std::sin(13.f * u.y + 1.f),
                        0.5f + 0.5f * std::sin(23.f * u.z + 2.f), 1.f});
  }
  return m;
}

}  // namespace voxcast::testing
