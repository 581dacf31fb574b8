#pragma once
// Image-based lighting for the GI integrator (gi_integrator.hpp): an
// environment seen at infinity, either one constant radiance or a
// latitude-longitude (equirectangular) HDR image.
//
// Mapping of a unit direction d (y up) to the image (u, v in [0, 1], v = 0
// the top row, pixel centers at (i + 0.5) / width):
//   u = 0.5 + atan2(d.x, -d.z) / (2 pi)    (u = 0.5 looks along -z)
//   v = acos(d.y) / pi                     (v = 0 straight up, 1 straight down)
// Lookups are bilinear, wrapping in u and clamped in v.
//
// Files: Radiance RGBE (.hdr, an own validated reader and writer) and
// OpenEXR (.exr, the R, G, B channels through OpenEXR).
#include <cstdint>
#include <filesystem>
#include <span>

#include "voxcast/image.hpp"
#include "voxcast/math.hpp"

namespace voxcast {

class Environment {
 public:
  /// A constant environment of radiance `c` in every direction.
  explicit Environment(Color c = {1.f, 1.f, 1.f, 1.f}) : constant_(c) {}
  /// A latitude-longitude image (3 channels, linear RGB radiance) times
  /// `scale`. Throws voxcast::Error for an empty image, channels != 3,
  /// negative or non-finite values, or a non-finite / negative scale.
  explicit Environment(Image latlong, float scale = 1.f);

  /// Radiance arriving from direction `d` (unit length; travelling towards -d).
  Color radiance(Vec3 d) const;
  bool is_constant() const { return image_.pixels.empty(); }
  const Image& image() const { return image_; }

 private:
  Color constant_{1.f, 1.f, 1.f, 1.f};
  Image image_;
  float scale_ = 1.f;
};

/// The (u, v) of direction `d` in the mapping above.
Vec2 latlong_uv(Vec3 d);
/// The unit direction at (u, v) (the inverse of latlong_uv).
Vec3 latlong_direction(float u, float v);

// ---- Files (src/io/environment_io.cpp) ----

/// Upper bound on width * height of an environment map read from a file
/// (64 Mpixels: 768 MB of floats), checked before decoding.
inline constexpr uint64_t kMaxEnvironmentPixels = uint64_t(1) << 26;

/// Parses a Radiance .hdr (RGBE, flat or run-length encoded scan lines,
/// orientation "-Y H +X W") from memory. Throws voxcast::Error (one line)
/// for anything that is not a complete, well-formed file of at most
/// kMaxEnvironmentPixels.
Image parse_hdr(std::span<const uint8_t> bytes);
/// Writes a 3-channel image as Radiance .hdr (run-length encoded scan lines
/// for widths 8..32767, flat otherwise), atomically. Negative and
/// non-finite values are written as 0.
void write_hdr(const std::filesystem::path& path, const Image& image);
/// Reads R, G, B of an OpenEXR file (missing channels read as 0). Throws
/// voxcast::Error for an unreadable file, more than kMaxEnvironmentPixels or
/// non-finite / negative values.
Image read_exr_rgb(const std::filesystem::path& path);
/// An environment map from a .hdr or .exr file (by extension), times `scale`.
Environment load_environment(const std::filesystem::path& path, float scale = 1.f);

/// A procedural sky for examples and tests (no file needed): a blue
/// gradient above the horizon brightening towards it, a warm glow around
/// `sun_dir` (the direction light travels; the glow is soft, the sun itself
/// is the GI integrator's delta light), and a darker ground below.
Image procedural_sky(int width, int height, Vec3 sun_dir);

}  // namespace voxcast
