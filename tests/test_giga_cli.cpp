// `voxcast volume render` (apps/voxcast/cmd_volume.cpp) as a user runs it:
// procedural and file sources render an image, -v prints per-pass
// statistics, --frames prints frames/s, one-pass and exact modes differ as
// documented, and usage / runtime errors follow the CLI conventions (one
// line, exit 2 / exit 1, no output written).
#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>

#include "support/cli_runner.hpp"
#include "support/test_data.hpp"
#include "voxcast/gigavoxels.hpp"
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

/// The finest node level of a cubic volume of `side` voxels: bricks of
/// M = giga::kBrickSide voxels at the finest level, one more level each
/// halving.
int max_level(int side) {
  return std::countr_zero(unsigned(side / giga::kBrickSide));
}
std::string max_level_text(const char* name, int side) {
  return std::string(name) + " (max level " + std::to_string(max_level(side)) + ")";
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
  EXPECT_NE(r.output.find(max_level_text("menger", 32)), std::string::npos) << r.output;
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

TEST(GigaCli, EightBitBricksHalveTheVoxelAndRenderTheSameCloud) {
  // --brick-bits 8: the pool says so, holds about twice the bricks of the
  // same budget, and the image stays within a few display steps of the
  // 16-bit pool's.
  TempDir dir;
  const std::string base =
      "volume render procedural:cloud --resolution 64 --size 48x32 --budget 8M";
  const CliResult a = run_cli_split(base + " -o " + dir.file("a.pfm"));
  const CliResult b = run_cli_split(base + " --brick-bits 8 -o " + dir.file("b.pfm"));
  ASSERT_EQ(a.exit_code, 0) << a.errors;
  ASSERT_EQ(b.exit_code, 0) << b.errors;
  auto bricks = [](const std::string& out, const char* kind) {
    const size_t at = out.find(kind);
    if (at == std::string::npos) return 0L;
    const size_t start = out.rfind('(', at);
    return std::stol(out.substr(start + 1, at - start - 1));
  };
  const long b16 = bricks(a.output, " 16-bit bricks"), b8 = bricks(b.output, " 8-bit bricks");
  EXPECT_GT(b16, 0) << a.output;
  EXPECT_GT(b8, b16 * 19 / 10) << b.output;
  const Image ia = read_pfm(dir.file("a.pfm")), ib = read_pfm(dir.file("b.pfm"));
  ASSERT_EQ(ia.pixels.size(), ib.pixels.size());
  double worst = 0;
  for (size_t i = 0; i < ia.pixels.size(); ++i)
    worst = std::max(worst, std::fabs(double(ia.pixels[i]) - double(ib.pixels[i])));
  EXPECT_GT(mean(ia), 0.02) << "the cloud must show";
  EXPECT_LT(worst, 4.0 / 255);
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
  EXPECT_NE(r.output.find(max_level_text("volume", 32)), std::string::npos) << r.output;
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
      {"volume render procedural:cloud --brick-bits 12" + out, 2},
      {"volume bench procedural:cloud --brick-bits 4", 2},
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

TEST(GigaCli, VolumeInfoDescribesFilesMeshesAndProceduralSources) {
  const CliResult file = run_cli("volume info " + skull());
  ASSERT_EQ(file.exit_code, 0) << file.output;
  EXPECT_NE(file.output.find("dimensions  32 x 32 x 32"), std::string::npos) << file.output;
  EXPECT_NE(file.output.find("range"), std::string::npos);
  EXPECT_NE(file.output.find("data        128.00 KiB"), std::string::npos) << file.output;
  EXPECT_NE(
      file.output.find("octree      " + std::to_string(max_level(32) + 1) + " levels, finest 32^3"),
      std::string::npos)
      << file.output;
  const CliResult proc = run_cli("volume info procedural:cloud --resolution 8192");
  ASSERT_EQ(proc.exit_code, 0) << proc.output;
  EXPECT_NE(proc.output.find(std::to_string(max_level(8192) + 1) + " levels, finest 8192^3"),
            std::string::npos)
      << proc.output;
  const std::string mesh =
      require_file(std::filesystem::path(VOXCAST_TEST_DATA_DIR) / "meshes/spot.obj").string();
  const CliResult m = run_cli("volume info " + mesh + " --resolution 16");
  ASSERT_EQ(m.exit_code, 0) << m.output;
  EXPECT_NE(m.output.find("mesh, solid voxels = 1"), std::string::npos) << m.output;
  EXPECT_NE(m.output.find("range       0 .. 1"), std::string::npos) << m.output;
  EXPECT_EQ(run_cli_split("volume info " + mesh + " --resolution 12").exit_code, 2);
}

TEST(GigaCli, MetaImageAndMeshSourcesRender) {
  TempDir dir;
  // A 8^3 MetaImage with a bright cube in the middle, data in a .raw file.
  std::ofstream(dir.file("c.mhd"))
      << "ObjectType = Image\nNDims = 3\nDimSize = 8 8 8\nElementType = MET_UCHAR\n"
         "ElementDataFile = c.raw\n";
  std::string raw(512, '\0');
  for (int z = 2; z < 6; ++z)
    for (int y = 2; y < 6; ++y)
      for (int x = 2; x < 6; ++x) raw[size_t((z * 8 + y) * 8 + x)] = char(200);
  std::ofstream(dir.file("c.raw"), std::ios::binary) << raw;
  const CliResult r =
      run_cli("volume render " + dir.file("c.mhd") +
              " --size 32x32 --transfer '0:0:1,1,1;1:50:1,1,1' -o " + dir.file("c.pfm"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_GT(mean(read_pfm(dir.file("c.pfm"))), 0.05);
  const std::string mesh =
      require_file(std::filesystem::path(VOXCAST_TEST_DATA_DIR) / "meshes/spot.obj").string();
  const CliResult m = run_cli(
      "volume render " + mesh +
      " --resolution 32 --size 32x32 --transfer '0:0:1,1,1;1:80:1,1,1' -o " + dir.file("m.pfm"));
  ASSERT_EQ(m.exit_code, 0) << m.output;
  EXPECT_GT(mean(read_pfm(dir.file("m.pfm"))), 0.05);
  // A truncated raw file: exit 1, one line.
  std::ofstream(dir.file("c.raw"), std::ios::binary) << raw.substr(0, 100);
  const CliResult bad =
      run_cli_split("volume render " + dir.file("c.mhd") + " -o " + dir.file("x.png"));
  EXPECT_EQ(bad.exit_code, 1);
  EXPECT_EQ(lines(bad.errors), 1) << bad.errors;
  EXPECT_NE(bad.errors.find("truncated"), std::string::npos) << bad.errors;
}

TEST(GigaCli, EffectsAndCameraPathFrames) {
  TempDir dir;
  const std::string base = "volume render procedural:menger --resolution 32 --size 32x24 ";
  for (const char* fx : {"--dof 0.05,1.5", "--soft-shadows", "--shadows --shading"}) {
    const CliResult r = run_cli(base + fx + " -o " + dir.file("fx.pfm"));
    ASSERT_EQ(r.exit_code, 0) << fx << "\n" << r.output;
    EXPECT_GT(mean(read_pfm(dir.file("fx.pfm"))), 0.02) << fx;
  }
  std::ofstream(dir.file("path.json"))
      << "{\"voxcast_camera_path\": 1, \"keyframes\": ["
         "{\"time\": 0, \"eye\": [0.5, 0.5, 2.2], \"target\": [0.5, 0.5, 0.5]},"
         "{\"time\": 1, \"eye\": [2.2, 0.5, 0.5], \"target\": [0.5, 0.5, 0.5]}]}";
  const CliResult p =
      run_cli(base + "--frames 4 --path " + dir.file("path.json") + " -o " + dir.file("p.pfm"));
  ASSERT_EQ(p.exit_code, 0) << p.output;
  EXPECT_NE(p.output.find("3 frames after the first"), std::string::npos) << p.output;
  EXPECT_NE(p.output.find("passes"), std::string::npos) << p.output;
  // The last frame looks from the last keyframe: the image of that camera.
  ASSERT_EQ(
      run_cli(base + "--camera 2.2,0.5,0.5,0.5,0.5,0.5,0,1,0,40 -o " + dir.file("k.pfm")).exit_code,
      0);
  EXPECT_EQ(read_pfm(dir.file("p.pfm")).pixels, read_pfm(dir.file("k.pfm")).pixels);
  const std::string out = " -o " + dir.file("x.png");
  for (const std::string& args :
       {base + "--dof 0.1" + out, base + "--dof -1,2" + out, base + "--dof a,b" + out,
        base + "--shadows --soft-shadows" + out, base + "--light 0,0,0" + out,
        base + "--shadows --shadow-lod -1" + out, base + "--shadows --shadow-step 0" + out,
        base + "--path " + dir.file("path.json") + out,
        base + "--frames 3 --path " + dir.file("path.json") + " --orbit 10,10" + out}) {
    const CliResult r = run_cli_split(args);
    EXPECT_EQ(r.exit_code, 2) << args << "\n" << r.errors;
    EXPECT_EQ(lines(r.errors), 1) << args << "\n" << r.errors;
  }
}

}  // namespace
// procedural:menger-recursive (RecursiveVolume, the sponge as a node graph
// of N^3-tree nodes, N = 3) through the CLI: its recursion as deep as the
// voxel sponge procedural:menger's iterations at the same resolution, and
// the same coverage of the image (the geometry itself is checked voxel by
// voxel in Giga.RecursiveMengerMatchesTheVoxelSponge).
TEST(GigaCli, RecursiveMengerRendersTheVoxelSponge) {
  TempDir dir;
  auto opacity = [&](const std::string& source, const std::string& depth_line) {
    const CliResult r =
        run_cli_split("volume render " + source +
                      " --resolution 64 --size 160x120 --orbit 35,25,1.9 -o " + dir.file("x.png"));
    EXPECT_EQ(r.exit_code, 0) << r.errors;
    EXPECT_NE(r.output.find(depth_line), std::string::npos) << r.output;
    const size_t at = r.output.find("mean opacity ");
    return at == std::string::npos ? -1.0 : std::stod(r.output.substr(at + 13));
  };
  const double graph = opacity("procedural:menger-recursive", "recursive menger graph (depth 3)");
  const double voxels = opacity("procedural:menger", max_level_text("menger", 64));
  EXPECT_GT(graph, 0.2);
  EXPECT_NEAR(graph, voxels, 0.03);
  // Not a producer: nothing to export.
  EXPECT_EQ(
      run_cli_split("volume export procedural:menger-recursive -o " + dir.file("x.vdb")).exit_code,
      2);
  const CliResult info = run_cli_split("volume info procedural:menger-recursive --resolution 81");
  EXPECT_EQ(info.exit_code, 2) << info.output;  // a power of two, as procedural:menger
}

}  // namespace voxcast::testing
