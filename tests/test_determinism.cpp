// Issue 15 item 9: the same input and options give the same output bytes on
// 1 and 2 threads, for every file the CLI writes, compared as files (what a
// user or a cache sees). The ESVO raw scene is Cli.BuildIsByteIdenticalWhatever-
// TheThreadCount; the in-process builders have their own tests
// (CompressedOctree.DeterministicForAnyThreadCount, DagBuild.Deterministic-
// AcrossThreadCounts, DagCompressed.DeterministicForOneAndTwoThreads,
// CellBuild / variable-depth 1-vs-all, Effects.DeterministicAcrossThreadCounts).
// These fill the gaps: every other .vxc variant, the rendered .png/.pfm/.exr,
// the voxel files `convert` writes (.vox, .binvox, .vdb, .raw + .raw.json)
// and the GigaVoxels volume images.
#include <gtest/gtest.h>

#include <functional>
#include <string>
#include <vector>

#include "support/cli_runner.hpp"

namespace voxcast {
namespace {

using testing::read_text;
using testing::run_cli;
using testing::TempDir;

const std::string kSpot = std::string(VOXCAST_TEST_DATA_DIR) + "/meshes/spot.obj";

struct SceneVariant {
  const char* name;
  const char* options;  // `voxcast build` options besides input/output/threads
};

class DeterministicScene : public ::testing::TestWithParam<SceneVariant> {};

TEST_P(DeterministicScene, SameBytesOnOneAndTwoThreads) {
  TempDir dir;
  std::string bytes[2];
  for (int t = 0; t < 2; ++t) {
    const std::string out = dir.file(t == 0 ? "one.vxc" : "two.vxc");
    const testing::CliResult r =
        run_cli("build '" + kSpot + "' -o '" + out + "' " + GetParam().options + " --threads " +
                std::to_string(t + 1));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    bytes[t] = read_text(out);
  }
  ASSERT_GT(bytes[0].size(), 1000u);
  EXPECT_TRUE(bytes[0] == bytes[1]) << GetParam().name << ": scene files differ";
}

INSTANTIATE_TEST_SUITE_P(
    Formats, DeterministicScene,
    ::testing::Values(
        SceneVariant{"esvo_compressed", "--resolution 128 --attributes compressed"},
        SceneVariant{"esvo_contours", "--resolution 128 --contours"},
        SceneVariant{"esvo_contours_compressed",
                     "--resolution 128 --contours --attributes compressed"},
        // In-core variable depth with attribute tolerances (the cell build is
        // the default without them; both are covered).
        SceneVariant{"esvo_variable_depth", "--resolution 128 --contours --geometry-error 1"},
        SceneVariant{"esvo_variable_depth_tolerances",
                     "--resolution 128 --contours --geometry-error 1 --color-error 8"},
        SceneVariant{"dag_raw", "--resolution 256 --format dag"},
        SceneVariant{"dag_compressed", "--resolution 256 --format dag --attributes compressed"},
        SceneVariant{"dag_out_of_core", "--resolution 256 --format dag --out-of-core"},
        SceneVariant{"brickmap", "--resolution 128 --format brickmap"}),
    [](const ::testing::TestParamInfo<SceneVariant>& p) { return std::string(p.param.name); });

// Every image format `render` writes: color .png and .pfm, depth .pfm,
// normals .png, AO .png; ESVO and DAG; with beam, shadows, AO and the
// post-filter, so every threaded stage is in the picture.
class DeterministicImages : public ::testing::TestWithParam<const char*> {};

TEST_P(DeterministicImages, SameBytesOnOneAndTwoThreads) {
  TempDir dir;
  const std::string scene = dir.file("s.vxc");
  const testing::CliResult b =
      run_cli("build '" + kSpot + "' -o '" + scene + "' --resolution 128 " + GetParam());
  ASSERT_EQ(b.exit_code, 0) << b.output;
  const char* outputs[] = {"c.png", "c.pfm", "d.pfm", "n.png", "a.png"};
  std::string bytes[2][5];
  for (int t = 0; t < 2; ++t) {
    const std::string p = dir.file(std::to_string(t) + "-");
    for (const char* color : {"c.png", "c.pfm"}) {
      const testing::CliResult r = run_cli(
          "render '" + scene + "' -o '" + p + color + "' --depth '" + p + "d.pfm' --normals '" + p +
          "n.png' --ao-output '" + p + "a.png' --size 96x72 --beam 4 --shadows hard --ao 4 " +
          "--filter --threads " + std::to_string(t + 1));
      ASSERT_EQ(r.exit_code, 0) << r.output;
    }
    for (int k = 0; k < 5; ++k) bytes[t][k] = read_text(p + outputs[k]);
  }
  for (int k = 0; k < 5; ++k) {
    ASSERT_GT(bytes[0][k].size(), 100u) << outputs[k];
    EXPECT_TRUE(bytes[0][k] == bytes[1][k]) << outputs[k] << " differs between 1 and 2 threads";
  }
}

INSTANTIATE_TEST_SUITE_P(Structures, DeterministicImages,
                         ::testing::Values("--format esvo", "--format dag"),
                         [](const ::testing::TestParamInfo<const char*>& p) {
                           return std::string(p.index == 0 ? "esvo" : "dag");
                         });

// The multi-layer EXR (color, depth and normal layers in one file).
TEST(DeterministicExr, SameBytesOnOneAndTwoThreads) {
  TempDir dir;
  const std::string scene = dir.file("s.vxc");
  const testing::CliResult b = run_cli("build '" + kSpot + "' -o '" + scene + "' --resolution 128");
  ASSERT_EQ(b.exit_code, 0) << b.output;
  std::string bytes[2];
  for (int t = 0; t < 2; ++t) {
    const std::string out = dir.file(std::to_string(t) + ".exr");
    const testing::CliResult r =
        run_cli("render '" + scene + "' -o '" + out +
                "' --aov depth,normal --size 96x72 --beam 4 --shadows hard --ao 4 --threads " +
                std::to_string(t + 1));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    bytes[t] = read_text(out);
  }
  ASSERT_GT(bytes[0].size(), 1000u);
  EXPECT_TRUE(bytes[0] == bytes[1]) << ".exr differs between 1 and 2 threads";
}

// `convert` from a mesh (voxelized on the threads) into every voxel format;
// solid fill for one of them, so the parity fill's threads are covered too.
struct VoxelOutput {
  const char* name;
  const char* file;
  const char* options;
};

class DeterministicVoxels : public ::testing::TestWithParam<VoxelOutput> {};

TEST_P(DeterministicVoxels, SameBytesOnOneAndTwoThreads) {
  TempDir dir;
  std::string bytes[2], json[2];
  const bool raw = std::string(GetParam().file).ends_with(".raw");
  for (int t = 0; t < 2; ++t) {
    const std::string out = dir.file(std::to_string(t) + GetParam().file);
    const testing::CliResult r =
        run_cli("convert '" + kSpot + "' '" + out + "' " + GetParam().options + " --threads " +
                std::to_string(t + 1));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    bytes[t] = read_text(out);
    if (raw) json[t] = read_text(out + ".json");
  }
  ASSERT_GT(bytes[0].size(), 100u);
  EXPECT_TRUE(bytes[0] == bytes[1]) << GetParam().name << " differs between 1 and 2 threads";
  if (raw) {
    ASSERT_FALSE(json[0].empty());
    EXPECT_EQ(json[0], json[1]);
  }
}

INSTANTIATE_TEST_SUITE_P(
    Formats, DeterministicVoxels,
    ::testing::Values(VoxelOutput{"vox", ".vox", "--resolution 64"},
                      VoxelOutput{"vox_solid", ".vox", "--resolution 64 --fill solid"},
                      VoxelOutput{"binvox", ".binvox", "--resolution 64"},
                      VoxelOutput{"vdb", ".vdb", "--resolution 64"},
                      VoxelOutput{"raw", ".raw", "--resolution 64"}),
    [](const ::testing::TestParamInfo<VoxelOutput>& p) { return std::string(p.param.name); });

// Runs the commands `commands(p)` (p: a file prefix per thread count) with
// --threads 1 and 2 and expects each of `files` (p + name) to be the same
// bytes both times.
void expect_same_files(const TempDir& dir,
                       const std::function<std::vector<std::string>(const std::string&)>& commands,
                       const std::vector<std::string>& files) {
  std::vector<std::string> bytes[2];
  for (int t = 0; t < 2; ++t) {
    const std::string p = dir.file(std::to_string(t));
    for (const std::string& run : commands(p)) {
      const testing::CliResult r = run_cli(run + " --threads " + std::to_string(t + 1));
      ASSERT_EQ(r.exit_code, 0) << run << "\n" << r.output;
    }
    for (const std::string& f : files) bytes[t].push_back(read_text(p + f));
  }
  for (size_t k = 0; k < files.size(); ++k) {
    ASSERT_GT(bytes[0][k].size(), 100u) << files[k];
    EXPECT_TRUE(bytes[0][k] == bytes[1][k]) << files[k] << " differs between 1 and 2 threads";
  }
}

// Brickmap worlds beyond `build`: a terrain written by `generate terrain`
// (chunk columns generated in parallel), its render in RAM and streamed from
// the file (uploads served between passes, with and without DXT1 colors).
TEST(DeterministicBrickmap, SameBytesOnOneAndTwoThreads) {
  TempDir dir;
  expect_same_files(dir,
                    [](const std::string& p) {
                      const std::string world = "'" + p + "w.vxc'";
                      return std::vector<std::string>{
                          "generate terrain --size 96x40x80 --seed 4 -o " + world,
                          "render " + world + " -o '" + p + "c.png' --depth '" + p +
                              "d.pfm' --size 64x48 --shadows hard --ao 2",
                          "render " + world + " --stream --frames 3 --budget 256K -o '" + p +
                              "s.png' --size 64x48",
                          "render " + world + " --stream --frames 3 --budget 256K --dxt1 -o '" + p +
                              "x.png' --size 64x48"};
                    },
                    {"w.vxc", "c.png", "d.pfm", "s.png", "x.png"});
}

// ESVO slice files (.vxs, esvo §7: the top-down slice builder) and the frames
// streamed from one within a budget (--write-frames).
TEST(DeterministicSlices, SameBytesOnOneAndTwoThreads) {
  TempDir dir;
  expect_same_files(dir,
                    [](const std::string& p) {
                      return std::vector<std::string>{
                          "build '" + kSpot + "' -o '" + p + "s.vxs' --resolution 128 --slices",
                          "render '" + p + "s.vxs' --frames 2 --budget 64K --write-frames -o '" +
                              p + "f.png' --size 64x48",
                          // §5.5 blocks per slice, with the decoded tolerance test (§7.3)
                          "build '" + kSpot + "' -o '" + p +
                              "c.vxs' --resolution 64 --slices --slice-size 8K --contours "
                              "--color-error 8 --normal-error 10 --attributes compressed"};
                    },
                    {"s.vxs", "f.png", "f-000.png", "c.vxs"});
}

// `volume render` (GigaVoxels: several passes that serve requests between
// them, so the pools' contents depend on what the threads asked for).
TEST(DeterministicVolume, SameBytesOnOneAndTwoThreads) {
  TempDir dir;
  std::string bytes[2][2];
  for (int t = 0; t < 2; ++t) {
    const std::string p = dir.file(std::to_string(t));
    const testing::CliResult r =
        run_cli("volume render procedural:menger -o '" + p + ".png' --depth '" + p +
                ".pfm' --resolution 64 --size 64x48 --shading --threads " + std::to_string(t + 1));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    bytes[t][0] = read_text(p + ".png");
    bytes[t][1] = read_text(p + ".pfm");
  }
  for (int k = 0; k < 2; ++k) {
    ASSERT_GT(bytes[0][k].size(), 100u);
    EXPECT_TRUE(bytes[0][k] == bytes[1][k]) << (k ? ".pfm" : ".png") << " differs";
  }
}

}  // namespace
}  // namespace voxcast
