// Environment maps (environment.hpp): the lat-long mapping, bilinear
// lookups, .hdr and .exr files (round trips through independent writers,
// malformed files refused) and the procedural sky.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "voxcast/environment.hpp"
#include "voxcast/error.hpp"
#include "voxcast/exr.hpp"
#include "voxcast/image.hpp"

namespace voxcast {
namespace {

namespace fs = std::filesystem;

fs::path temp_dir() {
  const fs::path d =
      fs::temp_directory_path() /
      ("voxcast_env_" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()) + "_" +
       ::testing::UnitTest::GetInstance()->current_test_info()->name());
  fs::create_directories(d);
  return d;
}

std::vector<uint8_t> bytes_of(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

Image ramp(int w, int h) {
  Image img(w, h, 3);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      float* p = img.at(x, y);
      p[0] = 0.01f + float(x) / float(w) * 4.f;  // HDR: above 1
      p[1] = 0.02f + float(y) / float(h);
      p[2] = 0.5f + 0.25f * float((x + y) % 3);
    }
  return img;
}

TEST(Environment, LatLongMappingRoundTrips) {
  // The documented axes: up is v = 0, -z is u = 0.5, +x is u = 0.75.
  EXPECT_NEAR(latlong_uv({0, 1, 0}).y, 0.f, 1e-6f);
  EXPECT_NEAR(latlong_uv({0, -1, 0}).y, 1.f, 1e-6f);
  EXPECT_NEAR(latlong_uv({0, 0, -1}).x, 0.5f, 1e-6f);
  EXPECT_NEAR(latlong_uv({1, 0, 0}).x, 0.75f, 1e-6f);
  EXPECT_NEAR(latlong_uv({-1, 0, 0}).x, 0.25f, 1e-6f);
  for (float u : {0.1f, 0.3f, 0.62f, 0.9f})
    for (float v : {0.05f, 0.4f, 0.77f}) {
      const Vec3 d = latlong_direction(u, v);
      EXPECT_NEAR(length(d), 1.f, 1e-5f);
      const Vec2 back = latlong_uv(d);
      EXPECT_NEAR(back.x, u, 1e-5f);
      EXPECT_NEAR(back.y, v, 1e-5f);
    }
}

TEST(Environment, LookupIsBilinearBetweenPixelCenters) {
  const Image img = ramp(16, 8);
  const Environment env(img, 2.f);
  // At a pixel center: the pixel times the scale.
  for (int y : {0, 3, 7})
    for (int x : {0, 5, 15}) {
      const Vec3 d = latlong_direction((float(x) + 0.5f) / 16.f, (float(y) + 0.5f) / 8.f);
      const Color c = env.radiance(d);
      EXPECT_NEAR(c.r, 2.f * img.at(x, y)[0], 1e-3f);
      EXPECT_NEAR(c.g, 2.f * img.at(x, y)[1], 1e-3f);
      EXPECT_NEAR(c.b, 2.f * img.at(x, y)[2], 1e-3f);
    }
  // Halfway between two centers in u: their mean; across the seam u = 0: wraps.
  const Color mid = env.radiance(latlong_direction(6.f / 16.f, 4.5f / 8.f));
  EXPECT_NEAR(mid.r, (img.at(5, 4)[0] + img.at(6, 4)[0]), 1e-3f);  // x 2 scale, / 2 mean
  const Color seam = env.radiance(latlong_direction(0.f, 2.5f / 8.f));
  EXPECT_NEAR(seam.r, (img.at(0, 2)[0] + img.at(15, 2)[0]), 1e-3f);
  // A constant environment ignores the direction.
  const Environment flat(Color{0.3f, 0.4f, 0.5f, 1.f});
  EXPECT_FLOAT_EQ(flat.radiance({0, 0, 1}).g, 0.4f);
  EXPECT_TRUE(flat.is_constant());
}

TEST(Environment, RefusesBadImages) {
  EXPECT_THROW(Environment(Image{}), Error);
  EXPECT_THROW(Environment(Image(4, 2, 1)), Error);
  Image neg(4, 2, 3);
  neg.pixels[5] = -1.f;
  EXPECT_THROW(Environment{neg}, Error);
  Image nan(4, 2, 3);
  nan.pixels[1] = NAN;
  EXPECT_THROW(Environment{nan}, Error);
  EXPECT_THROW(Environment(Image(4, 2, 3), -1.f), Error);
}

// A dim map with one bright pixel block (a small "sun" painted in).
Image spot_map(int w, int h) {
  Image img(w, h, 3);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      float* p = img.at(x, y);
      const bool bright = x >= w / 3 && x < w / 3 + 2 && y >= h / 4 && y < h / 4 + 2;
      p[0] = bright ? 300.f : 0.2f + 0.1f * float(x % 5);
      p[1] = bright ? 250.f : 0.3f;
      p[2] = bright ? 200.f : 0.4f + 0.05f * float(y % 3);
    }
  return img;
}

