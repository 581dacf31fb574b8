// voxcast bench MESH: the voxel ray caster against Embree on the same mesh,
// camera, image size, tiles and threads, measured in one run.
#include <tbb/blocked_range.h>
#include <tbb/combinable.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <sstream>
#include <thread>
#include <vector>

#include "camera_options.hpp"
#include "cli_io.hpp"
#include "commands.hpp"
#include "pipeline.hpp"
#include "voxcast/effects.hpp"
#include "voxcast/embree_reference.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/progress.hpp"
#include "voxcast/render.hpp"

namespace voxcast::cli {

namespace {
struct BenchArgs {
  std::string input, size = "1024x768", voxelization = "conservative", attributes = "raw";
  CameraArgs camera;
  uint32_t resolution = 2048;
  float lod = 1.f;
  int repeat = 5, threads = 0, beam = 8;
  double min_coverage = 0;  // > 0: zoom the automatic camera in (crops the model)
  bool verbose = false;
  bool contours = false;
  // --effects (svdag §4): shadow and AO occlusion rays
  bool effects = false;
  int ao_rays = 64;
  float ao_radius = 0.f;
};

class EmbreeOccluder final : public Occluder {
 public:
  explicit EmbreeOccluder(const EmbreeScene& s) : s_(s) {}
  bool occluded(const Ray& ray, const LodFootprint&) const override { return s_.occluded(ray); }

