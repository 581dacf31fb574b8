// voxcast render SCENE -o IMAGE: ray cast a scene file into an image.
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>

#include "commands.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/progress.hpp"
#include "voxcast/render.hpp"
#include "voxcast/scene_file.hpp"

namespace voxcast::cli {

namespace {
struct RenderArgs {
  std::string input, output, size = "1024x768", camera = "auto", depth, normal, light;
  float lod = 1.f;
  int threads = 0;
  bool verbose = false;
};

std::string lower_extension(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  for (auto& c : ext) c = char(std::tolower(static_cast<unsigned char>(c)));
  return ext;
}
}  // namespace

Runner add_render(CLI::App& app) {
  auto args = std::make_shared<RenderArgs>();
  CLI::App* cmd = app.add_subcommand("render", "Ray cast a scene file into an image");
  cmd->add_option("SCENE", args->input, "Scene file written by `voxcast build`")->required();
  cmd->add_option("-o,--output", args->output, "Output image (.png or .pfm)")->required();
  cmd->add_option("--size", args->size, "Image size WxH")->capture_default_str();
  cmd->add_option("--camera", args->camera,
                  "ex,ey,ez,tx,ty,tz,ux,uy,uz,fovy (eye, target, up, vertical fov in degrees) "
                  "or auto")
      ->capture_default_str();
  cmd->add_option("--lod", args->lod,
                  "Stop at voxels projecting to at most this many pixels (0 = finest level)")
      ->capture_default_str();
  cmd->add_option("--depth", args->depth,
                  "Also write per-pixel hit distance (.pfm; +inf on a miss)");
  cmd->add_option("--normals", args->normal, "Also write the voxel normals as an image");
  cmd->add_option("--light", args->light, "Direction the light travels, dx,dy,dz");
  cmd->add_option("--threads", args->threads, "Worker threads (0 = all cores)");
  cmd->add_flag("-v,--verbose", args->verbose, "Print timings per stage");
  return [args]() {
    ThreadLimit limit(args->threads);
    RenderOptions opt;
    parse_size(args->size, &opt.width, &opt.height);
    if (!std::isfinite(args->lod) || args->lod < 0) throw Error("--lod must be >= 0");
    opt.lod_pixels = args->lod;
    for (const std::string* path : {&args->output, &args->depth, &args->normal}) {
      if (path->empty()) continue;
      std::string ext = lower_extension(*path);
      if (ext != ".png" && ext != ".pfm")
        throw Error("'" + *path + "': unsupported image format (use .png or .pfm)");
    }
    if (!args->depth.empty() && lower_extension(args->depth) != ".pfm")
      throw Error("--depth must be a .pfm file");
    if (!args->light.empty()) {
      Vec3 l = parse_vec3(args->light, "--light");
      if (length(l) == 0) throw Error("--light must not be the zero vector");
      opt.light_dir = normalize(l);
    }
    StageTimer timer(args->verbose);
    auto octree = std::make_shared<esvo::EsvoOctree>(load_esvo_scene(args->input));
    timer.mark("load scene");
    esvo::EsvoStructure structure(octree);
    if (args->camera == "auto") {
      opt.camera = Camera::frame(esvo::occupied_bounds(*octree), opt.width, opt.height);
      std::printf("camera: %s\n", opt.camera.to_string().c_str());
    } else {
      opt.camera = Camera::parse(args->camera);
    }
    opt.want_depth = !args->depth.empty();
    opt.want_normal = !args->normal.empty();
    RenderResult result = render(structure, opt);
    timer.mark("ray cast");
    write_image(args->output, result.color);
    if (opt.want_depth) write_image(args->depth, result.depth);
    if (opt.want_normal) write_image(args->normal, result.normal, true);
    timer.mark("write images");
    std::printf("%s: %dx%d, %.1f%% of pixels hit, %.2f Mrays/s\n", args->output.c_str(),
                opt.width, opt.height, 100.0 * double(result.hits) / double(result.rays),
                double(result.rays) / result.seconds * 1e-6);
    return 0;
  };
}

}  // namespace voxcast::cli
