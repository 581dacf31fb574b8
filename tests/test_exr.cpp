// OpenEXR output (exr.hpp, write_image .exr, render -o X.exr --aov ...),
// read back with OpenEXR's own reader and compared with the same values
// written as PFM.
#include <Imath/half.h>
#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfInputFile.h>
#include <gtest/gtest.h>

#include <cmath>
#include <map>
#include <random>
#include <string>

#include "support/cli_runner.hpp"
#include "voxcast/error.hpp"
#include "voxcast/exr.hpp"
#include "voxcast/image.hpp"

using namespace voxcast;
using voxcast::testing::run_cli;
using voxcast::testing::TempDir;

namespace {

struct ExrFile {
  int width = 0, height = 0;
  std::map<std::string, Imf::PixelType> types;
  std::map<std::string, std::vector<float>> planes;  // every channel read as float
};

ExrFile read_exr(const std::string& path) {
  Imf::InputFile file(path.c_str());
  const Imath::Box2i dw = file.header().dataWindow();
  ExrFile out;
  out.width = dw.max.x - dw.min.x + 1;
  out.height = dw.max.y - dw.min.y + 1;
  Imf::FrameBuffer fb;
  for (auto it = file.header().channels().begin(); it != file.header().channels().end(); ++it) {
    out.types[it.name()] = it.channel().type;
    auto& plane = out.planes[it.name()];
    plane.assign(size_t(out.width) * size_t(out.height), 0.f);
    fb.insert(it.name(), Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(plane.data()),
                                    sizeof(float), sizeof(float) * size_t(out.width)));
  }
  file.setFrameBuffer(fb);
  file.readPixels(dw.min.y, dw.max.y);
  return out;
}

float as_half(float v) {
  return float(half(v));
}

}  // namespace

TEST(Exr, WriteImageRoundTripsThroughOpenExr) {
  TempDir dir;
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(0.f, 4.f);
  for (int channels : {1, 3, 4}) {
    SCOPED_TRACE(channels);
    Image im(37, 21, channels);
    for (float& v : im.pixels) v = u(rng);
    const std::string path = dir.file("im" + std::to_string(channels) + ".exr");
    write_image(path, im);
    const ExrFile f = read_exr(path);
    ASSERT_EQ(f.width, 37);
    ASSERT_EQ(f.height, 21);
    const std::vector<std::string> names = channels == 1 ? std::vector<std::string>{"Y"}
                                           : channels == 3
                                               ? std::vector<std::string>{"R", "G", "B"}
                                               : std::vector<std::string>{"R", "G", "B", "A"};
    ASSERT_EQ(f.planes.size(), names.size());
    for (int c = 0; c < channels; ++c) {
      const auto& plane = f.planes.at(names[size_t(c)]);
      EXPECT_EQ(f.types.at(names[size_t(c)]), Imf::HALF);
      for (int y = 0; y < 21; ++y)
        for (int x = 0; x < 37; ++x)
          ASSERT_EQ(plane[size_t(y) * 37 + size_t(x)], as_half(im.at(x, y)[c])) << x << "," << y;
    }
  }
  // Mismatched channels are refused.
  Image a(4, 4, 3), b(5, 4, 1);
  EXPECT_THROW(write_exr(dir.file("bad.exr"), {{"R", &a, 0, true}, {"Z", &b, 0, false}}), Error);
  EXPECT_THROW(write_exr(dir.file("bad.exr"), {{"R", &a, 3, true}}), Error);
}

TEST(Exr, RenderWritesColorDepthAndNormalLayers) {
  TempDir dir;
  const std::string scene = dir.file("b.vxc");
  const std::string bunny = std::string(VOXCAST_SOURCE_DIR) + "/scenes/bunny.obj";
  auto r = run_cli("build " + bunny + " --resolution 64 -o " + scene);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const std::string common = "render " + scene + " --size 64x48";
  r = run_cli(common + " -o " + dir.file("all.exr") + " --aov depth,normal");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = run_cli(common + " -o " + dir.file("c.pfm") + " --depth " + dir.file("d.pfm") +
              " --normals " + dir.file("n.pfm"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const ExrFile f = read_exr(dir.file("all.exr"));
  ASSERT_EQ(f.width, 64);
  ASSERT_EQ(f.height, 48);
  ASSERT_EQ(f.planes.size(), 7u);
  EXPECT_EQ(f.types.at("R"), Imf::HALF);
  EXPECT_EQ(f.types.at("Z"), Imf::FLOAT);
  EXPECT_EQ(f.types.at("N.x"), Imf::FLOAT);
  const Image color = read_pfm(dir.file("c.pfm")), depth = read_pfm(dir.file("d.pfm")),
              normal = read_pfm(dir.file("n.pfm"));
  int hits = 0;
  for (int y = 0; y < 48; ++y)
    for (int x = 0; x < 64; ++x) {
      const size_t i = size_t(y) * 64 + size_t(x);
      ASSERT_EQ(f.planes.at("R")[i], as_half(color.at(x, y)[0]));
      ASSERT_EQ(f.planes.at("G")[i], as_half(color.at(x, y)[1]));
      ASSERT_EQ(f.planes.at("B")[i], as_half(color.at(x, y)[2]));
      ASSERT_EQ(f.planes.at("Z")[i], depth.at(x, y)[0]);
      const char* n[3] = {"N.x", "N.y", "N.z"};
      for (int c = 0; c < 3; ++c)
        ASSERT_NEAR(f.planes.at(n[c])[i], 2.f * normal.at(x, y)[c] - 1.f, 1e-6f);
      if (std::isfinite(depth.at(x, y)[0])) {
        ++hits;
        const float len =
            std::hypot(f.planes.at("N.x")[i], f.planes.at("N.y")[i], f.planes.at("N.z")[i]);
        EXPECT_NEAR(len, 1.f, 1e-3f);
      }
    }
  EXPECT_GT(hits, 200);
  // A plain .exr output is the color alone; --aov needs an .exr output.
  r = run_cli(common + " -o " + dir.file("color.exr"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(read_exr(dir.file("color.exr")).planes.size(), 3u);
  r = run_cli(common + " -o " + dir.file("x.png") + " --aov depth");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  r = run_cli(common + " -o " + dir.file("x.exr") + " --aov albedo");
  EXPECT_EQ(r.exit_code, 2) << r.output;
}
