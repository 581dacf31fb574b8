// `voxcast view` for real: a virtual X server (Xvfb, with Mesa's software
// OpenGL) per test, the CLI opening its window on it, driving frames through
// a camera path and reading the window back. The screenshots are compared
// with `voxcast render` of the same cameras: the viewer shows the CPU frame
// through an RGB8 texture and a nearest-neighbour framebuffer blit, so the
// window must hold the very bytes `render` writes to its PNG.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <poll.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "support/cli_runner.hpp"
#include "voxcast/image.hpp"

using voxcast::Image;
using voxcast::read_pfm;
using voxcast::read_png;
using voxcast::testing::CliResult;
using voxcast::testing::read_text;
using voxcast::testing::run_cli;
using voxcast::testing::TempDir;
using voxcast::testing::write_text;

namespace {

// An Xvfb server on a display number it picks itself (-displayfd), stopped
// by the destructor. Missing Xvfb fails the test (./run installs it).
class Xvfb {
 public:
  Xvfb() {
    int fds[2];
    if (pipe(fds) != 0) throw std::runtime_error("pipe failed");
    pid_ = fork();
    if (pid_ == 0) {
      close(fds[0]);
      const std::string fd = std::to_string(fds[1]);
      const int devnull = open("/dev/null", O_WRONLY);
      dup2(devnull, 2);  // Xvfb's start-up chatter
      execlp("Xvfb", "Xvfb", "-displayfd", fd.c_str(), "-screen", "0", "1280x1024x24", "-nolisten",
             "tcp", "-noreset", static_cast<char*>(nullptr));
      _exit(127);
    }
    close(fds[1]);
    std::string number;
    pollfd p{fds[0], POLLIN, 0};
    char c;
    while (poll(&p, 1, 20000) > 0 && read(fds[0], &c, 1) == 1 && c != '\n') number += c;
    close(fds[0]);
    if (number.empty())
      throw std::runtime_error(
          "Xvfb did not start (is the xvfb package installed? ./run installs it)");
    display_ = ":" + number;
  }
  ~Xvfb() {
    kill(pid_, SIGTERM);
    int status;
    waitpid(pid_, &status, 0);
  }
  const std::string& display() const { return display_; }

 private:
  pid_t pid_ = -1;
  std::string display_;
};

const std::string kBunny = std::string(VOXCAST_SOURCE_DIR) + "/scenes/bunny.obj";

// A small scene, the X server, and DISPLAY pointing at it.
class ViewWindow : public ::testing::Test {
 protected:
  void SetUp() override {
    setenv("DISPLAY", x.display().c_str(), 1);
    unsetenv("WAYLAND_DISPLAY");
    scene = dir.file("bunny.vxc");
    const CliResult b = run_cli("build '" + kBunny + "' -o '" + scene + "' --resolution 128");
    ASSERT_EQ(b.exit_code, 0) << b.output;
    // Three keyframes at 0, 0.5 and 1 s; the last one changes the fovy too.
    path = dir.file("path.json");
    write_text(path, R"({"voxcast_camera_path": 1, "keyframes": [
      {"name": "start", "time": 0, "eye": [0.3, 0.2, 0.5], "target": [0, 0.1, 0]},
      {"name": "side", "time": 0.5, "eye": [0.45, 0.25, 0.1], "target": [-0.01, 0.1, 0]},
      {"name": "end", "time": 1.0, "eye": [-0.2, 0.3, 0.4], "target": [-0.02, 0.1, 0],
       "fovy": 30}]})");
  }
  Xvfb x;
  TempDir dir;
  std::string scene, path;
};

void expect_same_pixels(const Image& a, const Image& b, float tolerance) {
  ASSERT_EQ(a.width, b.width);
  ASSERT_EQ(a.height, b.height);
  ASSERT_EQ(a.pixels.size(), b.pixels.size());
  size_t differ = 0;
  float worst = 0;
  for (size_t i = 0; i < a.pixels.size(); ++i) {
    const float d = std::fabs(a.pixels[i] - b.pixels[i]);
    differ += d > tolerance;
    worst = std::max(worst, d);
  }
  EXPECT_EQ(differ, 0u) << "worst difference " << worst * 255 << " levels";
}

// Lit pixels (not the background): proves an image shows the model.
int lit_pixels(const Image& im) {
  int n = 0;
  for (int y = 0; y < im.height; ++y)
    for (int x = 0; x < im.width; ++x) n += im.at(x, y)[0] > 0.5f;
  return n;
}