TEST(Environment, ImportanceSamplingFollowsLuminanceAndItsDensity) {
  const int W = 32, H = 16;
  const Environment env(spot_map(W, H), 2.f);
  ASSERT_TRUE(env.can_sample());
  EXPECT_FALSE(Environment(Color{1, 1, 1, 1}).can_sample());
  EXPECT_FALSE(Environment(spot_map(W, H), 0.f).can_sample());
  // Oracle for a pixel's probability: the luminance of the lookups
  // integrated over the pixel's (u, v) rectangle (midpoint rule on 8 x 8
  // points, exact for bilinear pieces) times sin(theta) of its center (the
  // rectangle's solid angle within 0.5 %), normalized.
  std::vector<double> expect(size_t(W) * size_t(H));
  double total = 0;
  const double pi = 3.14159265358979;
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      double sum = 0;
      for (int j = 0; j < 8; ++j)
        for (int i = 0; i < 8; ++i) {
          const float u = (float(x) + (float(i) + 0.5f) / 8) / W;
          const float v = (float(y) + (float(j) + 0.5f) / 8) / H;
          const Color c = env.radiance(latlong_direction(u, v));
          sum += 0.2126 * c.r + 0.7152 * c.g + 0.0722 * c.b;
        }
      total += expect[size_t(y) * W + x] = sum * std::sin(pi * (y + 0.5) / H);
    }
  std::vector<double> count(expect.size(), 0.0);
  const int n = 400000;
  uint32_t state = 12345;
  auto uniform = [&state] {
    state = state * 1664525u + 1013904223u;
    return float(state >> 8) * 0x1p-24f;
  };
  int checked_pdf = 0;
  for (int i = 0; i < n; ++i) {
    const Environment::Sample s = env.sample(uniform(), uniform());
    ASSERT_GT(s.pdf, 0.f);
    ASSERT_NEAR(length(s.dir), 1.f, 1e-5f);
    const Vec2 uv = latlong_uv(s.dir);
    const int x = std::clamp(int(uv.x * W), 0, W - 1), y = std::clamp(int(uv.y * H), 0, H - 1);
    count[size_t(y) * W + x] += 1;
    // pdf() of the sampled direction is the density sample() reported
    // (away from pixel borders, where rounding may pick the neighbour).
    const float fx = uv.x * W - float(x), fy = uv.y * H - float(y);
    if (fx > 0.01f && fx < 0.99f && fy > 0.01f && fy < 0.99f) {
      ASSERT_NEAR(env.pdf(s.dir), s.pdf, 1e-3f * s.pdf);
      ++checked_pdf;
    }
  }
  EXPECT_GT(checked_pdf, n / 2);
  // Frequencies within 5 standard deviations (binomial) and float rounding.
  for (size_t i = 0; i < expect.size(); ++i) {
    const double p = expect[i] / total;
    const double sd = std::sqrt(n * p * (1 - p));
    EXPECT_NEAR(count[i], n * p, 5 * sd + 1e-3 * n * p) << "pixel " << i;
  }
  // The density integrates to 1 over the sphere (midpoint quadrature).
  double integral = 0;
  const int nt = 400, np = 800;
  for (int i = 0; i < nt; ++i)
    for (int j = 0; j < np; ++j) {
      const double theta = (i + 0.5) * pi / nt, phi = (j + 0.5) * 2 * pi / np;
      const Vec3 d{float(std::sin(theta) * std::sin(phi)), float(std::cos(theta)),
                   float(-std::sin(theta) * std::cos(phi))};
      integral += env.pdf(d) * std::sin(theta) * (pi / nt) * (2 * pi / np);
    }
  EXPECT_NEAR(integral, 1.0, 0.01);
}