 private:
  const EmbreeScene& s_;
};

struct EffectRun {
  double seconds = 1e30;  // best wall time
  uint64_t rays = 0;
  std::vector<float> values;  // per shading point
};

// Shadow (ao_rays == 0: one directional ray per point) or AO rays for every
// point, in parallel chunks; best wall time of `repeat` runs.
EffectRun run_effect_rays(const Occluder& occ, const std::vector<ShadingPoint>& points,
                          const EffectOptions& fx, Vec3 light_dir, int repeat) {
  EffectRun run;
  run.values.assign(points.size(), 0.f);
  for (int r = 0; r < repeat; ++r) {
    tbb::combinable<EffectCounters> counters;
    const auto t0 = std::chrono::steady_clock::now();
    tbb::parallel_for(tbb::blocked_range<size_t>(0, points.size(), 256),
                      [&](const tbb::blocked_range<size_t>& b) {
                        EffectCounters& c = counters.local();
                        for (size_t i = b.begin(); i != b.end(); ++i) {
                          const uint32_t seed = pixel_seed(int(i), 0, fx.seed);
                          run.values[i] =
                              fx.ao_rays > 0
                                  ? ambient_occlusion(occ, points[i], fx, fx.ao_radius, seed, &c)
                                  : shadow_visibility(occ, points[i], fx, light_dir, seed, &c);
                        }
                      });
    run.seconds = std::min(
        run.seconds, std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    EffectCounters total;
    counters.combine_each([&](const EffectCounters& c) { total += c; });
    run.rays = total.shadow_rays + total.ao_rays;
  }
  return run;
}

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
      ->capture_default_str()
      ->check(not_negative());
  cmd->add_option("--size", args->size,
                  "Image size WxH, or a comma-separated list of sizes measured one after another")
      ->capture_default_str();
  add_camera_options(cmd, args->camera);
  cmd->add_option("--min-coverage", args->min_coverage,
                  "Zoom the automatic camera in until this share of the pixels hits the mesh "
                  "(0 = off; crops the model; older BENCHMARKS rows used 0.3)")
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
  cmd->add_flag(
      "--contours", args->contours,
      "Also build the same voxels with contours (esvo section 5.2) and measure them, with "
      "and without the beam (the shape of esvo Table 4)");
  cmd->add_flag("--effects", args->effects,
                "Also measure shadow and AO rays (svdag section 4) on the ESVO, a DAG of the same "
                "voxels and Embree rtcOccluded1");
  cmd->add_option("--ao-rays", args->ao_rays, "AO rays per hit pixel for --effects")
      ->capture_default_str();
  cmd->add_option("--ao-radius", args->ao_radius,
                  "AO ray length for --effects (0 = 5% of the mesh bounds diagonal)")
      ->capture_default_str();
  return [args]() {
    ThreadLimit limit(args->threads);
    std::vector<std::pair<int, int>> sizes;
    {
      std::stringstream list(args->size);
      std::string one;
      while (std::getline(list, one, ',')) {
        int w = 0, h = 0;
        parse_size(one, &w, &h);
        sizes.emplace_back(w, h);
      }
      if (sizes.empty()) throw UsageError("--size: no size given");
    }
    require_power_of_two("--resolution", args->resolution, 1, uint64_t(1) << 20);
    require_range("--lod", args->lod, 0, 1e6);
    require_range("--repeat", args->repeat, 1, 1000);
    if (args->beam != 0 && args->beam != 4 && args->beam != 8)
      throw UsageError("--beam must be 0, 4 or 8");
    require_range("--min-coverage", args->min_coverage, 0, 0.95);
    require_range("--ao-rays", args->ao_rays, 1, 4096);
    require_range("--ao-radius", args->ao_radius, 0, 1e30);
    check_camera_options(args->camera, 64, 64);
    require_regular_input(args->input, "mesh");

    BuildSettings s;
    s.mesh_path = args->input;
    s.resolution = args->resolution;
    s.mode = parse_voxelization(args->voxelization);
    s.attributes = parse_attribute_format(args->attributes);
    s.verbose = args->verbose;
    BuiltScene built = build_scene(s);
    auto octree = std::make_shared<esvo::EsvoOctree>(std::move(built.octree));
    esvo::EsvoStructure voxels(octree);
    const Aabb occupied = esvo::occupied_bounds(*octree);
    EmbreeScene embree(built.mesh);
    std::shared_ptr<esvo::EsvoOctree> contoured;
    double contour_build_seconds = 0;
    if (args->contours) {
      BuildSettings cs = s;
      cs.contours = true;
      BuiltScene cb = build_scene(cs);
      contour_build_seconds = cb.voxelize_seconds + cb.octree_seconds;
      contoured = std::make_shared<esvo::EsvoOctree>(std::move(cb.octree));
    }

    for (size_t size_index = 0; size_index < sizes.size(); ++size_index) {
      const int width = sizes[size_index].first, height = sizes[size_index].second;
      // The same framing as `render` of a scene of these voxels: the occupied
      // voxel bounds the scene loader computes.
      bool derived_camera = false;
      Camera camera = resolve_camera(args->camera, occupied, width, height, &derived_camera);
      if (derived_camera && args->min_coverage > 0) {
        // Misses flatter every ray caster: optionally zoom in until the mesh
        // covers enough pixels (this crops the model).
        for (int i = 0; i < 12; ++i) {
          double c =
              coverage(embree.render_depth(camera, width, height, EmbreeScene::Mode::Single).depth);
          if (c >= args->min_coverage) break;
          if (camera.projection == Projection::Orthographic)
            camera.ortho_width *= 0.85f;
          else
            camera.fovy_degrees *= 0.85f;
        }
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
      double best_cont = 1e30, best_cont_beam = 1e30;
      RenderResult vox_result;
      EmbreeScene::DepthRender e1;
      std::unique_ptr<esvo::EsvoStructure> contour_voxels;
      if (contoured) contour_voxels = std::make_unique<esvo::EsvoStructure>(contoured);
      render(voxels, ro);  // warm-up: page in the octree, spin up the TBB workers
      if (contour_voxels) render(*contour_voxels, ro);
      for (int r = 0; r < args->repeat; ++r) {
        vox_result = render(voxels, ro);
        best_vox = std::min(best_vox, vox_result.seconds);
        if (args->beam) best_beam = std::min(best_beam, render(voxels, ro_beam).seconds);
        if (contour_voxels) {
          best_cont = std::min(best_cont, render(*contour_voxels, ro).seconds);
          if (args->beam)
            best_cont_beam = std::min(best_cont_beam, render(*contour_voxels, ro_beam).seconds);
        }
        e1 = embree.render_depth(camera, width, height, EmbreeScene::Mode::Single);
        best_e1 = std::min(best_e1, e1.seconds);
        auto e8 = embree.render_depth(camera, width, height, EmbreeScene::Mode::Packet8);
        best_e8 = std::min(best_e8, e8.seconds);
      }
      double rays = double(width) * height;
      double m_cont = rays / best_cont * 1e-6, m_cont_beam = rays / best_cont_beam * 1e-6;
      double m_vox = rays / best_vox * 1e-6, m_beam = rays / best_beam * 1e-6,
             m_e1 = rays / best_e1 * 1e-6, m_e8 = rays / best_e8 * 1e-6;

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
      std::printf("mesh        %s: %zu triangles\n", printable(args->input).c_str(),
                  built.mesh.triangle_count());
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
      if (args->beam)
        std::printf("voxcast+beam%8.2f Mrays/s (beam %dx%d, coarse pass included)\n", m_beam,
                    args->beam, args->beam);
      if (contour_voxels) {
        std::printf("contours    %8.2f Mrays/s (build %.2f s, %s)\n", m_cont, contour_build_seconds,
                    format_bytes(double(contoured->memory_stats().total_bytes)).c_str());
        if (args->beam)
          std::printf("contours+beam%7.2f Mrays/s (beam %dx%d)\n", m_cont_beam, args->beam,
                      args->beam);
      }
      std::printf("embree x1   %8.2f Mrays/s (rtcIntersect1)\n", m_e1);
      std::printf("embree x8   %8.2f Mrays/s (rtcIntersect8)\n", m_e8);
      double best_voxcast = std::max(m_vox, args->beam ? m_beam : 0.0);
      if (contour_voxels)
        best_voxcast = std::max({best_voxcast, m_cont, args->beam ? m_cont_beam : 0.0});
      std::printf("ratio voxcast/embree: %.3f\n", best_voxcast / std::max(m_e1, m_e8));
      if (args->effects && size_index == 0) {
        // Shading points: the ESVO's primary hits of this frame (finest level,
        // voxel normals), offset once (effects.hpp); every caster gets the
        // very same occlusion rays.
        const CameraRays cam(camera, width, height);
        std::vector<ShadingPoint> points;
        for (int y = 0; y < height; ++y)
          for (int x = 0; x < width; ++x) {
            const Ray ray = cam.ray(x, y);
            SurfaceHit hit;
            if (!voxels.trace(ray, LodFootprint{}, &hit)) continue;
            Color c;
            Vec3 n;
            voxels.attributes(hit, &c, &n);
            if (dot(n, ray.dir) > 0.f) n = -n;
            points.push_back({hit.position, n, ray.dir, hit.voxel_size});
          }
        BuildSettings ds = s;
        ds.dag = true;
        ds.verbose = false;
        BuiltScene dag_built = build_scene(ds);  // the same mesh, grid and voxelization
        const dag::DagStructure dag_voxels(
            std::make_shared<dag::SparseVoxelDag>(std::move(dag_built.dag)));
        // Primary rays on the DAG of the same voxels, same camera (svdag §4),
        // against the ESVO and Embree numbers printed above.
        {
          render(dag_voxels, ro);  // warm-up
          RenderOptions dag_beam = ro;
          dag_beam.beam = 8;
          double best_dag = 1e30, best_dag_beam = 1e30;
          for (int r = 0; r < args->repeat; ++r) {
            best_dag = std::min(best_dag, render(dag_voxels, ro).seconds);
            best_dag_beam = std::min(best_dag_beam, render(dag_voxels, dag_beam).seconds);
          }
          std::printf("primary dag %8.2f Mrays/s, with beam 8x8 %.2f Mrays/s (%s DAG)\n",
                      rays / best_dag * 1e-6, rays / best_dag_beam * 1e-6,
                      format_bytes(double(dag_voxels.dag().stats().dag_bytes)).c_str());
        }
        const StructureOccluder esvo_occ(voxels), dag_occ(dag_voxels);
        const EmbreeOccluder embree_occ(embree);
        EffectOptions shadow_fx;
        shadow_fx.shadows = ShadowMode::Hard;
        EffectOptions ao_fx;
        ao_fx.ao_rays = args->ao_rays;
        ao_fx.ao_radius =
            args->ao_radius > 0 ? args->ao_radius : 0.05f * length(built.mesh.bounds().extent());
        const Vec3 light_dir = ro.light_dir;
        std::printf(
            "effects     %zu shading points (ESVO primary hits, offset 2 voxels along the normal + "
            "1 back)\n",
            points.size());
        struct Row {
          const char* name;
          const Occluder* occ;
        };
        const Row rows[] = {{"esvo", &esvo_occ}, {"dag", &dag_occ}, {"embree x1", &embree_occ}};
        EffectRun shadow_runs[3], ao_runs[3];
        for (int k = 0; k < 3; ++k) {
          run_effect_rays(*rows[k].occ, points, shadow_fx, light_dir, 1);  // warm-up
          shadow_runs[k] =
              run_effect_rays(*rows[k].occ, points, shadow_fx, light_dir, args->repeat);
          ao_runs[k] =
              run_effect_rays(*rows[k].occ, points, ao_fx, light_dir, std::min(args->repeat, 3));
        }
        for (int k = 0; k < 3; ++k)
          std::printf("shadow %-9s %8.2f Mrays/s (directional, 1 ray per hit pixel, %llu rays%s)\n",
                      rows[k].name, double(shadow_runs[k].rays) / shadow_runs[k].seconds * 1e-6,
                      (unsigned long long)shadow_runs[k].rays,
                      k == 2 ? ", rtcOccluded1" : ", any hit");
        for (int k = 0; k < 3; ++k)
          std::printf("ao     %-9s %8.2f Mrays/s (%d rays per hit pixel, radius %g, %llu rays%s)\n",
                      rows[k].name, double(ao_runs[k].rays) / ao_runs[k].seconds * 1e-6,
                      args->ao_rays, double(ao_fx.ao_radius), (unsigned long long)ao_runs[k].rays,
                      k == 2 ? ", rtcOccluded1" : ", any hit");
        size_t same_shadow = 0, same_dag = 0;
        double ao_diff = 0;
        for (size_t i = 0; i < points.size(); ++i) {
          same_shadow += shadow_runs[0].values[i] == shadow_runs[2].values[i];
          same_dag += shadow_runs[0].values[i] == shadow_runs[1].values[i] &&
                      ao_runs[0].values[i] == ao_runs[1].values[i];
          ao_diff += std::fabs(ao_runs[0].values[i] - ao_runs[2].values[i]);
        }
        const double np = double(std::max<size_t>(points.size(), 1));
        std::printf(
            "effects agreement: shadow mask esvo/embree %.3f%%, mean |AO esvo - AO embree| %.4f, "
            "esvo == dag on %.3f%% of points\n",
            100.0 * double(same_shadow) / np, ao_diff / np, 100.0 * double(same_dag) / np);
      }
    }  // sizes
    return 0;
  };
}

}  // namespace voxcast::cli
