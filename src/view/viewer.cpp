// The viewer's main loop (viewer.hpp): input -> camera -> progressive render
// -> texture -> window, with the ImGui panel on top.
#include "view/viewer.hpp"

#include <GLFW/glfw3.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>

#include "view/camera_controller.hpp"
#include "view/gl_frame.hpp"
#include "view/panel.hpp"
#include "view/progressive.hpp"
#include "view/window.hpp"

namespace voxcast::view {

namespace {

using Clock = std::chrono::steady_clock;
double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

bool same_camera(const Camera& a, const Camera& b) {
  auto eq = [](Vec3 u, Vec3 v) { return u.x == v.x && u.y == v.y && u.z == v.z; };
  return eq(a.eye, b.eye) && eq(a.target, b.target) && eq(a.up, b.up) &&
         a.fovy_degrees == b.fovy_degrees && a.projection == b.projection &&
         a.ortho_width == b.ortho_width;
}

SceneStats scene_stats(const LoadedScene& scene) {
  SceneStats s;
  auto row = [&](const char* label, std::string value) { s.rows.emplace_back(label, value); };
  row("format", scene.format + " (" + scene.structure->name() + ")");
  if (!scene.info.source.empty()) row("source", scene.info.source);
  if (!scene.info.voxelization.empty()) row("voxelization", scene.info.voxelization);
  if (scene.info.source_triangles) row("triangles", std::to_string(scene.info.source_triangles));
  if (scene.info.leaf_voxels) row("leaf voxels", std::to_string(scene.info.leaf_voxels));
  std::string sections;
  for (uint32_t id : scene.sections) {
    if (!sections.empty()) sections += ' ';
    sections += fourcc_name(id);
  }
  row("sections", sections);
  const Vec3 e = scene.occupied.extent();
  char buf[96];
  std::snprintf(buf, sizeof buf, "%.3g x %.3g x %.3g", double(e.x), double(e.y), double(e.z));
  row("occupied", buf);
  return s;
}

// The next "voxcast-screenshot-NNN.png" that does not exist yet.
std::string numbered_screenshot() {
  for (int i = 1; i < 100000; ++i) {
    char name[64];
    std::snprintf(name, sizeof name, "voxcast-screenshot-%03d.png", i);
    std::error_code ec;
    if (!std::filesystem::exists(name, ec)) return name;
  }
  return "voxcast-screenshot.png";
}

// A line for the terminal the viewer was started from, right away (stdout
// may be a pipe, which would hold it until exit).
void say(const std::string& line) {
  std::printf("%s\n", line.c_str());
  std::fflush(stdout);
}

Image as_image(const WindowPixels& p) {
  Image im(p.width, p.height, 3);
  for (size_t i = 0; i < p.rgb.size(); ++i) im.pixels[i] = float(p.rgb[i]) / 255.f;
  return im;
}

// The preview resolution divisor while the camera moves: the last frame's
// cost per pixel says how many pixels fit in ~1/30 s.
int preview_scale(double seconds_per_pixel, int width, int height) {
  if (!(seconds_per_pixel > 0)) return 1;
  const double full = seconds_per_pixel * double(width) * double(height);
  const int s = int(std::ceil(std::sqrt(full / (1.0 / 30.0))));
  return std::clamp(s, 1, 8);
}

}  // namespace

ViewerReport run_viewer(const LoadedScene& scene, const ViewerOptions& o) {
  const bool scripted = o.frames >= 0;
  Window window(o.width, o.height, o.title, /*vsync=*/!scripted);
  FrameTexture texture;
  Gui gui(window.handle());
  const Structure& structure = *scene.structure;
  const float scene_size = length(scene.occupied.extent());

  CameraController controller;
  controller.reset(o.camera, scene_size);
  ViewSettings settings = o.settings;
  int max_passes = o.max_passes;
  CameraMode mode = CameraMode::Orbit;
  float speed = controller.speed();
  bool show_panel = o.show_panel;
  Accumulator accumulator(max_passes);
  const SceneStats stats = scene_stats(scene);

  // Path playback: scripted runs play o.path from frame 0 on frame time;
  // interactive playback (P) on the wall clock.
  const CameraPath* playing = scripted && o.path ? &*o.path : nullptr;
  Clock::time_point play_start = Clock::now();
  CameraPath recorded;
  bool recording = false;
  Clock::time_point record_start;

  Camera shown_camera;
  ViewSettings shown_settings;
  int shown_width = 0, shown_height = 0;
  bool have_shown = false;
  double seconds_per_pixel = 0;
  FrameStatus status;
  ViewerReport report;
  double cursor_x = 0, cursor_y = 0;
  glfwGetCursorPos(window.handle(), &cursor_x, &cursor_y);
  Clock::time_point last_frame = Clock::now();
  PanelActions pending;  // the panel's buttons act on the next frame, like their keys

  for (int frame = 0;; ++frame) {
    if (scripted && frame >= o.frames) break;
    if (window.should_close()) break;
    // Nothing left to refine and nothing moving: wait for input instead of
    // spinning (the machine's cores belong to the renderer).
    const bool pending_action =
        pending.toggle_record || pending.play || pending.screenshot || pending.reframe;
    if (!scripted && accumulator.done() && !playing && !recording && !pending_action)
      glfwWaitEventsTimeout(0.25);
    else
      glfwPollEvents();
    const Clock::time_point frame_start = Clock::now();
    const double dt = std::chrono::duration<double>(frame_start - last_frame).count();
    last_frame = frame_start;
    int W = 0, H = 0;
    window.framebuffer_size(&W, &H);
    if (W <= 0 || H <= 0) continue;  // minimized
    gui.begin_frame();

    // ---- input ----
    bool take_screenshot = (scripted && frame == o.frames - 1) || pending.screenshot;
    bool toggle_record = pending.toggle_record, play = pending.play, reframe = pending.reframe;
    pending = PanelActions{};
    double mx = 0, my = 0;
    glfwGetCursorPos(window.handle(), &mx, &my);
    const double dx = mx - cursor_x, dy = my - cursor_y;
    cursor_x = mx, cursor_y = my;
    const double scroll = window.take_scroll();
    if (!scripted) {
      if (!gui.wants_keyboard()) {
        if (window.pressed(GLFW_KEY_ESCAPE)) window.request_close();
        if (window.pressed(GLFW_KEY_TAB))
          mode = mode == CameraMode::Orbit ? CameraMode::Fly : CameraMode::Orbit;
        if (window.pressed(GLFW_KEY_H)) settings.heatmap = !settings.heatmap;
        if (window.pressed(GLFW_KEY_R)) toggle_record = true;
        if (window.pressed(GLFW_KEY_P)) play = true;
        if (window.pressed(GLFW_KEY_F)) reframe = true;
        if (window.pressed(GLFW_KEY_F1)) show_panel = !show_panel;
        if (window.pressed(GLFW_KEY_F12)) take_screenshot = true;
      }
      ControllerInput in;
      if (!gui.wants_mouse()) {
        in.dx = dx, in.dy = dy;
        in.rotate = glfwGetMouseButton(window.handle(), GLFW_MOUSE_BUTTON_LEFT) == GLFW_PRESS;
        in.pan = glfwGetMouseButton(window.handle(), GLFW_MOUSE_BUTTON_RIGHT) == GLFW_PRESS ||
                 glfwGetMouseButton(window.handle(), GLFW_MOUSE_BUTTON_MIDDLE) == GLFW_PRESS;
        in.scroll = scroll;
      }
      if (!gui.wants_keyboard()) {
        auto down = [&](int key) { return glfwGetKey(window.handle(), key) == GLFW_PRESS; };
        in.forward = down(GLFW_KEY_W), in.back = down(GLFW_KEY_S);
        in.left = down(GLFW_KEY_A), in.right = down(GLFW_KEY_D);
        in.up = down(GLFW_KEY_E), in.down = down(GLFW_KEY_Q);
        in.fast = down(GLFW_KEY_LEFT_SHIFT) || down(GLFW_KEY_RIGHT_SHIFT);
      }
      in.dt = dt;
      controller.set_mode(mode);
      controller.set_speed(speed);
      // Any camera input takes over from a playing path.
      if (controller.update(in, W, H)) playing = nullptr;
    }
    if (reframe) {
      controller.reset(Camera::frame(scene.occupied, W, H), scene_size);
      playing = nullptr;
    }
    if (play) {
      playing = !recorded.keyframes.empty() ? &recorded : (o.path ? &*o.path : nullptr);
      play_start = frame_start;
      if (!playing) say("view: no camera path to play (record one with R)");
    }

    // ---- camera ----
    Camera camera = controller.camera();
    if (playing) {
      const double t = scripted ? playing->start() + double(frame) / o.fps
                                : playing->start() + seconds_since(play_start);
      camera = playing->at(t);
      if (!scripted && t >= playing->end()) {  // done: hand the last camera to the controller
        controller.reset(camera, scene_size);
        playing = nullptr;
      }
    }
    if (toggle_record) {
      if (!recording) {
        recorded.keyframes.clear();
        recorded.keyframes.push_back({"", 0.0, camera});
        record_start = frame_start;
        recording = true;
      } else {
        recording = false;
        const double t =
            std::max(seconds_since(record_start), recorded.keyframes.back().time + 1e-3);
        if (!same_camera(camera, recorded.keyframes.back().camera))
          recorded.keyframes.push_back({"", t, camera});
        recorded.save(o.record_path);
        say("view: recorded " + std::to_string(recorded.keyframes.size()) + " keyframes to " +
            o.record_path);
      }
    } else if (recording) {
      // A keyframe at most every 1/10 s while the camera moves: linear
      // interpolation between them replays the motion closely.
      const double t = seconds_since(record_start);
      if (!same_camera(camera, recorded.keyframes.back().camera) &&
          t >= recorded.keyframes.back().time + 0.1)
        recorded.keyframes.push_back({"", t, camera});
    }

    // ---- progressive render ----
    // Only AO and GI samples change with the seed; other frames are final after one pass.
    accumulator.set_max_passes(refines(settings) ? max_passes : 1);
    const bool view_changed = !have_shown || !same_camera(camera, shown_camera) ||
                              !(settings == shown_settings) || W != shown_width ||
                              H != shown_height;
    if (view_changed) accumulator.reset();
    const bool render_now = view_changed || !accumulator.done();
    if (render_now) {
      // While the camera moves interactively, one cheap frame at reduced
      // resolution; once it stops, full-resolution passes are averaged.
      const int scale =
          !scripted && view_changed && have_shown ? preview_scale(seconds_per_pixel, W, H) : 1;
      const int rw = std::max(1, W / scale), rh = std::max(1, H / scale);
      const uint32_t seed =
          scale == 1 ? settings.seed + uint32_t(accumulator.passes() * seeds_per_pass(settings))
                     : settings.seed;
      const RenderOptions options = render_options(settings, camera, rw, rh, scene.occupied, seed);
      ViewFrame f = render_frame(structure, options, settings);
      seconds_per_pixel = f.seconds / (double(rw) * double(rh));
      const Image* shown = &f.color;
      if (scale == 1) {
        accumulator.add(f.color);
        shown = &accumulator.mean();
      }
      texture.upload(shown->width, shown->height, png_bytes(*shown));
      status.render_ms = f.seconds * 1e3;
      status.mrays = f.seconds > 0 ? double(f.rays) / f.seconds * 1e-6 : 0;
      status.mrays_total = f.seconds > 0 ? double(f.rays + f.secondary_rays) / f.seconds * 1e-6 : 0;
      status.preview_scale = scale;
      status.width = rw, status.height = rh;
      shown_camera = camera, shown_settings = settings;
      shown_width = W, shown_height = H;
      have_shown = true;
      // A preview frame leaves the accumulator empty, so the next still
      // frame starts the full-resolution passes.
      if (scale > 1) accumulator.reset();
    }
    status.passes = accumulator.passes();
    status.max_passes = accumulator.max_passes();
    status.recording = recording;
    status.recorded_keyframes = recorded.keyframes.size();
    status.playing = playing != nullptr;
    status.camera = camera;

    // ---- display ----
    texture.blit(W, H);
    WindowPixels shot;
    const bool shot_with_ui = scripted ? o.screenshot_ui : true;
    if (take_screenshot && !shot_with_ui) shot = read_back_buffer(W, H);
    pending = gui.panel(show_panel, stats, &settings, &max_passes, &mode, &speed, status);
    gui.end_frame();
    if (take_screenshot && shot_with_ui) shot = read_back_buffer(W, H);
    window.swap();
    if (!shot.rgb.empty()) {
      if (scripted) {
        report.screenshot = as_image(shot);
      } else {
        const std::string file =
            o.screenshot_path.empty() ? numbered_screenshot() : o.screenshot_path;
        write_image(file, as_image(shot), /*already_srgb=*/true);
        say("view: screenshot " + file + " (" + std::to_string(shot.width) + "x" +
            std::to_string(shot.height) + ")");
      }
    }
    // The overlay shows the last frame that rendered (idle frames only redraw).
    if (render_now) status.frame_ms = seconds_since(frame_start) * 1e3;
    if (!scripted) {
      char title[256];
      std::snprintf(title, sizeof title, "%s  %.1f ms  %.1f Mrays/s", o.title.c_str(),
                    status.frame_ms, status.mrays);
      window.set_title(title);
    }
    report.frames = frame + 1;
    report.last_camera = camera;
    report.passes = accumulator.passes();
  }
  return report;
}

}  // namespace voxcast::view
