// The CLI as a user meets it: usage errors, bad input files, one-line errors,
// non-zero exits, no half-written outputs, and byte-identical builds whatever
// the thread count.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <string>
#include <thread>
#include <vector>

#include "support/cli_runner.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/dag_format.hpp"
#include "voxcast/scene_file.hpp"

extern char** environ;

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
  // A voxel size that leaves the mesh a 1^3 grid: too small an ESVO (a
  // 1^3 .vox is a valid voxel file, and a valid brickmap world).
  expect_one_line_error(
      run_cli("build " + dir.file("t.obj") + " -o " + dir.file("a.vxc") + " --voxel-size 1e30"),
      "needs at least 2^3");
  ASSERT_EQ(
      run_cli("convert " + dir.file("t.obj") + " " + dir.file("one.vox") + " --voxel-size 1e30")
          .exit_code,
      0);
  expect_one_line_error(run_cli("build " + dir.file("one.vox") + " -o " + dir.file("a.vxc")),
                        "needs at least 2^3");
  EXPECT_EQ(
      run_cli("build " + dir.file("one.vox") + " -o " + dir.file("one.vxc") + " --format brickmap")
          .exit_code,
      0);
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

  // --caster scalar traces one ray at a time instead of the default packets:
  // the same image and depth bytes.
  CliResult r3 = run_cli("render " + dir.file("t.vxc") + " -o " + dir.file("t3.png") +
                         " --size 64x48 --caster scalar --depth " + dir.file("d3.pfm"));
  ASSERT_EQ(r3.exit_code, 0) << r3.output;
  EXPECT_EQ(read_text(dir.file("t.png")), read_text(dir.file("t3.png")));
  EXPECT_EQ(read_text(dir.file("d.pfm")), read_text(dir.file("d3.pfm")));
  // --caster tile: each tile by one walk of the octree, the same bytes.
  CliResult r3t = run_cli("render " + dir.file("t.vxc") + " -o " + dir.file("t3t.png") +
                          " --size 64x48 --caster tile --depth " + dir.file("d3t.pfm"));
  ASSERT_EQ(r3t.exit_code, 0) << r3t.output;
  EXPECT_EQ(read_text(dir.file("t.png")), read_text(dir.file("t3t.png")));
  EXPECT_EQ(read_text(dir.file("d.pfm")), read_text(dir.file("d3t.pfm")));

  // -v adds the ray cast's process CPU time and Mrays per CPU second (the
  // figure that a shared machine does not distort); the image is unchanged.
  CliResult r4 = run_cli("render " + dir.file("t.vxc") + " -o " + dir.file("t4.png") +
                         " --size 64x48 --threads 1 -v");
  ASSERT_EQ(r4.exit_code, 0) << r4.output;
  EXPECT_EQ(read_text(dir.file("t.png")), read_text(dir.file("t4.png")));
  const auto cpu = r4.output.find("of which CPU");
  ASSERT_NE(cpu, std::string::npos) << r4.output;
  const auto per = r4.output.find(" Mrays per CPU second)", cpu);
  ASSERT_NE(per, std::string::npos) << r4.output;
  const double mrays = std::stod(r4.output.substr(r4.output.rfind('(', per) + 1));
  EXPECT_GT(mrays, 0.0) << r4.output;
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
  expect_one_line_error(run_cli("render " + scene + " -o " + dir.file("x.png") + " --caster simd"));
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

// ---------------------------------------------------------------------------
// Issue 15 items 4-7: outputs that cannot destroy data, inputs that cannot hang
// or slip through, resources, one error convention.

namespace {

using voxcast::testing::run_cli_split;

// Exactly one stderr line "voxcast: error: ..." and the given exit code; for
// usage errors nothing on stdout either (no help dump).
void expect_error(const CliResult& r, int exit_code, const std::string& needle = "") {
  EXPECT_EQ(r.exit_code, exit_code) << r.output << r.errors;
  EXPECT_EQ(r.errors.rfind("voxcast: error: ", 0), 0u) << r.errors;
  EXPECT_EQ(std::count(r.errors.begin(), r.errors.end(), '\n'), 1) << r.errors;
  if (!r.errors.empty()) {
    EXPECT_EQ(r.errors.back(), '\n') << r.errors;
  }
  if (exit_code == 2) {
    EXPECT_EQ(r.output, "") << "usage errors print nothing on stdout";
  }
  if (!needle.empty()) {
    EXPECT_NE(r.errors.find(needle), std::string::npos)
        << "expected '" << needle << "' in " << r.errors;
  }
}

// Valid UTF-8 (RFC 3629), checked byte by byte.
bool is_valid_utf8(const std::string& s) {
  for (size_t i = 0; i < s.size();) {
    const unsigned char c = static_cast<unsigned char>(s[i]);
    size_t n = c < 0x80             ? 1
               : (c & 0xE0) == 0xC0 ? 2
               : (c & 0xF0) == 0xE0 ? 3
               : (c & 0xF8) == 0xF0 ? 4
                                    : 0;
    if (n == 0 || i + n > s.size() || (n == 2 && c < 0xC2)) return false;
    for (size_t k = 1; k < n; ++k)
      if ((static_cast<unsigned char>(s[i + k]) & 0xC0) != 0x80) return false;
    i += n;
  }
  return true;
}

struct Scene {
  TempDir dir;
  std::string mesh, scene;
  Scene() {
    mesh = dir.file("t.obj");
    scene = dir.file("t.vxc");
    write_text(mesh, tetra_obj());
    EXPECT_EQ(run_cli("build " + mesh + " -o " + scene + " --resolution 16").exit_code, 0);
  }
};

std::vector<std::string> dir_entries(const std::string& path) {
  std::vector<std::string> names;
  for (auto& e : std::filesystem::directory_iterator(path))
    names.push_back(e.path().filename().string());
  std::sort(names.begin(), names.end());
  return names;
}

}  // namespace

TEST(CliConvention, UsageErrorsExitTwoWithOneLineAndNoHelpDump) {
  Scene s;
  const std::string b = "build " + s.mesh + " -o " + s.dir.file("a.vxc");
  const std::string r = "render " + s.scene + " -o " + s.dir.file("a.png");
  expect_error(run_cli_split(""), 2, "subcommand");
  expect_error(run_cli_split("frobnicate"), 2);
  expect_error(run_cli_split("build " + s.mesh), 2, "--output");
  expect_error(run_cli_split(b + " --no-such-option"), 2, "--no-such-option");
  expect_error(run_cli_split(b + " --resolution 3"), 2, "--resolution");
  expect_error(run_cli_split(b + " --resolution abc"), 2, "--resolution");
  expect_error(run_cli_split(b + " --format svo"), 2, "--format");
  expect_error(run_cli_split(b + " --voxelization sloppy"), 2, "--voxelization");
  expect_error(run_cli_split(b + " --attributes dxt"), 2, "--attributes");
  expect_error(run_cli_split(r + " --size 0x0"), 2, "--size");
  expect_error(run_cli_split(r + " --shadows soft"), 2, "--shadows");
  // An ESVO scene is not a damaged brickmap world: --stream does not apply.
  expect_error(run_cli_split(r + " --stream"), 2, "--stream: ");
  expect_error(run_cli_split("generate donut -o " + s.dir.file("x.obj")), 2, "donut");
  // --help is where the help text goes, on stdout, exit 0.
  CliResult help = run_cli_split("render --help");
  EXPECT_EQ(help.exit_code, 0);
  EXPECT_NE(help.output.find("--depth"), std::string::npos);
  EXPECT_EQ(help.errors, "");
  EXPECT_FALSE(std::filesystem::exists(s.dir.file("a.vxc")));
  EXPECT_FALSE(std::filesystem::exists(s.dir.file("a.png")));
}

TEST(CliConvention, RuntimeErrorsExitOneWithOneLine) {
  Scene s;
  expect_error(run_cli_split("build " + s.dir.file("missing.obj") + " -o " + s.dir.file("a.vxc")),
               1, "missing.obj");
  expect_error(run_cli_split("render " + s.dir.file("missing.vxc") + " -o " + s.dir.file("a.png")),
               1, "missing.vxc");
  expect_error(run_cli_split("info " + s.mesh), 1);  // a mesh is not a scene
  const std::string bytes = read_text(s.scene);
  write_text(s.dir.file("cut.vxc"), bytes.substr(0, bytes.size() / 2));
  expect_error(run_cli_split("info " + s.dir.file("cut.vxc")), 1);
  expect_error(run_cli_split("render " + s.dir.file("cut.vxc") + " -o " + s.dir.file("a.png")), 1);
}

