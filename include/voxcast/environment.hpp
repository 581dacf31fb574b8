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
// Importance sampling (sample()/pdf()): a map's directions are drawn with
// probability proportional to the luminance that lookups return, integrated
// over each pixel's (u, v) rectangle (the (1, 6, 1) / 8 filter of the pixel
// luminances, exact for bilinear lookups), times the rectangle's solid angle
// (sin theta of its center): a piecewise-constant density over the pixels (a
// marginal CDF over the rows, a conditional CDF within each row), uniform
// within a rectangle. The density is per solid angle,
//   pdf(d) = p_ij * W * H / (2 pi^2 sin theta),
// p_ij the probability of pixel (i, j). A black region has density 0:
// sampling is meant for multiple importance sampling with a second strategy
// that covers every direction (the GI integrator's cosine bounce).
//
// Files: Radiance RGBE (.hdr, an own validated reader and writer) and
// OpenEXR (.exr, the R, G, B channels through OpenEXR).
#include <cstdint>
#include <filesystem>
#include <span>
#include <vector>

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

  /// True for a map with some light (luminance > 0 somewhere) and scale > 0:
  /// sample() and pdf() apply. False for a constant environment.
  bool can_sample() const { return total_ > 0.0; }
  struct Sample {
    Vec3 dir;       // unit direction towards the environment
    float pdf = 0;  // per solid angle (0: no sample, e.g. at a pole)
  };
  /// A direction for two uniform numbers in [0, 1) (can_sample() only).
  Sample sample(float u1, float u2) const;
  /// The density of sample() at unit direction `d` (0 when !can_sample()).
  float pdf(Vec3 d) const;

 private:
  void build_distribution();
  Color constant_{1.f, 1.f, 1.f, 1.f};
  Image image_;
  float scale_ = 1.f;
  // The sampling distribution: row_cdf_ (H + 1 entries, 0..1), col_cdf_
  // (H rows of W + 1 entries, 0..1), the pixel weights (luminance * sin of
  // the row center's theta) and their total.
  std::vector<float> row_cdf_, col_cdf_, weight_;
  double total_ = 0.0;
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
