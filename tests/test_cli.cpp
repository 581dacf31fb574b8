// The CLI as a user meets it: usage errors, bad input files, one-line errors,
// non-zero exits, no half-written outputs, and byte-identical builds whatever
// the thread count.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>

#include "support/cli_runner.hpp"

using voxcast::testing::CliResult;
using voxcast::testing::read_text;
using voxcast::testing::run_cli;
using voxcast::testing::TempDir;
using voxcast::testing::write_text;

namespace {

const std::string kBunny = std::string(VOXCAST_SOURCE_DIR) + "/scenes/bunny.obj";

// A failing command must say what went wrong on one line starting "voxcast: error:".
void expect_one_line_error(const CliResult& r, const std::string& needle = "") {
  EXPECT_NE(r.exit_code, 0) << r.output;
  EXPECT_LT(r.exit_code, 128) << "crashed: " << r.output;
  auto pos = r.output.find("voxcast: error: ");
  ASSERT_NE(pos, std::string::npos) << r.output;
  auto eol = r.output.find('\n', pos);
  ASSERT_NE(eol, std::string::npos);
  if (!needle.empty()) {
    EXPECT_NE(r.output.substr(pos, eol - pos).find(needle), std::string::npos) << r.output;
  }
}

std::string tetra_obj() {
  return "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";
}

}  // namespace

TEST(Cli, UsageAndHelp) {
  CliResult none = run_cli("");
  EXPECT_NE(none.exit_code, 0);
  EXPECT_NE(none.output.find("build"), std::string::npos) << none.output;
  for (const char* sub : {"build", "render", "info", "bench"}) {
    CliResult help = run_cli(std::string(sub) + " --help");
    EXPECT_EQ(help.exit_code, 0) << sub;
    EXPECT_NE(help.output.find("Usage"), std::string::npos) << help.output;
  }
  CliResult unknown = run_cli("frobnicate");
  EXPECT_NE(unknown.exit_code, 0);
  CliResult missing_output = run_cli("build " + kBunny);
  EXPECT_EQ(missing_output.exit_code, 2);
  EXPECT_NE(missing_output.output.find("--output"), std::string::npos) << missing_output.output;
}

TEST(Cli, BuildRejectsBadInput) {
  TempDir dir;
  expect_one_line_error(run_cli("build /nonexistent/mesh.obj -o " + dir.file("a.vxc")));
  write_text(dir.file("empty.obj"), "");
  expect_one_line_error(run_cli("build " + dir.file("empty.obj") + " -o " + dir.file("a.vxc")));
  write_text(dir.file("nan.obj"), "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n");
  expect_one_line_error(run_cli("build " + dir.file("nan.obj") + " -o " + dir.file("a.vxc")));
  write_text(dir.file("t.obj"), tetra_obj());
  expect_one_line_error(
      run_cli("build " + dir.file("t.obj") + " -o " + dir.file("a.vxc") + " --resolution 1000"));
  expect_one_line_error(
      run_cli("build " + dir.file("t.obj") + " -o " + dir.file("a.vxc") + " --resolution 0"));
  expect_one_line_error(
      run_cli("build " + dir.file("t.obj") + " -o " + dir.file("a.vxc") + " --resolution 2097152"));
  expect_one_line_error(run_cli("build " + dir.file("t.obj") + " -o " + dir.file("a.vxc") +
                                " --voxelization sloppy"));
  expect_one_line_error(
      run_cli("build " + dir.file("t.obj") + " -o " + dir.file("a.vxc") + " --voxel-size -1"));
  // An absurd resolution is refused up front by the memory estimate.
  expect_one_line_error(
      run_cli("build " + dir.file("t.obj") + " -o " + dir.file("a.vxc") + " --resolution 1048576"),
      "memory");
  expect_one_line_error(run_cli("build " + dir.file("t.obj") + " -o " + dir.file("a.vxc") +
                                " --resolution 256 --memory-budget 1K"),
                        "memory");
  EXPECT_FALSE(std::filesystem::exists(dir.file("a.vxc")));
  // Nothing half-written is left behind either.
  for (auto& e : std::filesystem::directory_iterator(dir.path))
    EXPECT_EQ(e.path().string().find(".tmp"), std::string::npos) << e.path();
}