// Every numeric option of every subcommand refuses non-finite and
// out-of-range values as a usage error, before reading any file (the
// meshes and scenes named here do not exist: exit 1 would mean the value
// slipped through to the file stage).
TEST(CliConvention, EveryNumericOptionIsRangeChecked) {
  TempDir dir;
  const std::string b = "build " + dir.file("none.obj") + " -o " + dir.file("a.vxc");
  const std::string bc = b + " --contours";
  const std::string r = "render " + dir.file("none.vxc") + " -o " + dir.file("a.png");
  const std::string bench = "bench " + dir.file("none.obj");
  const std::string g = "generate ";
  const std::string o = " -o " + dir.file("g.obj");
  // Twice the machine's physical memory: never a useful budget.
  uint64_t total_kib = 0;
  {
    std::string meminfo = read_text("/proc/meminfo");
    std::sscanf(meminfo.c_str() + meminfo.find("MemTotal:") + 9, "%llu",
                reinterpret_cast<unsigned long long*>(&total_kib));
  }
  ASSERT_GT(total_kib, 0u);
  const std::string twice_memory = std::to_string(2 * total_kib) + "K";
  struct Case {
    std::string args, option;
  };
  const std::vector<Case> cases = {
      {b + " --resolution 0", "--resolution"},
      {b + " --resolution 3", "--resolution"},
      {b + " --resolution 2097152", "--resolution"},
      {b + " --resolution 1", "--resolution: esvo"},  // (a brickmap of 1^3 is valid)
      {b + " --format dag --resolution 2", "--resolution: dag"},
      {b + " --slices --slice-size 0", "--slice-size: "},
      {b + " --voxel-size nan", "--voxel-size"},
      {b + " --voxel-size inf", "--voxel-size"},
      {b + " --voxel-size -1", "--voxel-size"},
      {b + " --voxel-size 0", "--voxel-size"},
      {b + " --threads -1", "--threads"},
      {b + " --memory-budget nan", "--memory-budget"},
      {b + " --memory-budget 0", "--memory-budget"},
      {b + " --memory-budget " + twice_memory, "--memory-budget"},
      {b + " --format dag --cell-size 100", "--cell-size"},
      {b + " --format dag --cell-size 2", "--cell-size"},
      {bc + " --max-level -1", "--max-level"},
      {bc + " --max-level 21", "--max-level"},
      {bc + " --geometry-error nan", "--geometry-error"},
      {bc + " --geometry-error 0", "--geometry-error"},
      {bc + " --color-error 256", "--color-error"},
      {bc + " --color-error nan", "--color-error"},
      {bc + " --normal-error inf", "--normal-error"},
      {r + " --size 0x10", "--size"},
      {r + " --size 16385x10", "--size"},
      {r + " --size nanxnan", "--size"},
      // Values past 2^32 are refused, not wrapped (4294967360 = 2^32 + 64).
      {r + " --size 4294967360x4294967344", "--size"},
      {r + " --size 4294967297x1", "--size"},
      {r + " --size 640x480x", "--size"},
      {r + " --size +640x480", "--size"},
      {"volume render procedural:cloud -o " + dir.file("v.png") + " --size 4294967360x48",
       "--size"},
      {g + "sky --sky-size 4294967304x4 -o " + dir.file("g.hdr"), "--sky-size: "},
      {g + "terrain --size 4294967312x16x16 -o " + dir.file("g.vxc"), "--size"},
      {g + "terrain --size 4294967298" + o, "--size"},
      {r + " --lod nan", "--lod"},
      {r + " --lod -1", "--lod"},
      {r + " --lod inf", "--lod"},
      {r + " --beam 1", "--beam"},
      {r + " --beam 65", "--beam"},
      {r + " --heatmap-max nan", "--heatmap-max"},
      {r + " --heatmap-max 0", "--heatmap-max"},
      {r + " --light nan,0,0", "--light"},
      {r + " --light 0,0,0", "--light"},
      {r + " --light 1e38,1e38,1e38", "--light"},
      {r + " --point-light 1,inf,0", "--point-light"},
      {r + " --area-light 0,0,0,1,0,0,nan,1,0", "--area-light"},
      {r + " --area-light 0,0,0,1,0,0,2,0,0", "--area-light"},
      {r + " --shadow-rays 0", "--shadow-rays"},
      {r + " --shadow-rays 5000", "--shadow-rays"},
      {r + " --ao -1", "--ao"},
      {r + " --ao 5000", "--ao"},
      {r + " --ao 4 --ao-radius nan", "--ao-radius"},
      {r + " --ao 4 --ao-radius -1", "--ao-radius"},
      {r + " --ao 4 --ao-cone-angle nan", "--ao-cone-angle"},
      {r + " --ao 4 --ao-cone-angle 90", "--ao-cone-angle"},
      {r + " --seed -1", "--seed"},
      {r + " --threads -2", "--threads"},
      {r + " --camera 0,0,5,0,0,0,0,1,0,nan", "--camera"},
      {r + " --camera 0,0,5,0,0,0,0,1,0,180", "--camera"},
      {r + " --camera inf,0,5,0,0,0,0,1,0,45", "--camera"},
      {r + " --camera 1e38,0,0,0,0,0,0,1,0,40", "--camera: eye and target too far apart"},
      {r + " --memory-budget " + twice_memory, "--memory-budget"},
      {bench + " --resolution 3", "--resolution"},
      {bench + " --size 0x0", "--size"},
      {bench + " --size 4294967328x24", "--size"},
      {bench + " --lod nan", "--lod"},
      {bench + " --repeat 0", "--repeat"},
      {bench + " --beam 3", "--beam"},
      {bench + " --min-coverage nan", "--min-coverage"},
      {bench + " --min-coverage 1", "--min-coverage"},
      {bench + " --ao-rays 0", "--ao-rays"},
      {bench + " --ao-radius inf", "--ao-radius"},
      {bench + " --camera 1,2,3", "--camera"},
      {g + "menger --level 9" + o, "level"},
      {g + "menger --level -1" + o, "level"},
      {g + "hairball --tubes 0" + o, "tubes"},
      {g + "hairball --segments 0" + o, "segments"},
      {g + "hairball --sides 2" + o, "sides"},
      {g + "hairball --radius nan" + o, "radius"},
      {g + "hairball --step inf" + o, "step"},
      {g + "hairball --seed -1" + o, "--seed"},
      {g + "terrain --size 1" + o, "size"},
      {g + "terrain --octaves 17" + o, "octaves"},
      {g + "terrain --height nan" + o, "height"},
      // Later subcommands: the option each names is the one given.
      {r + " --stream --budget 1x", "--budget: "},
      {r + " --stream --frames 0", "--frames"},
      {r + " --stream --uploads 0", "--uploads"},
      {"edit " + dir.file("none.vxc") + " --snow 0", "--snow: "},
      {"edit " + dir.file("none.vxc") + " --snow 2 --snow-rate nan", "--snow-rate"},
      {"edit " + dir.file("none.vxc") + " --sphere 0,0,0,inf --add", "--sphere"},
      {"volume render procedural:cloud -o " + dir.file("v.png") + " --budget 1x", "--budget: "},
      {"volume export procedural:cloud -o " + dir.file("v.vdb") + " --resolution 0",
       "--resolution"},
      {"volume render procedural:cloud -o " + dir.file("v.png") + " --transfer 0.5:1:nan,1,1",
       "--transfer: "},
      {"volume render procedural:cloud -o " + dir.file("v.png") + " --transfer 0.5:1:1,-1,1",
       "--transfer: "},
      {"volume render procedural:cloud -o " + dir.file("v.png") + " --background=-5,0,0",
       "--background: "},
      {g + "terrain --persistence 2" + o, "persistence"},
      {g + "menger --memory-budget " + twice_memory + o, "--memory-budget"},
      // A .vxc terrain's shape has no octaves, height or persistence.
      {g + "terrain --size 16x16x16 --height 0.5 -o " + dir.file("g.vxc"), "--height"},
      {g + "terrain --size 16x16x16 --octaves 3 -o " + dir.file("g.vxc"), "--octaves"},
      {g + "terrain --size 16x16x16 --persistence 0.5 -o " + dir.file("g.vxc"), "--persistence"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.args);
    expect_error(run_cli_split(c.args), 2, c.option);
  }
  EXPECT_TRUE(dir_entries(dir.path).empty());
}