// Runs `voxcast ARGS` writing the PFM `out` and adds its pixels to `sum`
// (the first image is kept in `single`).
void add_render(const std::string& args, const std::string& out, std::vector<double>* sum,
                Image* single) {
  const CliResult r = run_cli(args);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const Image im = read_pfm(out);  // bottom row first in the file; read_pfm flips it back
  if (sum->empty()) sum->assign(im.pixels.size(), 0.0), *single = im;
  for (size_t i = 0; i < im.pixels.size(); ++i) (*sum)[i] += im.pixels[i];
}

// The viewer's screenshot `shot` shows the mean of five passes whose sums
// (double) are `sum`, and not just the first pass `single`: both
// sRGB-encoded like the viewer's texture; the viewer sums in float, so one
// 8-bit step is allowed.
void expect_shows_the_mean(const std::string& shot, const std::vector<double>& sum,
                           const Image& single) {
  Image mean = single;
  for (size_t i = 0; i < sum.size(); ++i) mean.pixels[i] = float(sum[i] / 5.0);
  const std::vector<uint8_t> expected = voxcast::png_bytes(mean);
  const std::vector<uint8_t> one_pass = voxcast::png_bytes(single);
  const Image shown = read_png(shot);
  ASSERT_EQ(shown.pixels.size(), expected.size());
  size_t off = 0, differs_from_one_pass = 0;
  for (size_t i = 0; i < expected.size(); ++i) {
    const int got = int(std::lround(shown.pixels[i] * 255.f));
    off += std::abs(got - int(expected[i])) > 1;
    differs_from_one_pass += got != int(one_pass[i]);
  }
  EXPECT_EQ(off, 0u);
  EXPECT_GT(differs_from_one_pass, 100u);
}

}  // namespace

TEST_F(ViewWindow, ScreenshotsAtPathKeyframesEqualRender) {
  // Frame k shows the path at k / fps seconds: with 4 fps, frame 2 is at
  // 0.5 s ("side") and frame 4 and later at the end ("end").
  const std::string common = " --size 200x150 --path '" + path + "'";
  for (const auto& [frames, key] : {std::pair<int, const char*>{3, "side"}, {7, "end"}}) {
    SCOPED_TRACE(key);
    const std::string shot = dir.file(std::string("view-") + key + ".png");
    const std::string ref = dir.file(std::string("render-") + key + ".png");
    const CliResult v = run_cli("view '" + scene + "'" + common + " --fps 4 --frames " +
                                std::to_string(frames) + " --screenshot '" + shot + "'");
    ASSERT_EQ(v.exit_code, 0) << v.output;
    EXPECT_NE(v.output.find("view: " + std::to_string(frames) + " frames"), std::string::npos)
        << v.output;
    const CliResult r =
        run_cli("render '" + scene + "'" + common + " --frame " + key + " -o '" + ref + "'");
    ASSERT_EQ(r.exit_code, 0) << r.output;
    const Image a = read_png(shot), b = read_png(ref);
    EXPECT_GT(lit_pixels(b), 500);  // the bunny is in view
    expect_same_pixels(a, b, 0.f);  // byte for byte
  }
  // And `render --path` writes one image per keyframe, the same as --frame.
  const CliResult all =
      run_cli("render '" + scene + "'" + common + " -o '" + dir.file("k.png") + "'");
  ASSERT_EQ(all.exit_code, 0) << all.output;
  expect_same_pixels(read_png(dir.file("k-001.png")), read_png(dir.file("render-side.png")), 0.f);
  expect_same_pixels(read_png(dir.file("k-002.png")), read_png(dir.file("render-end.png")), 0.f);
  EXPECT_GT(lit_pixels(read_png(dir.file("k-000.png"))), 500);
}

