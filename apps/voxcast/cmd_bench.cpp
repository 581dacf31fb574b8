// voxcast bench MESH: the voxel ray caster against Embree on the same mesh,
// camera, image size, tiles and threads, measured in one run.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <memory>
#include <thread>

#include "commands.hpp"
#include "pipeline.hpp"
#include "voxcast/embree_reference.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/progress.hpp"
#include "voxcast/render.hpp"

namespace voxcast::cli {

namespace {
struct BenchArgs {
  std::string input, size = "1024x768", camera = "auto", voxelization = "conservative",
              attributes = "raw";
  uint32_t resolution = 2048;
  float lod = 1.f;
  int repeat = 5, threads = 0, beam = 8;
  double min_coverage = 0.3;
  bool verbose = false;
};

double coverage(const Image& depth) {
  size_t hits = 0;
  for (float d : depth.pixels) hits += std::isfinite(d);
  return double(hits) / double(depth.pixels.size());
}
}  // namespace

Runner add_bench(CLI::App& app) {
  auto args = std::make_shared<BenchArgs>();
  CLI::App* cmd = app.add_subcommand(
      "bench", "Build a mesh as voxels and as an Embree BVH, ray cast both, compare Mrays/s");
  cmd->add_option("MESH", args->input, "Input mesh")->required();
  cmd->add_option("--resolution", args->resolution, "Voxels per axis (power of two)")
      ->capture_default_str();
  cmd->add_option("--size", args->size, "Image size WxH")->capture_default_str();
  cmd->add_option("--camera", args->camera,
                  "ex,ey,ez,tx,ty,tz,ux,uy,uz,fovy or auto (frames the mesh so that at least "
                  "--min-coverage of the pixels hit it)")
      ->capture_default_str();
  cmd->add_option("--min-coverage", args->min_coverage, "Pixel coverage the auto camera aims at")
      ->capture_default_str();
  cmd->add_option("--lod", args->lod, "Voxel LOD in pixels (0 = finest level)")
      ->capture_default_str();
  cmd->add_option("--voxelization", args->voxelization, "conservative | 6-separating")
      ->capture_default_str();
  cmd->add_option("--attributes", args->attributes, "raw | compressed")->capture_default_str();
  cmd->add_option("--repeat", args->repeat, "Timed frames per ray caster (best is reported)")
      ->capture_default_str();
  cmd->add_option("--beam", args->beam,
                  "Beam block size for the second voxcast run (4 or 8; 0 = skip that run)")
      ->capture_default_str();
  cmd->add_option("--threads", args->threads, "Worker threads (0 = all cores)");
  cmd->add_flag("-v,--verbose", args->verbose, "Print timings per stage");
  return [args]() {
    ThreadLimit limit(args->threads);
    int width = 0, height = 0;
    parse_size(args->size, &width, &height);
    if (args->repeat < 1 || args->repeat > 1000) throw Error("--repeat must be in 1..1000");
    if (args->beam != 0 && args->beam != 4 && args->beam != 8) throw Error("--beam must be 0, 4 or 8");
    if (!(args->min_coverage >= 0 && args->min_coverage <= 0.95))
      throw Error("--min-coverage must be in [0, 0.95]");

    BuildSettings s;
    s.mesh_path = args->input;
    s.resolution = args->resolution;
    s.mode = parse_voxelization(args->voxelization);
    s.attributes = parse_attribute_format(args->attributes);
    s.verbose = args->verbose;
    BuiltScene built = build_scene(s);
    auto octree = std::make_shared<esvo::EsvoOctree>(std::move(built.octree));
    esvo::EsvoStructure voxels(octree);
    EmbreeScene embree(built.mesh);

    Camera camera;
    if (args->camera == "auto") {
      camera = Camera::frame(built.mesh.bounds(), width, height);
      // Misses flatter every ray caster: zoom in until the mesh covers enough pixels.
      for (int i = 0; i < 12; ++i) {
        double c = coverage(embree.render_depth(camera, width, height, EmbreeScene::Mode::Single).depth);
        if (c >= args->min_coverage) break;
        camera.fovy_degrees *= 0.85f;
      }
    } else {
      camera = Camera::parse(args->camera);
    }

    RenderOptions ro;
    ro.width = width;
    ro.height = height;
    ro.camera = camera;
    ro.lod_pixels = args->lod;
    ro.want_depth = true;

    RenderOptions ro_beam = ro;
    ro_beam.beam = args->beam;

    double best_vox = 1e30, best_beam = 1e30, best_e1 = 1e30, best_e8 = 1e30;
    RenderResult vox_result;
    EmbreeScene::DepthRender e1;
    render(voxels, ro);  // warm-up: page in the octree, spin up the TBB workers
    for (int r = 0; r < args->repeat; ++r) {
      vox_result = render(voxels, ro);
      best_vox = std::min(best_vox, vox_result.seconds);
      if (args->beam) best_beam = std::min(best_beam, render(voxels, ro_beam).seconds);
      e1 = embree.render_depth(camera, width, height, EmbreeScene::Mode::Single);
      best_e1 = std::min(best_e1, e1.seconds);
      auto e8 = embree.render_depth(camera, width, height, EmbreeScene::Mode::Packet8);
      best_e8 = std::min(best_e8, e8.seconds);
    }
    double rays = double(width) * height;
    double m_vox = rays / best_vox * 1e-6, m_beam = rays / best_beam * 1e-6, m_e1 = rays / best_e1 * 1e-6,
           m_e8 = rays / best_e8 * 1e-6;

    // How well the voxels reproduce the mesh in this very frame.
    size_t agree = 0, both = 0, close = 0;
    double tol = 2.0 * std::sqrt(3.0) * octree->grid.voxel_size;
    for (size_t i = 0; i < vox_result.depth.pixels.size(); ++i) {
      float dv = vox_result.depth.pixels[i], de = e1.depth.pixels[i];
      agree += std::isfinite(dv) == std::isfinite(de);
      if (std::isfinite(dv) && std::isfinite(de)) {
        ++both;
        close += std::fabs(dv - de) <= tol;
      }
    }
    auto mem = octree->memory_stats();
    int threads = args->threads ? args->threads : int(std::thread::hardware_concurrency());
    std::printf("mesh        %s: %zu triangles\n", args->input.c_str(), built.mesh.triangle_count());
    std::printf("camera      %s\n", camera.to_string().c_str());
    std::printf("image       %dx%d, %.1f%% of pixels hit the mesh, %d threads, best of %d\n",
                width, height, 100.0 * coverage(e1.depth), threads, args->repeat);
    std::printf("voxels      %u^3 %s, %llu leaf voxels, lod %.2g px\n", octree->grid.resolution,
                voxelization_name(s.mode), (unsigned long long)built.leaf_voxels, args->lod);
    std::printf("agreement   hit/miss %.3f%%, depth within 2 leaf voxel diagonals %.3f%%\n",
                100.0 * double(agree) / rays, both ? 100.0 * double(close) / double(both) : 0.0);
    std::printf("build       voxcast %.2f s (voxelize %.2f s + octree %.2f s), embree %.2f s\n",
                built.voxelize_seconds + built.octree_seconds, built.voxelize_seconds,
                built.octree_seconds, embree.build_seconds());
    std::printf("memory      voxcast %s (%.2f B/leaf voxel), embree %s\n",
                format_bytes(double(mem.total_bytes)).c_str(),
                double(mem.total_bytes) / double(built.leaf_voxels),
                format_bytes(double(embree.memory_bytes())).c_str());
    std::printf("voxcast     %8.2f Mrays/s\n", m_vox);
    if (args->beam) std::printf("voxcast+beam%8.2f Mrays/s (beam %dx%d, coarse pass included)\n", m_beam, args->beam, args->beam);
    std::printf("embree x1   %8.2f Mrays/s (rtcIntersect1)\n", m_e1);
    std::printf("embree x8   %8.2f Mrays/s (rtcIntersect8)\n", m_e8);
    std::printf("ratio voxcast/embree: %.3f\n",
                std::max(m_vox, args->beam ? m_beam : 0.0) / std::max(m_e1, m_e8));
    return 0;
  };
}

}  // namespace voxcast::cli