TEST(CliOutputs, ExtensionMustMatchTheFormat) {
  Scene s;
  expect_error(run_cli_split("build " + s.mesh + " -o " + s.dir.file("out.png")), 2, ".vxc");
  expect_error(run_cli_split("render " + s.scene + " -o " + s.dir.file("out.vxc")), 2, ".png");
  expect_error(run_cli_split("render " + s.scene + " -o " + s.dir.file("a.png") + " --depth " +
                             s.dir.file("d.png")),
               2, "--depth");
  expect_error(run_cli_split("render " + s.scene + " -o " + s.dir.file("a.png") + " --heatmap " +
                             s.dir.file("h.pfm")),
               2, "--heatmap");
  expect_error(run_cli_split("generate menger -o " + s.dir.file("m.vxc")), 2, ".obj");
  EXPECT_EQ(dir_entries(s.dir.path), (std::vector<std::string>{"t.obj", "t.vxc"}));
}

TEST(CliOutputs, AnOutputThatIsAnInputIsRefused) {
  Scene s;
  const std::string scene_bytes = read_text(s.scene), mesh_bytes = read_text(s.mesh);
  namespace fs = std::filesystem;
  // The same file under another name: a hard link, a symlink, a "./" path.
  fs::create_hard_link(s.scene, s.dir.file("hard.png"));
  fs::create_symlink("t.vxc", s.dir.file("soft.png"));
  fs::create_hard_link(s.mesh, s.dir.file("mesh.vxc"));
  expect_error(run_cli_split("render " + s.scene + " -o " + s.dir.file("hard.png")), 2,
               "same file as the input");
  expect_error(run_cli_split("render " + s.scene + " -o " + s.dir.file("soft.png")), 2,
               "same file as the input");
  expect_error(run_cli_split("build " + s.mesh + " -o " + s.dir.path + "/./mesh.vxc"), 2,
               "same file as the input");
  EXPECT_EQ(read_text(s.scene), scene_bytes);
  EXPECT_EQ(read_text(s.mesh), mesh_bytes);
}

TEST(CliOutputs, TwoOutputsOnOnePathAreRefused) {
  Scene s;
  const std::string r = "render " + s.scene + " --size 16x16 -o " + s.dir.file("a.png");
  expect_error(run_cli_split(r + " --normals " + s.dir.path + "/./a.png"), 2, "same file");
  expect_error(run_cli_split(r + " --heatmap " + s.dir.file("a.png")), 2, "same file");
  std::filesystem::create_symlink("a.png", s.dir.file("b.png"));
  expect_error(run_cli_split(r + " --ao 1 --ao-output " + s.dir.file("b.png")), 2, "same file");
  write_text(s.dir.file("c.pfm"), "old");
  std::filesystem::create_hard_link(s.dir.file("c.pfm"), s.dir.file("d.pfm"));
  expect_error(run_cli_split(r + " --depth " + s.dir.file("c.pfm") + " --ao 1 --ao-output " +
                             s.dir.file("d.pfm")),
               2, "same file");
  EXPECT_FALSE(std::filesystem::exists(s.dir.file("a.png")));
  EXPECT_EQ(read_text(s.dir.file("c.pfm")), "old");
}

TEST(CliOutputs, NonRegularOutputsAreRefused) {
  Scene s;
  namespace fs = std::filesystem;
  fs::create_directory(s.dir.file("dir.png"));
  ASSERT_EQ(mkfifo(s.dir.file("fifo.png").c_str(), 0600), 0);
  fs::create_symlink("/dev/null", s.dir.file("null.png"));
  const std::string r = "render " + s.scene + " --size 16x16 -o ";
  // A FIFO would block the writer until a reader appears: the timeout turns a
  // hang into a failure.
  expect_error(run_cli_split(r + s.dir.file("dir.png"), 20), 2, "directory");
  expect_error(run_cli_split(r + s.dir.file("fifo.png"), 20), 2, "FIFO");
  expect_error(run_cli_split(r + s.dir.file("null.png"), 20), 2, "device");
  expect_error(run_cli_split("build " + s.mesh + " -o " + s.dir.file("nodir/x.vxc")), 2,
               "does not exist");
  EXPECT_TRUE(fs::is_symlink(s.dir.file("null.png")));
  EXPECT_TRUE(fs::is_fifo(s.dir.file("fifo.png")));
  EXPECT_TRUE(fs::is_directory(s.dir.file("dir.png")));
}

TEST(CliOutputs, SymlinksAreWrittenThroughToTheirTarget) {
  Scene s;
  namespace fs = std::filesystem;
  fs::create_directory(s.dir.file("real"));
  fs::create_symlink("real/new.png", s.dir.file("new.png"));  // target does not exist yet
  write_text(s.dir.file("real/old.pfm"), "old");
  fs::create_symlink(s.dir.file("real/old.pfm"), s.dir.file("old.pfm"));
  CliResult r = run_cli_split("render " + s.scene + " --size 16x12 -o " + s.dir.file("new.png") +
                              " --depth " + s.dir.file("old.pfm"));
  ASSERT_EQ(r.exit_code, 0) << r.errors;
  EXPECT_TRUE(fs::is_symlink(s.dir.file("new.png")));
  EXPECT_TRUE(fs::is_symlink(s.dir.file("old.pfm")));
  EXPECT_EQ(read_text(s.dir.file("real/new.png")).substr(1, 3), "PNG");
  EXPECT_EQ(read_text(s.dir.file("real/old.pfm")).substr(0, 2), "Pf");
  // Nothing but the two written targets appeared (no staged leftovers).
  EXPECT_EQ(dir_entries(s.dir.file("real")), (std::vector<std::string>{"new.png", "old.pfm"}));
}

// A render with five outputs whose last write fails (a name one over the file
// system's limit once staged) leaves every output as it was, old contents and
// absences alike, and no temporary behind.
TEST(CliOutputs, SeveralOutputsAreWrittenAllOrNone) {
  Scene s;
  write_text(s.dir.file("a.png"), "old a");
  write_text(s.dir.file("d.pfm"), "old d");
  const std::string long_name = std::string(240, 'h') + ".png";  // fits NAME_MAX, its stage not
  const std::string base = "render " + s.scene + " --size 16x12 --ao 1 -o " + s.dir.file("a.png") +
                           " --depth " + s.dir.file("d.pfm") + " --normals " + s.dir.file("n.png") +
                           " --ao-output " + s.dir.file("o.pfm") + " --heatmap ";
  const std::vector<std::string> before = dir_entries(s.dir.path);
  CliResult bad = run_cli_split(base + s.dir.file(long_name));
  expect_error(bad, 1, "cannot write");
  EXPECT_EQ(dir_entries(s.dir.path), before);
  EXPECT_EQ(read_text(s.dir.file("a.png")), "old a");
  EXPECT_EQ(read_text(s.dir.file("d.pfm")), "old d");
  // The same command with a writable heat map name writes all five.
  CliResult ok = run_cli_split(base + s.dir.file("h.png"));
  ASSERT_EQ(ok.exit_code, 0) << ok.errors;
  for (const char* f : {"a.png", "n.png", "h.png"})
    EXPECT_EQ(read_text(s.dir.file(f)).substr(1, 3), "PNG") << f;
  for (const char* f : {"d.pfm", "o.pfm"}) EXPECT_EQ(read_text(s.dir.file(f))[0], 'P') << f;
  EXPECT_EQ(dir_entries(s.dir.path).size(), before.size() + 3);
}

