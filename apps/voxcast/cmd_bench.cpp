// voxcast bench MESH: the voxel ray casters against Embree on the same mesh,
// camera, image size, tiles and threads, measured in one run (issue 10, the
// fair benchmark): Embree in every primary mode (x1, 2x2/4x2/4x4 packets,
// stream), trace only and with the same shading, voxel casters at LOD 0 and
// --lod, occlusion rays generated once for every caster, and an instrumented
// single-threaded cycles-per-ray profile. docs/BENCHMARKS.md shows the output.

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <functional>
#include <iterator>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "camera_options.hpp"
#include "cli_io.hpp"
#include "commands.hpp"
#include "pipeline.hpp"
#include "render/beam.hpp"
#include "render/bench_timing.hpp"
#include "render/tiling.hpp"
#include "voxcast/brickmap.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/effects.hpp"
#include "voxcast/embree_reference.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/packet_caster.hpp"
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
  bool brickmap = false;
  int ao_rays = 64;
  float ao_radius = 0.f;
  std::string json;  // --json FILE: every figure
  std::string memory_budget;
};

// What bench holds at once, estimated before anything is built. Each voxel
// build is estimated as `build` does (estimate_build_bytes: its peak, which
// bounds the structure it leaves), each extra build also holds its own copy
// of the mesh. Embree's high-quality BVH (primitive references, spatial
// splits, nodes and the triangle copy): 384 bytes per triangle bounds it.
// Images: per pixel, the voxel render kept for the agreement figures
// (color, depth, normals: 28 B), Embree's depth render (4 B), and the frame
// being measured (up to 28 + 4 B of iteration counts), rounded up to 128 B.
constexpr uint64_t kEmbreeBytesPerTriangle = 384;
constexpr uint64_t kImageBytesPerPixel = 128;

struct BenchMemory {
  uint64_t mesh = 0;      // every mesh copy held for the whole run
  uint64_t esvo = 0;      // the ESVO build (estimate_build_bytes)
  uint64_t embree = 0;    // Embree's BVH
  uint64_t contours = 0;  // the contour build and its own mesh copy
  uint64_t images = 0;    // the largest --size
  uint64_t dag = 0;       // --effects: what the DAG holds once built
  uint64_t total() const { return mesh + esvo + embree + contours + images + dag; }
};

// Occlusion rays of --effects, known once the shading points are: every
// shadow and AO ray (28 B) twice (as generated and sample-major), one answer
// byte per ray and caster row (at most 8), and the point itself.
uint64_t effects_bytes(uint64_t points, uint64_t ao_rays) {
  return points * ((1 + ao_rays) * (2 * sizeof(Ray) + 8) + sizeof(ShadingPoint) + 4);
}

void require_within_budget(uint64_t need, uint64_t budget, const std::string& what) {
  if (budget && need > budget)
    throw Error("bench: " + what + " need an estimated " + format_bytes(double(need)) +
                ", more than the " + format_bytes(double(budget)) +
                " memory budget; lower --resolution or --size, drop --contours/--effects, or "
                "raise --memory-budget");
}

// One timing harness for every caster, voxel or Embree. Each row has a
// frame() that runs one frame and returns the seconds of its timed loop only
// (setup and allocation outside). Every row gets a warm-up frame (pages its
// structure in, spins up the TBB workers), then `repeat` rounds run every
// row once each, in turn, so that a load change on the (shared) machine hits
// all casters alike; each row keeps its best frame.
struct Timed {
  double seconds = 1e30;
  uint64_t rays = 0, hits = 0;  // hits: primary hits, or occluded rays
  double mrays() const { return double(rays) / seconds * 1e-6; }
  double mhits() const { return double(hits) / seconds * 1e-6; }
};
template <class Row>
void measure_interleaved(std::vector<Row>& rows, int repeat) {
  for (Row& r : rows) {
    r.t = r.frame();  // warm-up
    r.t.seconds = 1e30;
  }
  for (int k = 0; k < repeat; ++k)
    for (Row& r : rows) {
      const Timed t = r.frame();
      if (t.seconds < r.t.seconds) r.t = t;
    }
}

Timed timed(const RenderResult& r) {
  return {r.seconds, r.rays, r.hits};
}
Timed timed(const EmbreeScene::DepthRender& r) {
  return {r.seconds, r.rays, r.hits};
}

// The pixel cone of render() (esvo §6.1): lod_pixels pixels per unit distance.
LodFootprint pixel_lod(const CameraRays& cam, float lod_pixels) {
  LodFootprint lod;
  lod.size_per_t = lod_pixels * cam.pixel_angle();
  return lod;
}

// One trace-only frame: the same tiles and threads as render(), depth
// written. trace_tile(tile, cam, lod) traces a tile's primary rays (generated
// in the loop, as render() does), writes their depth and returns its hits.
template <class TraceTile>
Timed depth_frame(const RenderOptions& ro, Image* depth, const TraceTile& trace_tile) {
  const CameraRays cam(ro.camera, ro.width, ro.height);
  const LodFootprint lod = pixel_lod(cam, ro.lod_pixels);
  *depth = Image(ro.width, ro.height, 1);
  std::atomic<uint64_t> hits{0};
  Timed t;
  t.rays = uint64_t(ro.width) * uint64_t(ro.height);
  t.seconds =
      detail::for_each_tile(ro.width, ro.height, ro.tile_size, [&](const detail::Tile& tile) {
        hits.fetch_add(trace_tile(tile, cam, lod), std::memory_order_relaxed);
      });
  t.hits = hits.load();
  return t;
}

