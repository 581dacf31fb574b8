// The CLI as a user meets it: usage errors, bad input files, one-line errors,
// non-zero exits, no half-written outputs, and byte-identical builds whatever
// the thread count.
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include "support/cli_runner.hpp"
#include "voxcast/scene_file.hpp"

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
      {r + " --memory-budget " + twice_memory, "--memory-budget"},
      {bench + " --resolution 3", "--resolution"},
      {bench + " --size 0x0", "--size"},
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
      {g + "terrain --persistence 2" + o, "persistence"},
      {g + "menger --memory-budget " + twice_memory + o, "--memory-budget"},
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
  // (--resolution 1: the voxel estimate alone would fit.)
  expect_error(run_cli_split("build " + s.dir.file("big.obj") + " -o " + s.dir.file("a.vxc") +
                             " --resolution 1 --memory-budget 32K"),
               1, "memory budget");
  // A generated mesh too large for the budget is refused before it is built.
  expect_error(
      run_cli_split("generate terrain --size 1024 --memory-budget 1M -o " + s.dir.file("t.ply")), 1,
      "memory budget");
  expect_error(run_cli_split("generate hairball --tubes 100000 --memory-budget 10M -o " +
                             s.dir.file("h.obj")),
               1, "memory budget");
  EXPECT_FALSE(std::filesystem::exists(s.dir.file("a.png")));
  EXPECT_FALSE(std::filesystem::exists(s.dir.file("a.vxc")));
  EXPECT_FALSE(std::filesystem::exists(s.dir.file("t.ply")));
  EXPECT_FALSE(std::filesystem::exists(s.dir.file("h.obj")));
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
