// Adaptive post-process filter (esvo paper §6.3, Figures 17-19).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <memory>
#include <numbers>
#include <set>
#include <utility>
#include <vector>

#include "support/esvo_testing.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/render.hpp"

namespace voxcast {
namespace {

uint64_t mix(uint64_t x) {  // splitmix64 finalizer: deterministic test noise
  x += 0x9e3779b97f4a7c15ull;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
  return x ^ (x >> 31);
}
float noise01(uint64_t seed) {
  return float(mix(seed) >> 40) / float(1 << 24);
}

Image single_channel(int w, int h, float (*f)(int, int)) {
  Image im(w, h, 1);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) *im.at(x, y) = f(x, y);
  return im;
}

// Figure 17c: every pixel filtered with its own radius, no clamping to the
// neighbors (the "standard" method the paper compares against).
Image naive_filter(const Image& color, const std::vector<uint8_t>& code) {
  Image out(color.width, color.height, 1);
  for (int y = 0; y < color.height; ++y) {
    for (int x = 0; x < color.width; ++x) {
      const float r = decode_filter_radius(code[size_t(y) * color.width + x]);
      if (r <= 1.f) {
        *out.at(x, y) = *color.at(x, y);
        continue;
      }
      double a = 0, aw = 0;
      for (const PostFilterSample& s : post_filter_kernel()) {
        if (s.dist > r) break;
        const int sx = x + s.dx, sy = y + s.dy;
        if (sx < 0 || sy < 0 || sx >= color.width || sy >= color.height) continue;
        const double w = s.weight * std::min(r - s.dist, 1.f);
        a += *color.at(sx, sy) * w, aw += w;
      }
      *out.at(x, y) = float(a / aw);
    }
  }
  return out;
}

double variance(const Image& im, int margin) {
  double sum = 0, sum2 = 0;
  size_t n = 0;
  for (int y = margin; y < im.height - margin; ++y)
    for (int x = margin; x < im.width - margin; ++x) {
      const double v = *im.at(x, y);
      sum += v, sum2 += v * v, ++n;
    }
  const double mean = sum / double(n);
  return sum2 / double(n) - mean * mean;
}

TEST(PostFilterKernel, HasThePaperShape) {
  const auto k = post_filter_kernel();
  ASSERT_EQ(k.size(), 96u);
  EXPECT_EQ(k[0].dx, 0);
  EXPECT_EQ(k[0].dy, 0);
  EXPECT_EQ(k[0].dist, 0.f);
  std::set<std::pair<int, int>> offsets;
  double weight_sum = 0;
  for (size_t i = 0; i < k.size(); ++i) {
    EXPECT_LE(k[i].dist, 24.f) << i;
    EXPECT_FLOAT_EQ(k[i].dist, std::hypot(float(k[i].dx), float(k[i].dy))) << i;
    EXPECT_GT(k[i].weight, 0.f) << i;
    if (i > 0) {
      EXPECT_GE(k[i].dist, k[i - 1].dist) << "not sorted at " << i;
    }
    offsets.insert({k[i].dx, k[i].dy});
    weight_sum += k[i].weight;
  }
  EXPECT_EQ(offsets.size(), 96u) << "two samples fetch the same pixel";
  // Weights are the areas the samples represent: they tile the disc.
  EXPECT_NEAR(weight_sum, std::numbers::pi * 24 * 24, 1e-3 * std::numbers::pi * 24 * 24);
  // Density ∝ d^-1/2  <=>  samples within d: 96 (d/24)^1.5. A uniform disc
  // (d^2) or a 1/d density (d^1) would miss these by 6-12 samples.
  for (double d : {6.0, 12.0, 18.0}) {
    const double expected = 96.0 * std::pow(d / 24.0, 1.5);
    const auto inside =
        std::count_if(k.begin(), k.end(), [&](const auto& s) { return s.dist <= d; });
    EXPECT_NEAR(double(inside), expected, 3.0) << "d = " << d;
  }
  // Sparser samples stand for more area: weight * density ≈ 1, i.e. the
  // weight grows like sqrt(distance).
  const double density_coef = 0.75 * 96.0 / (std::numbers::pi * std::pow(24.0, 1.5));
  for (size_t i = 8; i < k.size(); ++i) {
    const double product = k[i].weight * density_coef / std::sqrt(double(k[i].dist));
    EXPECT_GT(product, 0.7) << i;
    EXPECT_LT(product, 1.4) << i;
  }
}

TEST(PostFilterKernel, RadiusCodeIsLog2In3_5FixedPoint) {
  EXPECT_EQ(encode_filter_radius(1.f), 0);
  EXPECT_EQ(encode_filter_radius(0.25f), 0);
  EXPECT_EQ(encode_filter_radius(0.f), 0);
  EXPECT_EQ(encode_filter_radius(NAN), 0);
  EXPECT_EQ(encode_filter_radius(2.f), 32);
  EXPECT_EQ(encode_filter_radius(128.f), 224);
  EXPECT_EQ(encode_filter_radius(1e9f), 255);
  EXPECT_EQ(encode_filter_radius(INFINITY), 255);
  EXPECT_FLOAT_EQ(decode_filter_radius(0), 1.f);
  EXPECT_FLOAT_EQ(decode_filter_radius(32), 2.f);
  EXPECT_FLOAT_EQ(decode_filter_radius(160), 32.f);
  for (float r = 1.f; r < 200.f; r *= 1.07f) {
    const float back = decode_filter_radius(encode_filter_radius(r));
    EXPECT_NEAR(back / r, 1.f, 0.011f) << r;  // half a step of 2^(1/32)
  }
}

TEST(PostFilter, ConstantImageStaysConstant) {
  const int W = 70, H = 50;
  Image im(W, H, 3);
  for (size_t i = 0; i < im.pixels.size(); i += 3)
    im.pixels[i] = 0.3f, im.pixels[i + 1] = 0.6f, im.pixels[i + 2] = 0.9f;
  std::vector<uint8_t> code(size_t(W) * H);
  for (size_t i = 0; i < code.size(); ++i) code[i] = uint8_t(mix(i) % 256);
  const Image out = post_filter(im, code);
  for (size_t i = 0; i < out.pixels.size(); ++i)
    ASSERT_NEAR(out.pixels[i], im.pixels[i], 1e-6f) << i;
}

TEST(PostFilter, RadiusOneEverywhereIsIdentity) {
  const int W = 40, H = 30;
  Image im(W, H, 3);
  for (size_t i = 0; i < im.pixels.size(); ++i) im.pixels[i] = noise01(i);
  const Image out = post_filter(im, std::vector<uint8_t>(size_t(W) * H, 0));
  EXPECT_EQ(out.pixels, im.pixels);
  // A patch with radius 6 changes pixels inside the patch only.
  std::vector<uint8_t> code(size_t(W) * H, 0);
  for (int y = 8; y < 20; ++y)
    for (int x = 14; x < 26; ++x) code[size_t(y) * W + x] = encode_filter_radius(6.f);
  const Image patch = post_filter(im, code);
  int changed_inside = 0;
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const bool changed = patch.at(x, y)[0] != im.at(x, y)[0];
      if (code[size_t(y) * W + x] == 0) {
        EXPECT_FALSE(changed) << x << "," << y;
      } else {
        changed_inside += changed;
      }
    }
  EXPECT_GT(changed_inside, 12 * 12 / 2);
}