// The output rules above hold for the subcommands that came later:
// `generate terrain`, `edit` (-o and --snow --render), `volume export` and
// `render --write-frames`. Each refusal is a usage error before any work and
// leaves every file as it was.
TEST(CliOutputs, LaterSubcommandsKeepTheOutputRules) {
  Scene s;
  namespace fs = std::filesystem;
  const std::string world = s.dir.file("w.vxc");
  ASSERT_EQ(run_cli("generate terrain --size 32x16x32 -o " + world).exit_code, 0);
  const std::string world_bytes = read_text(world);
  fs::create_directory(s.dir.file("dir.vxc"));
  ASSERT_EQ(mkfifo(s.dir.file("fifo.vxc").c_str(), 0600), 0);
  ASSERT_EQ(mkfifo(s.dir.file("fifo.vdb").c_str(), 0600), 0);
  fs::create_symlink("/dev/null", s.dir.file("null.vxc"));
  fs::create_hard_link(world, s.dir.file("hard.vxc"));
  const std::string terrain = "generate terrain --size 32x16x32 -o ";
  expect_error(run_cli_split(terrain + s.dir.file("fifo.vxc"), 20), 2, "FIFO");
  expect_error(run_cli_split(terrain + s.dir.file("dir.vxc"), 20), 2, "directory");
  expect_error(run_cli_split(terrain + s.dir.file("null.vxc"), 20), 2, "device");
  expect_error(run_cli_split(terrain + s.dir.file("t.png")), 2, "vertex count");
  const std::string edit = "edit " + world + " --sphere 0,0,0,0.2 --add -o ";
  expect_error(run_cli_split(edit + s.dir.file("hard.vxc")), 2, "same file as the input");
  expect_error(run_cli_split(edit + s.dir.file("fifo.vxc"), 20), 2, "FIFO");
  expect_error(run_cli_split(edit + s.dir.file("e.png")), 2, ".vxc");
  // -o and --render on one file (through a symlink): refused, nothing written.
  fs::create_symlink("e.vxc", s.dir.file("frame.png"));
  expect_error(run_cli_split("edit " + world + " --snow 2 --render " + s.dir.file("frame.png") +
                             " -o " + s.dir.file("e.vxc")),
               2, "same file");
  EXPECT_FALSE(fs::exists(s.dir.file("e.vxc")));
  expect_error(run_cli_split("edit " + world + " --snow 2 --render " + s.dir.file("hard.vxc")), 2,
               ".png");
  const std::string vdb = s.dir.file("v.vdb");
  ASSERT_EQ(run_cli("volume export procedural:cloud --resolution 16 -o " + vdb).exit_code, 0);
  fs::create_hard_link(vdb, s.dir.file("v2.vdb"));
  expect_error(
      run_cli_split("volume export " + vdb + " --resolution 16 -o " + s.dir.file("v2.vdb")), 2,
      "same file as the input");
  expect_error(
      run_cli_split("volume export procedural:cloud --resolution 16 -o " + s.dir.file("fifo.vdb"),
                    20),
      2, "FIFO");
  expect_error(run_cli_split("volume export procedural:cloud -o " + s.dir.file("v.png")), 2,
               ".vdb");
  // --write-frames: every numbered frame is an output like -o.
  const std::string slices = s.dir.file("s.vxs");
  ASSERT_EQ(run_cli("build " + s.mesh + " -o " + slices + " --resolution 16 --slices").exit_code,
            0);
  const std::string frames =
      "render " + slices + " --frames 3 --budget 1M --size 8x8 --write-frames";
  ASSERT_EQ(mkfifo(s.dir.file("f-001.png").c_str(), 0600), 0);
  expect_error(run_cli_split(frames + " -o " + s.dir.file("f.png"), 20), 2, "FIFO");
  fs::create_symlink("s.vxs", s.dir.file("g-002.png"));
  expect_error(run_cli_split(frames + " -o " + s.dir.file("g.png")), 2, "same file as the input");
  for (const char* f : {"f.png", "f-000.png", "f-002.png", "g.png", "g-000.png", "g-001.png"})
    EXPECT_FALSE(fs::exists(s.dir.file(f))) << f;
  EXPECT_EQ(read_text(world), world_bytes);
  EXPECT_FALSE(fs::exists(world + ".journal"));
}

// A brickmap world's edit journal (brickmap_file.hpp) is read by every
// subcommand that opens the world; one that is a FIFO, a device or a
// directory is refused in one line instead of blocking the reader (a FIFO)
// or never ending (/dev/zero).
TEST(CliInputs, NonRegularEditJournalsAreRefusedNotHung) {
  Scene s;
  namespace fs = std::filesystem;
  const std::string world = s.dir.file("w.vxc"), journal = world + ".journal";
  ASSERT_EQ(run_cli("generate terrain --size 32x16x32 -o " + world).exit_code, 0);
  for (const std::string kind : {"FIFO", "device", "directory"}) {
    SCOPED_TRACE(kind);
    fs::remove(journal);
    if (kind == "FIFO") {
      ASSERT_EQ(mkfifo(journal.c_str(), 0600), 0);
    }
    if (kind == "device") fs::create_symlink("/dev/zero", journal);
    if (kind == "directory") fs::create_directory(journal);
    expect_error(run_cli_split("info " + world, 20), 1, kind);
    expect_error(run_cli_split("render " + world + " --size 8x8 -o " + s.dir.file("a.png"), 20), 1,
                 kind);
    expect_error(
        run_cli_split("render " + world + " --stream --size 8x8 -o " + s.dir.file("a.png"), 20), 1,
        kind);
    expect_error(run_cli_split("edit " + world + " --sphere 0,0,0,0.2 --add", 20), 1, kind);
  }
  EXPECT_FALSE(fs::exists(s.dir.file("a.png")));
}

// The edit journal is bound to the exact world file it was written against
// (brickmap_file.hpp): another world of the same grid size copied over the
// file leaves a journal that every reader refuses in one line, leaving
// both files as they are; the same bytes copied keep replaying it; a world
// written whole over the file (generate terrain -o, build -o) removes it.
TEST(CliInputs, AnEditJournalOfAnotherVersionOfTheWorldIsRefusedNotReplayed) {
  Scene s;
  namespace fs = std::filesystem;
  const std::string a = s.dir.file("a.vxc"), b = s.dir.file("b.vxc"), w = s.dir.file("w.vxc"),
                    c = s.dir.file("c.vxc");
  const std::string terrain = "generate terrain --size 32x16x32 --seed ";
  ASSERT_EQ(run_cli(terrain + "1 -o " + a).exit_code, 0);
  ASSERT_EQ(run_cli(terrain + "2 -o " + b).exit_code, 0);
  ASSERT_NE(read_text(a), read_text(b));
  ASSERT_EQ(run_cli("edit " + a + " --sphere 0,0,0,0.3 --add").exit_code, 0);
  ASSERT_TRUE(fs::exists(a + ".journal"));
  fs::copy_file(b, w);
  fs::copy_file(a + ".journal", w + ".journal");
  const std::string world_bytes = read_text(w), journal_bytes = read_text(w + ".journal");
  const std::string message = "journal '" + w + ".journal' belongs to another version of the world";
  expect_error(run_cli_split("info " + w), 1, message);
  expect_error(run_cli_split("info " + w), 1, "remove the journal");
  expect_error(run_cli_split("render " + w + " --size 8x8 -o " + s.dir.file("x.png")), 1, message);
  expect_error(run_cli_split("render " + w + " --stream --size 8x8 -o " + s.dir.file("x.png")), 1,
               message);
  expect_error(run_cli_split("edit " + w + " --sphere 0,0,0,0.2 --add"), 1, message);
  expect_error(run_cli_split("edit " + w + " --snow 1 --checkpoint"), 1, message);
  EXPECT_FALSE(fs::exists(s.dir.file("x.png")));
  EXPECT_EQ(read_text(w), world_bytes);
  EXPECT_EQ(read_text(w + ".journal"), journal_bytes);
  EXPECT_EQ(read_text(b), world_bytes);
  // The same bytes under another name: its journal replays.
  fs::copy_file(a, c);
  fs::copy_file(a + ".journal", c + ".journal");
  ASSERT_EQ(run_cli("render " + a + " --size 16x16 -o " + s.dir.file("a.png")).exit_code, 0);
  ASSERT_EQ(run_cli("render " + c + " --size 16x16 -o " + s.dir.file("c.png")).exit_code, 0);
  EXPECT_EQ(read_text(s.dir.file("a.png")), read_text(s.dir.file("c.png")));
  fs::remove(c + ".journal");
  ASSERT_EQ(run_cli("render " + c + " --size 16x16 -o " + s.dir.file("c.png")).exit_code, 0);
  EXPECT_NE(read_text(s.dir.file("a.png")), read_text(s.dir.file("c.png")))
      << "the edit changes the image";
  // Written whole over the file: the stale journal goes with the old world.
  ASSERT_EQ(run_cli(terrain + "3 -o " + w).exit_code, 0);
  EXPECT_FALSE(fs::exists(w + ".journal"));
  EXPECT_EQ(run_cli("info " + w).exit_code, 0);
  fs::copy_file(a + ".journal", w + ".journal");
  ASSERT_EQ(
      run_cli("build " + s.mesh + " -o " + w + " --resolution 32 --format brickmap").exit_code, 0);
  EXPECT_FALSE(fs::exists(w + ".journal"));
  EXPECT_EQ(run_cli("info " + w).exit_code, 0);
  // And edit --checkpoint folds the journal in: the file replaced, no journal.
  ASSERT_EQ(run_cli("edit " + a + " --snow 1 --checkpoint").exit_code, 0);
  EXPECT_FALSE(fs::exists(a + ".journal"));
  EXPECT_FALSE(fs::exists(a + ".checkpoint"));
  EXPECT_EQ(run_cli("info " + a).exit_code, 0);
}

