// voxcast view SCENE: the interactive viewer (src/view), and its scripted
// mode for tests and automation (--frames N [--screenshot OUT.png]).
#include <cstdio>
#include <memory>
#include <optional>
#include <string>

#include "camera_options.hpp"
#include "cli_io.hpp"
#include "commands.hpp"
#include "gi_cli.hpp"
#include "view/camera_path.hpp"
#include "view/viewer.hpp"
#include "voxcast/error.hpp"
#include "voxcast/scene_file.hpp"

namespace voxcast::cli {

namespace {
struct ViewArgs {
  std::string input, size = "1024x768", path, screenshot, record = "camera_path.json";
  std::string shadows = "none";
  CameraArgs camera;
  int frames = 0;  // 0: interactive (the option's absence)
  double fps = 30;
  bool screenshot_ui = false, no_panel = false, filter = false, heatmap = false;
  float lod = 1.f, ao_radius = 0.f, heatmap_max = 64.f;
  int beam = 0, ao = 0, passes = 16, threads = 0;
  bool gi = false, no_sun = false;  // progressive GI (G toggles it in the panel)
  int bounces = 8, spp = 1;
  GiArgs gi_args;  // --env, --env-scale, --no-env-sampling, --sun, --sun-intensity, --bounce-cone
  uint32_t seed = 0;
  CLI::Option* frames_option = nullptr;
};
}  // namespace

Runner add_view(CLI::App& app) {
  auto args = std::make_shared<ViewArgs>();
  CLI::App* cmd = app.add_subcommand(
      "view", "Open a window on a scene: orbit/fly camera, settings panel, camera paths");
  cmd->add_option("SCENE", args->input, "Scene file written by `voxcast build`")->required();
  cmd->add_option("--size", args->size, "Window size WxH")->capture_default_str();
  add_camera_options(cmd, args->camera);
  cmd->add_option("--path", args->path,
                  "Camera path (JSON, README 'Camera path JSON'): the first camera; P plays "
                  "it, and a scripted run (--frames) plays it from the first frame");
  args->frames_option =
      cmd->add_option("--frames", args->frames,
                      "Scripted mode: run N frames, then exit (the window opens all the same)");
  cmd->add_option("--fps", args->fps, "Scripted mode: path seconds per frame = 1/FPS")
      ->capture_default_str();
  cmd->add_option("--screenshot", args->screenshot,
                  "PNG of the last scripted frame as the window shows it; interactive: where "
                  "F12 saves (default voxcast-screenshot-NNN.png)");
  cmd->add_flag("--screenshot-ui", args->screenshot_ui,
                "The scripted screenshot includes the panel and the frame-time overlay");
  cmd->add_option("--record", args->record, "Where R saves a recorded camera path")
      ->capture_default_str();
  cmd->add_flag("--no-panel", args->no_panel, "Start with the panel hidden (F1 shows it)");
  cmd->add_option("--lod", args->lod, "LOD in pixels (0 = finest level)")->capture_default_str();
  cmd->add_option("--beam", args->beam, "Beam block size (0 = off)")->capture_default_str();
  cmd->add_option("--shadows", args->shadows, "none | hard")->capture_default_str();
  cmd->add_option("--ao", args->ao, "Ambient occlusion rays per pixel and pass (0 = off)")
      ->capture_default_str();
  cmd->add_option("--ao-radius", args->ao_radius,
                  "AO ray length in world units (0 = 5% of the scene diagonal)")
      ->capture_default_str();
  cmd->add_flag("--filter", args->filter, "Adaptive post-filter (esvo paper section 6.3)");
  cmd->add_flag("--heatmap", args->heatmap, "Show the iteration heat map (H toggles it)");
  cmd->add_option("--heatmap-max", args->heatmap_max, "Iterations at the top of the ramp")
      ->capture_default_str();
  cmd->add_option("--passes", args->passes,
                  "Passes averaged once the camera stops (AO and GI samples refine; 1..256)")
      ->capture_default_str();
  cmd->add_option("--seed", args->seed, "Effect seed of the first pass (pass k: seed + k)")
      ->capture_default_str()
      ->check(not_negative());
  cmd->add_flag("--gi", args->gi,
                "Progressive diffuse GI: path-traced samples accumulate while the camera "
                "stands still (up to --passes passes)");
  cmd->add_option("--bounces", args->bounces, "With --gi: diffuse bounces at most")
      ->capture_default_str();
  cmd->add_flag("--no-sun", args->no_sun, "With --gi: no sun, the environment alone");
  cmd->add_option("--env", args->gi_args.env,
                  "With --gi: environment map (.hdr or .exr, latitude-longitude), as render "
                  "--env; default a uniform sky of radiance 1");
  cmd->add_option("--env-scale", args->gi_args.env_scale, "With --gi: multiplies the environment")
      ->capture_default_str();
  cmd->add_flag("--no-env-sampling", args->gi_args.no_env_sampling,
                "With --env: cosine bounces alone (as render --no-env-sampling)");
  cmd->add_option("--sun", args->gi_args.sun,
                  "With --gi: the sun travels along dx,dy,dz (default -0.4,-1,-0.6, the "
                  "surface shading's light)");
  cmd->add_option("--sun-intensity", args->gi_args.sun_intensity,
                  "With --gi: the sun's irradiance on a surface facing it")
      ->capture_default_str();
  cmd->add_option("--bounce-cone", args->gi_args.bounce_cone,
                  "With --gi: LOD cone of the rays after the first hit, degrees (0 = finest)")
      ->capture_default_str();
  cmd->add_option("--spp", args->spp,
                  "Antialiasing of the surface shading: jittered camera rays per pixel and "
                  "pass, as render --spp (1..4096)")
      ->capture_default_str();
  cmd->add_option("--threads", args->threads, "Render threads (0 = all cores)");
  return [args]() {
    ThreadLimit limit(args->threads);
    view::ViewerOptions o;
    parse_size(args->size, &o.width, &o.height);
    const bool scripted = args->frames_option->count() > 0;
    if (scripted) require_range("--frames", args->frames, 1, 1e6);
    o.frames = scripted ? args->frames : -1;
    require_range("--fps", args->fps, 1e-3, 1e6);
    o.fps = args->fps;
    require_range("--lod", args->lod, 0, 1e6);
    if (args->beam != 0 && (args->beam < 2 || args->beam > 64))
      throw UsageError("--beam must be 0 (off) or a block size in 2..64");
    if (args->shadows != "none" && args->shadows != "hard")
      throw UsageError("--shadows must be none or hard");
    require_range("--ao", args->ao, 0, 4096);
    require_range("--ao-radius", args->ao_radius, 0, 1e30);
    require_range("--heatmap-max", args->heatmap_max, 1e-6, 1e9);
    require_range("--passes", args->passes, 1, 256);
    require_range("--bounces", args->bounces, 0, 1024);
    require_range("--spp", args->spp, 1, 4096);
    // The GI options through render's checks (gi_cli.hpp); the sun is on
    // unless --no-sun, along the surface shading's light unless --sun.
    GiArgs gi_args = args->gi_args;
    gi_args.spp = 1;
    if (gi_args.sun.empty()) gi_args.sun = "-0.4,-1,-0.6";
    const GiOptions gi = gi_options(gi_args, "", args->seed);
    if (args->no_sun && !args->gi_args.sun.empty())
      throw UsageError("--sun and --no-sun exclude each other");
    if (args->screenshot_ui && !scripted)
      throw UsageError("--screenshot-ui is for scripted runs (--frames N)");
    refuse_camera_options_with_path(args->camera, args->path);
    check_camera_options(args->camera, o.width, o.height);
    view::ViewSettings& s = o.settings;
    s.lod_pixels = args->lod;
    s.beam = args->beam;
    s.hard_shadows = args->shadows == "hard";
    s.ao_rays = args->ao;
    s.ao_radius = args->ao_radius;
    s.filter = args->filter;
    s.heatmap = args->heatmap;
    s.heatmap_max = args->heatmap_max;
    s.seed = args->seed;
    s.gi = args->gi;
    s.gi_bounces = args->bounces;
    s.gi_sun = !args->no_sun;
    const Vec3 sun = parse_vec3(gi_args.sun, "--sun");  // as given: render_frame normalizes
    s.gi_sun_dir = {sun.x, sun.y, sun.z};
    s.gi_sun_intensity = gi_args.sun_intensity;
    s.gi_bounce_cone = gi.bounce_cone_deg;
    s.gi_env_sampling = gi.env_sampling;
    s.spp = args->spp;
    o.max_passes = args->passes;
    o.show_panel = !args->no_panel;
    o.screenshot_ui = args->screenshot_ui;
    o.record_path = args->record;

    std::vector<std::string> inputs = {args->input};
    if (!args->path.empty()) inputs.push_back(args->path);
    if (!args->gi_args.env.empty()) inputs.push_back(args->gi_args.env);
    OutputSet outputs(inputs);
    if (scripted && !args->screenshot.empty())
      outputs.add("--screenshot", args->screenshot, {".png"});
    if (!scripted) {
      OutputSet check(inputs);  // refused up front, written when R stops a recording
      check.add("--record", args->record, {".json"});
      if (!args->screenshot.empty()) check.add("--screenshot", args->screenshot, {".png"});
      o.screenshot_path = args->screenshot;
    }
    require_regular_input(args->input, "scene");
    if (!args->path.empty()) {
      require_regular_input(args->path, "camera path");
      o.path = view::CameraPath::load(args->path);
    }
    if (!args->gi_args.env.empty()) {
      GiOptions loaded = gi;
      load_gi_environment(gi_args, &loaded);
      s.gi_environment = loaded.environment;
    } else if (gi_args.env_scale != 1.f) {
      s.gi_environment = gi.environment;  // the uniform sky times --env-scale
    }
    LoadedScene scene = load_scene(args->input);
    o.camera = o.path ? o.path->keyframes.front().camera
                      : resolve_camera(args->camera, scene.occupied, o.width, o.height);
    o.title = "voxcast view  " + printable(args->input);
    const view::ViewerReport report = view::run_viewer(scene, o);
    if (scripted) {
      if (!args->screenshot.empty()) {
        outputs.write(args->screenshot, [&](const std::filesystem::path& to) {
          write_image(to, report.screenshot, /*already_srgb=*/true);
        });
        outputs.commit();
        std::printf("view: %d frames, screenshot %s (%dx%d, %d pass%s), camera %s\n", report.frames,
                    printable(args->screenshot).c_str(), report.screenshot.width,
                    report.screenshot.height, report.passes, report.passes == 1 ? "" : "es",
                    report.last_camera.to_string().c_str());
      } else {
        std::printf("view: %d frames, camera %s\n", report.frames,
                    report.last_camera.to_string().c_str());
      }
    }
    return 0;
  };
}

}  // namespace voxcast::cli