TEST(Environment, HdrRoundTripWithinRgbeQuantization) {
  const fs::path dir = temp_dir();
  for (int w : {5, 64}) {  // < 8: flat scan lines; 64: run-length encoded
    const Image img = ramp(w, 6);
    write_hdr(dir / "a.hdr", img);
    const Image back = parse_hdr(bytes_of(dir / "a.hdr"));
    ASSERT_EQ(back.width, w);
    ASSERT_EQ(back.height, 6);
    for (size_t i = 0; i < img.pixels.size(); ++i) {
      // RGBE: 8 mantissa bits under the largest channel's exponent.
      const size_t px = i / 3 * 3;
      const float top = std::max({img.pixels[px], img.pixels[px + 1], img.pixels[px + 2]});
      EXPECT_NEAR(back.pixels[i], img.pixels[i], top / 128.f) << i;
    }
    const Environment env = load_environment(dir / "a.hdr", 1.f);
    EXPECT_EQ(env.image().width, w);
  }
  fs::remove_all(dir);
}

TEST(Environment, HdrBytesDecodeAsTheFormatSays) {
  // Hand-made files, decoded by the rule (m + 0.5) * 2^(e - 136), e = 0 black.
  auto file = [](const std::string& res, std::vector<uint8_t> pixels) {
    const std::string h = "#?RADIANCE\nEXPOSURE=1.0\nFORMAT=32-bit_rle_rgbe\n\n" + res + "\n";
    std::vector<uint8_t> b(h.begin(), h.end());
    b.insert(b.end(), pixels.begin(), pixels.end());
    return b;
  };
  const Image flat = parse_hdr(file("-Y 1 +X 2", {128, 64, 0, 129, 9, 9, 9, 0}));
  ASSERT_EQ(flat.width, 2);
  EXPECT_FLOAT_EQ(flat.at(0, 0)[0], 128.5f / 128.f);
  EXPECT_FLOAT_EQ(flat.at(0, 0)[1], 64.5f / 128.f);
  EXPECT_FLOAT_EQ(flat.at(0, 0)[2], 0.5f / 128.f);
  EXPECT_EQ(flat.at(1, 0)[0], 0.f);  // e = 0
  // One run-length encoded scan line of width 8: R a run of 200, G the
  // literals 1..8, B a run of 0, E a run of 130.
  const Image rle = parse_hdr(file("-Y 1 +X 8", {2, 2, 0, 8, 128 + 8, 200, 8, 1, 2, 3, 4, 5, 6, 7,
                                                 8, 128 + 8, 0, 128 + 8, 130}));
  for (int x = 0; x < 8; ++x) {
    EXPECT_FLOAT_EQ(rle.at(x, 0)[0], 200.5f / 64.f);
    EXPECT_FLOAT_EQ(rle.at(x, 0)[1], (float(x + 1) + 0.5f) / 64.f);
    EXPECT_FLOAT_EQ(rle.at(x, 0)[2], 0.5f / 64.f);
  }
  // A run longer than the scan line, a zero literal count, a wrong length.
  EXPECT_THROW(parse_hdr(file("-Y 1 +X 8", {2, 2, 0, 8, 128 + 9, 1})), Error);
  EXPECT_THROW(parse_hdr(file("-Y 1 +X 8", {2, 2, 0, 8, 0, 1, 1, 1})), Error);
  EXPECT_THROW(parse_hdr(file("-Y 1 +X 8", {2, 2, 0, 9, 128 + 8, 1})), Error);
  EXPECT_THROW(parse_hdr(file("-Y 1 +X 2", {128, 64, 0, 129})), Error);  // one pixel short
}

TEST(Environment, MutatedHdrFilesAreRefusedOrWellFormed) {
  // The fuzz target's property (fuzz/fuzz_hdr.cpp) on deterministic
  // mutations of valid files: byte changes, truncations, insertions.
  const fs::path dir = temp_dir();
  std::vector<std::vector<uint8_t>> seeds;
  for (int w : {5, 40}) {
    write_hdr(dir / "s.hdr", ramp(w, 4));
    seeds.push_back(bytes_of(dir / "s.hdr"));
  }
  uint32_t state = 12345;
  auto next = [&] {
    state = state * 1664525u + 1013904223u;
    return state >> 8;
  };
  int parsed = 0, refused = 0;
  for (int i = 0; i < 3000; ++i) {
    std::vector<uint8_t> b = seeds[size_t(i) % seeds.size()];
    const int edits = 1 + int(next() % 4);
    for (int e = 0; e < edits && !b.empty(); ++e) {
      const size_t at = next() % b.size();
      switch (next() % 3) {
        case 0:
          b[at] = uint8_t(next());
          break;
        case 1:
          b.resize(at);
          break;
        default:
          b.insert(b.begin() + long(at), uint8_t(next()));
          break;
      }
    }
    try {
      const Image img = parse_hdr(b);
      ASSERT_EQ(img.pixels.size(), size_t(img.width) * size_t(img.height) * 3);
      for (float p : img.pixels) ASSERT_TRUE(p >= 0.f && std::isfinite(p));
      ++parsed;
    } catch (const Error&) {
      ++refused;
    }
  }
  EXPECT_GT(parsed, 100);  // mutations in pixel bytes still decode
  EXPECT_GT(refused, 100);
  fs::remove_all(dir);
}