TEST(CliInputs, NonRegularInputsAreRefusedNotHung) {
  Scene s;
  ASSERT_EQ(mkfifo(s.dir.file("fifo.vxc").c_str(), 0600), 0);
  ASSERT_EQ(mkfifo(s.dir.file("fifo.obj").c_str(), 0600), 0);
  // Opening a FIFO for reading blocks until a writer appears.
  expect_error(run_cli_split("info " + s.dir.file("fifo.vxc"), 20), 1, "FIFO");
  expect_error(run_cli_split("render " + s.dir.file("fifo.vxc") + " -o " + s.dir.file("a.png"), 20),
               1, "FIFO");
  expect_error(run_cli_split("build " + s.dir.file("fifo.obj") + " -o " + s.dir.file("a.vxc"), 20),
               1, "FIFO");
  expect_error(run_cli_split("bench " + s.dir.file("fifo.obj"), 20), 1, "FIFO");
  expect_error(run_cli_split("info " + s.dir.path, 20), 1, "directory");
  expect_error(run_cli_split("info /dev/zero", 20), 1, "device");
}

TEST(CliInputs, MessagesArePrintableUtf8WithoutJsonJargon) {
  Scene s;
  // A file name with an invalid UTF-8 byte is shown escaped.
  const std::string bad_name = s.dir.file("bad\xff.obj");
  CliResult r = run_cli_split("build '" + bad_name + "' -o " + s.dir.file("a.vxc"));
  expect_error(r, 1, "bad\\xFF.obj");
  EXPECT_TRUE(is_valid_utf8(r.errors)) << r.errors;
  // ... also by info, text and JSON (which must stay parseable).
  std::filesystem::copy_file(s.scene, s.dir.file("sc\xfe.vxc"));
  CliResult info = run_cli_split("info '" + s.dir.file("sc\xfe.vxc") + "'");
  ASSERT_EQ(info.exit_code, 0) << info.errors;
  EXPECT_TRUE(is_valid_utf8(info.output));
  CliResult json = run_cli_split("info --json '" + s.dir.file("sc\xfe.vxc") + "'");
  ASSERT_EQ(json.exit_code, 0) << json.errors;
  EXPECT_TRUE(is_valid_utf8(json.output));
  EXPECT_NE(json.output.find("\"file\""), std::string::npos) << json.output;
  // A scene whose META section is not JSON, behind a valid checksum: no
  // "[json.exception.parse_error.101]" in the message.
  voxcast::Container c;
  const std::string not_json = "{\"format\": \"esvo\", \xff";
  c.add(voxcast::fourcc("META"), std::vector<uint8_t>(not_json.begin(), not_json.end()));
  c.add(voxcast::fourcc("ESVO"), std::vector<uint8_t>(8192, 0));
  c.write(s.dir.file("meta.vxc"));
  for (const std::string cmd : {"info ", "render "}) {
    CliResult m = run_cli_split(cmd + s.dir.file("meta.vxc") +
                                (cmd == "render " ? " -o " + s.dir.file("m.png") : ""));
    expect_error(m, 1);
    EXPECT_EQ(m.errors.find("json.exception"), std::string::npos) << m.errors;
    EXPECT_EQ(m.errors.find("last read"), std::string::npos) << m.errors;
    EXPECT_NE(m.errors.find("line 1, column"), std::string::npos) << m.errors;
    EXPECT_TRUE(is_valid_utf8(m.errors)) << m.errors;
  }
}

TEST(CliResources, MemoryBudgetsAreCheckedBeforeAllocating) {
  Scene s;
  // A render whose buffers exceed the budget is refused before the scene is read.
  expect_error(run_cli_split("render " + s.scene + " -o " + s.dir.file("a.png") +
                             " --size 4096x4096 --memory-budget 1M"),
               1, "memory budget");
  // A mesh file larger than the budget is not even imported.
  std::string big = tetra_obj();
  while (big.size() < 64 * 1024) big += "# padding to make the file larger than the budget\n";
  write_text(s.dir.file("big.obj"), big);
  // (--resolution 2: the voxel estimate alone would fit.)
  expect_error(run_cli_split("build " + s.dir.file("big.obj") + " -o " + s.dir.file("a.vxc") +
                             " --resolution 2 --memory-budget 32K"),
               1, "memory budget");
  // A generated mesh or world too large for the budget is refused before it
  // is built (menger level 5: 13 M triangles; a 1024^2 x 64 brickmap
  // terrain: its brickgrid header and the chunk columns in flight).
  const std::pair<std::string, std::string> generated[] = {
      {"t.ply", "terrain --size 1024 --memory-budget 1M"},
      {"h.obj", "hairball --tubes 100000 --memory-budget 10M"},
      {"m.obj", "menger --level 5 --memory-budget 64M"},
      {"terrain.vxc", "terrain --size 1024x1024x64 --memory-budget 1M"},
  };
  for (const auto& [file, args] : generated) {
    expect_error(run_cli_split("generate " + args + " -o " + s.dir.file(file)), 1, "memory budget");
    EXPECT_FALSE(std::filesystem::exists(s.dir.file(file))) << file;
  }
  EXPECT_FALSE(std::filesystem::exists(s.dir.file("a.png")));
  EXPECT_FALSE(std::filesystem::exists(s.dir.file("a.vxc")));
}