TEST(Cli, BuildRenderInfoEndToEnd) {
  TempDir dir;
  write_text(dir.file("t.obj"), tetra_obj());
  CliResult b =
      run_cli("build " + dir.file("t.obj") + " -o " + dir.file("t.vxc") + " --resolution 64");
  ASSERT_EQ(b.exit_code, 0) << b.output;
  CliResult info = run_cli("info " + dir.file("t.vxc"));
  ASSERT_EQ(info.exit_code, 0) << info.output;
  EXPECT_NE(info.output.find("dimensionality"), std::string::npos) << info.output;
  EXPECT_NE(info.output.find("64^3"), std::string::npos) << info.output;
  CliResult r = run_cli("render " + dir.file("t.vxc") + " -o " + dir.file("t.png") +
                        " --size 64x48 --depth " + dir.file("d.pfm"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("camera: "), std::string::npos) << r.output;
  EXPECT_TRUE(std::filesystem::file_size(dir.file("t.png")) > 0);
  // Header + 64*48 little-endian floats.
  EXPECT_GE(std::filesystem::file_size(dir.file("d.pfm")), 64u * 48u * 4u);

  // The printed auto camera, passed back explicitly, renders the same image.
  auto pos = r.output.find("camera: ");
  std::string cam = r.output.substr(pos + 8, r.output.find('\n', pos) - pos - 8);
  CliResult r2 = run_cli("render " + dir.file("t.vxc") + " -o " + dir.file("t2.png") +
                         " --size 64x48 --camera " + cam);
  ASSERT_EQ(r2.exit_code, 0) << r2.output;
  EXPECT_EQ(read_text(dir.file("t.png")), read_text(dir.file("t2.png")));
}

TEST(Cli, RenderRejectsBadInput) {
  TempDir dir;
  write_text(dir.file("t.obj"), tetra_obj());
  ASSERT_EQ(run_cli("build " + dir.file("t.obj") + " -o " + dir.file("t.vxc") + " --resolution 32")
                .exit_code,
            0);
  std::string scene = dir.file("t.vxc");
  expect_one_line_error(run_cli("render /nonexistent.vxc -o " + dir.file("x.png")));
  expect_one_line_error(run_cli("render " + scene + " -o " + dir.file("x.jpg2")));
  expect_one_line_error(run_cli("render " + scene + " -o " + dir.file("x.png") + " --size 0x10"));
  expect_one_line_error(run_cli("render " + scene + " -o " + dir.file("x.png") + " --size 10"));
  expect_one_line_error(
      run_cli("render " + scene + " -o " + dir.file("x.png") + " --camera 1,2,3"));
  expect_one_line_error(
      run_cli("render " + scene + " -o " + dir.file("x.png") + " --camera 0,0,0,0,0,0,0,1,0,45"));
  expect_one_line_error(
      run_cli("render " + scene + " -o " + dir.file("x.png") + " --camera 0,0,5,0,0,0,0,1,0,190"));
  expect_one_line_error(run_cli("render " + scene + " -o " + dir.file("x.png") + " --lod -1"));
  expect_one_line_error(run_cli("render " + scene + " -o " + dir.file("x.png") + " --light 0,0,0"));
  // A mesh is not a scene; a truncated scene is not a scene.
  expect_one_line_error(run_cli("render " + dir.file("t.obj") + " -o " + dir.file("x.png")));
  std::string bytes = read_text(scene);
  write_text(dir.file("cut.vxc"), bytes.substr(0, bytes.size() / 2));
  expect_one_line_error(run_cli("render " + dir.file("cut.vxc") + " -o " + dir.file("x.png")));
  expect_one_line_error(run_cli("info " + dir.file("cut.vxc")));
  EXPECT_FALSE(std::filesystem::exists(dir.file("x.png")));
}

TEST(Cli, BuildIsByteIdenticalWhateverTheThreadCount) {
  TempDir dir;
  ASSERT_EQ(
      run_cli("build " + kBunny + " -o " + dir.file("a.vxc") + " --resolution 256 --threads 1")
          .exit_code,
      0);
  ASSERT_EQ(
      run_cli("build " + kBunny + " -o " + dir.file("b.vxc") + " --resolution 256 --threads 2")
          .exit_code,
      0);
  std::string a = read_text(dir.file("a.vxc")), b = read_text(dir.file("b.vxc"));
  ASSERT_FALSE(a.empty());
  EXPECT_TRUE(a == b) << "scene files differ between 1 and 2 threads";
}
