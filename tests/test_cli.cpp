// The CLI as a user meets it: usage errors, bad input files, one-line errors,
// non-zero exits, no half-written outputs, and byte-identical builds whatever
// the thread count.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
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

namespace {
// The "camera: ..." line `render` prints (empty if none).
std::string printed_camera(const std::string& output, const char* prefix = "camera: ") {
  const auto pos = output.find(prefix);
  if (pos == std::string::npos) return "";
  const size_t start = pos + std::string(prefix).size();
  return output.substr(start, output.find('\n', pos) - start);
}
}  // namespace

// --camera auto|ortho, --orbit, --look-at and --ortho (README "Camera
// contract"): each prints the camera it made in the --camera form, which
// renders the same image when passed back; bench frames like render.
TEST(Cli, CameraOptions) {
  TempDir dir;
  write_text(dir.file("t.obj"), tetra_obj());
  const CliResult built =
      run_cli("build " + dir.file("t.obj") + " -o " + dir.file("t.vxc") + " --resolution 64");
  ASSERT_EQ(built.exit_code, 0) << built.output;
  const std::string render = "render " + dir.file("t.vxc") + " --size 64x48 -o ";
  struct Case {
    const char* options;
    const char* expect_prefix;  // of the printed camera
  };
  const Case cases[] = {
      {"--camera auto", ""},
      {"--camera ortho", "ortho,"},
      {"--ortho", "ortho,"},
      {"--orbit 30,20 --ortho 3", "ortho,"},
      {"--orbit 0,0,4", ""},
      {"--look-at 2,1.5,3,0.5,0.5,0.5", "2,1.5,3,0.5,0.5,0.5,0,1,0,40"},
      {"--look-at 2,1.5,3,0.5,0.5,0.5,0,0,1,30 --ortho 2.5", "ortho,2,1.5,3,0.5,0.5,0.5,0,0,1,2.5"},
      {"--camera 3,3,3,0.5,0.5,0.5,0,1,0,35 --ortho", "ortho,3,3,3,0.5,0.5,0.5,0,1,0,"},
  };
  int i = 0;
  for (const Case& c : cases) {
    SCOPED_TRACE(c.options);
    const std::string a = dir.file("a" + std::to_string(i) + ".png"),
                      b = dir.file("b" + std::to_string(i) + ".png");
    ++i;
    const CliResult r = run_cli(render + a + " " + c.options);
    ASSERT_EQ(r.exit_code, 0) << r.output;
    const std::string cam = printed_camera(r.output);
    ASSERT_FALSE(cam.empty()) << r.output;
    EXPECT_EQ(cam.rfind(c.expect_prefix, 0), 0u) << cam;
    const CliResult again = run_cli(render + b + " --camera " + cam);
    ASSERT_EQ(again.exit_code, 0) << again.output;
    EXPECT_TRUE(read_text(a) == read_text(b)) << "the printed camera renders differently";
    EXPECT_EQ(printed_camera(again.output), "") << "an explicit camera is not re-printed";
  }
  // --orbit 0,0,4: eye 4 in front (+z) of the model's center, looking at it.
  {
    const CliResult r = run_cli(render + dir.file("o.png") + " --orbit 0,0,4");
    float e[3], t[3], u[3], fovy;
    ASSERT_EQ(std::sscanf(printed_camera(r.output).c_str(), "%f,%f,%f,%f,%f,%f,%f,%f,%f,%f", &e[0],
                          &e[1], &e[2], &t[0], &t[1], &t[2], &u[0], &u[1], &u[2], &fovy),
              10)
        << r.output;
    EXPECT_NEAR(e[0], t[0], 1e-5f);
    EXPECT_NEAR(e[1], t[1], 1e-5f);
    EXPECT_NEAR(e[2], t[2] + 4.f, 1e-5f);
    EXPECT_NEAR(u[1], 1.f, 1e-6f);
    EXPECT_EQ(fovy, 40.f);
  }
  // The orthographic renders of both casters agree with and without the beam.
  {
    const CliResult a = run_cli(render + dir.file("p.png") + " --ortho --depth " +
                                dir.file("p.pfm") + " --normals " + dir.file("pn.png"));
    const CliResult b = run_cli(render + dir.file("q.png") + " --ortho --beam 8 --depth " +
                                dir.file("q.pfm") + " --normals " + dir.file("qn.png"));
    ASSERT_EQ(a.exit_code, 0) << a.output;
    ASSERT_EQ(b.exit_code, 0) << b.output;
    EXPECT_TRUE(read_text(dir.file("p.png")) == read_text(dir.file("q.png")));
    EXPECT_TRUE(read_text(dir.file("p.pfm")) == read_text(dir.file("q.pfm")));
    EXPECT_TRUE(read_text(dir.file("pn.png")) == read_text(dir.file("qn.png")));
  }
  // Bad values and conflicting options are one-line errors.
  for (const char* bad :
       {"--orbit 1", "--orbit 0,95", "--orbit 0,0,-2", "--orbit a,b", "--look-at 1,2,3",
        "--look-at 0,0,0,0,5,0", "--ortho 0", "--ortho -1", "--ortho abc", "--ortho nan",
        "--camera auto --orbit 0,0", "--orbit 0,0 --look-at 1,2,3,0,0,0",
        "--camera ortho,0,0,5,0,0,0,0,1,0,0"})
    expect_one_line_error(run_cli(render + dir.file("x.png") + " " + bad));
  EXPECT_FALSE(std::filesystem::exists(dir.file("x.png")));
  // bench frames the same voxels exactly like render (one framing function).
  const CliResult bench =
      run_cli("bench " + dir.file("t.obj") + " --resolution 64 --size 64x48 --repeat 1 --beam 0");
  ASSERT_EQ(bench.exit_code, 0) << bench.output;
  const CliResult r = run_cli(render + dir.file("auto.png"));
  const std::string bench_camera = printed_camera(bench.output, "camera      ");
  EXPECT_FALSE(bench_camera.empty()) << bench.output;
  EXPECT_EQ(bench_camera, printed_camera(r.output));
}