// The build estimate (printed when it exceeds the budget) depends on the
// triangles' shape, not on where the mesh lies: a tetrahedron with 1024-unit
// edges at the origin and 2^24 away (coordinates exact in float) gets the
// same estimate up to the grid's growth by the far origin's float rounding.
TEST(CliResources, MemoryEstimateIsTheSameFarFromTheOrigin) {
  TempDir dir;
  auto estimate_mib = [&](double o) {
    const double e = 1024;
    char obj[512];
    std::snprintf(obj, sizeof obj,
                  "v %.1f %.1f %.1f\nv %.1f %.1f %.1f\nv %.1f %.1f %.1f\nv %.1f %.1f %.1f\n"
                  "f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n",
                  o, o, o, o + e, o, o, o, o + e, o, o, o, o + e);
    write_text(dir.file("m.obj"), obj);
    CliResult r = run_cli_split("build " + dir.file("m.obj") + " -o " + dir.file("m.vxc") +
                                " --resolution 512 --memory-budget 1K");
    EXPECT_EQ(r.exit_code, 1) << r.errors;
    const size_t at = r.errors.find("needs an estimated ");
    EXPECT_NE(at, std::string::npos) << r.errors;
    double mib = 0;
    char unit[8] = {};
    if (at != std::string::npos)
      std::sscanf(r.errors.c_str() + at, "needs an estimated %lf %3s", &mib, unit);
    EXPECT_STREQ(unit, "MiB") << r.errors;
    return mib;
  };
  const double near = estimate_mib(0), far = estimate_mib(16777216.0);
  EXPECT_GT(near, 1.0);
  EXPECT_NEAR(far / near, 1.0, 0.02) << near << " MiB vs " << far << " MiB";
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

// ------------------------------------------------------------ issue 15 hardening, remainder

namespace {

// A PNG whose header claims w x h RGBA texels and whose data holds almost
// nothing: decoding it would allocate w * h * 4 bytes before finding out.
std::string png_claiming(uint32_t w, uint32_t h) {
  auto be32 = [](uint32_t v) {
    return std::string{char(v >> 24), char(v >> 16), char(v >> 8), char(v)};
  };
  auto crc32 = [](const std::string& bytes) {  // PNG's CRC (ISO 3309), bit by bit
    uint32_t c = 0xFFFFFFFFu;
    for (unsigned char b : bytes) {
      c ^= b;
      for (int k = 0; k < 8; ++k) c = (c >> 1) ^ (0xEDB88320u & (0u - (c & 1u)));
    }
    return ~c;
  };
  auto chunk = [&](const std::string& type, const std::string& data) {
    const std::string td = type + data;
    return be32(uint32_t(data.size())) + td + be32(crc32(td));
  };
  const std::string ihdr = be32(w) + be32(h) + std::string{8, 6, 0, 0, 0};    // 8-bit RGBA
  const std::string idat = {0x78, 0x01, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01};  // empty zlib stream
  return std::string("\x89PNG\r\n\x1a\n", 8) + chunk("IHDR", ihdr) + chunk("IDAT", idat) +
         chunk("IEND", "");
}

// A tetrahedron whose material has the base-color texture `texture`.
void write_textured_tetra(const TempDir& dir, const std::string& texture) {
  write_text(dir.file("t.mtl"), "newmtl m\nKd 1 1 1\nmap_Kd " + texture + "\n");
  write_text(dir.file("t.obj"),
             "mtllib t.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nvt 0 0\nvt 1 0\nvt 0 1\n"
             "usemtl m\nf 1/1 3/3 2/2\nf 1/1 2/2 4/3\nf 1/1 4/3 3/3\nf 2/2 3/3 4/3\n");
}

#if defined(__SANITIZE_ADDRESS__)
constexpr bool kAddressSanitizer = true;
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
constexpr bool kAddressSanitizer = true;
#else
constexpr bool kAddressSanitizer = false;
#endif
#else
constexpr bool kAddressSanitizer = false;
#endif

// "needs an estimated 1.23 MiB" -> bytes (0 if absent).
double printed_estimate(const std::string& text, const char* lead) {
  const size_t at = text.find(lead);
  if (at == std::string::npos) return 0;
  double v = 0;
  char unit[8] = {};
  if (std::sscanf(text.c_str() + at + std::strlen(lead), "%lf %3[A-Za-z]", &v, unit) != 2) return 0;
  const std::string u = unit;
  const double scale = u == "B"     ? 1
                       : u == "KiB" ? 1024.0
                       : u == "MiB" ? 1048576.0
                       : u == "GiB" ? 1073741824.0
                                    : 0;
  return v * scale;
}

}  // namespace

// Issue 15, item 1: a texture is checked against the memory budget from its
// header, before it is decoded. 16384^2 texels (the 2^28 cap, so allowed on
// their own) are 1 GiB of RGBA: with a 256 MiB budget `build` refuses it in
// one line naming the texture; without a budget the 15-byte IDAT fails to
// decode and the model only loses its texture (a warning).
TEST(CliResources, TextureDecodeIsCheckedAgainstTheBudget) {
  TempDir dir;
  write_text(dir.file("huge.png"), png_claiming(16384, 16384));
  write_textured_tetra(dir, "huge.png");
  const std::string build =
      "build " + dir.file("t.obj") + " -o " + dir.file("t.vxc") + " --resolution 16";
  const CliResult refused = run_cli_split(build + " --memory-budget 256M");
  expect_error(refused, 1, "memory budget");
  EXPECT_NE(refused.errors.find("huge.png"), std::string::npos) << refused.errors;
  EXPECT_NE(refused.errors.find("16384x16384"), std::string::npos) << refused.errors;
  EXPECT_FALSE(std::filesystem::exists(dir.file("t.vxc")));
  const CliResult lenient = run_cli_split(build + " --memory-budget 8G");
  if (lenient.exit_code == 2) {  // a machine with less than 8 GiB: no budget at all
    const CliResult no_budget = run_cli_split(build);
    EXPECT_EQ(no_budget.exit_code, 0) << no_budget.errors;
    EXPECT_NE(no_budget.errors.find("using the base color"), std::string::npos);
  } else {
    EXPECT_EQ(lenient.exit_code, 0) << lenient.errors;
    EXPECT_NE(lenient.errors.find("using the base color"), std::string::npos) << lenient.errors;
  }
  // A real 64 x 64 texture fits a small budget.
  write_text(dir.file("small.png"), png_claiming(64, 64));
  write_textured_tetra(dir, "small.png");
  const CliResult small = run_cli_split(build + " --memory-budget 4M");
  EXPECT_EQ(small.exit_code, 0) << small.errors;
  EXPECT_EQ(small.errors.find("memory budget"), std::string::npos) << small.errors;
}

// Issue 15, item 2: files a mesh refers to (OBJ material libraries and
// textures, glTF buffers and images) that are FIFOs or directories are
// refused in one line instead of hanging the importer (a FIFO blocks its
// reader until a writer appears; the timeout turns a hang into a failure).
TEST(CliInputs, ReferencedNonRegularFilesAreRefusedNotHung) {
  TempDir dir;
  ASSERT_EQ(mkfifo(dir.file("pipe").c_str(), 0600), 0);
  std::filesystem::create_directory(dir.file("folder"));
  const std::string tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
  write_text(dir.file("a.obj"), "mtllib pipe\n" + tri);
  write_text(dir.file("b.obj"), "  mtllib folder\n" + tri);
  write_text(dir.file("c.obj"), "mtllib missing.mtl pipe\n" + tri);  // a list of names
  write_text(dir.file("t.mtl"), "newmtl m\nmap_Kd pipe\n");
  write_text(dir.file("d.obj"), "mtllib t.mtl\nvt 0 0\nusemtl m\n" + tri);
  // glTF 2: a triangle whose buffer, or whose image, is the FIFO.
  auto gltf = [](const std::string& buffer_uri, const std::string& image_uri) {
    return R"({"asset":{"version":"2.0"},"scenes":[{"nodes":[0]}],"nodes":[{"mesh":0}],)"
           R"("meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],)"
           R"("images":[{"uri":")" +
           image_uri + R"("}],"buffers":[{"uri":")" + buffer_uri +
           R"(","byteLength":36}],"bufferViews":[{"buffer":0,"byteLength":36}],)"
           R"("accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3",)"
           R"("min":[0,0,0],"max":[1,1,0]}]})";
  };
  {
    std::string bin(36, '\0');
    const float v[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    std::memcpy(bin.data(), v, 36);
    write_text(dir.file("tri.bin"), bin);
    write_text(dir.file("tex.png"), png_claiming(2, 2));
  }
  write_text(dir.file("ok.gltf"), gltf("tri.bin", "tex.png"));
  write_text(dir.file("e.gltf"), gltf("pipe", "tex.png"));
  write_text(dir.file("f.gltf"), gltf("tri.bin", "pipe"));
  const CliResult ok = run_cli_split(
      "build " + dir.file("ok.gltf") + " -o " + dir.file("ok.vxc") + " --resolution 8", 20);
  ASSERT_EQ(ok.exit_code, 0) << ok.errors;  // the control loads
  const struct {
    const char* file;
    const char* kind;
    const char* what;
  } cases[] = {{"a.obj", "FIFO", "material library 'pipe'"},
               {"b.obj", "directory", "material library 'folder'"},
               {"c.obj", "FIFO", "material library 'pipe'"},
               {"d.obj", "FIFO", "pipe"},
               {"e.gltf", "FIFO", "buffer 0 file 'pipe'"},
               {"f.gltf", "FIFO", "image 'pipe'"}};
  for (const auto& c : cases) {
    SCOPED_TRACE(c.file);
    const CliResult r = run_cli_split(
        "build " + dir.file(c.file) + " -o " + dir.file("x.vxc") + " --resolution 8", 20);
    expect_error(r, 1, c.kind);
    EXPECT_NE(r.errors.find(c.what), std::string::npos) << r.errors;
    EXPECT_NE(r.errors.find("not a regular file"), std::string::npos) << r.errors;
  }
  EXPECT_FALSE(std::filesystem::exists(dir.file("x.vxc")));
  EXPECT_TRUE(std::filesystem::is_fifo(dir.file("pipe")));
}

// Issue 15, item 3: `build` refuses a grid the scene loader would refuse
// (GridTransform::placement_is_valid: the world cube a box of float
// coordinates within +-1e18) instead of writing a file nothing can read.
// Oracle: `info` on what build wrote. Tetrahedra of half-size s around the
// origin: build succeeds exactly when info then accepts the file.
TEST(CliInputs, BuildRefusesGridsTheLoaderWouldRefuse) {
  TempDir dir;
  int built = 0, refused = 0;
  for (const double s : {1.0, 1e17, 4e17, 9e17, 1e18, 3e18, 1e30}) {
    SCOPED_TRACE(s);
    char obj[512];
    std::snprintf(obj, sizeof obj,
                  "v %.17g %.17g %.17g\nv %.17g %.17g %.17g\nv %.17g %.17g %.17g\n"
                  "v %.17g %.17g %.17g\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n",
                  -s, -s, -s, s, -s, -s, -s, s, -s, -s, -s, s);
    write_text(dir.file("m.obj"), obj);
    std::filesystem::remove(dir.file("m.vxc"));
    const CliResult b = run_cli_split("build " + dir.file("m.obj") + " -o " + dir.file("m.vxc") +
                                      " --resolution 8");
    if (b.exit_code == 0) {
      ++built;
      const CliResult info = run_cli_split("info " + dir.file("m.vxc"));
      EXPECT_EQ(info.exit_code, 0) << "build wrote a scene the loader refuses: " << info.errors;
    } else {
      ++refused;
      expect_error(b, 1, "not a box of float coordinates within +-1e18");
      EXPECT_FALSE(std::filesystem::exists(dir.file("m.vxc")));
    }
  }
  EXPECT_GE(built, 3);    // 1, 1e17, 4e17 fit
  EXPECT_GE(refused, 3);  // 1e18 (with its margin), 3e18, 1e30 do not
}

