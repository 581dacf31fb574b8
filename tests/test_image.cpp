// Image export/import (PNG, PFM), sRGB transfer functions, atomic writes.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

#include "voxcast/error.hpp"
#include "voxcast/image.hpp"

namespace fs = std::filesystem;
using namespace voxcast;

namespace {

struct TempDir {
  fs::path path;
  TempDir() {
    std::string tmpl = (fs::temp_directory_path() / "voxcast_image_XXXXXX").string();
    if (!mkdtemp(tmpl.data())) throw std::runtime_error("mkdtemp failed");
    path = tmpl;
  }
  ~TempDir() {
    std::error_code ec;
    fs::remove_all(path, ec);
  }
  size_t file_count() const {
    return size_t(std::distance(fs::directory_iterator(path), fs::directory_iterator()));
  }
};

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// A deterministic image whose values cover [0,1] and every pixel differs.
Image gradient(int w, int h, int c) {
  Image im(w, h, c);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      for (int k = 0; k < c; ++k) im.at(x, y)[k] = float((x * 7 + y * 13 + k * 5) % 64) / 63.0f;
  return im;
}

}  // namespace

TEST(Srgb, KnownValuesAndInverse) {
  EXPECT_FLOAT_EQ(srgb_to_linear(0.0f), 0.0f);
  EXPECT_FLOAT_EQ(srgb_to_linear(1.0f), 1.0f);
  EXPECT_NEAR(srgb_to_linear(0.5f), 0.214041f, 1e-5f);
  EXPECT_NEAR(linear_to_srgb(0.5f), 0.735357f, 1e-5f);
  // The linear segment below the threshold.
  EXPECT_NEAR(srgb_to_linear(0.02f), 0.02f / 12.92f, 1e-9f);
  EXPECT_NEAR(linear_to_srgb(0.001f), 0.01292f, 1e-8f);
  // Both pieces meet at the threshold (the exact curve is continuous there).
  EXPECT_NEAR(srgb_to_linear(0.04045f), srgb_to_linear(0.040451f), 1e-6f);
  for (int i = 0; i <= 1000; ++i) {
    float x = i / 1000.0f;
    EXPECT_NEAR(linear_to_srgb(srgb_to_linear(x)), x, 2e-6f) << x;
    EXPECT_NEAR(srgb_to_linear(linear_to_srgb(x)), x, 2e-6f) << x;
  }
  for (int i = 1; i <= 100; ++i)
    EXPECT_GT(srgb_to_linear(i / 100.0f), srgb_to_linear((i - 1) / 100.0f));
}

TEST(Pfm, RoundTripIsBitExact) {
  TempDir tmp;
  for (int c : {1, 3}) {
    Image im = gradient(5, 4, c);
    im.at(2, 1)[0] = -3.5f;  // PFM is HDR: negative and > 1 must survive
    im.at(3, 2)[0] = 1e6f;
    fs::path p = tmp.path / ("rt" + std::to_string(c) + ".pfm");
    write_image(p, im);
    Image back = read_pfm(p);
    ASSERT_EQ(back.width, 5);
    ASSERT_EQ(back.height, 4);
    ASSERT_EQ(back.channels, c);
    EXPECT_EQ(std::memcmp(back.pixels.data(), im.pixels.data(), im.pixels.size() * 4), 0);
  }
}