// Trace only, the voxel side of the trace-only comparison: no attributes and
// no shading. S is a final class, so the trace() call is direct, not virtual.
template <class S>
Timed trace_depth(const S& s, const RenderOptions& ro, Image* depth) {
  return depth_frame(ro, depth,
                     [&](const detail::Tile& tile, const CameraRays& cam, const LodFootprint& lod) {
                       uint64_t h = 0;
                       TraceContext ctx;  // plain (non-counting), one per tile
                       for (int y = tile.y0; y < tile.y1; ++y)
                         for (int x = tile.x0; x < tile.x1; ++x) {
                           SurfaceHit hit;
                           const bool found = s.trace(cam.ray(x, y), lod, ctx, &hit);
                           h += found;
                           *depth->at(x, y) = found ? hit.t : INFINITY;
                         }
                       return h;
                     });
}

// trace_depth through the packet caster (voxcast/packet_caster.hpp): each
// tile's rays generated in 4x4 block order and traced as one queue.
// beam > 0: the coarse pass (esvo §6.2) per beam x beam block first, inside
// the timed loop; each ray starts at its block's region, rays of empty
// blocks are not traced.
// shade: also each hit's attributes and surface_phong (the shading of
// render() without effects), written to *color: the packet caster in the
// "trace + the same shading" comparison (attributes are still looked up hit
// by hit).
template <class S>
Timed trace_depth_packets(const S& s, const RenderOptions& ro, int beam, Image* depth,
                          bool shade = false, Image* color = nullptr) {
  if (shade) *color = Image(ro.width, ro.height, 3);
  const Vec3 to_light = normalize(-ro.light_dir);
  return depth_frame(
      ro, depth, [&](const detail::Tile& tile, const CameraRays& cam, const LodFootprint& lod) {
        thread_local std::vector<uint32_t> order;
        thread_local std::vector<Ray> rays;
        thread_local std::vector<SurfaceHit> out;
        thread_local std::vector<uint8_t> found;
        thread_local std::vector<BeamStart> starts;
        thread_local std::vector<const BeamStart*> beams;
        order.clear();
        block_order(tile.x0, tile.y0, tile.x1 - tile.x0, tile.y1 - tile.y0, &order);
        rays.resize(order.size());
        out.resize(order.size());
        found.resize(order.size());
        for (size_t i = 0; i < order.size(); ++i)
          rays[i] = cam.ray(int(order[i] & 0xFFFF), int(order[i] >> 16));
        TraceContext ctx;
        if (beam > 0) {
          const int bw = (tile.x1 - tile.x0 + beam - 1) / beam;
          const int bh = (tile.y1 - tile.y0 + beam - 1) / beam;
          starts.resize(size_t(bw * bh));
          for (int by = 0; by < bh; ++by)
            for (int bx = 0; bx < bw; ++bx) {
              const int x0 = tile.x0 + bx * beam, y0 = tile.y0 + by * beam;
              s.beam_start(detail::block_beam(cam, x0, y0, std::min(x0 + beam, tile.x1),
                                              std::min(y0 + beam, tile.y1), lod),
                           ctx, &starts[size_t(by * bw + bx)]);
            }
          beams.resize(order.size());
          for (size_t i = 0; i < order.size(); ++i) {
            const int bx = (int(order[i] & 0xFFFF) - tile.x0) / beam;
            const int by = (int(order[i] >> 16) - tile.y0) / beam;
            beams[i] = &starts[size_t(by * bw + bx)];
          }
        }
        trace_packets(s, rays.data(), rays.size(), lod, out.data(), found.data(), active_isa(),
                      beam > 0 ? beams.data() : nullptr);
        uint64_t h = 0;
        for (size_t i = 0; i < order.size(); ++i) {
          const int x = int(order[i] & 0xFFFF), y = int(order[i] >> 16);
          h += found[i];
          *depth->at(x, y) = found[i] ? out[i].t : INFINITY;
          if (shade && found[i]) {
            Color c;
            Vec3 n;
            s.attributes(out[i], ctx, &c, &n);
            const Color sh = surface_phong(c, n, rays[i].dir, to_light);
            float* o = color->at(x, y);
            o[0] = sh.r, o[1] = sh.g, o[2] = sh.b;
          }
        }
        return h;
      });
}

// Any-hit answers for pre-generated rays, in the same chunks as
// EmbreeScene::occluded_all (finest level, as the effects trace): chunk(b, e,
// o) answers rays [b, e) into o[b, e).
template <class Chunk>
Timed occluded_frame(const std::vector<Ray>& rays, std::vector<uint8_t>* occ, const Chunk& chunk) {
  occ->assign(rays.size(), 0);
  uint8_t* o = occ->data();
  Timed t;
  t.rays = rays.size();
  t.seconds = detail::for_each_chunk(rays.size(), EmbreeScene::kOcclusionChunk,
                                     [&](size_t b, size_t e) { chunk(b, e, o); });
  for (uint8_t v : *occ) t.hits += v;
  return t;
}

// A voxel structure's occluded(), ray by ray.
template <class S>
Timed occluded_all(const S& s, const std::vector<Ray>& rays, std::vector<uint8_t>* occ) {
  return occluded_frame(rays, occ, [&](size_t b, size_t e, uint8_t* o) {
    TraceContext ctx;
    for (size_t i = b; i < e; ++i) o[i] = s.occluded(rays[i], LodFootprint{}, ctx);
  });
}