TEST(PostFilter, LargeRadiusSmoothsACheckerboard) {
  const int W = 96, H = 96;
  const Image im = single_channel(W, H, [](int x, int y) { return float((x + y) & 1); });
  std::vector<uint8_t> code(size_t(W) * H, encode_filter_radius(16.f));
  const Image out = post_filter(im, code);
  const double before = variance(im, 24), after = variance(out, 24);
  EXPECT_NEAR(before, 0.25, 1e-9);
  EXPECT_LT(after, before / 20.0) << "before " << before << " after " << after;
  // A 2x2 checkerboard (voxels of 2 pixels) as well.
  const Image im2 =
      single_channel(W, H, [](int x, int y) { return float(((x >> 1) + (y >> 1)) & 1); });
  const double after2 = variance(post_filter(im2, code), 24);
  EXPECT_LT(after2, variance(im2, 24) / 20.0) << after2;
}

TEST(PostFilter, MissesStopTheBlurAtSilhouettes) {
  // Left: a textured hit region with a large radius; right: background
  // (code 0), much brighter than anything in the hit region.
  const int W = 80, H = 48, edge = 40;
  Image im(W, H, 1);
  std::vector<uint8_t> code(size_t(W) * H);
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const bool hit = x < edge;
      *im.at(x, y) = hit ? (((x >> 1) + (y >> 1)) & 1 ? 0.8f : 0.2f) : 5.f;
      code[size_t(y) * W + x] = hit ? encode_filter_radius(12.f) : 0;
    }
  const Image out = post_filter(im, code);
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      if (x < edge) {
        ASSERT_GE(*out.at(x, y), 0.2f - 1e-5f) << x << "," << y;
        ASSERT_LE(*out.at(x, y), 0.8f + 1e-5f) << "background bled into " << x << "," << y;
      } else {
        ASSERT_EQ(*out.at(x, y), 5.f) << x << "," << y;
      }
    }
  // Control: had the background carried a radius too, it would have bled in,
  // so the check above is not vacuous.
  std::vector<uint8_t> all_large(code.size(), encode_filter_radius(12.f));
  const Image bled = post_filter(im, all_large);
  EXPECT_GT(*bled.at(edge - 1, H / 2), 1.f);
}

