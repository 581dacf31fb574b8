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
  build_distribution();
}

void Environment::build_distribution() {
  if (!(scale_ > 0.f)) return;  // a black environment: nothing to sample
  const int W = image_.width, H = image_.height;
  weight_.assign(size_t(W) * size_t(H), 0.f);
  col_cdf_.assign(size_t(H) * size_t(W + 1), 0.f);
  row_cdf_.assign(size_t(H) + 1, 0.f);
  std::vector<float> lum(size_t(W) * size_t(H));
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const float* p = image_.at(x, y);
      lum[size_t(y) * size_t(W) + size_t(x)] = 0.2126f * p[0] + 0.7152f * p[1] + 0.0722f * p[2];
    }
  // A pixel's (u, v) rectangle spans half of each neighbour's bilinear
  // ramp: the mean of the bilinear lookup over it is the separable filter
  // (1, 6, 1) / 8 of the luminance (wrapped in u, clamped in v, as the
  // lookup). So the density follows the radiance that lookups return, and
  // a dim pixel next to a bright one is sampled as often as its light needs.
  const float k[3] = {0.125f, 0.75f, 0.125f};
  std::vector<double> row_sum(size_t(H), 0.0);
  for (int y = 0; y < H; ++y) {
    const float sin_theta = std::sin((float(y) + 0.5f) / float(H) * kPi);
    double acc = 0.0;
    for (int x = 0; x < W; ++x) {
      float mean = 0.f;
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const int yy = std::clamp(y + dy, 0, H - 1), xx = (x + dx + W) % W;
          mean += k[dy + 1] * k[dx + 1] * lum[size_t(yy) * size_t(W) + size_t(xx)];
        }
      const float w = mean * sin_theta;
      weight_[size_t(y) * size_t(W) + size_t(x)] = w;
      acc += double(w);
    }
    row_sum[size_t(y)] = acc;
    float* cdf = &col_cdf_[size_t(y) * size_t(W + 1)];
    double run = 0.0;
    for (int x = 0; x < W; ++x) {
      run += double(weight_[size_t(y) * size_t(W) + size_t(x)]);
      cdf[x + 1] = acc > 0.0 ? float(run / acc) : float(x + 1) / float(W);
    }
    cdf[W] = 1.f;
  }
  double total = 0.0;
  for (double r : row_sum) total += r;
  if (!(total > 0.0) || !std::isfinite(total)) {
    weight_.clear(), col_cdf_.clear(), row_cdf_.clear();
    return;
  }
  double run = 0.0;
  for (int y = 0; y < H; ++y) {
    run += row_sum[size_t(y)];
    row_cdf_[size_t(y) + 1] = float(run / total);
  }
  row_cdf_[size_t(H)] = 1.f;
  total_ = total;
}

namespace {
/// The interval k of a CDF (cdf[0] = 0 .. cdf[n] = 1) with cdf[k] <= u <
/// cdf[k + 1], and u's fraction within it; -1 when the interval is empty.
int invert_cdf(const float* cdf, int n, float u, float* frac) {
  const int k = int(std::upper_bound(cdf, cdf + n + 1, u) - cdf) - 1;
  const int i = std::clamp(k, 0, n - 1);
  const float width = cdf[i + 1] - cdf[i];
  if (!(width > 0.f)) return -1;
  *frac = std::clamp((u - cdf[i]) / width, 0.f, 0x1.fffffep-1f);
  return i;
}
}  // namespace

Environment::Sample Environment::sample(float u1, float u2) const {
  Sample s;
  if (!can_sample()) return s;
  const int W = image_.width, H = image_.height;
  float fy = 0.f, fx = 0.f;
  const int y = invert_cdf(row_cdf_.data(), H, u1, &fy);
  if (y < 0) return s;
  const int x = invert_cdf(&col_cdf_[size_t(y) * size_t(W + 1)], W, u2, &fx);
  if (x < 0) return s;
  const float u = (float(x) + fx) / float(W), v = (float(y) + fy) / float(H);
  s.dir = latlong_direction(u, v);
  const float sin_theta = std::sin(v * kPi);
  if (!(sin_theta > 0.f)) return s;
  const double p = double(weight_[size_t(y) * size_t(W) + size_t(x)]) / total_;
  s.pdf = float(p * double(W) * double(H) / (2.0 * double(kPi) * double(kPi) * sin_theta));
  return s;
}

float Environment::pdf(Vec3 d) const {
  if (!can_sample()) return 0.f;
  const int W = image_.width, H = image_.height;
  const Vec2 uv = latlong_uv(d);
  // sin(theta) from x and z: exact near the poles, where acos(d.y) is not.
  const float sin_theta = std::sqrt(d.x * d.x + d.z * d.z);
  if (!(sin_theta > 0.f)) return 0.f;
  const int x = std::clamp(int(std::floor(uv.x * float(W))), 0, W - 1);
  const int y = std::clamp(int(std::floor(uv.y * float(H))), 0, H - 1);
  const double p = double(weight_[size_t(y) * size_t(W) + size_t(x)]) / total_;
  return float(p * double(W) * double(H) / (2.0 * double(kPi) * double(kPi) * sin_theta));
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
