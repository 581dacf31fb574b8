// `voxcast volume render` (apps/voxcast/cmd_volume.cpp) as a user runs it:
// procedural and file sources render an image, -v prints per-pass
// statistics, --frames prints frames/s, one-pass and exact modes differ as
// documented, and usage / runtime errors follow the CLI conventions (one
// line, exit 2 / exit 1, no output written).
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "support/cli_runner.hpp"
#include "support/test_data.hpp"
#include "voxcast/image.hpp"

namespace voxcast::testing {
namespace {

std::string skull() {
  return require_file(std::filesystem::path(VOXCAST_TEST_DATA_DIR) / "volumes/skull32.inr")
      .string();
}

int lines(const std::string& s) {
  int n = 0;
  for (char c : s) n += c == '\n';
  return n;
}

double mean(const Image& im) {
  double s = 0;
  for (float v : im.pixels) s += v;
  return s / double(im.pixels.size());
}

TEST(GigaCli, ProceduralRenderWritesImageAndPassStatistics) {
  TempDir dir;
  const CliResult r =
      run_cli_split("volume render procedural:menger --resolution 32 --size 48x32 -o " +
                    dir.file("m.pfm") + " --depth " + dir.file("d.pfm") + " -v");
  ASSERT_EQ(r.exit_code, 0) << r.output << r.errors;
  EXPECT_NE(r.output.find("menger (max level 2)"), std::string::npos) << r.output;
  // Per-pass statistics on stderr, the last pass of the exact mode asks for nothing.
  EXPECT_NE(r.errors.find("frame 0 pass 0:"), std::string::npos) << r.errors;
  EXPECT_NE(r.errors.find("cache hits"), std::string::npos);
  EXPECT_NE(r.errors.find("pools"), std::string::npos);
  const size_t last = r.errors.rfind("frame 0 pass");
  EXPECT_NE(r.errors.find(" 0 requests", last), std::string::npos) << r.errors.substr(last);
  const Image im = read_pfm(dir.file("m.pfm"));
  EXPECT_EQ(im.width, 48);
  EXPECT_GT(mean(im), 0.05) << "the sponge must show";
  const Image depth = read_pfm(dir.file("d.pfm"));
  EXPECT_EQ(depth.channels, 1);
}

TEST(GigaCli, OnePassModeShowsLessThanExactInTheFirstFrame) {
  TempDir dir;
  const std::string base = "volume render procedural:cloud --resolution 32 --size 32x32 ";
  ASSERT_EQ(run_cli(base + "--passes 1 -o " + dir.file("one.pfm")).exit_code, 0);
  ASSERT_EQ(run_cli(base + "--passes exact -o " + dir.file("exact.pfm")).exit_code, 0);
  // Frame 0 of the one-pass mode finds nothing resident: an empty image.
  EXPECT_EQ(mean(read_pfm(dir.file("one.pfm"))), 0.0);
  EXPECT_GT(mean(read_pfm(dir.file("exact.pfm"))), 0.01);
  // With frames, one-pass converges to the exact image.
  const CliResult r = run_cli(base + "--passes 1 --frames 12 -o " + dir.file("later.pfm"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("frames/s"), std::string::npos) << r.output;
  EXPECT_EQ(read_pfm(dir.file("later.pfm")).pixels, read_pfm(dir.file("exact.pfm")).pixels);
}

TEST(GigaCli, VolumeFileRendersWithTransferFunction) {
  TempDir dir;
  const CliResult r = run_cli(
      "volume render " + skull() +
      " --size 32x32 --shading --transfer '0.4:0:1,1,1;0.6:200:1,0.9,0.8' -o " + dir.file("s.png"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_TRUE(std::filesystem::exists(dir.file("s.png")));
  EXPECT_NE(r.output.find("volume (max level 2)"), std::string::npos) << r.output;
}

TEST(GigaCli, ErrorsAreOneLineWithConventionalExitCodes) {
  TempDir dir;
  const std::string out = " -o " + dir.file("x.png");
  struct Case {
    std::string args;
    int code;
  };
  const Case cases[] = {
      {"volume render procedural:smoke" + out, 2},
      {"volume render procedural:cloud --resolution 100" + out, 2},
      {"volume render procedural:cloud --passes 0" + out, 2},
      {"volume render procedural:cloud --passes sometimes" + out, 2},
      {"volume render procedural:cloud --transfer 1:2" + out, 2},
      {"volume render procedural:cloud --size 0x4" + out, 2},
      {"volume render procedural:cloud --frames 0" + out, 2},
      {"volume render procedural:cloud --budget lots" + out, 2},
      {"volume render procedural:cloud -o " + dir.file("x.txt"), 2},
      {"volume render " + dir.file("missing.inr") + out, 1},
      {"volume", 2},
  };
  for (const Case& c : cases) {
    const CliResult r = run_cli_split(c.args);
    EXPECT_EQ(r.exit_code, c.code) << c.args << "\n" << r.errors;
    EXPECT_EQ(lines(r.errors), 1) << c.args << "\n" << r.errors;
    EXPECT_NE(r.errors.find("voxcast: error: "), std::string::npos) << r.errors;
    EXPECT_EQ(r.errors.find("--memory-budget"), std::string::npos) << r.errors;
  }
  // A corrupted file: exit 1, one line naming the file and the problem, no image.
  std::ifstream in(skull(), std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  bytes.resize(bytes.size() - 100);
  const std::string cut = dir.file("cut.inr");
  std::ofstream(cut, std::ios::binary) << bytes;
  const CliResult r = run_cli_split("volume render " + cut + out);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_EQ(lines(r.errors), 1) << r.errors;
  EXPECT_NE(r.errors.find("truncated"), std::string::npos) << r.errors;
  EXPECT_FALSE(std::filesystem::exists(dir.file("x.png")));
  const CliResult help = run_cli("volume render --help");
  EXPECT_EQ(help.exit_code, 0);
  EXPECT_NE(help.output.find("--passes"), std::string::npos);
}

}  // namespace
}  // namespace voxcast::testing