TEST_F(ViewWindow, SettingsMeanWhatRendersFlagsMean) {
  // The viewer's options map onto the same RenderOptions as `render`'s flags:
  // LOD, beam, hard shadows and the post-filter, and the heat map.
  const std::string common = " --size 200x150 --camera auto";
  const std::string v1 = dir.file("v1.png"), r1 = dir.file("r1.png");
  const std::string flags = " --lod 4 --beam 8 --shadows hard --filter";
  ASSERT_EQ(
      run_cli("view '" + scene + "'" + common + flags + " --frames 2 --screenshot '" + v1 + "'")
          .exit_code,
      0);
  ASSERT_EQ(run_cli("render '" + scene + "'" + common + flags + " -o '" + r1 + "'").exit_code, 0);
  expect_same_pixels(read_png(v1), read_png(r1), 0.f);
  const std::string v2 = dir.file("v2.png"), r2 = dir.file("r2.png");
  ASSERT_EQ(run_cli("view '" + scene + "'" + common +
                    " --heatmap --heatmap-max 40 --frames 2 --screenshot '" + v2 + "'")
                .exit_code,
            0);
  ASSERT_EQ(run_cli("render '" + scene + "'" + common + " --heatmap '" + r2 +
                    "' --heatmap-max 40 -o '" + dir.file("color.png") + "'")
                .exit_code,
            0);
  expect_same_pixels(read_png(v2), read_png(r2), 0.f);
  // Not trivially equal: the settings changed the picture.
  const Image plain = read_png(dir.file("color.png")), lod = read_png(r1);
  size_t changed = 0;
  for (size_t i = 0; i < plain.pixels.size(); ++i) changed += plain.pixels[i] != lod.pixels[i];
  EXPECT_GT(changed, 300u);
}

TEST_F(ViewWindow, StillFramesAverageAmbientOcclusionPasses) {
  // The camera reaches the last keyframe at frame 4 (1 s at 4 fps) and stays:
  // frames 4..8 are five passes with seeds 0..4, averaged. The oracle: five
  // `render` runs with those seeds, averaged here in double precision.
  const std::string common = " --size 160x120 --path '" + path + "' --ao 3";
  const std::string shot = dir.file("view.png");
  const CliResult v =
      run_cli("view '" + scene + "'" + common + " --fps 4 --frames 9 --screenshot '" + shot + "'");
  ASSERT_EQ(v.exit_code, 0) << v.output;
  EXPECT_NE(v.output.find("5 passes"), std::string::npos) << v.output;
  std::vector<double> sum;
  Image single;
  for (int seed = 0; seed < 5; ++seed) {
    const std::string out = dir.file("seed" + std::to_string(seed) + ".pfm");
    add_render("render '" + scene + "'" + common + " --frame end --seed " + std::to_string(seed) +
                   " -o '" + out + "'",
               out, &sum, &single);
  }
  // The average is not just the first pass (AO noise differs per seed).
  expect_shows_the_mean(shot, sum, single);
}

namespace {

// `view --gi VIEW_FLAGS` along `path`, still from frame 4 on (at 4 fps):
// frames 4..8 are five passes of kGiSamplesPerPass (2) samples with seeds
// base + k, averaged. The oracle: five `render --gi 2 RENDER_FLAGS --seed k`
// runs, averaged here in double.
void expect_view_shows_gi_passes(const std::string& scene, const std::string& path, TempDir& dir,
                                 const std::string& view_flags, const std::string& render_flags) {
  const std::string common = " --size 96x72 --path '" + path + "'";
  const std::string shot = dir.file("view.png");
  const CliResult v = run_cli("view '" + scene + "'" + common + " --gi" + view_flags +
                              " --fps 4 --frames 9 --screenshot '" + shot + "'");
  ASSERT_EQ(v.exit_code, 0) << v.output;
  EXPECT_NE(v.output.find("5 passes"), std::string::npos) << v.output;
  std::vector<double> sum;
  Image single;
  for (int seed = 0; seed < 5; ++seed) {
    const std::string out = dir.file("gi" + std::to_string(seed) + ".pfm");
    add_render("render '" + scene + "'" + common + " --frame end --gi 2" + render_flags +
                   " --seed " + std::to_string(seed) + " -o '" + out + "'",
               out, &sum, &single);
  }
  expect_shows_the_mean(shot, sum, single);  // path-tracing noise differs per seed
}

}  // namespace

TEST_F(ViewWindow, StillFramesAccumulateGiPasses) {
  // The viewer's default sun is the default light direction, its sky uniform 1.
  expect_view_shows_gi_passes(scene, path, dir, " --bounces 3", " --bounces 3 --sun -0.4,-1,-0.6");
}