TEST(Pfm, HeaderAndBottomToTopRows) {
  TempDir tmp;
  Image im(2, 3, 3);
  for (int y = 0; y < 3; ++y)
    for (int x = 0; x < 2; ++x)
      for (int k = 0; k < 3; ++k) im.at(x, y)[k] = float(100 * y + 10 * x + k);
  fs::path p = tmp.path / "o.pfm";
  write_image(p, im);
  std::string bytes = slurp(p);
  const std::string header = "PF\n2 3\n-1.0\n";
  ASSERT_EQ(bytes.substr(0, header.size()), header);
  ASSERT_EQ(bytes.size(), header.size() + 2 * 3 * 3 * 4);
  auto file_float = [&](size_t i) {
    const unsigned char* b =
        reinterpret_cast<const unsigned char*>(bytes.data() + header.size() + 4 * i);
    uint32_t u = uint32_t(b[0]) | uint32_t(b[1]) << 8 | uint32_t(b[2]) << 16 | uint32_t(b[3]) << 24;
    float f;
    std::memcpy(&f, &u, 4);
    return f;
  };
  // The first row in the file is the last (bottom) row of the image.
  EXPECT_EQ(file_float(0), 200.0f);
  EXPECT_EQ(file_float(1), 201.0f);
  EXPECT_EQ(file_float(3), 210.0f);
  // The last row in the file is the top row.
  EXPECT_EQ(file_float(12), 0.0f);
  EXPECT_EQ(file_float(15), 10.0f);

  // Gray images use 'Pf'.
  Image g(1, 1, 1);
  write_image(tmp.path / "g.pfm", g);
  EXPECT_EQ(slurp(tmp.path / "g.pfm").substr(0, 3), "Pf\n");
}

TEST(Pfm, ReadsBigEndianAndRejectsGarbage) {
  TempDir tmp;
  // Positive scale means big-endian.
  std::string be = "Pf\n2 1\n1.0\n";
  for (float f : {1.5f, -2.0f}) {
    uint32_t u;
    std::memcpy(&u, &f, 4);
    for (int k = 3; k >= 0; --k) be.push_back(char((u >> (8 * k)) & 0xff));
  }
  std::ofstream(tmp.path / "be.pfm", std::ios::binary) << be;
  Image im = read_pfm(tmp.path / "be.pfm");
  ASSERT_EQ(im.channels, 1);
  EXPECT_EQ(im.at(0, 0)[0], 1.5f);
  EXPECT_EQ(im.at(1, 0)[0], -2.0f);

  auto write = [&](const std::string& name, const std::string& content) {
    std::ofstream(tmp.path / name, std::ios::binary) << content;
    return tmp.path / name;
  };
  EXPECT_THROW(read_pfm(write("trunc.pfm", "PF\n4 4\n-1.0\n" + std::string(10, '\0'))), Error);
  EXPECT_THROW(read_pfm(write("magic.pfm", "P6\n1 1\n255\nabc")), Error);
  EXPECT_THROW(read_pfm(write("dims.pfm", "PF\n-1 4\n-1.0\n")), Error);
  EXPECT_THROW(read_pfm(write("text.pfm", "PF\nab 4\n-1.0\n")), Error);
  EXPECT_THROW(read_pfm(write("empty.pfm", "")), Error);
  EXPECT_THROW(read_pfm(tmp.path / "missing.pfm"), Error);
}

TEST(Png, RoundTripEncodesSrgb) {
  TempDir tmp;
  Image im = gradient(7, 5, 3);
  fs::path p = tmp.path / "rt.png";
  write_image(p, im);
  Image back = read_png(p);
  ASSERT_EQ(back.width, 7);
  ASSERT_EQ(back.height, 5);
  ASSERT_EQ(back.channels, 3);
  for (size_t i = 0; i < im.pixels.size(); ++i) {
    // The file holds sRGB bytes; read_png does no conversion.
    EXPECT_NEAR(back.pixels[i], linear_to_srgb(im.pixels[i]), 0.5f / 255 + 1e-6f) << i;
    EXPECT_NEAR(srgb_to_linear(back.pixels[i]), im.pixels[i], 0.01f) << i;
  }
}