TEST(PostFilter, RadiusStepGivesNoSeam) {
  // Figure 17: the voxel size (radius) steps from 16 to 2 pixels at x = 48;
  // the picture is a 2-pixel bright horizontal line, which a 16-pixel blur
  // spreads out and a 2-pixel blur keeps. Filtering each pixel with its own
  // radius leaves a seam at the step; clamping to the neighbors' radii while
  // walking the kernel makes the transition gradual.
  const int W = 96, H = 64, step = 48, line = 31;
  const Image im = single_channel(W, H, [](int, int y) { return y == 31 || y == 32 ? 1.f : 0.f; });
  std::vector<uint8_t> code(size_t(W) * H);
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x)
      code[size_t(y) * W + x] = encode_filter_radius(x < step ? 16.f : 2.f);
  const Image ours = post_filter(im, code), naive = naive_filter(im, code);
  auto max_jump = [&](const Image& out, int* where) {
    float jump = 0;
    for (int x = 25; x < W - 1; ++x) {
      const float j = std::fabs(*out.at(x + 1, line) - *out.at(x, line));
      if (j > jump) jump = j, *where = x;
    }
    return jump;
  };
  int at_naive = -1, at_ours = -1;
  const float naive_jump = max_jump(naive, &at_naive), our_jump = max_jump(ours, &at_ours);
  EXPECT_EQ(at_naive, step - 1);  // the seam of the standard method is at the step
  EXPECT_GT(naive_jump, 0.9f);
  // The sparse kernel (3 samples within 2 pixels) limits how gradual the
  // transition into a 2-pixel radius can be; the clamp still halves the jump
  // and spreads it over several columns left of the step.
  EXPECT_LT(our_jump, naive_jump * 0.5f) << "at x = " << at_ours;
  const float plateau = *ours.at(24, line), top = *ours.at(step, line);
  int in_between = 0;
  for (int x = 24; x < step; ++x) {
    const float v = *ours.at(x, line);
    in_between += v > plateau + 0.02f && v < top - 0.02f;
  }
  EXPECT_GE(in_between, 6);
  // Far from the step the full radius is used (the clamp is local).
  EXPECT_NEAR(*ours.at(20, line), *naive.at(20, line), 1e-6f);
}