TEST_F(ViewWindow, EnvironmentSunAndAntialiasingMeanWhatRendersFlagsMean) {
  // --env, --env-scale, --sun, --sun-intensity and --bounce-cone are render
  // --gi's.
  const std::string sky = std::string(VOXCAST_SOURCE_DIR) + "/scenes/sky.hdr";
  const std::string gi_flags = " --bounces 2 --env '" + sky +
                               "' --env-scale 0.7 --sun 0.3,-1,0.2 --sun-intensity 2 "
                               "--bounce-cone 2";
  expect_view_shows_gi_passes(scene, path, dir, gi_flags, gi_flags);
  // --spp: one pass without AO is final and is render --spp's image.
  const std::string aa = dir.file("aa.png"), ref = dir.file("aa-render.png");
  const CliResult a = run_cli("view '" + scene + "' --size 160x120 --camera auto --spp 4 " +
                              "--frames 2 --screenshot '" + aa + "'");
  ASSERT_EQ(a.exit_code, 0) << a.output;
  EXPECT_NE(a.output.find("1 pass)"), std::string::npos) << a.output;
  ASSERT_EQ(run_cli("render '" + scene + "' --size 160x120 --camera auto --spp 4 -o '" + ref + "'")
                .exit_code,
            0);
  expect_same_pixels(read_png(aa), read_png(ref), 0.f);
  ASSERT_EQ(run_cli("render '" + scene + "' --size 160x120 --camera auto -o '" +
                    dir.file("plain.png") + "'")
                .exit_code,
            0);
  EXPECT_NE(read_png(aa).pixels, read_png(dir.file("plain.png")).pixels);
  // A broken environment map: one line, exit 1; --spp 0: usage, exit 2.
  const std::string bad = dir.file("bad.hdr");
  {
    std::FILE* f = std::fopen(bad.c_str(), "wb");
    std::fputs("#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 4 +X 4\n", f);
    std::fclose(f);
  }
  const CliResult b = run_cli("view '" + scene + "' --frames 1 --gi --env '" + bad + "'");
  EXPECT_EQ(b.exit_code, 1) << b.output;
  EXPECT_EQ(std::count(b.output.begin(), b.output.end(), '\n'), 1) << b.output;
  EXPECT_EQ(run_cli("view '" + scene + "' --frames 1 --spp 0").exit_code, 2);
}

