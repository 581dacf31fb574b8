// voxcast render SCENE -o IMAGE: ray cast a scene file into an image.
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "camera_options.hpp"
#include "cli_io.hpp"
#include "cmd_render_sliced.hpp"
#include "commands.hpp"
#include "exr_output.hpp"
#include "gi_cli.hpp"
#include "stream_render.hpp"
#include "view/camera_path.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/format_registry.hpp"
#include "voxcast/progress.hpp"
#include "voxcast/render.hpp"
#include "voxcast/scene_file.hpp"
#include "voxcast/system.hpp"

namespace voxcast::cli {

namespace {
struct RenderArgs {
  std::string input, output, size = "1024x768", depth, normal, light;
  std::string aov;  // EXR output: extra layers in the same file
  CameraArgs camera;
  float lod = 1.f;
  int threads = 0;
  bool verbose = false;
  int beam = 0;                   // esvo §6.2 block size, 0 = off
  int frustum = 0;                // tile frustum pass block size (issue 10 item 4), 0 = off
  std::string caster = "packet";  // primary rays: packet | scalar (same image)
  bool stats = false;             // esvo §8.5 Table 6 counters
  std::string heatmap;            // iteration heat map (Figure 32)
  float heatmap_max = 64.f;       // iterations mapped to the top of the ramp
  bool filter = false;
  // Effects (svdag §4): shadows and ambient occlusion.
  std::string shadows = "none", point_light, area_light, shadow_beam = "conservative", ao_output;
  int shadow_rays = 16, ao = 0;
  float ao_radius = 0.f, ao_cone_angle = 0.f;
  uint32_t seed = 0;
  std::string memory_budget;
  std::string path, frame;  // camera path (src/view/camera_path.hpp) and one keyframe of it
  StreamArgs stream;        // --stream: brickmap worlds streamed (cmd_stream.cpp)
  // --budget and --frames (stream.budget / stream.frames) also drive
  // streamed scene formats (slice files, esvo §7): cmd_render_sliced.cpp.
  bool write_frames = false;  // slice files with --frames: every frame, not only the last
  int spp = 1;                // antialiasing: jittered camera rays per pixel (render.hpp)
  GiArgs gi;                  // --gi SPP and its options (gi_cli.hpp)
};

// The output for keyframe `index` of `count` when a whole path is rendered:
// "out.png" -> "out-007.png" (at least 3 digits, more for long paths).
std::string keyframe_file(const std::string& path, size_t index, size_t count) {
  const std::filesystem::path p(path);
  int digits = 3;
  for (size_t n = count - 1; n >= 1000; n /= 10) ++digits;
  char number[32];
  std::snprintf(number, sizeof number, "-%0*zu", digits, index);
  return (p.parent_path() / (p.stem().string() + number + p.extension().string())).string();
}

// Table 6 style block (esvo §8.5): per-ray averages over the full-resolution
// rays; with the beam, the coarse pass is listed and added like in the paper.
void print_stats(const RenderResult& r, int beam) {
  const RayCounters& f = r.counters;
  const RayCounters& c = r.coarse_counters;
  std::printf("profile (per ray, %llu rays%s):\n", (unsigned long long)r.rays,
              beam ? ", coarse pass added in" : "");
  auto row = [&](const char* name, uint64_t fine, uint64_t coarse) {
    if (beam)
      std::printf("  %-12s %9.2f   (rays %.2f + coarse %.2f)\n", name, r.per_ray(fine + coarse),
                  r.per_ray(fine), r.per_ray(coarse));
    else
      std::printf("  %-12s %9.2f\n", name, r.per_ray(fine));
  };
  row("iterations", f.iterations, c.iterations);
  row("intersect", f.intersects, c.intersects);
  row("push", f.pushes, c.pushes);
  row("store", f.stores, 0);
  row("advance", f.advances, 0);
  row("pop", f.pops, 0);
  row("bytes", f.bytes(), c.bytes());
  if (beam)
    std::printf("  coarse pass: %llu beams of %dx%d, %.1f nodes visited per beam\n",
                (unsigned long long)r.beams, beam, beam,
                r.beams ? double(c.iterations) / double(r.beams) : 0.0);
  std::printf(
      "  note: counting is compiled into a separate caster; Mrays/s above is\n"
      "        lower than without --stats/--heatmap\n");
}
}  // namespace

Runner add_render(CLI::App& app) {
  auto args = std::make_shared<RenderArgs>();
  CLI::App* cmd = app.add_subcommand("render", "Ray cast a scene file into an image");
  cmd->add_option("SCENE", args->input, "Scene file written by `voxcast build`")->required();
  cmd->add_option("-o,--output", args->output,
                  "Output image (.png, .pfm or .exr; .exr may hold the --aov layers too)")
      ->required();
  cmd->add_option("--aov", args->aov,
                  "With -o X.exr: also store depth (Z) and/or normal (N.x, N.y, N.z) in it, "
                  "e.g. depth,normal");
  cmd->add_option("--size", args->size, "Image size WxH")->capture_default_str();
  add_camera_options(cmd, args->camera);
  cmd->add_option("--path", args->path,
                  "Camera path (JSON, README 'Camera path JSON'): one image per keyframe, "
                  "named OUT-000.png, OUT-001.png, ... (every output alike)");
  cmd->add_option("--frame", args->frame,
                  "With --path: render only this keyframe (its name or index) to the names given");
  cmd->add_option("--lod", args->lod,
                  "Stop at voxels projecting to at most this many pixels (0 = finest level)")
      ->capture_default_str();
  cmd->add_option("--depth", args->depth,
                  "Also write per-pixel hit distance (.pfm; +inf on a miss)");
  cmd->add_option("--normals", args->normal, "Also write the voxel normals as an image");
  cmd->add_option("--light", args->light, "Direction the light travels, dx,dy,dz");
  cmd->add_option("--threads", args->threads, "Worker threads (0 = all cores)");
  cmd->add_flag("-v,--verbose", args->verbose, "Print timings per stage");
  cmd->add_option("--beam", args->beam,
                  "Beam optimization block size, e.g. 4 or 8 (0 = off; esvo paper section 6.2)")
      ->capture_default_str();
  cmd->add_option("--frustum", args->frustum,
                  "Tile frustum pass: per tile the octree cubes its rays can touch (empty tiles "
                  "cost no ray), per KxK pixel block the finer cubes the packets start from "
                  "(2..64, K >= the tile size: the tile's cubes; 0 = off; packet caster only, "
                  "the image is the same)")
      ->capture_default_str();
  cmd->add_option("--caster", args->caster,
                  "Primary rays: packet (4x4 pixel blocks through the packet caster where the "
                  "structure has one), tile (each tile by one walk of the octree, ESVO and DAG; "
                  "--beam and --frustum do not apply) or scalar (one ray at a time); the image "
                  "is the same")
      ->check(CLI::IsMember({"packet", "tile", "scalar"}))
      ->capture_default_str();
  cmd->add_flag("--stats", args->stats,
                "Print per-ray profiling counters (esvo paper Table 6); slower");
  cmd->add_option("--heatmap", args->heatmap,
                  "Write the per-pixel iteration count as a .png heat map");
  cmd->add_option("--heatmap-max", args->heatmap_max, "Iterations at the top of the heat map ramp")
      ->capture_default_str();
  cmd->add_flag("--filter", args->filter,
                "Adaptive post-process blur sized by the hit voxels (esvo paper section 6.3)");
  cmd->add_option("--shadows", args->shadows, "none | hard | soft (soft needs --area-light)")
      ->capture_default_str();
  cmd->add_option("--point-light", args->point_light, "Point light position x,y,z");
  cmd->add_option(
      "--area-light", args->area_light,
      "Rectangular area light cx,cy,cz,ux,uy,uz,vx,vy,vz: center and two half-edge vectors");
  cmd->add_option("--shadow-rays", args->shadow_rays, "Soft shadow rays per pixel (stratified)")
      ->capture_default_str();
  cmd->add_option("--shadow-beam", args->shadow_beam,
                  "Soft shadow beam per pixel (svdag section 4): conservative (exact) | corners "
                  "(4 corner rays, approximate) | off")
      ->capture_default_str();
  cmd->add_option("--ao", args->ao, "Ambient occlusion rays per pixel (0 = off; the paper uses 64)")
      ->capture_default_str();
  cmd->add_option("--ao-radius", args->ao_radius,
                  "AO ray length in world units (0 = 5% of the scene diagonal)")
      ->capture_default_str();
  cmd->add_option("--ao-cone-angle", args->ao_cone_angle,
                  "AO rays stop at nodes subtending this angle in degrees (0 = finest level)")
      ->capture_default_str();
  cmd->add_option("--ao-output", args->ao_output,
                  "Also write the AO term as an image (.png or .pfm)");
  cmd->add_option("--seed", args->seed, "Seed of the per-pixel effect samples")
      ->capture_default_str()
      ->check(not_negative());
  cmd->add_option("--spp", args->spp,
                  "Antialiasing: camera rays per pixel at jittered sub-pixel offsets, the same "
                  "on every structure (1 = pixel centers)")
      ->capture_default_str();
  add_gi_options(cmd, args->gi);
  cmd->add_option("--memory-budget", args->memory_budget,
                  "Refuse renders estimated to need more (e.g. 2G; default 90% of free memory)");
  add_stream_options(cmd, args->stream);
  cmd->add_flag("--write-frames", args->write_frames,
                "Slice file with --budget/--frames: write every frame, named like -o with -NNN "
                "before the extension (out-000.png, ...), besides -o");
  return [args, cmd]() {
    ThreadLimit limit(args->threads);
    // Every option value first (usage errors, exit 2), then the files.
    RenderOptions opt;
    parse_size(args->size, &opt.width, &opt.height);
    require_range("--lod", args->lod, 0, 1e6);
    opt.lod_pixels = args->lod;
    if (args->beam != 0 && (args->beam < 2 || args->beam > 64))
      throw UsageError("--beam must be 0 (off) or a block size in 2..64");
    opt.beam = args->beam;
    if (args->frustum != 0 && (args->frustum < 2 || args->frustum > 64))
      throw UsageError("--frustum must be 0 (off) or a block size in 2..64");
    opt.frustum = args->frustum;
    opt.caster = args->caster == "scalar" ? Caster::Scalar
                 : args->caster == "tile" ? Caster::Tile
                                          : Caster::Packet;
    require_range("--heatmap-max", args->heatmap_max, 1e-6, 1e9);
    opt.collect_stats = args->stats || !args->heatmap.empty();
    if (!args->light.empty()) {
      Vec3 l = parse_vec3(args->light, "--light");
      if (!(length(l) > 0) || !std::isfinite(length(l)))
        throw UsageError("--light must be a non-zero, finite vector");
      opt.light_dir = normalize(l);
    }
    // ---- effects (svdag §4) ----
    EffectOptions& fx = opt.effects;
    if (int(!args->light.empty()) + int(!args->point_light.empty()) +
            int(!args->area_light.empty()) >
        1)
      throw UsageError("--light, --point-light and --area-light are mutually exclusive");
    if (!args->point_light.empty()) {
      fx.light = LightKind::Point;
      fx.light_position = parse_vec3(args->point_light, "--point-light");
    }
    if (!args->area_light.empty()) {
      std::vector<std::string> parts;
      std::string rest = args->area_light;
      for (size_t pos; (pos = rest.find(',')) != std::string::npos; rest = rest.substr(pos + 1))
        parts.push_back(rest.substr(0, pos));
      parts.push_back(rest);
      if (parts.size() != 9)
        throw UsageError("--area-light: '" + printable(args->area_light) +
                         "' is not cx,cy,cz,ux,uy,uz,vx,vy,vz");
      fx.light = LightKind::Area;
      fx.light_position = parse_vec3(parts[0] + "," + parts[1] + "," + parts[2], "--area-light");
      fx.area_u = parse_vec3(parts[3] + "," + parts[4] + "," + parts[5], "--area-light");
      fx.area_v = parse_vec3(parts[6] + "," + parts[7] + "," + parts[8], "--area-light");
      const float area = length(cross(fx.area_u, fx.area_v));
      if (!(area > 0) || !std::isfinite(area))
        throw UsageError(
            "--area-light: the half-edge vectors must be non-zero, finite and not parallel");
    }
    if (args->shadows == "none")
      fx.shadows = ShadowMode::None;
    else if (args->shadows == "hard")
      fx.shadows = ShadowMode::Hard;
    else if (args->shadows == "soft")
      fx.shadows = ShadowMode::Soft;
    else
      throw UsageError("--shadows must be none, hard or soft");
    if (fx.shadows == ShadowMode::Soft && fx.light != LightKind::Area)
      throw UsageError("--shadows soft needs --area-light");
    require_range("--shadow-rays", args->shadow_rays, 1, 4096);
    fx.shadow_rays = args->shadow_rays;
    if (args->shadow_beam == "conservative")
      fx.shadow_beam = ShadowBeam::Conservative;
    else if (args->shadow_beam == "corners")
      fx.shadow_beam = ShadowBeam::Corners;
    else if (args->shadow_beam == "off")
      fx.shadow_beam = ShadowBeam::Off;
    else
      throw UsageError("--shadow-beam must be conservative, corners or off");
    require_range("--ao", args->ao, 0, 4096);
    fx.ao_rays = args->ao;
    require_range("--ao-radius", args->ao_radius, 0, 1e30);
    if (!(args->ao_cone_angle >= 0 && args->ao_cone_angle < 90))
      throw UsageError("--ao-cone-angle must be in [0, 90) degrees");
    fx.ao_cone_angle_deg = args->ao_cone_angle;
    fx.seed = args->seed;
    if (!args->ao_output.empty() && fx.ao_rays == 0)
      throw UsageError("--ao-output needs --ao N (N > 0)");
    check_camera_options(args->camera, opt.width, opt.height);
    refuse_camera_options_with_path(args->camera, args->path);
    if (!args->frame.empty() && args->path.empty()) throw UsageError("--frame needs --path");
    // A streamed structure (a format of its own files with stream counters,
    // format_registry.hpp: slice files) streams frame by frame with --budget
    // or --frames (cmd_render_sliced.cpp); without them it loads as any scene.
    const SceneFormat* own = std::filesystem::is_regular_file(args->input)
                                 ? format_registry().recognize(args->input)
                                 : nullptr;
    const bool streamed = own != nullptr && own->stream_counters;
    const bool stream_frames = !args->stream.budget.empty() || args->stream.frames != 1;
    if (!args->stream.enabled && !streamed && stream_frames)
      throw UsageError(
          "--budget and --frames apply to slice files (build --slices) and to --stream");
    if (streamed && args->stream.enabled)
      throw UsageError("--stream applies to brickmap worlds; a slice file streams by itself");
    if (streamed && stream_frames) {
      if (!args->depth.empty() || !args->normal.empty() || !args->heatmap.empty() ||
          !args->aov.empty() || !args->ao_output.empty() || args->stats || args->filter ||
          !args->frame.empty())
        throw UsageError(
            "a slice file streamed with --budget or --frames renders color only: no --depth, "
            "--normals, --heatmap, --aov, --ao-output, --stats, --filter or --frame");
      std::vector<std::string> frame_files;
      if (args->write_frames)
        for (int f = 0; f < args->stream.frames; ++f)
          frame_files.push_back(
              keyframe_file(args->output, size_t(f), size_t(args->stream.frames)));
      return render_sliced({args->input, args->output, args->path, args->stream.budget,
                            &args->camera, args->stream.frames, frame_files},
                           opt);
    }
    if (args->write_frames)
      throw UsageError("--write-frames applies to slice files rendered with --budget or --frames");
    require_range("--spp", args->spp, 1, 4096);
    opt.spp = args->spp;
    // --gi: the GI integrator instead of the surface shading (gi_cli.hpp).
    GiOptions gi;
    const bool use_gi = args->gi.spp != 0;
    if (use_gi) {
      std::string surface_only;
      for (const char* o :
           {"--beam", "--stats", "--heatmap", "--filter", "--shadows", "--point-light",
            "--area-light", "--light", "--shadow-rays", "--shadow-beam", "--ao", "--ao-radius",
            "--ao-cone-angle", "--ao-output", "--spp"})
        if (surface_only.empty() && cmd->count(o) > 0) surface_only = o;
      gi = gi_options(args->gi, surface_only, args->seed);
    } else {
      for (const char* o :
           {"--bounces", "--env", "--env-scale", "--sun", "--sun-intensity", "--bounce-cone"})
        if (cmd->count(o) > 0) throw UsageError(std::string(o) + " needs --gi SPP");
    }
    uint64_t budget = 0;
    if (!args->memory_budget.empty()) budget = parse_memory_budget(args->memory_budget);
    // All outputs are checked before the scene is read, and written together
    // at the end (OutputSet): a failure leaves every one of them untouched.
    std::vector<std::string> inputs = {args->input};
    if (!args->path.empty()) inputs.push_back(args->path);
    if (!args->gi.env.empty()) inputs.push_back(args->gi.env);
    // Every image of one view, in this order: -o, --depth, --normals,
    // --heatmap, --ao-output (the paths as given; empty where not asked).
    const std::vector<std::string> given = {args->output, args->depth, args->normal, args->heatmap,
                                            args->ao_output};
    auto add_output = [](OutputSet& set, size_t which, const std::string& file) {
      if (file.empty()) return;
      switch (which) {
        case 0:
          return set.add("-o", file, {".png", ".pfm", ".exr"});
        case 1:
          return set.add("--depth", file, {".pfm", ".exr"});
        case 2:
          return set.add("--normals", file, {".png", ".pfm", ".exr"});
        case 3:
          return set.add("--heatmap", file, {".png"});
        default:
          return set.add("--ao-output", file, {".png", ".pfm"});
      }
    };
    const ExrLayers layers = parse_exr_layers(args->aov, args->output);
    {
      OutputSet as_given(inputs);  // the names as given: usage errors before any file is read
      for (size_t i = 0; i < given.size(); ++i) add_output(as_given, i, given[i]);
    }
    // The views to render: the camera options' one, one keyframe of --path
    // (to the names given) or every keyframe (to numbered names).
    struct View {
      std::optional<Camera> camera;    // none: resolved from the camera options
      std::vector<std::string> files;  // per entry of `given` (empty where not asked)
    };
    std::vector<View> views;
    auto files_for = [&](std::optional<size_t> index, size_t count) {
      std::vector<std::string> f;
      for (const std::string& g : given)
        f.push_back(g.empty() || !index ? g : keyframe_file(g, *index, count));
      return f;
    };
    if (!args->path.empty()) {
      require_regular_input(args->path, "camera path");
      const view::CameraPath path = view::CameraPath::load(args->path);
      const size_t n = path.keyframes.size();
      if (!args->frame.empty()) {
        views.push_back({path.keyframes[path.find(args->frame)].camera, files_for({}, 1)});
      } else {
        for (size_t k = 0; k < n; ++k) views.push_back({path.keyframes[k].camera, files_for(k, n)});
      }
    } else {
      views.push_back({std::nullopt, files_for({}, 1)});
    }
    if (args->stream.enabled) {
      // Brickmap worlds streamed over --frames frames (cmd_stream.cpp).
      std::vector<Camera> path_cameras;
      for (const View& v : views)
        if (v.camera) path_cameras.push_back(*v.camera);
      const CameraArgs camera = args->camera;
      return render_stream(args->stream, args->input, args->output, opt, path_cameras,
                           [camera](const Aabb& b, int w, int h) {
                             bool derived = false;
                             return resolve_camera(camera, b, w, h, &derived);
                           });
    }
    OutputSet outputs(inputs);
    for (const View& v : views)
      for (size_t i = 0; i < given.size(); ++i) add_output(outputs, i, v.files[i]);
    require_regular_input(args->input, "scene");
    if (use_gi) load_gi_environment(args->gi, &gi);
    {
      // Checked before anything large is allocated: the file as read, its
      // parsed copy, and per pixel the float buffers the renderer fills plus
      // the encoded images.
      if (budget == 0) budget = uint64_t(double(available_memory_bytes()) * 0.9);
      std::error_code ec;
      const double scene_bytes = 2.0 * double(std::filesystem::file_size(args->input, ec));
      double per_pixel = 12 + 12;  // color floats, 8-bit copy + PNG bytes
      if (!args->depth.empty() || layers.depth) per_pixel += 4 + 4;
      if (!args->normal.empty() || layers.normal) per_pixel += 12 + 12;
      if (opt.collect_stats) per_pixel += 4 + 12 + 12;  // iterations, heat map, PNG
      if (fx.ao_rays > 0) per_pixel += 4 + 4;
      if (use_gi) per_pixel += 24 + 24 + 16;  // two double RGB sums, sample 0's depth and normal
      // One view at a time: the images of earlier views are written before
      // the next is rendered (staged, not yet renamed into place).
      const double need = scene_bytes + per_pixel * double(opt.width) * double(opt.height);
      if (budget && need > double(budget))
        throw Error("rendering " + std::to_string(opt.width) + "x" + std::to_string(opt.height) +
                    " needs an estimated " + format_bytes(need) + ", more than the " +
                    format_bytes(double(budget)) +
                    " memory budget; lower --size or raise --memory-budget");
    }
    StageTimer timer(args->verbose);
    LoadedScene scene = load_scene(args->input);  // esvo or dag, by META "format"
    timer.mark("load scene");
    if (fx.ao_rays > 0)  // default: 5% of the occupied bounds' diagonal
      fx.ao_radius =
          args->ao_radius > 0 ? args->ao_radius : 0.05f * length(scene.occupied.extent());
    const Structure& structure = *scene.structure;
    for (const View& v : views) {
      bool derived_camera = false;
      if (v.camera)
        opt.camera = *v.camera;
      else
        opt.camera =
            resolve_camera(args->camera, scene.occupied, opt.width, opt.height, &derived_camera);
      if (derived_camera) std::printf("camera: %s\n", opt.camera.to_string().c_str());
      opt.want_depth = !args->depth.empty() || layers.depth;
      opt.want_normal = !args->normal.empty() || layers.normal;
      opt.filter = args->filter;
      RenderResult result;
      const double cpu0 = cpu_seconds();
      {
        Progress progress("render", uint64_t(0));  // the frame loop adds the tiles
        opt.progress = &progress;
        result =
            use_gi ? render_gi_view(structure, opt, gi, args->verbose) : render(structure, opt);
        opt.progress = nullptr;
      }
      timer.mark("ray cast");
      // On a shared machine the wall clock counts other jobs' time slices;
      // the process CPU time of the frame does not (with --threads 1 it is
      // the ray cast's own cost).
      if (args->verbose) {
        const double cpu = std::max(cpu_seconds() - cpu0, 1e-9);
        std::fprintf(stderr, "  %-22s %9.1f ms (%.2f Mrays per CPU second)\n", "  of which CPU",
                     cpu * 1e3, double(result.rays) / cpu * 1e-6);
      }
      if (args->verbose && opt.filter)
        std::fprintf(stderr, "  %-22s %9.1f ms\n", "  of which filter",
                     result.filter_seconds * 1e3);
      auto image = [&](const std::string& path, const Image& im, bool already_srgb = false) {
        outputs.write(path,
                      [&](const std::filesystem::path& to) { write_image(to, im, already_srgb); });
      };
      const std::vector<std::string>& f = v.files;  // in the order of `given`
      if (layers.depth || layers.normal)
        outputs.write(
            f[0], [&](const std::filesystem::path& to) { write_exr_layers(to, result, layers); });
      else
        image(f[0], result.color);
      if (!args->depth.empty()) image(f[1], result.depth);
      if (!args->normal.empty()) image(f[2], result.normal, true);
      if (!args->heatmap.empty())
        image(f[3], iteration_heatmap(result.iterations, args->heatmap_max));
      if (!args->ao_output.empty()) image(f[4], result.ao, true);  // as stored, linear
      if (!args->heatmap.empty())
        std::printf("heatmap: %s, inferno ramp, black = 0, pale yellow = %g iterations\n",
                    printable(f[3]).c_str(), double(args->heatmap_max));
      if (use_gi)  // the rates are on render_gi_view's "gi:" line
        std::printf("%s: %dx%d, %.1f%% of pixels hit\n", printable(f[0]).c_str(), opt.width,
                    opt.height, 100.0 * double(result.hits) / double(result.rays));
      else
        std::printf("%s: %dx%d, %.1f%% of pixels hit, %.2f Mrays/s\n", printable(f[0]).c_str(),
                    opt.width, opt.height, 100.0 * double(result.hits) / double(result.rays),
                    double(result.rays) / result.seconds * 1e-6);
      if (fx.active()) {
        const EffectCounters& ec = result.effect_counters;
        const double secondary = double(ec.shadow_rays + ec.ao_rays);
        std::printf("effects: %llu shadow rays, %llu AO rays (radius %g)",
                    (unsigned long long)ec.shadow_rays, (unsigned long long)ec.ao_rays,
                    double(fx.ao_radius));
        if (ec.beams)
          std::printf(", %llu of %llu soft-shadow beams fully lit",
                      (unsigned long long)ec.beams_lit, (unsigned long long)ec.beams);
        // result.seconds covers primary and secondary rays: the Mrays/s above
        // counts primary rays only.
        std::printf("; %.2f Mrays/s primary + secondary\n",
                    (double(result.rays) + secondary) / result.seconds * 1e-6);
      }
      if (args->stats) print_stats(result, opt.beam);
    }
    outputs.commit();
    timer.mark("write images");
    return 0;
  };
}

}  // namespace voxcast::cli
