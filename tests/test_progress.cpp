// The progress facility (progress.hpp): fractions, weighted phases and the
// ETA with an injected clock (no timing in the test), the drawn lines, the
// redraw limit, quiet mode; the voxelizer's and the frame loop's phases and
// units; the CLI's bars on a real pseudo-terminal (script(1)).
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "support/cli_runner.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/esvo_slices.hpp"
#include "voxcast/format_registry.hpp"
#include "voxcast/generate.hpp"
#include "voxcast/progress.hpp"
#include "voxcast/scene_file.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast {
namespace {

constexpr int64_t kMs = 1'000'000;

// A clock the test moves by hand and the text a Progress drew.
struct FakeTerminal {
  std::shared_ptr<int64_t> now = std::make_shared<int64_t>(0);
  std::shared_ptr<std::vector<std::string>> writes = std::make_shared<std::vector<std::string>>();
  ProgressSink sink(bool tty = true) const {
    ProgressSink s;
    s.tty = tty;
    auto n = now;
    s.now_ns = [n] { return *n; };
    auto w = writes;
    s.write = [w](const std::string& text) { w->push_back(text); };
    return s;
  }
  void at(int64_t ms) const { *now = ms * kMs; }
  // A sink whose every clock read moves `ms` on, so each advance may draw.
  ProgressSink stepping_sink(int64_t ms) const {
    ProgressSink s = sink();
    auto n = now;
    s.now_ns = [n, ms] { return *n += ms * kMs; };
    return s;
  }
  // The phases among `names` drawn, in the order drawn (repeats collapsed).
  std::vector<std::string> phases_drawn(const std::vector<std::string>& names) const {
    std::vector<std::string> seen;
    for (const std::string& w : *writes)
      for (const std::string& phase : names)
        if (w.find("(" + phase + ")") != std::string::npos &&
            (seen.empty() || seen.back() != phase))
          seen.push_back(phase);
    return seen;
  }
};

VoxelSet menger_voxels(int resolution) {
  const Mesh mesh = generate::menger(2);
  VoxelizeOptions vo;
  vo.attributes = true;
  return voxelize(mesh, GridTransform::fit(mesh.bounds(), resolution), vo);
}

TEST(Progress, SinglePhaseFractionAndEta) {
  FakeTerminal term;
  Progress p("task", {{"", 1}}, term.sink());
  p.start_phase(0, 200);
  EXPECT_DOUBLE_EQ(p.fraction(), 0.0);
  EXPECT_LT(p.eta_seconds(), 0);  // no estimate before 1%
  term.at(2000);
  p.advance(50);
  EXPECT_DOUBLE_EQ(p.fraction(), 0.25);
  // 25% in 2 s: 6 s left at the same rate.
  EXPECT_DOUBLE_EQ(p.eta_seconds(), 6.0);
  EXPECT_NE(p.status_line().find(" 25.0%"), std::string::npos) << p.status_line();
  EXPECT_NE(p.status_line().find("ETA 6.0s"), std::string::npos) << p.status_line();
}

// The issue-14 complaint: a bar over the first phase only reads ETA 0 at its
// end while the rest of the task is ahead. With weights, the end of a phase
// of weight 0.5 is 50% of the task, and the ETA is the time spent so far.
TEST(Progress, WeightedPhasesKeepTheEtaHonestAcrossPhases) {
  FakeTerminal term;
  Progress p("voxelize", {{"rasterize", 0.5}, {"sort", 0.3}, {"merge", 0.2}}, term.sink());
  p.start_phase(0, 1000);
  term.at(4000);
  p.advance(1000);  // rasterization done after 4 s
  EXPECT_DOUBLE_EQ(p.fraction(), 0.5);
  EXPECT_DOUBLE_EQ(p.eta_seconds(), 4.0);
  p.start_phase(1, 3);
  EXPECT_DOUBLE_EQ(p.fraction(), 0.5);  // a new phase starts where the last ended
  p.advance(2);
  EXPECT_NEAR(p.fraction(), 0.7, 1e-12);
  EXPECT_NE(p.status_line().find("voxelize (sort)"), std::string::npos) << p.status_line();
  p.start_phase(2, 4);
  p.advance(4);
  EXPECT_DOUBLE_EQ(p.fraction(), 1.0);
  EXPECT_DOUBLE_EQ(p.eta_seconds(), 0.0);
}

TEST(Progress, WeightsAreRelative) {
  FakeTerminal term;
  Progress p("t", {{"a", 3}, {"b", 1}}, term.sink());
  p.start_phase(0, 10);
  p.advance(10);
  EXPECT_DOUBLE_EQ(p.fraction(), 0.75);
  p.start_phase(1, 0);  // a phase of unknown size counts as not started
  EXPECT_DOUBLE_EQ(p.fraction(), 0.75);
  p.add_units(8);
  p.advance(4);
  EXPECT_DOUBLE_EQ(p.fraction(), 0.875);
  p.set_done(8);
  EXPECT_DOUBLE_EQ(p.fraction(), 1.0);
  p.advance(5);  // more than announced: clamped
  EXPECT_DOUBLE_EQ(p.fraction(), 1.0);
}

TEST(Progress, DrawsAfterTheDelayAtMostTenTimesASecondAndEndsTheLine) {
  FakeTerminal term;
  {
    Progress p("task", {{"", 1}}, term.sink());
    p.start_phase(0, 100);
    for (int ms = 0; ms < 1000; ms += 10) {  // first second: silent
      term.at(ms);
      p.advance(0);
    }
    EXPECT_TRUE(term.writes->empty());
    for (int ms = 1000; ms < 2000; ms += 10) {  // next second: 100 calls, <= 10 draws
      term.at(ms);
      p.advance(ms % 100 == 0 ? 5 : 0);
    }
    EXPECT_GE(term.writes->size(), 9u);
    EXPECT_LE(term.writes->size(), 10u);
    for (const std::string& w : *term.writes) {
      EXPECT_EQ(w[0], '\r');
      EXPECT_EQ(w.find('\n'), std::string::npos);
    }
  }
  // The destructor finished the bar: 100% and a newline, no ETA.
  const std::string& last = term.writes->back();
  EXPECT_NE(last.find("100.0%"), std::string::npos) << last;
  EXPECT_EQ(last.back(), '\n');
  EXPECT_EQ(last.find("ETA"), std::string::npos) << last;
}

TEST(Progress, NothingWithoutATerminalOrForAShortTask) {
  FakeTerminal piped;
  {
    Progress p("task", {{"", 1}}, piped.sink(/*tty=*/false));
    p.start_phase(0, 10);
    piped.at(5000);
    p.advance(10);
  }
  EXPECT_TRUE(piped.writes->empty());
  FakeTerminal quick;
  {
    Progress p("task", {{"", 1}}, quick.sink());
    p.start_phase(0, 10);
    quick.at(900);
    p.advance(10);
  }
  EXPECT_TRUE(quick.writes->empty());  // no bar drawn, so no final line either
}

TEST(Progress, QuietTurnsTheTerminalSinkOff) {
  Progress::set_quiet(true);
  EXPECT_FALSE(ProgressSink::terminal().tty);
  Progress::set_quiet(false);
  EXPECT_FALSE(Progress::quiet());
}

TEST(Progress, ShorterLinesOverwriteLongerOnes) {
  FakeTerminal term;
  Progress p("t", {{"a-long-phase-name", 1}, {"b", 1}}, term.sink());
  p.start_phase(0, 10);
  term.at(1500);
  p.advance(1);
  p.start_phase(1, 10);
  term.at(1700);
  p.advance(1);
  ASSERT_EQ(term.writes->size(), 2u);
  EXPECT_GE((*term.writes)[1].size(), (*term.writes)[0].size());
}

// The voxelizer re-plans the bar it is given into its three phases and
// leaves it complete; the drawn phase names come in order.
TEST(Progress, VoxelizeReportsItsPhasesInOrder) {
  const Mesh mesh = generate::menger(2);
  FakeTerminal term;
  Progress p("voxelize", {{"", 1}}, term.stepping_sink(150));
  VoxelizeOptions vo;
  vo.progress = &p;
  vo.attributes = true;
  const VoxelSet v = voxelize(mesh, GridTransform::fit(mesh.bounds(), 256), vo);
  ASSERT_GT(v.size(), 0u);
  EXPECT_DOUBLE_EQ(p.fraction(), 1.0);
  std::vector<std::string> seen;
  for (const std::string& w : *term.writes)
    for (const char* phase : {"rasterize", "sort", "merge"})
      if (w.find(std::string("(") + phase + ")") != std::string::npos &&
          (seen.empty() || seen.back() != phase))
        seen.push_back(phase);
  EXPECT_EQ(seen, (std::vector<std::string>{"rasterize", "sort", "merge"}));
  // The drawn fractions never go back.
  double last = -1;
  for (const std::string& w : *term.writes) {
    const size_t pct = w.find('%');
    ASSERT_NE(pct, std::string::npos) << w;
    const double f = std::atof(w.substr(w.rfind(' ', pct - 2) + 1, pct).c_str());
    EXPECT_GE(f, last) << w;
    last = f;
  }
  EXPECT_EQ(last, 100.0);
}

// The ESVO and DAG builds re-plan the bar they are given into their phases,
// draw them in order and leave the bar complete.
TEST(Progress, EsvoAndDagBuildsReportTheirPhasesInOrder) {
  const VoxelSet v = menger_voxels(128);
  {
    FakeTerminal term;
    Progress p("esvo build", {{"", 1}}, term.stepping_sink(600));
    esvo::BuildOptions bo;
    bo.progress = &p;
    const esvo::EsvoOctree octree = esvo::build_octree(v, bo);
    EXPECT_EQ(octree.words, esvo::build_octree(v).words);  // the bar changes nothing
    EXPECT_DOUBLE_EQ(p.fraction(), 1.0);
    EXPECT_EQ(term.phases_drawn({"levels", "layout"}),
              (std::vector<std::string>{"levels", "layout"}));
  }
  {
    FakeTerminal term;
    Progress p("dag build", {{"", 1}}, term.stepping_sink(600));
    const dag::SparseVoxelDag d = dag::build_dag(v, &p);
    EXPECT_EQ(d.words, dag::build_dag(v).words);
    EXPECT_DOUBLE_EQ(p.fraction(), 1.0);
    // Phases draw when they advance: the short ones (a single unit) may end
    // before a draw, the others come in plan order.
    EXPECT_EQ(term.phases_drawn({"leaf masks", "levels", "layout", "attributes"}),
              (std::vector<std::string>{"levels", "attributes"}));
  }
}

// The in-core contour / variable-depth build re-plans the bar into levels,
// contours, layout and (compressed attributes with a color tolerance)
// attributes, draws them in plan order, ends complete and builds the same
// words as without a bar.
TEST(Progress, ContourBuildReportsItsPhasesInOrder) {
  const Mesh mesh = generate::menger(2);
  VoxelizeOptions vo;
  vo.attributes = true;
  const VoxelSet v = voxelize(mesh, GridTransform::fit(mesh.bounds(), 128), vo);
  for (const bool compressed : {false, true}) {
    esvo::BuildOptions bo;
    bo.contours = true;
    bo.geometry_error = 0.5;
    bo.color_error = 8;
    if (compressed) bo.attributes = esvo::AttributeFormat::Compressed;
    const esvo::EsvoOctree plain = esvo::build_octree(v, mesh, bo);
    FakeTerminal term;
    Progress p("esvo build", {{"", 1}}, term.stepping_sink(600));
    bo.progress = &p;
    const esvo::EsvoOctree octree = esvo::build_octree(v, mesh, bo);
    EXPECT_EQ(octree.words, plain.words) << compressed;
    EXPECT_DOUBLE_EQ(p.fraction(), 1.0) << compressed;
    EXPECT_NE(term.writes->back().find("100.0%"), std::string::npos) << compressed;
    const std::vector<std::string> plan = {"levels", "contours", "layout", "attributes"};
    const std::vector<std::string> seen = term.phases_drawn(plan);
    ASSERT_FALSE(seen.empty()) << compressed;
    EXPECT_EQ(seen.front(), "levels") << compressed;
    size_t at = 0;  // plan order: every drawn phase after the previous one
    for (const std::string& phase : seen) {
      const size_t i = size_t(std::find(plan.begin(), plan.end(), phase) - plan.begin());
      EXPECT_GE(i, at) << phase;
      at = i;
    }
    if (!compressed) {
      EXPECT_EQ(std::find(seen.begin(), seen.end(), "attributes"), seen.end());
    }
  }
}

std::string file_bytes(const std::string& path) {
  std::string text;
  if (std::FILE* f = std::fopen(path.c_str(), "rb")) {
    char buf[4096];
    for (size_t n; (n = std::fread(buf, 1, sizeof buf, f)) > 0;) text.append(buf, n);
    std::fclose(f);
  }
  return text;
}

// Loading a scene re-plans the bar into its read (bytes read and hashed)
// and bounds phases, draws them in order, ends complete, and loads the same
// scene as without a bar.
LoadedScene load_with_read_bounds_bar(const std::string& path, const std::string& what) {
  FakeTerminal term;
  Progress p("load scene", {{"", 1}}, term.stepping_sink(600));
  SceneLoadOptions lo;
  lo.progress = &p;
  LoadedScene scene = load_scene(path, lo);
  EXPECT_DOUBLE_EQ(p.fraction(), 1.0) << what;
  EXPECT_EQ(term.phases_drawn({"read", "bounds"}), (std::vector<std::string>{"read", "bounds"}))
      << what;
  EXPECT_NE(term.writes->back().find("100.0%"), std::string::npos) << what;
  return scene;
}

TEST(Progress, SceneLoadReportsReadThenBounds) {
  register_builtin_formats();
  const VoxelSet v = menger_voxels(128);
  const std::string dir = ::testing::TempDir();
  const std::string path = dir + "/progress-load.vxc";
  for (const std::string format : {"esvo", "dag"}) {
    const LoadedStructure built = format_registry().get(format).build(v, {});
    save_scene(path, format, *built, SceneInfo{"menger", "conservative", 0, v.size()});
    const LoadedScene with_bar = load_with_read_bounds_bar(path, format);
    const LoadedScene without = load_scene(path);
    // The same scene: the same bounds and the same file when saved again.
    for (int i = 0; i < 3; ++i) {
      EXPECT_EQ(with_bar.occupied.lo[i], without.occupied.lo[i]) << format;
      EXPECT_EQ(with_bar.occupied.hi[i], without.occupied.hi[i]) << format;
    }
    save_scene(dir + "/progress-load-a.vxc", format, *with_bar.structure, with_bar.info);
    save_scene(dir + "/progress-load-b.vxc", format, *without.structure, without.info);
    EXPECT_EQ(file_bytes(dir + "/progress-load-a.vxc"), file_bytes(dir + "/progress-load-b.vxc"))
        << format;
  }
}

// Opening a whole slice file (every slice read, hashed, checked and merged,
// then the occupied-bounds walk) draws a read and a bounds phase, ends
// complete, and opens the same scene as without a bar.
TEST(Progress, SliceFileOpenReportsReadThenBounds) {
  register_builtin_formats();
  const esvo::EsvoOctree octree = esvo::build_octree(menger_voxels(64));
  const std::string path = ::testing::TempDir() + "/progress-open.vxs";
  esvo::SliceOptions so;
  so.slice_bytes = 2048;  // many slices: many advances
  esvo::write_slices(octree, path, so);
  const LoadedScene with_bar = load_with_read_bounds_bar(path, "slices");
  const LoadedScene without = load_scene(path);
  const auto& s = dynamic_cast<const esvo::StreamedEsvo&>(*with_bar.structure);
  EXPECT_EQ(s.stats().resident_slices, s.file().slices().size());
  EXPECT_GT(s.file().slices().size(), 8u);
  const Aabb want = esvo::occupied_bounds(octree);
  for (int i = 0; i < 3; ++i) {
    EXPECT_EQ(with_bar.occupied.lo[i], without.occupied.lo[i]);
    EXPECT_EQ(with_bar.occupied.hi[i], without.occupied.hi[i]);
    EXPECT_EQ(with_bar.occupied.lo[i], want.lo[i]);
    EXPECT_EQ(with_bar.occupied.hi[i], want.hi[i]);
  }
  std::filesystem::remove(path);
}

// The CLI on a real pseudo-terminal (script(1) gives the child a pty as
// stderr): build and render draw bars with an ETA; --quiet draws none.
// VOXCAST_PROGRESS_DELAY_MS=0 so a quick task draws too.
std::string on_a_terminal(const std::string& args) {
  const std::string log = ::testing::TempDir() + "/voxcast-pty.log";
  const std::string cmd = "VOXCAST_PROGRESS_DELAY_MS=0 script -qec \"" +
                          std::string(VOXCAST_CLI_PATH) + " " + args + "\" " + log +
                          " > /dev/null 2>&1";
  if (std::system(cmd.c_str()) != 0) return "command failed: " + cmd;
  return file_bytes(log);
}

TEST(ProgressCli, BarsOnATerminalAndNoneWhenQuiet) {
  // script(1) is util-linux's (Debian's bsdutils, always installed).
  ASSERT_EQ(std::system("command -v script > /dev/null 2>&1"), 0) << "no script(1)";
  const std::string dir = ::testing::TempDir();
  const std::string mesh = std::string(VOXCAST_TEST_DATA_DIR) + "/meshes/spot.obj";
  const std::string scene = dir + "/progress-spot.vxc";
  const std::string built = on_a_terminal("build " + mesh + " -o " + scene + " --resolution 128");
  EXPECT_NE(built.find("voxelize ("), std::string::npos) << built;
  EXPECT_NE(built.find("ETA"), std::string::npos) << built;
  EXPECT_NE(built.find("load spot.obj"), std::string::npos) << built;
  EXPECT_NE(built.find("esvo build (levels)"), std::string::npos) << built;
  EXPECT_NE(built.find("write scene ["), std::string::npos) << built;
  // The in-core contour build (a color tolerance keeps it in core).
  const std::string contours =
      on_a_terminal("build " + mesh + " -o " + dir +
                    "/progress-spot-c.vxc --resolution 128 --contours --color-error 8");
  EXPECT_NE(contours.find("esvo build (levels)"), std::string::npos) << contours;
  const std::string contours_quiet =
      on_a_terminal("build " + mesh + " -o " + dir +
                    "/progress-spot-cq.vxc --resolution 128 --contours --color-error 8 -q");
  EXPECT_EQ(contours_quiet.find("esvo build"), std::string::npos) << contours_quiet;
  EXPECT_EQ(file_bytes(dir + "/progress-spot-c.vxc"), file_bytes(dir + "/progress-spot-cq.vxc"));
  const std::string dag = on_a_terminal("build " + mesh + " -o " + dir +
                                        "/progress-spot-dag.vxc --resolution 128 --format dag");
  EXPECT_NE(dag.find("dag build ("), std::string::npos) << dag;
  const std::string dag_quiet =
      on_a_terminal("build " + mesh + " -o " + dir +
                    "/progress-spot-dag-q.vxc --resolution 128 --format dag --quiet");
  EXPECT_EQ(dag_quiet.find("build ["), std::string::npos) << dag_quiet;
  EXPECT_EQ(dag_quiet.find("build ("), std::string::npos) << dag_quiet;
  // On a pipe: no bar either (stderr is not a terminal).
  const std::string piped = std::string("VOXCAST_PROGRESS_DELAY_MS=0 ") + VOXCAST_CLI_PATH +
                            " build " + mesh + " -o " + dir +
                            "/progress-spot-pipe.vxc --resolution 128 --format dag 2>&1 | cat > " +
                            dir + "/progress-pipe.log";
  ASSERT_EQ(std::system(piped.c_str()), 0);
  const std::string pipe_text = file_bytes(dir + "/progress-pipe.log");
  EXPECT_NE(pipe_text.find("progress-spot-pipe.vxc"), std::string::npos) << pipe_text;
  EXPECT_EQ(pipe_text.find('\r'), std::string::npos) << pipe_text;
  EXPECT_EQ(pipe_text.find("build ["), std::string::npos) << pipe_text;
  const std::string info_piped = std::string("VOXCAST_PROGRESS_DELAY_MS=0 ") + VOXCAST_CLI_PATH +
                                 " info " + scene + " 2>&1 | cat > " + dir + "/progress-info.log";
  ASSERT_EQ(std::system(info_piped.c_str()), 0);
  EXPECT_EQ(file_bytes(dir + "/progress-info.log").find("load scene"), std::string::npos);
  const std::string rendered =
      on_a_terminal("render " + scene + " -o " + dir + "/progress-spot.png --size 64x48");
  EXPECT_NE(rendered.find("render ["), std::string::npos) << rendered;
  EXPECT_NE(rendered.find("100.0%"), std::string::npos) << rendered;
  EXPECT_NE(rendered.find("load scene ("), std::string::npos) << rendered;
  EXPECT_NE(rendered.find("write image ("), std::string::npos) << rendered;  // the PNG
  const std::string info = on_a_terminal("info " + scene);
  EXPECT_NE(info.find("load scene ("), std::string::npos) << info;
  const std::string quiet =
      on_a_terminal("render " + scene + " -o " + dir + "/progress-spot-q.png --size 64x48 --quiet");
  EXPECT_EQ(quiet.find("render ["), std::string::npos) << quiet;
  EXPECT_EQ(quiet.find("load scene"), std::string::npos) << quiet;
  EXPECT_EQ(quiet.find("write image"), std::string::npos) << quiet;
  // Writing an EXR (planes, then the rows encoded; the final line).
  const std::string exr = on_a_terminal("render " + scene + " -o " + dir +
                                        "/progress-spot.exr --size 64x48 --aov depth,normal");
  EXPECT_NE(exr.find("write image ["), std::string::npos) << exr;
  const std::string exr_quiet = on_a_terminal(
      "render " + scene + " -o " + dir + "/progress-spot-q.exr --size 64x48 --aov depth,normal -q");
  EXPECT_EQ(exr_quiet.find("write image"), std::string::npos) << exr_quiet;
  EXPECT_EQ(file_bytes(dir + "/progress-spot.exr"), file_bytes(dir + "/progress-spot-q.exr"));
  EXPECT_EQ(file_bytes(dir + "/progress-spot.png"), file_bytes(dir + "/progress-spot-q.png"));
  EXPECT_NE(quiet.find("progress-spot-q.png: 64x48"), std::string::npos) << quiet;  // stdout stays
}

}  // namespace
}  // namespace voxcast
