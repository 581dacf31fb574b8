// `voxcast render --gi SPP [--bounces N] [--env ENV] [--sun DIR]`, `render
// --spp N`, `voxcast generate sky` and `bench --gi` as a user runs them.
#include <gtest/gtest.h>

#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

#include "support/cli_runner.hpp"
#include "voxcast/environment.hpp"
#include "voxcast/image.hpp"

namespace voxcast {
namespace {

using testing::CliResult;
using testing::run_cli;
using testing::TempDir;

const std::string kBunny = std::string(VOXCAST_SOURCE_DIR) + "/scenes/bunny.obj";
const std::string kSky = std::string(VOXCAST_SOURCE_DIR) + "/scenes/sky.hdr";

class GiCli : public ::testing::Test {
 protected:
  void SetUp() override {
    scene = dir.file("bunny.vxc");
    const CliResult b = run_cli("build '" + kBunny + "' -o '" + scene + "' --resolution 64");
    ASSERT_EQ(b.exit_code, 0) << b.output;
  }
  TempDir dir;
  std::string scene;
};

TEST_F(GiCli, RendersWithTheCommittedSkyAndTheSun) {
  const std::string out = dir.file("gi.pfm");
  const CliResult r = run_cli("render '" + scene + "' --size 48x36 --gi 8 --bounces 3 --env '" +
                              kSky + "' --sun -0.4,-1,-0.6 -o '" + out + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("gi: 8 spp, 3 bounces at most"), std::string::npos) << r.output;
  const Image im = read_pfm(out);
  ASSERT_EQ(im.width, 48);
  double sum = 0;
  for (float v : im.pixels) sum += v;
  EXPECT_GT(sum / double(im.pixels.size()), 0.2);
  // The thread count changes no byte (per-pixel random streams).
  const std::string again = dir.file("again.pfm");
  ASSERT_EQ(run_cli("render '" + scene + "' --size 48x36 --gi 8 --bounces 3 --env '" + kSky +
                    "' --sun -0.4,-1,-0.6 --threads 1 -o '" + again + "'")
                .exit_code,
            0);
  EXPECT_EQ(read_pfm(again).pixels, im.pixels);  // 1 thread vs all
  // --no-env-sampling: cosine bounces alone, other samples, a similar mean.
  const std::string cosine = dir.file("cosine.pfm");
  ASSERT_EQ(run_cli("render '" + scene + "' --size 48x36 --gi 8 --bounces 3 --env '" + kSky +
                    "' --sun -0.4,-1,-0.6 --no-env-sampling -o '" + cosine + "'")
                .exit_code,
            0);
  const Image c = read_pfm(cosine);
  EXPECT_NE(c.pixels, im.pixels);
  double csum = 0;
  for (float v : c.pixels) csum += v;
  EXPECT_NEAR(csum / sum, 1.0, 0.05);
}

TEST_F(GiCli, BenchGiRowsDoEqualWork) {
  // bench --gi: the Embree path tracer of the mesh and the GI integrator on
  // every structure trace the same camera samples (equal work); no timing
  // is asserted.
  const std::string json = dir.file("bench.json");
  const CliResult r = run_cli("bench '" + kBunny +
                              "' --resolution 64 --size 32x24 --repeat 1 --gi 2 --bounces 2 "
                              "--effects --json '" +
                              json + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("diffuse GI, 2 spp, 2 bounces at most"), std::string::npos) << r.output;
  std::ifstream in(json);
  const nlohmann::json j = nlohmann::json::parse(in);
  const nlohmann::json& gi = j.at("runs").at(0).at("gi");
  EXPECT_EQ(gi.at("spp"), 2);
  std::vector<std::string> names;
  for (const nlohmann::json& row : gi.at("renderers")) {
    names.push_back(row.at("renderer"));
    EXPECT_EQ(row.at("samples").get<uint64_t>(), 32u * 24u * 2u) << row;
    EXPECT_GT(row.at("rays").get<uint64_t>(), row.at("samples").get<uint64_t>()) << row;
    EXPECT_GT(row.at("ratio").get<double>(), 0.0) << row;
  }
  ASSERT_GE(names.size(), 3u);
  EXPECT_EQ(names[0], "embree (mesh)");
  EXPECT_EQ(names[1], "voxcast esvo");
  EXPECT_EQ(names[2], "voxcast dag");
  EXPECT_EQ(gi.at("renderers").at(0).at("ratio").get<double>(), 1.0);
  EXPECT_EQ(run_cli("bench '" + kBunny + "' --gi -1").exit_code, 2);
  EXPECT_EQ(run_cli("bench '" + kBunny + "' --gi 2 --bounces -1").exit_code, 2);
}

TEST_F(GiCli, AovsInOneExr) {
  const std::string out = dir.file("gi.exr");
  const CliResult r =
      run_cli("render '" + scene + "' --size 32x24 --gi 2 --aov depth,normal -o '" + out + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(read_exr_rgb(out).width, 32);
}

TEST_F(GiCli, UsageErrors) {
  const std::string base = "render '" + scene + "' --size 16x16 -o '" + dir.file("x.png") + "' ";
  for (const char* bad :
       {"--gi 0 --bounces 2", "--bounces 2", "--env x.hdr", "--sun 0,-1,0", "--gi 4 --ao 8",
        "--gi 4 --beam 8", "--gi 4 --spp 2", "--gi 4 --sun 0,0,0", "--gi 4 --bounce-cone 95",
        "--gi -1", "--spp 0", "--gi 4 --bounces -1"}) {
    const CliResult r = run_cli(base + bad);
    EXPECT_EQ(r.exit_code, 2) << bad << ": " << r.output;
  }
  // A broken environment map is an input error (exit 1), one line.
  testing::write_text(dir.file("bad.hdr"), "#?RADIANCE\n\n-Y 4 +X 4\nshort");
  const CliResult r = run_cli(base + "--gi 2 --env '" + dir.file("bad.hdr") + "'");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("bad.hdr"), std::string::npos) << r.output;
}

TEST_F(GiCli, SppAntialiases) {
  const std::string one = dir.file("one.pfm"), four = dir.file("four.pfm");
  ASSERT_EQ(run_cli("render '" + scene + "' --size 40x30 -o '" + one + "'").exit_code, 0);
  const CliResult r = run_cli("render '" + scene + "' --size 40x30 --spp 4 -o '" + four + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(read_pfm(one).pixels, read_pfm(four).pixels);
}

TEST_F(GiCli, GenerateSkyWritesALoadableMap) {
  const std::string hdr = dir.file("sky.hdr"), exr = dir.file("sky.exr");
  ASSERT_EQ(run_cli("generate sky -o '" + hdr + "' --sky-size 64x32").exit_code, 0);
  ASSERT_EQ(run_cli("generate sky -o '" + exr + "' --sky-size 64x32 --sun 1,-1,0").exit_code, 0);
  EXPECT_EQ(load_environment(hdr).image().width, 64);
  EXPECT_EQ(load_environment(exr).image().height, 32);
  EXPECT_EQ(run_cli("generate sky -o '" + dir.file("sky.png") + "'").exit_code, 2);
}

}  // namespace
}  // namespace voxcast