// Issue 15, item 1: `info` on a scene of 2^60 voxels (the full 1048576^3
// grid as a DAG: one node per level, a file under 4 KB) answers at once and
// within a 1 GiB address space: every statistic is computed per DAG node,
// none per voxel or per octree node. Oracle: the counts of a full grid.
TEST(CliResources, InfoOnAHugeSceneIsFastAndBounded) {
  TempDir dir;
  voxcast::dag::SparseVoxelDag d;
  const int L = 20;
  d.grid.levels = L;
  d.grid.resolution = 1u << L;
  d.grid.voxel_size = 1.0 / double(d.grid.resolution);
  for (int l = 0; l <= L - 3; ++l) {  // interior: all 8 children, the next level's one node
    d.words.push_back(0xFF);
    for (int c = 0; c < 8; ++c) d.words.push_back(uint32_t(9 * (l + 1)));
  }
  d.words.push_back(0xFFFFFFFFu);  // the leaf-mask node: all 4^3 voxels
  d.words.push_back(0xFFFFFFFFu);
  d.finalize();
  voxcast::SceneInfo info;
  info.source = "full";
  info.voxelization = "conservative";
  info.leaf_voxels = d.leaf_voxels;
  voxcast::save_dag_scene(dir.file("full.vxc"), d, info);
  EXPECT_LT(std::filesystem::file_size(dir.file("full.vxc")), 4096u);
  const auto t0 = std::chrono::steady_clock::now();
  // ulimit -v: an allocation per voxel (or per SVO node) fails instead of
  // paging the machine to death; 1 GiB leaves room for the libraries' and
  // threads' address space reservations. Not under AddressSanitizer (./run
  // asan builds the CLI with the same flags as this test), whose shadow
  // memory alone reserves terabytes of address space: there only the time
  // bound and the counts are checked.
  CliResult r;
  {
    const std::string limit = kAddressSanitizer ? "" : "ulimit -v 1048576; ";
    const std::string cmd = limit + "timeout -k 5 30 '" + std::string(VOXCAST_CLI_PATH) +
                            "' info --json '" + dir.file("full.vxc") + "' 2>&1 </dev/null";
    FILE* p = popen(cmd.c_str(), "r");
    ASSERT_NE(p, nullptr);
    char buf[4096];
    for (size_t n; (n = fread(buf, 1, sizeof buf, p)) > 0;) r.output.append(buf, n);
    const int status = pclose(p);
    r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  }
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  ASSERT_EQ(r.exit_code, 0) << r.output.substr(0, 2000);
  EXPECT_LT(seconds, 10.0);
  const uint64_t voxels = uint64_t(1) << 60;  // (2^20)^3
  EXPECT_NE(r.output.find("\"leaf_voxels\": " + std::to_string(voxels)), std::string::npos)
      << r.output.substr(0, 2000);
  // SVO nodes of levels 0..L-1 of a full octree: sum of 8^l.
  uint64_t svo = 0;
  for (int l = 0; l < L; ++l) svo += uint64_t(1) << (3 * l);
  EXPECT_NE(r.output.find("\"svo\": " + std::to_string(svo)), std::string::npos)
      << r.output.substr(0, 2000);
  const CliResult text = run_cli_split("info " + dir.file("full.vxc"), 30);
  EXPECT_EQ(text.exit_code, 0) << text.errors;
}

// Issue 15, item 1: `bench` holds several structures at once; its estimate
// covers them all and is checked before anything is built. Oracle: build's
// own estimate of one voxel build of the same mesh and resolution (printed
// when refused): bench's covers at least that, one more with --contours, and
// with --effects the occlusion rays are checked once the shading points are
// known (AO rays 4096 per point: megabytes for a 48 x 36 frame).
TEST(CliResources, BenchEstimateCoversEveryStructureItHolds) {
  TempDir dir;
  write_text(dir.file("t.obj"), tetra_obj());
  const std::string res = " --resolution 64";
  const CliResult b = run_cli_split("build " + dir.file("t.obj") + " -o " + dir.file("t.vxc") +
                                    res + " --memory-budget 1K");
  const double one_build = printed_estimate(b.errors, "needs an estimated ");
  ASSERT_GT(one_build, 0) << b.errors;
  const std::string bench =
      "bench " + dir.file("t.obj") + res + " --size 48x36 --repeat 1 --beam 0 --memory-budget ";
  const CliResult plain = run_cli_split(bench + "1K");
  expect_error(plain, 1, "memory budget");
  EXPECT_EQ(plain.output, "") << "refused before anything is built or measured";
  const double plain_need = printed_estimate(plain.errors, "need an estimated ");
  EXPECT_GE(plain_need, one_build * 0.99) << plain.errors;
  const CliResult contours = run_cli_split(bench + "1K --contours");
  expect_error(contours, 1, "contour octree");
  const double contour_need = printed_estimate(contours.errors, "need an estimated ");
  EXPECT_GE(contour_need - plain_need, one_build * 0.98) << contours.errors;
  // Within the estimate (and a margin for the DAG of --effects), bench runs.
  const auto kib = [](double bytes) { return std::to_string(uint64_t(bytes / 1024) + 1) + "K"; };
  const CliResult ok = run_cli_split(bench + kib(plain_need * 1.02));
  EXPECT_EQ(ok.exit_code, 0) << ok.errors;
  EXPECT_NE(ok.output.find("voxcast esvo"), std::string::npos) << ok.output;
  // --effects builds every other registered format (the DAG, the brickmap
  // world): one build's estimate each, plus a margin.
  const CliResult effects =
      run_cli_split(bench + kib(plain_need + 3 * one_build) + " --effects --ao-rays 4096");
  expect_error(effects, 1, "occlusion rays");
  EXPECT_NE(effects.output.find("voxcast esvo"), std::string::npos)
      << "the structures fit: the primary rays were measured";
}