TEST_F(ViewWindow, ScreenshotWithThePanelShowsIt) {
  const std::string plain = dir.file("plain.png"), ui = dir.file("ui.png");
  const std::string common = " --size 480x360 --frames 3 --camera auto";
  ASSERT_EQ(run_cli("view '" + scene + "'" + common + " --screenshot '" + plain + "'").exit_code,
            0);
  const CliResult r =
      run_cli("view '" + scene + "'" + common + " --screenshot-ui --screenshot '" + ui + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const Image a = read_png(plain), b = read_png(ui);
  ASSERT_EQ(a.pixels.size(), b.pixels.size());
  // The panel (right) and the overlay (top left) cover part of the frame;
  // the bottom-left corner stays the CPU frame.
  size_t changed = 0;
  for (size_t i = 0; i < a.pixels.size(); ++i) changed += a.pixels[i] != b.pixels[i];
  EXPECT_GT(changed, a.pixels.size() / 10);
  for (int y = b.height - 20; y < b.height; ++y)
    for (int x = 0; x < 20; ++x)
      for (int c = 0; c < 3; ++c) ASSERT_EQ(a.at(x, y)[c], b.at(x, y)[c]) << x << "," << y;
  // Without a camera path the first camera is --camera auto, as in render.
  const CliResult ref = run_cli("render '" + scene + "' --size 480x360 --camera auto -o '" +
                                dir.file("auto.png") + "'");
  ASSERT_EQ(ref.exit_code, 0) << ref.output;
  expect_same_pixels(a, read_png(dir.file("auto.png")), 0.f);
}

TEST_F(ViewWindow, NoDisplayIsAOneLineErrorExit1) {
  unsetenv("DISPLAY");
  const CliResult r = run_cli("view '" + scene + "' --frames 1");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_EQ(r.output.rfind("voxcast: error: view: no display", 0), 0u) << r.output;
  EXPECT_EQ(std::count(r.output.begin(), r.output.end(), '\n'), 1) << r.output;
  // A display that does not exist: the same kind of line.
  setenv("DISPLAY", ":4242", 1);
  const CliResult bad = run_cli("view '" + scene + "' --frames 1");
  EXPECT_EQ(bad.exit_code, 1) << bad.output;
  EXPECT_EQ(bad.output.rfind("voxcast: error: view: cannot open the display", 0), 0u) << bad.output;
  EXPECT_EQ(std::count(bad.output.begin(), bad.output.end(), '\n'), 1) << bad.output;
}

TEST_F(ViewWindow, UsageAndInputErrors) {
  const std::string v = "view '" + scene + "' ";
  const CliResult help = run_cli("view --help");
  EXPECT_EQ(help.exit_code, 0);
  EXPECT_NE(help.output.find("--screenshot"), std::string::npos) << help.output;
  for (const std::string& bad :
       {v + "--frames 0", v + "--frames 1 --fps 0", v + "--frames 1 --shadows soft",
        v + "--frames 1 --beam 1", v + "--frames 1 --passes 0", v + "--frames 1 --lod nan",
        v + "--frames -1", v + "--frames 1 --fps nan", v + "--frames 1 --ao-radius nan",
        v + "--frames 1 --heatmap-max inf", v + "--frames 1 --seed -1", v + "--frames 1 --ao -1",
        v + "--record '" + dir.file("r.txt") + "'",
        v + "--frames 1 --path '" + path + "' --orbit 10,10", v + "--screenshot-ui",
        v + "--frames 1 --screenshot '" + dir.file("x.jpg") + "'", v + "--size 0x0 --frames 1",
        "render '" + scene + "' -o '" + dir.file("a.png") + "' --frame end",
        "render '" + scene + "' -o '" + dir.file("a.png") + "' --path '" + path +
            "' --look-at 1,1,1,0,0,0"}) {
    const CliResult r = run_cli(bad);
    EXPECT_EQ(r.exit_code, 2) << bad << "\n" << r.output;
    EXPECT_EQ(r.output.rfind("voxcast: error: ", 0), 0u) << bad << "\n" << r.output;
  }
  // Damaged camera paths and unknown keyframes: runtime errors naming the file.
  const std::string broken = dir.file("broken.json");
  write_text(broken, R"({"voxcast_camera_path": 1, "keyframes": [{"time": 0, "eye": [0, 0, 1]}]})");
  for (const std::string& bad :
       {v + "--frames 1 --path '" + broken + "'",
        "render '" + scene + "' -o '" + dir.file("a.png") + "' --path '" + broken + "'",
        "render '" + scene + "' -o '" + dir.file("a.png") + "' --path '" + path + "' --frame nope",
        v + "--frames 1 --path '" + dir.file("missing.json") + "'"}) {
    const CliResult r = run_cli(bad);
    EXPECT_EQ(r.exit_code, 1) << bad << "\n" << r.output;
    EXPECT_EQ(r.output.rfind("voxcast: error: ", 0), 0u) << bad << "\n" << r.output;
    EXPECT_EQ(std::count(r.output.begin(), r.output.end(), '\n'), 1) << r.output;
  }
  EXPECT_NE(run_cli(v + "--frames 1 --path '" + broken + "'").output.find("missing 'target'"),
            std::string::npos);
}

// The interactive mode driven like a user would, with X events from xdotool:
// R starts recording, a left drag orbits, W walks forward, R stops and
// saves, P replays the recording, F12 saves a screenshot, Esc quits. The
// recording is read here with a JSON parser of its own, and the screenshot
// after the replay must show the recording's last keyframe as `render` draws it.
TEST_F(ViewWindow, InteractiveRecordReplayAndScreenshot) {
  const std::string rec = dir.file("rec.json"), shot = dir.file("shot.png");
  const std::string log = dir.file("view.log"), script = dir.file("drive.sh");
  const std::string launch = std::string("'") + VOXCAST_CLI_PATH + "' view '" + scene +
                             "' --size 320x240 --no-panel --record '" + rec + "' --screenshot '" +
                             shot + "' > '" + log + "' 2>&1 &\n";
  // The sleeps leave the viewer time to render between the steps; the path
  // recorded lasts ~2.5 s, so 6 s after P its replay is over and the still
  // camera has a full-resolution frame. Escape is sent with "|| true": the
  // window may be gone before xdotool sends the key's release.
  const std::string steps = R"(pid=$!
wid=$(timeout 30 xdotool search --sync --name 'voxcast view' | head -1)
sleep 1
xdotool mousemove --window $wid 160 120
xdotool key --window $wid r
sleep 0.5
xdotool mousedown 1
for i in 1 2 3 4 5 6 7 8 9 10; do xdotool mousemove_relative -- 8 0; sleep 0.05; done
xdotool mouseup 1
sleep 0.5
xdotool keydown w; sleep 0.3; xdotool keyup w
sleep 0.5
xdotool key --window $wid r
sleep 0.5
xdotool key --window $wid p
sleep 6
xdotool key --window $wid F12
sleep 1
xdotool key --window $wid Escape || true
wait $pid
)";
  write_text(script, "set -e\n" + launch + steps);
  const std::string drive_log = dir.file("drive.log");
  const int rc =
      std::system(("timeout 90 sh -x '" + script + "' > '" + drive_log + "' 2>&1").c_str());
  const std::string out = read_text(log);
  ASSERT_EQ(rc, 0) << out << "\n" << read_text(drive_log);
  EXPECT_NE(out.find("view: recorded "), std::string::npos) << out;
  EXPECT_NE(out.find("view: screenshot " + shot), std::string::npos) << out;

  const nlohmann::json doc = nlohmann::json::parse(read_text(rec));
  ASSERT_EQ(doc.at("voxcast_camera_path"), 1);
  const nlohmann::json& keys = doc.at("keyframes");
  ASSERT_GE(keys.size(), 3u) << doc.dump();
  auto vec = [](const nlohmann::json& v) {
    return std::vector<double>{v[0].get<double>(), v[1].get<double>(), v[2].get<double>()};
  };
  auto dist = [](const std::vector<double>& a, const std::vector<double>& b) {
    return std::sqrt((a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) +
                     (a[2] - b[2]) * (a[2] - b[2]));
  };
  for (size_t i = 1; i < keys.size(); ++i)
    EXPECT_GT(keys[i].at("time").get<double>(), keys[i - 1].at("time").get<double>());
  // The recording starts at the first camera: `render --camera auto`'s.
  const CliResult auto_cam =
      run_cli("render '" + scene + "' --size 320x240 -o '" + dir.file("auto.png") + "'");
  ASSERT_EQ(auto_cam.exit_code, 0) << auto_cam.output;
  std::vector<double> cam;
  {
    const size_t at = auto_cam.output.find("camera: ");
    ASSERT_NE(at, std::string::npos) << auto_cam.output;
    std::string list = auto_cam.output.substr(at + 8);
    for (size_t pos = 0; cam.size() < 6;) {
      cam.push_back(std::stod(list.substr(pos)));
      pos = list.find(',', pos) + 1;
    }
  }
  const std::vector<double> eye0 = vec(keys[0].at("eye")), target0 = vec(keys[0].at("target"));
  EXPECT_LT(dist(eye0, {cam[0], cam[1], cam[2]}), 1e-6);
  EXPECT_LT(dist(target0, {cam[3], cam[4], cam[5]}), 1e-6);
  // The drag orbits: some keyframe keeps the target and the distance to it
  // while the eye has moved.
  const double d0 = dist(eye0, target0);
  bool orbited = false;
  for (const auto& k : keys) {
    const std::vector<double> e = vec(k.at("eye")), t = vec(k.at("target"));
    if (dist(t, target0) < 1e-6 && dist(e, eye0) > 0.05 * d0 &&
        std::fabs(dist(e, t) - d0) < 1e-4 * d0)
      orbited = true;
  }
  EXPECT_TRUE(orbited) << doc.dump();
  // W walked: the last keyframe's target has moved towards where the eye looked.
  EXPECT_GT(dist(vec(keys.back().at("target")), target0), 0.01 * d0) << doc.dump();

  // After the replay the window shows the last keyframe, as `render` draws it
  // (below the frame-time overlay, top left).
  const CliResult ref =
      run_cli("render '" + scene + "' --size 320x240 --path '" + rec + "' --frame " +
              std::to_string(keys.size() - 1) + " -o '" + dir.file("last.png") + "'");
  ASSERT_EQ(ref.exit_code, 0) << ref.output;
  const Image a = read_png(shot), b = read_png(dir.file("last.png"));
  ASSERT_EQ(a.width, b.width);
  ASSERT_EQ(a.height, b.height);
  size_t differ = 0;
  for (int y = 90; y < a.height; ++y)
    for (int x = 0; x < a.width; ++x)
      for (int c = 0; c < 3; ++c) differ += a.at(x, y)[c] != b.at(x, y)[c];
  EXPECT_EQ(differ, 0u);
  EXPECT_GT(lit_pixels(b), 500);
}
