// voxcast volume render SOURCE -o IMAGE: GigaVoxels volume rendering
// (gigavoxels.hpp) of a volume file or a procedural volume, through the
// frame loop with the volume integrator.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include "camera_options.hpp"
#include "cli_io.hpp"
#include "commands.hpp"
#include "voxcast/error.hpp"
#include "voxcast/gigavoxels.hpp"
#include "voxcast/image.hpp"
#include "voxcast/integrator.hpp"
#include "voxcast/progress.hpp"
#include "voxcast/volume_integrator.hpp"

namespace voxcast::cli {
namespace {

// Scalar data (files): below 0.2 of the value range transparent, then a warm
// ramp to dense white (a CT's soft tissue to bone).
constexpr const char* kDefaultTransfer = "0.2:0:0.8,0.5,0.3;0.35:30:0.95,0.8,0.6;1:400:1,1,1";

struct VolumeArgs {
  std::string source, output, depth, size = "640x480", budget = "256M", passes = "exact";
  std::string transfer, background;
  CameraArgs camera;
  int resolution = 256, frames = 1, threads = 0;
  float lod = 1.f, step = 0.5f;
  bool shading = false, verbose = false;
};

void print_pass_stats(uint32_t frame, const FrameStats& fs, const giga::GigaVoxels& g) {
  const auto& gs = g.pass_stats();
  for (size_t p = 0; p < fs.passes.size(); ++p) {
    const PassStats& ps = fs.passes[p];
    std::fprintf(stderr, "frame %u pass %zu: %d tiles, %llu requests", frame, p, ps.tiles,
                 (unsigned long long)ps.requests);
    if (ps.dropped)
      std::fprintf(stderr, " (+%llu dropped: full buffers)", (unsigned long long)ps.dropped);
    if (p < gs.size()) {
      const giga::GigaPassStats& s = gs[p];
      std::fprintf(stderr,
                   " (data %llu, subdivide %llu); uploads %llu bricks + %llu constants, %llu "
                   "subdivisions, %llu pending; cache hits %llu bricks / %llu tiles, misses %llu; "
                   "recycled %llu bricks / %llu tiles; pools %llu/%u bricks, %llu/%u tiles",
                   (unsigned long long)s.data_requests, (unsigned long long)s.subdivide_requests,
                   (unsigned long long)s.bricks_uploaded, (unsigned long long)s.constants,
                   (unsigned long long)s.subdivisions, (unsigned long long)s.pending,
                   (unsigned long long)s.bricks_used, (unsigned long long)s.tiles_used,
                   (unsigned long long)s.data_requests, (unsigned long long)s.recycled_bricks,
                   (unsigned long long)s.recycled_tiles, (unsigned long long)s.bricks_resident,
                   g.brick_capacity(), (unsigned long long)s.tiles_resident, g.tile_capacity());
    }
    std::fprintf(stderr, "; %.1f ms trace + %.1f ms serve\n", ps.seconds * 1e3,
                 ps.serve_seconds * 1e3);
  }
}

}  // namespace

Runner add_volume(CLI::App& app) {
  auto args = std::make_shared<VolumeArgs>();
  CLI::App* vol =
      app.add_subcommand("volume", "GigaVoxels volumes (see 'voxcast volume render --help')");
  vol->require_subcommand(1);
  CLI::App* cmd = vol->add_subcommand("render", "Render a volume file or a procedural volume");
  cmd->add_option("SOURCE", args->source,
                  "An INRIMAGE-4 volume (.inr) or procedural:cloud|mandelbulb|menger")
      ->required();
  cmd->add_option("-o,--output", args->output, "Output image (.png or .pfm)")->required();
  cmd->add_option("--depth", args->depth,
                  "Also write the distance at which opacity reaches 0.5 (.pfm; +inf elsewhere)");
  cmd->add_option("--size", args->size, "Image size WxH")->capture_default_str();
  add_camera_options(cmd, args->camera);
  cmd->add_option("--resolution", args->resolution,
                  "Procedural sources: voxels per axis at the finest level (power of two, 8..8192)")
      ->capture_default_str();
  cmd->add_option("--budget", args->budget, "Memory for the node and brick pools (e.g. 64M, 2G)")
      ->capture_default_str();
  cmd->add_option("--passes", args->passes,
                  "exact (passes until nothing is missing) | N (at most N passes per frame; 1 = "
                  "one-pass mode, coarser data meanwhile)")
      ->capture_default_str();
  cmd->add_option("--frames", args->frames,
                  "Render this many frames of the same view; prints frames/s after the first")
      ->capture_default_str();
  cmd->add_option("--transfer", args->transfer,
                  "Transfer function for scalar data: v:density:r,g,b;... (values in [0,1]; "
                  "default for files: " +
                      std::string(kDefaultTransfer) + ")");
  cmd->add_option("--background", args->background, "Background color r,g,b (linear)");
  cmd->add_option("--lod", args->lod, "Stop at voxels projecting to at most this many pixels")
      ->capture_default_str();
  cmd->add_option("--step", args->step, "Brick sampling step in voxels")->capture_default_str();
  cmd->add_flag("--shading", args->shading, "Blinn-Phong with density-gradient normals");
  cmd->add_option("--threads", args->threads, "Worker threads (0 = all cores)");
  cmd->add_flag("-v,--verbose", args->verbose, "Per-pass statistics on stderr");
  return [args, cmd]() {
    if (!cmd->parsed()) return 2;
    ThreadLimit limit(args->threads);
    // Every option first (usage errors, exit 2), then the source.
    FrameView view;
    parse_size(args->size, &view.width, &view.height);
    require_range("--lod", args->lod, 0, 1e6);
    view.lod_pixels = args->lod;
    require_range("--frames", args->frames, 1, 100000);
    require_range("--step", args->step, 0.01, 16);
    FrameOptions fo;
    if (args->passes == "exact") {
      fo.max_passes = 100000;
    } else {
      char* end = nullptr;
      const long n = std::strtol(args->passes.c_str(), &end, 10);
      if (args->passes.empty() || *end != 0 || n < 1 || n > 100000)
        throw UsageError("--passes must be exact or a number of passes in 1..100000");
      fo.max_passes = int(n);
    }
    VolumeIntegratorOptions io;
    io.shading = args->shading;
    io.step_scale = args->step;
    if (!args->background.empty()) {
      const Vec3 b = parse_vec3(args->background, "--background");
      io.background = {b.x, b.y, b.z, 1.f};
    }
    const bool procedural = args->source.rfind("procedural:", 0) == 0;
    try {
      if (!args->transfer.empty())
        io.transfer = TransferFunction::parse(args->transfer);
      else if (!procedural)
        io.transfer = TransferFunction::parse(kDefaultTransfer);
    } catch (const Error& e) {
      throw UsageError(std::string("--transfer: ") + e.what());
    }
    giga::GigaOptions go;
    try {
      go.budget_bytes = parse_memory_budget(args->budget);
    } catch (const UsageError& e) {  // the shared parser names its own option
      std::string m = e.what();
      if (m.rfind("--memory-budget", 0) == 0) m.replace(0, 15, "--budget");
      throw UsageError(m);
    }
    check_camera_options(args->camera, view.width, view.height);
    OutputSet outputs(procedural ? std::vector<std::string>{}
                                 : std::vector<std::string>{args->source});
    outputs.add("-o", args->output, {".png", ".pfm"});
    if (!args->depth.empty()) outputs.add("--depth", args->depth, {".pfm"});

    std::shared_ptr<giga::Producer> producer;
    if (procedural) {
      try {
        producer = giga::make_procedural(args->source.substr(11), args->resolution);
      } catch (const Error& e) {
        throw UsageError(e.what());
      }
    } else {
      require_regular_input(args->source, "volume");
      producer = giga::make_volume_producer(giga::read_inrimage(args->source));
    }
    giga::GigaVoxels volume(producer, go);
    const Aabb bounds = volume.bounds();
    bool derived = false;
    view.camera = resolve_camera(args->camera, bounds, view.width, view.height, &derived);
    if (derived) std::printf("camera: %s\n", view.camera.to_string().c_str());
    VolumeIntegrator integrator(io);
    Film film;
    double later_seconds = 0;
    uint64_t later_rays = 0;
    // One bar phase per frame; each pass adds its tiles to the frame's work.
    Progress progress("volume render",
                      std::vector<Progress::Phase>(size_t(args->frames), Progress::Phase{"", 1}));
    fo.progress = &progress;
    for (int f = 0; f < args->frames; ++f) {
      view.frame = uint32_t(f);
      progress.start_phase(size_t(f), 0);
      const auto t0 = std::chrono::steady_clock::now();
      const FrameStats fs = render_frame(volume, integrator, view, fo, &film);
      const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      if (args->verbose) print_pass_stats(uint32_t(f), fs, volume);
      if (f > 0) later_seconds += s, later_rays += integrator.stats().rays;
      if (f + 1 == args->frames && fo.max_passes > 1 && !fs.passes.empty() &&
          fs.passes.back().requests != 0 && !Progress::quiet())
        std::fprintf(stderr,
                     "voxcast: warning: the last pass still asked for %llu elements (the pool is "
                     "too small for the view or --passes too low): the image shows coarser data\n",
                     (unsigned long long)fs.passes.back().requests);
    }
    outputs.write(args->output,
                  [&](const std::filesystem::path& to) { write_image(to, film.color); });
    if (!args->depth.empty())
      outputs.write(args->depth,
                    [&](const std::filesystem::path& to) { write_image(to, film.depth); });
    outputs.commit();
    double covered = 0;
    for (float a : film.alpha.pixels) covered += a;
    std::printf("%s: %dx%d, %s (max level %d), pools %s (%u bricks, %u tiles), mean opacity %.3f\n",
                printable(args->output).c_str(), view.width, view.height, producer->name().c_str(),
                producer->max_level(), format_bytes(double(volume.pool_bytes())).c_str(),
                volume.brick_capacity(), volume.tile_capacity(),
                covered / double(film.alpha.pixels.size()));
    if (args->frames > 1)
      std::printf("%d frames after the first: %.2f frames/s, %.2f Mrays/s\n", args->frames - 1,
                  double(args->frames - 1) / later_seconds,
                  double(later_rays) / later_seconds * 1e-6);
    return 0;
  };
}

}  // namespace voxcast::cli