namespace {

// Starts `voxcast args` with stdout/stderr to /dev/null and default signal
// dispositions (a test run in the background may ignore SIGINT).
pid_t spawn_cli(const std::vector<std::string>& args) {
  std::vector<std::string> all{VOXCAST_CLI_PATH};
  all.insert(all.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (std::string& a : all) argv.push_back(a.data());
  argv.push_back(nullptr);
  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  posix_spawn_file_actions_addopen(&fa, 0, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_addopen(&fa, 1, "/dev/null", O_WRONLY, 0);
  posix_spawn_file_actions_addopen(&fa, 2, "/dev/null", O_WRONLY, 0);
  posix_spawnattr_t attr;
  posix_spawnattr_init(&attr);
  sigset_t def, none;
  sigemptyset(&def);
  for (int s : {SIGINT, SIGTERM, SIGHUP}) sigaddset(&def, s);
  sigemptyset(&none);
  posix_spawnattr_setsigdefault(&attr, &def);
  posix_spawnattr_setsigmask(&attr, &none);
  posix_spawnattr_setflags(&attr, POSIX_SPAWN_SETSIGDEF | POSIX_SPAWN_SETSIGMASK);
  pid_t pid = -1;
  const int rc = posix_spawn(&pid, all[0].c_str(), &fa, &attr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&fa);
  posix_spawnattr_destroy(&attr);
  return rc == 0 ? pid : -1;
}

bool is_staged_temporary(const std::string& name) {
  return name.find(".voxcast-") != std::string::npos;
}

}  // namespace

// Issue 15, item 4: SIGINT or SIGTERM while a command writes its outputs
// removes the staged temporaries and leaves no output (or, if it came while
// the outputs were being renamed into place, all of them: never some). The
// test starts `build` (a 3 MB scene) and a three-output `render`, watches
// the directory for the first staged file and then sends the signal. A run
// that finishes before the signal lands is retried; each command and signal
// must be caught mid-write at least once.
TEST(CliSignals, InterruptedWritesLeaveNoOutputAndNoTemporary) {
  TempDir dir;
  const std::string scene = dir.file("b.vxc");
  ASSERT_EQ(run_cli("build " + kBunny + " -o " + scene + " --resolution 128").exit_code, 0);
  struct Job {
    const char* name;
    std::vector<std::string> args;
    std::vector<std::string> outputs;
  };
  const Job jobs[] = {
      {"build", {"build", kBunny, "-o", dir.file("out/b.vxc"), "--resolution", "256"}, {"b.vxc"}},
      {"render",
       {"render", scene, "--size", "1024x1024", "-o", dir.file("out/a.png"), "--depth",
        dir.file("out/d.pfm"), "--normals", dir.file("out/n.png")},
       {"a.png", "d.pfm", "n.png"}},
  };
  const std::string out = dir.file("out");
  for (const Job& job : jobs)
    for (const int sig : {SIGINT, SIGTERM}) {
      SCOPED_TRACE(std::string(job.name) + " " + strsignal(sig));
      int caught_mid_write = 0;
      for (int attempt = 0; attempt < 4 && caught_mid_write == 0; ++attempt) {
        std::filesystem::remove_all(out);
        std::filesystem::create_directory(out);
        const pid_t pid = spawn_cli(job.args);
        ASSERT_GT(pid, 0);
        bool sent = false;
        int status = 0;
        const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(120);
        for (;;) {
          const pid_t done = waitpid(pid, &status, sent ? 0 : WNOHANG);
          if (done == pid) break;
          if (std::chrono::steady_clock::now() > deadline) {
            kill(pid, SIGKILL);
            waitpid(pid, &status, 0);
            FAIL() << "timed out";
          }
          for (const std::string& name : dir_entries(out))
            if (!sent && is_staged_temporary(name)) {
              kill(pid, sig);
              sent = true;
            }
          if (!sent) std::this_thread::sleep_for(std::chrono::microseconds(200));
        }
        const std::vector<std::string> left = dir_entries(out);
        for (const std::string& name : left)
          EXPECT_FALSE(is_staged_temporary(name)) << "temporary left behind: " << name;
        size_t outputs = 0;
        for (const std::string& o : job.outputs) outputs += std::count(left.begin(), left.end(), o);
        EXPECT_TRUE(outputs == 0 || outputs == job.outputs.size())
            << outputs << " of " << job.outputs.size() << " outputs written";
        if (!sent) continue;  // finished before a staged file was seen
        if (WIFSIGNALED(status)) {
          EXPECT_EQ(WTERMSIG(status), sig);
          caught_mid_write += outputs == 0;
        }
      }
      EXPECT_GE(caught_mid_write, 1) << "never interrupted while writing";
    }
}

// A full disk (here a file size limit, `ulimit -f`, with SIGXFSZ ignored so
// that write() fails with EFBIG) is a runtime error: one line, exit 1, the
// old output kept, no temporary left. OpenVDB's io::File does not check its
// stream, so the .vdb writers used to exit 0 with a truncated file in place.
TEST(CliOutputs, AFullDiskKeepsTheOldOutput) {
  TempDir dir;
  const std::string scene = dir.file("b.vxc");
  ASSERT_EQ(run_cli("build " + kBunny + " -o " + scene + " --resolution 64").exit_code, 0);
  const std::string out = dir.file("out");
  const struct {
    const char* file;
    std::string args;
  } jobs[] = {
      {"c.vdb", "convert " + kBunny + " " + out + "/c.vdb --resolution 128"},
      {"v.vdb", "volume export procedural:cloud --resolution 64 -o " + out + "/v.vdb"},
      {"b.vxc", "build " + kBunny + " -o " + out + "/b.vxc --resolution 256"},
      {"c.vox", "convert " + kBunny + " " + out + "/c.vox --resolution 128"},
      {"r.exr", "render " + scene + " -o " + out + "/r.exr --size 512x512"},
  };
  for (const auto& job : jobs) {
    SCOPED_TRACE(job.args);
    std::filesystem::remove_all(out);
    std::filesystem::create_directory(out);
    write_text(out + "/" + job.file, "old");
    // 20 blocks (10-20 KiB): every job's output is larger.
    const std::string cmd = "trap '' XFSZ; ulimit -f 20; exec '" + std::string(VOXCAST_CLI_PATH) +
                            "' " + job.args + " 2>&1 >/dev/null </dev/null";
    FILE* p = popen(cmd.c_str(), "r");
    ASSERT_NE(p, nullptr);
    CliResult r;
    char buf[4096];
    for (size_t n; (n = fread(buf, 1, sizeof buf, p)) > 0;) r.output.append(buf, n);
    const int status = pclose(p);
    r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
    EXPECT_EQ(r.exit_code, 1) << r.output;
    expect_one_line_error(r, "cannot write");
    EXPECT_EQ(std::count(r.output.begin(), r.output.end(), '\n'), 1) << r.output;
    EXPECT_TRUE(read_text(out + "/" + job.file) == "old") << "the old output was replaced";
    EXPECT_EQ(dir_entries(out).size(), 1u) << "a temporary left behind";
  }
}

// `render --path` registers one output per keyframe; each registration used
// to compare itself with every earlier one through the file system (stat,
// weakly_canonical), so 2,000 keyframes took ~28 s and 3,000 over a minute.
// 4,000 tiny frames must finish well inside the 120 s limit (~3 s now).
TEST(CliOutputs, APathOfThousandsOfKeyframesIsNotQuadratic) {
  Scene s;
  std::string json = "{\"voxcast_camera_path\": 1, \"keyframes\": [";
  constexpr int kFrames = 4000;
  for (int i = 0; i < kFrames; ++i)
    json += std::string(i ? "," : "") + "{\"time\": " + std::to_string(i) +
            ", \"eye\": [0.3, 0.4, 1.5], \"target\": [0.3, 0.3, 0.3]}";
  write_text(s.dir.file("path.json"), json + "]}");
  std::filesystem::create_directory(s.dir.file("frames"));
  const CliResult r = run_cli_split("render " + s.scene + " -o " + s.dir.file("frames/f.png") +
                                        " --size 8x6 -q --path " + s.dir.file("path.json"),
                                    120);
  ASSERT_EQ(r.exit_code, 0) << r.errors;
  EXPECT_EQ(dir_entries(s.dir.file("frames")).size(), size_t(kFrames));
}

// `edit --batch`: an error names its line, and a huge line is not echoed
// whole (a 1 MB line gave a 1 MB error line); `edit W --checkpoint` with no
// edit folds the journal into the world file.
TEST(CliEdit, BatchErrorsNameTheirLineAndCheckpointAloneFoldsTheJournal) {
  TempDir dir;
  const std::string world = dir.file("w.vxc");
  ASSERT_EQ(run_cli("generate terrain --size 64x64x32 -o " + world).exit_code, 0);
  write_text(dir.file("b1.txt"), "sphere 0,0.1,0,0.05 add\n# a comment\n\nbox 0,0,0,1,1 add\n");
  CliResult r = run_cli_split("edit " + world + " --batch " + dir.file("b1.txt"));
  expect_error(r, 2, "line 4: --box");
  std::string huge = "sphere 0,0,0";
  while (huge.size() < (1u << 20)) huge += ",1";
  write_text(dir.file("b2.txt"), huge + " add\n");
  r = run_cli_split("edit " + world + " --batch " + dir.file("b2.txt"));
  expect_error(r, 2, "line 1: --sphere");
  EXPECT_LT(r.errors.size(), 1000u);
  // An edit in place leaves a journal; --checkpoint alone folds it in.
  ASSERT_EQ(run_cli("edit " + world + " --sphere 0,0.1,0,0.05 --add").exit_code, 0);
  ASSERT_TRUE(std::filesystem::exists(world + ".journal"));
  // (What info says of the world, but for the file's size.)
  auto facts = [&] {
    std::string j = run_cli_split("info --json " + world).output;
    const size_t at = j.find("\"file_bytes\"");
    return at == std::string::npos ? j : j.erase(at, j.find('\n', at) - at);
  };
  const std::string before = facts();
  r = run_cli_split("edit " + world + " --checkpoint");
  ASSERT_EQ(r.exit_code, 0) << r.errors;
  EXPECT_NE(r.output.find("checkpointed"), std::string::npos) << r.output;
  EXPECT_FALSE(std::filesystem::exists(world + ".journal"));
  EXPECT_EQ(facts(), before) << "the same world";
  expect_error(run_cli_split("edit " + world + " --checkpoint -o " + dir.file("x.vxc")), 2,
               "--checkpoint");
}