TEST(Png, AlreadySrgbIsStoredVerbatimAndClamped) {
  TempDir tmp;
  Image im(4, 1, 1);
  im.pixels = {0.0f, 0.5f, 2.0f, -1.0f};
  write_image(tmp.path / "g.png", im, /*already_srgb=*/true);
  Image back = read_png(tmp.path / "g.png");
  ASSERT_EQ(back.channels, 1);
  EXPECT_FLOAT_EQ(back.pixels[0], 0.0f);
  EXPECT_FLOAT_EQ(back.pixels[1], 128 / 255.0f);
  EXPECT_FLOAT_EQ(back.pixels[2], 1.0f);
  EXPECT_FLOAT_EQ(back.pixels[3], 0.0f);
}

TEST(Png, RgbaKeepsAlphaLinearAndRowOrder) {
  TempDir tmp;
  Image im(1, 2, 4);
  float top[4] = {1, 0, 0, 0.5f};
  float bottom[4] = {0, 0, 0.5f, 1};
  std::memcpy(im.at(0, 0), top, sizeof top);
  std::memcpy(im.at(0, 1), bottom, sizeof bottom);
  write_image(tmp.path / "a.png", im);
  Image back = read_png(tmp.path / "a.png");
  ASSERT_EQ(back.channels, 4);
  EXPECT_FLOAT_EQ(back.at(0, 0)[0], 1.0f);
  EXPECT_FLOAT_EQ(back.at(0, 0)[3], 128 / 255.0f);  // alpha is not sRGB-encoded
  EXPECT_FLOAT_EQ(back.at(0, 1)[2], std::round(linear_to_srgb(0.5f) * 255) / 255.0f);
  EXPECT_FLOAT_EQ(back.at(0, 1)[3], 1.0f);
}

TEST(Png, RejectsNonPng) {
  TempDir tmp;
  std::ofstream(tmp.path / "x.png", std::ios::binary) << "not a png at all";
  EXPECT_THROW(read_png(tmp.path / "x.png"), Error);
  EXPECT_THROW(read_png(tmp.path / "missing.png"), Error);
}

TEST(WriteImage, UnknownExtensionAndBadImagesThrowWithoutLeavingFiles) {
  TempDir tmp;
  Image im(2, 2, 3);
  EXPECT_THROW(write_image(tmp.path / "a.jpg", im), Error);
  EXPECT_THROW(write_image(tmp.path / "noext", im), Error);
  Image bad(2, 2, 3);
  bad.pixels.resize(5);
  EXPECT_THROW(write_image(tmp.path / "b.png", bad), Error);
  EXPECT_THROW(write_image(tmp.path / "b.pfm", Image{}), Error);
  EXPECT_EQ(tmp.file_count(), 0u);
  // Extensions are case-insensitive.
  EXPECT_NO_THROW(write_image(tmp.path / "UP.PNG", im));
  EXPECT_TRUE(fs::exists(tmp.path / "UP.PNG"));
}

TEST(WriteFileAtomic, WritesReplacesAndCleansUp) {
  TempDir tmp;
  fs::path p = tmp.path / "f.bin";
  const std::string a = "first version", b = "second";
  write_file_atomic(p, a.data(), a.size());
  EXPECT_EQ(slurp(p), a);
  write_file_atomic(p, b.data(), b.size());
  EXPECT_EQ(slurp(p), b);
  write_file_atomic(p, nullptr, 0);
  EXPECT_EQ(fs::file_size(p), 0u);
  EXPECT_EQ(tmp.file_count(), 1u);  // no temporaries left behind

  // A target inside a missing directory fails cleanly.
  try {
    write_file_atomic(tmp.path / "no" / "dir.bin", a.data(), a.size());
    ADD_FAILURE() << "expected voxcast::Error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("dir.bin"), std::string::npos);
  }
  // Renaming onto a directory fails after the temporary was written: it must be removed.
  fs::create_directory(tmp.path / "d");
  EXPECT_THROW(write_file_atomic(tmp.path / "d", a.data(), a.size()), Error);
  EXPECT_EQ(tmp.file_count(), 2u);
  EXPECT_TRUE(fs::is_empty(tmp.path / "d"));
}