// The packet caster's occluded_packets: each chunk as one queue.
template <class S>
Timed occluded_all_packets(const S& s, const std::vector<Ray>& rays, std::vector<uint8_t>* occ) {
  return occluded_frame(rays, occ, [&](size_t b, size_t e, uint8_t* o) {
    occluded_packets(s, rays.data() + b, e - b, LodFootprint{}, o + b);
  });
}

// Records the rays shadow_visibility() / ambient_occlusion() would trace
// (answering "open"), so that the occlusion rays are generated once, with
// the renderer's very sampling, and every caster gets the same array.
class RayRecorder final : public Occluder {
 public:
  float transmittance(const Ray& ray, const LodFootprint&, TraceContext&,
                      const BeamStart*) const override {
    rays.push_back(ray);
    return 1.f;
  }
  mutable std::vector<Ray> rays;
};

// Stage ticks of the instrumented single-threaded voxel pass: what render()
// does per pixel (ray generation, trace, attributes, shading without
// effects), with timestamp reads between the stages.
template <class S>
EmbreeScene::StageTicks profile_voxels(const S& s, const RenderOptions& ro) {
  const CameraRays cam(ro.camera, ro.width, ro.height);
  const LodFootprint lod = pixel_lod(cam, ro.lod_pixels);
  const Vec3 to_light = normalize(-ro.light_dir);
  const uint64_t overhead = detail::tick_overhead();
  auto since = [overhead](uint64_t a, uint64_t b) {
    return b - a > overhead ? b - a - overhead : 0;
  };
  EmbreeScene::StageTicks st;
  Image color(ro.width, ro.height, 3);
  TraceContext ctx;
  for (int y = 0; y < ro.height; ++y)
    for (int x = 0; x < ro.width; ++x) {
      const uint64_t t0 = detail::ticks();
      const Ray ray = cam.ray(x, y);
      const uint64_t t1 = detail::ticks();
      SurfaceHit hit;
      const bool found = s.trace(ray, lod, ctx, &hit);
      const uint64_t t2 = detail::ticks();
      st.ray_generation += since(t0, t1);
      st.traversal += since(t1, t2);
      if (!found) continue;
      Color c;
      Vec3 n;
      s.attributes(hit, ctx, &c, &n);
      const uint64_t t3 = detail::ticks();
      const Color sh = surface_phong(c, n, ray.dir, to_light);
      float* o = color.at(x, y);
      o[0] = sh.r, o[1] = sh.g, o[2] = sh.b;
      const uint64_t t4 = detail::ticks();
      st.attributes += since(t2, t3);
      st.shading += since(t3, t4);
    }
  st.rays = uint64_t(ro.width) * uint64_t(ro.height);
  return st;
}

// The value of the first line of a /proc file that starts with `key`
// ("key<TAB>: value"), or the whole first line for an empty key.
std::string first_line_of(const char* path, const std::string& key) {
  std::ifstream in(path);
  std::string line;
  while (std::getline(in, line)) {
    if (key.empty()) return line;
    if (line.rfind(key, 0) != 0) continue;
    const size_t colon = line.find(':');
    const size_t v = colon == std::string::npos ? colon : line.find_first_not_of(" \t", colon + 1);
    return v == std::string::npos ? std::string() : line.substr(v);
  }
  return "unknown";
}