TEST(PostFilter, DeterministicAcrossThreadCounts) {
  const int W = 123, H = 77;
  Image im(W, H, 3);
  for (size_t i = 0; i < im.pixels.size(); ++i) im.pixels[i] = noise01(i * 7 + 1);
  std::vector<uint8_t> code(size_t(W) * H);
  for (size_t i = 0; i < code.size(); ++i) code[i] = uint8_t(mix(i + 99) % 180);
  const Image one = post_filter(im, code, 1);
  EXPECT_NE(one.pixels, im.pixels);
  for (int threads : {2, 0})
    EXPECT_EQ(post_filter(im, code, threads).pixels, one.pixels) << threads;
}

TEST(PostFilter, RejectsMismatchedInputs) {
  Image im(8, 8, 3);
  EXPECT_THROW(post_filter(im, std::vector<uint8_t>(63, 0)), Error);
  EXPECT_THROW(post_filter(im, std::vector<uint8_t>(64, 0), -1), Error);
}

class PostFilterRender : public ::testing::Test {
 protected:
  void SetUp() override {
    auto octree =
        std::make_shared<esvo::EsvoOctree>(esvo::build_octree(testing::make_sphere_shell(5)));
    structure = std::make_unique<esvo::EsvoStructure>(octree);
    options.width = 96, options.height = 72;
    options.lod_pixels = 0.f;
    options.want_depth = true;
    // Framed like the CLI frames a scene: the occupied voxels' bounds.
    options.camera = Camera::frame(esvo::occupied_bounds(*octree), options.width, options.height);
  }
  std::unique_ptr<esvo::EsvoStructure> structure;
  RenderOptions options;
};

TEST_F(PostFilterRender, FilterChangesOnlyHitPixels) {
  const RenderResult plain = render(*structure, options);
  options.filter = true;
  const RenderResult filtered = render(*structure, options);
  EXPECT_EQ(plain.filter_seconds, 0.0);
  ASSERT_EQ(filtered.depth.pixels, plain.depth.pixels);
  ASSERT_GT(plain.hits, 500u);
  ASSERT_LT(plain.hits, plain.rays);
  float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
  for (int y = 0; y < options.height; ++y)
    for (int x = 0; x < options.width; ++x)
      if (std::isfinite(*plain.depth.at(x, y)))
        for (int c = 0; c < 3; ++c)
          lo[c] = std::min(lo[c], plain.color.at(x, y)[c]),
          hi[c] = std::max(hi[c], plain.color.at(x, y)[c]);
  uint64_t changed = 0;
  for (int y = 0; y < options.height; ++y)
    for (int x = 0; x < options.width; ++x) {
      const bool hit = std::isfinite(*plain.depth.at(x, y));
      for (int c = 0; c < 3; ++c) {
        const float v = filtered.color.at(x, y)[c];
        ASSERT_TRUE(std::isfinite(v)) << x << "," << y;
        if (!hit) {
          ASSERT_EQ(v, plain.color.at(x, y)[c]) << "miss pixel changed at " << x << "," << y;
        } else {  // a blend of hit pixels only: no background mixed in
          ASSERT_GE(v, lo[c] - 1e-5f) << x << "," << y;
          ASSERT_LE(v, hi[c] + 1e-5f) << x << "," << y;
        }
      }
      if (hit && filtered.color.at(x, y)[0] != plain.color.at(x, y)[0]) ++changed;
    }
  // 32^3 voxels framed in 72 rows are several pixels wide: most hits blur.
  EXPECT_GT(changed, plain.hits / 2) << changed << " of " << plain.hits;
}

TEST_F(PostFilterRender, SubPixelVoxelsAreNotBlurred) {
  // Seen from far away every voxel projects to less than a pixel: radius 1,
  // the filter must leave the image untouched.
  options.width = 64, options.height = 48;
  const Vec3 center = (structure->bounds().lo + structure->bounds().hi) * 0.5f;
  options.camera.target = center;
  options.camera.eye = center + Vec3{0.f, 0.f, 40.f};
  options.camera.fovy_degrees = 10.f;
  const RenderResult plain = render(*structure, options);
  ASSERT_GT(plain.hits, 20u);
  options.filter = true;
  EXPECT_EQ(render(*structure, options).color.pixels, plain.color.pixels);
}

}  // namespace
}  // namespace voxcast
