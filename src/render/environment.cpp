// Environment lookups and the procedural sky (include/voxcast/environment.hpp).
#include "voxcast/environment.hpp"

#include <algorithm>
#include <cmath>
#include <utility>

#include "voxcast/error.hpp"

namespace voxcast {
namespace {
constexpr float kPi = 3.14159265358979f;
}  // namespace

Environment::Environment(Image latlong, float scale) : image_(std::move(latlong)), scale_(scale) {
  if (image_.width <= 0 || image_.height <= 0 || image_.pixels.empty())
    throw Error("environment: empty image");
  if (image_.channels != 3) throw Error("environment: the image must have 3 channels (RGB)");
  if (image_.pixels.size() != size_t(image_.width) * size_t(image_.height) * 3)
    throw Error("environment: image size does not match its pixels");
  if (!(scale >= 0.f) || !std::isfinite(scale))
    throw Error("environment: scale must be finite and >= 0");
  for (float p : image_.pixels)
    if (!(p >= 0.f) || !std::isfinite(p))
      throw Error("environment: radiance must be finite and >= 0");
}

Vec2 latlong_uv(Vec3 d) {
  const float u = 0.5f + std::atan2(d.x, -d.z) / (2.f * kPi);
  const float v = std::acos(std::clamp(d.y, -1.f, 1.f)) / kPi;
  return {u, v};
}

Vec3 latlong_direction(float u, float v) {
  const float phi = (u - 0.5f) * 2.f * kPi, theta = v * kPi;
  const float s = std::sin(theta);
  return {s * std::sin(phi), std::cos(theta), -s * std::cos(phi)};
}

Color Environment::radiance(Vec3 d) const {
  if (image_.pixels.empty()) return constant_;
  const Vec2 uv = latlong_uv(d);
  const int W = image_.width, H = image_.height;
  // Bilinear between the four nearest pixel centers: wrap in u, clamp in v.
  const float fx = uv.x * float(W) - 0.5f, fy = uv.y * float(H) - 0.5f;
  const float x0f = std::floor(fx), y0f = std::floor(fy);
  const float ax = fx - x0f, ay = fy - y0f;
  auto wrap = [W](long x) { return int(((x % W) + W) % W); };
  const long xi = long(x0f), yi = long(y0f);
  const int x0 = wrap(xi), x1 = wrap(xi + 1);
  const int y0 = int(std::clamp(yi, 0L, long(H - 1))),
            y1 = int(std::clamp(yi + 1, 0L, long(H - 1)));
  const float* p00 = image_.at(x0, y0);
  const float* p10 = image_.at(x1, y0);
  const float* p01 = image_.at(x0, y1);
  const float* p11 = image_.at(x1, y1);
  float c[3];
  for (int k = 0; k < 3; ++k) {
    const float top = p00[k] + (p10[k] - p00[k]) * ax;
    const float bottom = p01[k] + (p11[k] - p01[k]) * ax;
    c[k] = (top + (bottom - top) * ay) * scale_;
  }
  return {c[0], c[1], c[2], 1.f};
}

Image procedural_sky(int width, int height, Vec3 sun_dir) {
  if (width <= 0 || height <= 0 || width > 16384 || height > 16384)
    throw Error("environment: sky size must be in 1..16384");
  Vec3 to_sun = normalize(-sun_dir);
  if (!is_finite(to_sun) || length(to_sun) == 0.f) to_sun = normalize(Vec3{0.4f, 1.f, 0.6f});
  Image img(width, height, 3);
  for (int y = 0; y < height; ++y)
    for (int x = 0; x < width; ++x) {
      const Vec3 d =
          latlong_direction((float(x) + 0.5f) / float(width), (float(y) + 0.5f) / float(height));
      float r, g, b;
      if (d.y >= 0.f) {
        // Zenith blue to a pale horizon: the horizon weight falls off with
        // elevation like a thin atmosphere's optical depth.
        const float h = std::pow(1.f - d.y, 4.f);
        r = 0.25f + 0.65f * h, g = 0.45f + 0.5f * h, b = 0.95f + 0.1f * h;
      } else {
        // Ground: a warm grey, darker further down.
        const float k = 0.35f + 0.15f * (1.f + d.y);
        r = 0.5f * k, g = 0.45f * k, b = 0.4f * k;
      }
      // A soft glow around the sun (cosine lobe), no disc: the sun itself is
      // the integrator's delta light, sampled by next-event estimation.
      const float c = std::max(0.f, dot(d, to_sun));
      const float glow = 2.5f * std::pow(c, 64.f) + 0.4f * std::pow(c, 8.f);
      float* o = img.at(x, y);
      o[0] = r + glow * 1.0f, o[1] = g + glow * 0.85f, o[2] = b + glow * 0.6f;
    }
  return img;
}

}  // namespace voxcast