// The command line as the kernel has it (arguments NUL-separated).
std::string command_line() {
  std::ifstream in("/proc/self/cmdline", std::ios::binary);
  std::string all((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>()), out;
  for (char c : all) out += c ? c : ' ';
  while (!out.empty() && out.back() == ' ') out.pop_back();
  return out;
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
  cmd->add_flag(
      "--effects", args->effects,
      "Also measure the DAG of the same voxels, and shadow and AO rays (svdag section 4), "
      "generated once, on the ESVO, the DAG and Embree rtcOccluded1/8/16/1M");
  cmd->add_flag("--brickmap", args->brickmap,
                "Also measure the brickmap world of the same voxels (van Wingerden 2015)");
  cmd->add_option("--ao-rays", args->ao_rays, "AO rays per hit pixel for --effects")
      ->capture_default_str();
  cmd->add_option("--ao-radius", args->ao_radius,
                  "AO ray length for --effects (0 = 5% of the mesh bounds diagonal)")
      ->capture_default_str();
  cmd->add_option("--json", args->json, "Also write every figure as JSON to this file");
  cmd->add_option("--memory-budget", args->memory_budget,
                  "Bytes every structure, image and ray array held at once may take (512M, 8G, "
                  "...; default 90% of available memory); checked before anything is built");
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

    const uint64_t budget = effective_budget(
        args->memory_budget.empty() ? 0 : parse_memory_budget(args->memory_budget));

    BuildSettings s;
    s.mesh_path = args->input;
    s.resolution = args->resolution;
    s.mode = parse_voxelization(args->voxelization);
    s.attributes = parse_attribute_format(args->attributes);
    s.verbose = args->verbose;
    s.memory_budget = budget;
    MeshLoadStats mesh_stats;
    Mesh mesh = load_build_mesh(s.mesh_path, budget, &mesh_stats, s.verbose);
    // Every structure bench holds at once, against the budget, before the
    // first build: the ESVO, Embree's BVH, the contour octree, the images.
    BenchMemory held;
    {
      const GridTransform grid = build_grid(s, mesh.bounds());
      const uint64_t build = estimate_build_bytes(mesh, grid), one_mesh = mesh_bytes(mesh);
      // The ESVO build's mesh, and the copy later builds start from.
      held.mesh = one_mesh * (args->contours || args->effects || args->brickmap ? 2 : 1);
      held.esvo = build;
      held.embree = uint64_t(mesh.triangle_count()) * kEmbreeBytesPerTriangle;
      if (args->contours) held.contours = build + one_mesh;
      for (const auto& [w, h] : sizes)
        held.images = std::max(held.images, uint64_t(w) * uint64_t(h) * kImageBytesPerPixel);
      std::string parts = "the mesh, the ESVO, Embree's BVH";
      if (args->contours) parts += ", the contour octree";
      parts += " and the images";
      require_within_budget(held.total(), budget, parts);
    }
    const Mesh mesh_copy = (args->contours || args->effects || args->brickmap) ? mesh : Mesh();
    BuiltScene built = build_scene(s, std::move(mesh), mesh_stats);  // BuildSettings::format: esvo
    const esvo::EsvoStructure& voxels = dynamic_cast<const esvo::EsvoStructure&>(*built.structure);
    const esvo::EsvoOctree* octree = &voxels.octree();
    const Aabb occupied = esvo::occupied_bounds(*octree);
    EmbreeScene embree(built.mesh);
    LoadedStructure contour_structure;
    const esvo::EsvoOctree* contoured = nullptr;
    double contour_build_seconds = 0;
    // What is left for a later build (0 would mean "no budget").
    auto left_after = [&](uint64_t bytes) { return budget > bytes ? budget - bytes : 1; };
    if (args->contours) {
      BuildSettings cs = s;
      cs.contours = true;
      // (build_scene counts its own copy of the mesh.)
      cs.memory_budget = left_after(held.mesh + held.esvo + held.embree + held.images);
      BuiltScene cb = build_scene(cs, mesh_copy, mesh_stats);
      contour_build_seconds = cb.voxelize_seconds + cb.octree_seconds;
      contour_structure = std::move(cb.structure);
      contoured = &dynamic_cast<const esvo::EsvoStructure&>(*contour_structure).octree();
    }

    // Machine and command line first: every figure below depends on them.
    // "AMD EPYC" alone does not tell Zen generations apart: add family/model.
    const std::string cpu = first_line_of("/proc/cpuinfo", "model name") + " (family " +
                            first_line_of("/proc/cpuinfo", "cpu family") + ", model " +
                            first_line_of("/proc/cpuinfo", "model\t") + ")";
    const std::string isa = EmbreeScene::probe_isa();
    std::string load = first_line_of("/proc/loadavg", "");  // the 1, 5, 15 min averages
    for (int spaces = 0, i = 0; i < int(load.size()); ++i)
      if (load[size_t(i)] == ' ' && ++spaces == 3) load.resize(size_t(i));
    const std::string cmdline = command_line();
    std::printf("command     %s\n", printable(cmdline).c_str());
    std::printf("machine     %s, %u logical CPUs, load average %s\n", cpu.c_str(),
                std::thread::hardware_concurrency(), load.c_str());
    std::printf("embree      %s\n", isa.c_str());
    nlohmann::json json_runs = nlohmann::json::array();
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

      const int threads = args->threads ? args->threads : int(std::thread::hardware_concurrency());
      const double rays = double(width) * height;
      nlohmann::json run;
      run["image"] = {{"width", width}, {"height", height}};
      run["camera"] = camera.to_string();

      // ---- Primary rays: Embree in every mode, then the voxel casters. ----
      struct PrimaryRow {
        std::string caster, call;
        float lod;  // < 0: not a voxel caster
        bool shaded;
        std::function<Timed()> frame;
        Timed t;
      };
      std::vector<PrimaryRow> primary;
      EmbreeScene::DepthRender e1;  // rtcIntersect1 depth: coverage and agreement
      for (const EmbreeScene::Mode m : EmbreeScene::kModes) {
        const std::string name = std::string("embree ") + EmbreeScene::mode_name(m);
        primary.push_back({name,
                           EmbreeScene::mode_call(m),
                           -1.f,
                           false,
                           [&, m] {
                             auto r = embree.render_depth(camera, width, height, m);
                             if (m == EmbreeScene::Mode::Single) e1 = std::move(r);
                             return timed(m == EmbreeScene::Mode::Single ? e1 : r);
                           },
                           {}});
        primary.push_back(
            {name,
             std::string(EmbreeScene::mode_call(m)) + ", normals + Phong",
             -1.f,
             true,
             [&, m] { return timed(embree.render_shaded(camera, width, height, m, ro.light_dir)); },
             {}});
      }
      // LOD 0 (finest level) and --lod: trace only and render() (attributes + shading).
      std::vector<float> lods{0.f};
      if (args->lod != 0.f) lods.push_back(args->lod);
      RenderResult vox_result;  // at --lod, for the agreement line
      const esvo::EsvoStructure* contour_voxels =
          contour_structure ? &dynamic_cast<const esvo::EsvoStructure&>(*contour_structure)
                            : nullptr;
      // Trace-only and render() rows of one voxel structure at every LOD.
      auto add_voxel_rows = [&](const std::string& caster, const auto& structure) {
        for (float lod : lods) {
          RenderOptions rl = ro;
          rl.lod_pixels = lod;
          primary.push_back({caster,
                             "trace, depth only",
                             lod,
                             false,
                             [&structure, rl] {
                               Image depth;
                               return trace_depth(structure, rl, &depth);
                             },
                             {}});
          primary.push_back({caster + " packet",
                             std::string("trace_packets ") + isa_name(active_isa()) + " x" +
                                 std::to_string(packet_width(active_isa())) + ", depth only",
                             lod,
                             false,
                             [&structure, rl] {
                               Image depth;
                               return trace_depth_packets(structure, rl, 0, &depth);
                             },
                             {}});
          primary.push_back({caster + " packet",
                             "trace_packets + attributes + Phong (no effects)",
                             lod,
                             true,
                             [&structure, rl] {
                               Image depth, color;
                               return trace_depth_packets(structure, rl, 0, &depth, true, &color);
                             },
                             {}});
          if (args->beam)
            primary.push_back({caster + " packet+beam",
                               std::string("trace_packets, beam ") + std::to_string(args->beam) +
                                   "x" + std::to_string(args->beam) +
                                   " (coarse pass included), depth only",
                               lod,
                               false,
                               [&structure, rl, k = args->beam] {
                                 Image depth;
                                 return trace_depth_packets(structure, rl, k, &depth);
                               },
                               {}});
          primary.push_back(
              {caster,
               "render(): attributes + Phong",
               lod,
               true,
               [&, rl, keep = static_cast<const void*>(&structure) == &voxels && lod == args->lod] {
                 if (!keep) return timed(render(structure, rl));
                 vox_result = render(structure, rl);
                 return timed(vox_result);
               },
               {}});
        }
      };
      add_voxel_rows("voxcast esvo", voxels);
      // The existing variants at --lod, rendered (attributes + shading).
      RenderOptions ro_beam = ro;
      ro_beam.beam = args->beam;
      if (args->beam)
        primary.push_back({"voxcast esvo+beam",
                           "render(), beam " + std::to_string(args->beam) + "x" +
                               std::to_string(args->beam) + " (coarse pass included)",
                           args->lod,
                           true,
                           [&] { return timed(render(voxels, ro_beam)); },
                           {}});
      if (contour_voxels) {
        primary.push_back({"voxcast contours",
                           "render()",
                           args->lod,
                           true,
                           [&] { return timed(render(*contour_voxels, ro)); },
                           {}});
        if (args->beam)
          primary.push_back({"voxcast contours+beam",
                             "render(), beam",
                             args->lod,
                             true,
                             [&] { return timed(render(*contour_voxels, ro_beam)); },
                             {}});
      }
      // With --effects: the DAG of the same voxels (svdag §4), same camera.
      LoadedStructure dag_structure;
      const dag::DagStructure* dag_voxels = nullptr;
      RenderOptions dag_beam = ro;
      dag_beam.beam = 8;
      if (args->effects && size_index == 0) {
        BuildSettings ds = s;
        ds.format = "dag";
        ds.verbose = false;
        // Out of core within what the others leave when in core would not fit
        // (build_scene counts its own copy of the mesh).
        ds.memory_budget = left_after(held.total());
        // Held afterwards: at most its in-core estimate (the same grid as the
        // ESVO's) or the budget it was given.
        held.dag = std::min(held.esvo, ds.memory_budget);
        // The same mesh, grid and voxelization.
        BuiltScene dag_built = build_scene(ds, mesh_copy, mesh_stats);
        dag_structure = std::move(dag_built.structure);
        dag_voxels = &dynamic_cast<const dag::DagStructure&>(*dag_structure);
        add_voxel_rows("voxcast dag", *dag_voxels);
        primary.push_back({"voxcast dag+beam",
                           "render(), beam 8x8",
                           args->lod,
                           true,
                           [&] { return timed(render(*dag_voxels, dag_beam)); },
                           {}});
      }
      // With --brickmap: the brickmap world of the same voxels, same camera:
      // trace only and render() (no packet kernel for brickmaps).
      LoadedStructure brick_structure;
      const brickmap::BrickmapStructure* brick_voxels = nullptr;
      brickmap::WorldStats brick_stats;
      if (args->brickmap && size_index == 0) {
        BuildSettings bs = s;
        bs.format = "brickmap";
        bs.verbose = false;
        bs.memory_budget = left_after(held.total());
        // The same mesh, grid and voxelization.
        BuiltScene brick_built = build_scene(bs, mesh_copy, mesh_stats);
        brick_structure = std::move(brick_built.structure);
        brick_voxels = &dynamic_cast<const brickmap::BrickmapStructure&>(*brick_structure);
        brick_stats = brick_voxels->world().stats();
        for (float lod : lods) {
          RenderOptions rl = ro;
          rl.lod_pixels = lod;
          primary.push_back({"voxcast brickmap", "trace, depth only", lod, false,
                             [brick_voxels, rl] {
                               Image depth;
                               return trace_depth(*brick_voxels, rl, &depth);
                             },
                             {}});
          primary.push_back({"voxcast brickmap", "render(): attributes + Phong", lod, true,
                             [brick_voxels, rl] { return timed(render(*brick_voxels, rl)); },
                             {}});
        }
      }
      measure_interleaved(primary, args->repeat);
      const double cov = double(primary[0].t.hits) / rays;
      // Ratios against the fastest Embree mode of the same comparison.
      double fastest[2] = {0, 0};
      std::string fastest_name[2];
      for (const PrimaryRow& r : primary)
        if (r.lod < 0 && r.t.mrays() > fastest[r.shaded])
          fastest[r.shaded] = r.t.mrays(), fastest_name[r.shaded] = r.caster;

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
      std::printf("mesh        %s: %zu triangles\n", printable(args->input).c_str(),
                  built.mesh.triangle_count());
      std::printf("camera      %s\n", camera.to_string().c_str());
      std::printf("image       %dx%d, %.1f%% of pixels hit the mesh, %d threads, best of %d\n",
                  width, height, 100.0 * cov, threads, args->repeat);
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
      for (int shaded = 0; shaded < 2; ++shaded) {
        std::printf("\n%s (ratio: Mrays/s over %s, the fastest Embree mode here)\n",
                    shaded ? "trace + the same shading" : "trace only (depth written)",
                    fastest_name[shaded].c_str());
        std::printf("  %-22s %4s %9s %9s %7s  %s\n", "caster", "lod", "Mrays/s", "Mhits/s", "ratio",
                    "how");
        for (const PrimaryRow& r : primary) {
          if (r.shaded != bool(shaded)) continue;
          char lod[16] = "-";
          if (r.lod >= 0) std::snprintf(lod, sizeof lod, "%g", double(r.lod));
          std::printf("  %-22s %4s %9.2f %9.2f %7.3f  %s\n", r.caster.c_str(), lod, r.t.mrays(),
                      r.t.mhits(), r.t.mrays() / fastest[shaded], r.call.c_str());
        }
      }
      std::printf("\n");
      // The one-line summary (bench/*.sh read these lines): voxcast render()
      // at --lod against Embree trace only, as before, now with every mode.
      auto find = [&](const std::string& caster, bool shaded, float lod) -> const Timed* {
        for (const PrimaryRow& r : primary)
          if (r.caster == caster && r.shaded == shaded && (r.lod < 0 || r.lod == lod)) return &r.t;
        return nullptr;
      };
      const double m_vox = find("voxcast esvo", true, args->lod)->mrays();
      std::printf("voxcast     %8.2f Mrays/s\n", m_vox);
      double best_voxcast = m_vox;
      if (const Timed* t = find("voxcast esvo+beam", true, args->lod)) {
        std::printf("voxcast+beam%8.2f Mrays/s (beam %dx%d, coarse pass included)\n", t->mrays(),
                    args->beam, args->beam);
        best_voxcast = std::max(best_voxcast, t->mrays());
      }
      if (const Timed* t = find("voxcast contours", true, args->lod)) {
        std::printf("contours    %8.2f Mrays/s (build %.2f s, %s)\n", t->mrays(),
                    contour_build_seconds,
                    format_bytes(double(contoured->memory_stats().total_bytes)).c_str());
        best_voxcast = std::max(best_voxcast, t->mrays());
      }
      if (const Timed* t = find("voxcast contours+beam", true, args->lod)) {
        std::printf("contours+beam%7.2f Mrays/s (beam %dx%d)\n", t->mrays(), args->beam,
                    args->beam);
        best_voxcast = std::max(best_voxcast, t->mrays());
      }
      for (const EmbreeScene::Mode m : EmbreeScene::kModes) {
        const std::string name = std::string("embree ") + EmbreeScene::mode_name(m);
        std::printf("%-12s%8.2f Mrays/s (%s)\n", name.c_str(), find(name, false, 0)->mrays(),
                    EmbreeScene::mode_call(m));
      }
      if (const Timed* t = find("voxcast dag", true, args->lod))
        std::printf("primary dag %8.2f Mrays/s, with beam 8x8 %.2f Mrays/s (%s DAG)\n", t->mrays(),
                    find("voxcast dag+beam", true, args->lod)->mrays(),
                    format_bytes(double(dag_voxels->dag().stats().dag_bytes)).c_str());
      if (const Timed* t = find("voxcast brickmap", true, args->lod))
        std::printf("brickmap    %8.2f Mrays/s (%llu bricks, %s, %.2f bits/voxel)\n", t->mrays(),
                    (unsigned long long)brick_stats.bricks,
                    format_bytes(double(brick_stats.total_bytes())).c_str(),
                    brick_stats.bits_per_voxel());
      std::printf("ratio voxcast/embree: %.3f\n", best_voxcast / fastest[0]);

      run["coverage"] = cov;
      run["agreement"] = {{"hit_miss", double(agree) / rays},
                          {"depth_within_2_diagonals", both ? double(close) / double(both) : 0.0}};
      run["fastest_embree"] = {{"trace", fastest_name[0]}, {"shaded", fastest_name[1]}};
      for (const PrimaryRow& r : primary)
        run["primary"].push_back({{"caster", r.caster},
                                  {"how", r.call},
                                  {"lod", r.lod >= 0 ? nlohmann::json(r.lod) : nlohmann::json()},
                                  {"shaded", r.shaded},
                                  {"seconds", r.t.seconds},
                                  {"rays", r.t.rays},
                                  {"hits", r.t.hits},
                                  {"mrays_per_s", r.t.mrays()},
                                  {"mhits_per_s", r.t.mhits()},
                                  {"ratio", r.t.mrays() / fastest[r.shaded]}});

      // ---- Cycles per ray: one instrumented single-threaded pass each. ----
      {
        const double hz = detail::tsc_hz();
        struct ProfileRow {
          std::string caster;
          float lod;
          EmbreeScene::StageTicks st;
        };
        std::vector<ProfileRow> prof;
        // Timestamps count wall time: a pass that another process preempted
        // reads high. The pass with the lowest total of a few (after a warm-up
        // pass) is the one least disturbed.
        const int passes = std::min(args->repeat, 3);
        auto least_disturbed = [&](const auto& pass) {
          pass();  // warm-up
          EmbreeScene::StageTicks best = pass();
          for (int k = 1; k < passes; ++k) {
            const EmbreeScene::StageTicks st = pass();
            if (st.total() < best.total()) best = st;
          }
          return best;
        };
        prof.push_back({"embree x1", -1.f, least_disturbed([&] {
                          return embree.profile_single(camera, width, height, ro.light_dir);
                        })});
        for (float lod : lods) {
          RenderOptions rl = ro;
          rl.lod_pixels = lod;
          prof.push_back(
              {"voxcast esvo", lod, least_disturbed([&] { return profile_voxels(voxels, rl); })});
          if (dag_voxels)
            prof.push_back({"voxcast dag", lod,
                            least_disturbed([&] { return profile_voxels(*dag_voxels, rl); })});
        }
        std::printf(
            "cycles per ray (TSC ticks at %.2f GHz, 1 thread, instrumented pass; per primary ray,\n"
            "attributes and shading only on hits)\n",
            hz * 1e-9);
        std::printf("  %-14s %4s %9s %9s %10s %8s %8s\n", "caster", "lod", "ray gen", "traversal",
                    "attributes", "shading", "total");
        for (const ProfileRow& p : prof) {
          const double n = double(std::max<uint64_t>(p.st.rays, 1));
          const double total = double(p.st.total()) / n;
          char lod[16] = "-";
          if (p.lod >= 0) std::snprintf(lod, sizeof lod, "%g", double(p.lod));
          std::printf("  %-14s %4s %9.1f %9.1f %10.1f %8.1f %8.1f\n", p.caster.c_str(), lod,
                      double(p.st.ray_generation) / n, double(p.st.traversal) / n,
                      double(p.st.attributes) / n, double(p.st.shading) / n, total);
          run["cycles_per_ray"].push_back(
              {{"caster", p.caster},
               {"lod", p.lod >= 0 ? nlohmann::json(p.lod) : nlohmann::json()},
               {"ray_generation", double(p.st.ray_generation) / n},
               {"traversal", double(p.st.traversal) / n},
               {"attributes", double(p.st.attributes) / n},
               {"shading", double(p.st.shading) / n},
               {"total", total}});
        }
        run["tsc_hz"] = hz;
        std::printf("\n");
      }

      if (args->effects && size_index == 0) {
        // Shading points: the ESVO's primary hits of this frame (finest level,
        // voxel normals), offset once (effects.hpp). Their shadow and AO rays
        // are generated once, here, and every caster traces the same arrays.
        // Pixels in 4x4 block order (block_order): the shadow rays of a block
        // are neighbours in the arrays, so a 16-ray packet, voxcast's or
        // Embree's, holds the parallel shadow rays of one pixel block.
        const CameraRays cam(camera, width, height);
        std::vector<ShadingPoint> points;
        std::vector<uint32_t> seeds;
        std::vector<uint32_t> pixel_order;
        block_order(0, 0, width, height, &pixel_order);
        TraceContext ctx;
        for (const uint32_t xy : pixel_order) {
          const int x = int(xy & 0xFFFF), y = int(xy >> 16);
          const Ray ray = cam.ray(x, y);
          SurfaceHit hit;
          if (!voxels.trace(ray, LodFootprint{}, ctx, &hit)) continue;
          Color c;
          Vec3 n;
          voxels.attributes(hit, ctx, &c, &n);
          if (dot(n, ray.dir) > 0.f) n = -n;
          points.push_back({hit.position, n, ray.dir, hit.voxel_size});
          seeds.push_back(pixel_seed(x, y, 0));
        }
        // The rays are recorded next: check them against what the structures
        // and images leave of the budget.
        require_within_budget(
            held.total() + effects_bytes(points.size(), uint64_t(args->ao_rays)), budget,
            "the structures and the " + std::to_string(points.size()) + " shading points' " +
                std::to_string(args->ao_rays + 1) + " occlusion rays each");
        EffectOptions shadow_fx;
        shadow_fx.shadows = ShadowMode::Hard;
        EffectOptions ao_fx;
        ao_fx.ao_rays = args->ao_rays;
        ao_fx.ao_radius =
            args->ao_radius > 0 ? args->ao_radius : 0.05f * length(built.mesh.bounds().extent());
        RayRecorder shadow_rec, ao_rec;
        bool ao_uniform = true;
        for (size_t i = 0; i < points.size(); ++i) {
          shadow_visibility(shadow_rec, ctx, points[i], shadow_fx, ro.light_dir, seeds[i], nullptr);
          const size_t before = ao_rec.rays.size();
          ambient_occlusion(ao_rec, ctx, points[i], ao_fx, ao_fx.ao_radius, seeds[i], nullptr);
          ao_uniform &= ao_rec.rays.size() - before == size_t(args->ao_rays);
        }
        // AO rays sample-major (ray k of consecutive points next to each
        // other), so a packet holds the same sample of neighbouring pixels.
        std::vector<Ray> ao_rays = ao_rec.rays;
        if (ao_uniform) {
          const size_t np = points.size(), k = size_t(args->ao_rays);
          for (size_t p = 0; p < np; ++p)
            for (size_t j = 0; j < k; ++j) ao_rays[j * np + p] = ao_rec.rays[p * k + j];
        }
        std::printf(
            "occlusion   %zu shading points (ESVO primary hits, offset 2 voxels along the normal "
            "+ "
            "1 back); %zu shadow rays (directional), %zu AO rays (%d per point, radius %g), "
            "generated once\n",
            points.size(), shadow_rec.rays.size(), ao_rays.size(), args->ao_rays,
            double(ao_fx.ao_radius));
        struct OccRow {
          std::string caster, how;
          bool embree;
          std::function<Timed()> frame;
          Timed t;
          std::vector<uint8_t> answers;
        };
        nlohmann::json occ_json;
        for (int kind = 0; kind < 2; ++kind) {
          const std::vector<Ray>& rs = kind == 0 ? shadow_rec.rays : ao_rays;
          const char* kind_name = kind == 0 ? "shadow" : "ao";
          // Every row answers into its own array (frames capture the row's
          // index: the vector may move while rows are added).
          std::vector<OccRow> rows;
          rows.push_back(
              {"voxcast esvo",
               "any hit (trace)",
               false,
               [&, i = rows.size()] { return occluded_all(voxels, rs, &rows[i].answers); },
               {},
               {}});
          rows.push_back(
              {"voxcast dag",
               "any hit (cast_occluded)",
               false,
               [&, i = rows.size()] { return occluded_all(*dag_voxels, rs, &rows[i].answers); },
               {},
               {}});
          const std::string occ_how = std::string("occluded_packets ") + isa_name(active_isa()) +
                                      " x" + std::to_string(packet_width(active_isa()));
          rows.push_back(
              {"voxcast esvo packet",
               occ_how,
               false,
               [&, i = rows.size()] { return occluded_all_packets(voxels, rs, &rows[i].answers); },
               {},
               {}});
          rows.push_back({"voxcast dag packet",
                          occ_how,
                          false,
                          [&, i = rows.size()] {
                            return occluded_all_packets(*dag_voxels, rs, &rows[i].answers);
                          },
                          {},
                          {}});
          for (const EmbreeScene::Mode m : EmbreeScene::kOcclusionModes) {
            static const char* const calls[] = {"rtcOccluded1", "", "rtcOccluded8 coherent",
                                                "rtcOccluded16 coherent", "rtcOccluded1M coherent"};
            rows.push_back({std::string("embree ") + EmbreeScene::mode_name(m),
                            calls[int(m)],
                            true,
                            [&, m, i = rows.size()] {
                              Timed t;
                              t.rays = rs.size();
                              t.seconds = embree.occluded_all(rs, m, &rows[i].answers);
                              for (uint8_t v : rows[i].answers) t.hits += v;
                              return t;
                            },
                            {},
                            {}});
          }
          // AO has ~16x the rays of the shadows: fewer rounds.
          measure_interleaved(rows, kind == 0 ? args->repeat : std::min(args->repeat, 3));
          double fastest_occ = 0;
          std::string fastest_occ_name;
          for (const OccRow& r : rows)
            if (r.embree && r.t.mrays() > fastest_occ)
              fastest_occ = r.t.mrays(), fastest_occ_name = r.caster;
          std::printf("%s rays (ratio over %s; 'same' = answers equal to embree x1)\n", kind_name,
                      fastest_occ_name.c_str());
          std::printf("  %-14s %9s %9s %7s %9s  %s\n", "caster", "Mrays/s", "occluded", "ratio",
                      "same", "how");
          const std::vector<uint8_t>& ref = rows[4].answers;  // embree x1
          nlohmann::json kj;
          for (const OccRow& r : rows) {
            size_t same = 0;
            for (size_t i = 0; i < ref.size(); ++i) same += r.answers[i] == ref[i];
            const double nr = double(std::max<size_t>(rs.size(), 1));
            std::printf("  %-14s %9.2f %8.2f%% %7.3f %8.3f%%  %s\n", r.caster.c_str(), r.t.mrays(),
                        100.0 * double(r.t.hits) / nr, r.t.mrays() / fastest_occ,
                        100.0 * double(same) / nr, r.how.c_str());
            kj.push_back({{"caster", r.caster},
                          {"how", r.how},
                          {"seconds", r.t.seconds},
                          {"rays", r.t.rays},
                          {"occluded", r.t.hits},
                          {"same_as_embree_x1", same},
                          {"mrays_per_s", r.t.mrays()},
                          {"ratio", r.t.mrays() / fastest_occ}});
          }
          // Rows 0, 1: the scalar casters; 2, 3: their packet casters.
          size_t esvo_dag = 0, packet_same = 0;
          for (size_t i = 0; i < rs.size(); ++i) {
            esvo_dag += rows[0].answers[i] == rows[1].answers[i];
            packet_same += rows[0].answers[i] == rows[2].answers[i] &&
                           rows[1].answers[i] == rows[3].answers[i];
          }
          std::printf("  esvo == dag on %.3f%% of the rays, packet == scalar on %.3f%%\n\n",
                      100.0 * double(esvo_dag) / double(std::max<size_t>(rs.size(), 1)),
                      100.0 * double(packet_same) / double(std::max<size_t>(rs.size(), 1)));
          occ_json[kind_name] = {{"rays", rs.size()},
                                 {"fastest_embree", fastest_occ_name},
                                 {"esvo_equals_dag", esvo_dag},
                                 {"packet_equals_scalar", packet_same},
                                 {"casters", kj}};
        }
        occ_json["points"] = points.size();
        occ_json["ao_rays_per_point"] = args->ao_rays;
        occ_json["ao_radius"] = ao_fx.ao_radius;
        run["occlusion"] = occ_json;
      }
      json_runs.push_back(run);
    }  // sizes
    if (!args->json.empty()) {
      const nlohmann::json j = {
          {"command", cmdline},
          {"machine",
           {{"cpu", cpu},
            {"logical_cpus", std::thread::hardware_concurrency()},
            {"loadavg", load},
            {"embree_isa", isa},
            {"threads", args->threads ? args->threads : int(std::thread::hardware_concurrency())}}},
          {"mesh", args->input},
          {"triangles", built.mesh.triangle_count()},
          {"resolution", octree->grid.resolution},
          {"repeat", args->repeat},
          {"runs", json_runs}};
      std::ofstream out(args->json);
      out << j.dump(2) << "\n";
      if (!out) throw Error("bench: cannot write --json file " + printable(args->json));
    }
    return 0;
  };
}

}  // namespace voxcast::cli