TEST(Environment, ExrRoundTrip) {
  const fs::path dir = temp_dir();
  const Image img = ramp(12, 7);
  write_exr_image(dir / "a.exr", img);  // half floats
  const Image back = read_exr_rgb(dir / "a.exr");
  ASSERT_EQ(back.width, 12);
  ASSERT_EQ(back.height, 7);
  for (size_t i = 0; i < img.pixels.size(); ++i)
    EXPECT_NEAR(back.pixels[i], img.pixels[i], img.pixels[i] / 1024.f + 1e-4f);
  EXPECT_EQ(load_environment(dir / "a.exr").image().height, 7);
  fs::remove_all(dir);
}

TEST(Environment, RefusesMalformedHdr) {
  const fs::path dir = temp_dir();
  write_hdr(dir / "a.hdr", ramp(64, 16));
  const std::vector<uint8_t> good = bytes_of(dir / "a.hdr");
  auto refused = [](std::vector<uint8_t> b) {
    try {
      parse_hdr(b);
    } catch (const Error& e) {
      return std::string(e.what()).find('\n') == std::string::npos;  // one line
    }
    return false;
  };
  EXPECT_TRUE(refused({}));
  EXPECT_TRUE(refused({'P', '6', '\n'}));
  // Truncated in the header and in the pixels.
  EXPECT_TRUE(refused(std::vector<uint8_t>(good.begin(), good.begin() + 20)));
  // Flat scan lines (width < 8) cut short: stb would read zeros.
  write_hdr(dir / "flat.hdr", ramp(5, 6));
  const std::vector<uint8_t> flat = bytes_of(dir / "flat.hdr");
  EXPECT_NO_THROW(parse_hdr(flat));
  EXPECT_TRUE(refused(std::vector<uint8_t>(flat.begin(), flat.end() - 8)));
  // Run-length encoded scan lines cut short.
  EXPECT_TRUE(refused(std::vector<uint8_t>(good.begin(), good.end() - good.size() / 3)));
  // The header claims more pixels than the bytes can hold.
  auto header = [](const std::string& res) {
    const std::string h = "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + res + "\n";
    std::vector<uint8_t> b(h.begin(), h.end());
    b.resize(b.size() + 64, 0);
    return b;
  };
  EXPECT_TRUE(refused(header("-Y 100000 +X 100000")));
  EXPECT_TRUE(refused(header("-Y 0 +X 10")));
  EXPECT_TRUE(refused(header("-Y x +X 10")));
  EXPECT_TRUE(refused(header("+X 10 -Y 10")));  // an orientation not supported
  // Not a Radiance file at all, even if stb could decode it as an image.
  Image ldr(4, 4, 3);
  write_image(dir / "a.png", ldr);
  EXPECT_TRUE(refused(bytes_of(dir / "a.png")));
  EXPECT_THROW(load_environment(dir / "a.png"), Error);
  EXPECT_THROW(load_environment(dir / "missing.hdr"), Error);
  fs::remove_all(dir);
}

TEST(Environment, ProceduralSkyIsBrighterAboveAndAroundTheSun) {
  const Vec3 sun_dir = normalize(Vec3{-0.3f, -1.f, 0.2f});
  const Environment env(procedural_sky(128, 64, sun_dir));
  const Color up = env.radiance({0, 1, 0}), down = env.radiance({0, -1, 0});
  const Color sun = env.radiance(-sun_dir);
  EXPECT_GT(up.b, down.b);
  EXPECT_GT(sun.r, up.r);
  for (float p : env.image().pixels) EXPECT_TRUE(p >= 0.f && std::isfinite(p));
}

}  // namespace
}  // namespace voxcast
