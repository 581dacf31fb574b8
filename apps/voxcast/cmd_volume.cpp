// voxcast volume render SOURCE -o IMAGE: GigaVoxels volume rendering
// (gigavoxels.hpp) of a volume file or a procedural volume, through the
// frame loop with the volume integrator.

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <functional>
#include <initializer_list>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "bench_machine.hpp"
#include "camera_options.hpp"
#include "cli_io.hpp"
#include "commands.hpp"
#include "io/meta_json.hpp"
#include "view/camera_path.hpp"
#include "voxcast/error.hpp"
#include "voxcast/gigavoxels.hpp"
#include "voxcast/gigavoxels_scene.hpp"
#include "voxcast/image.hpp"
#include "voxcast/integrator.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/progress.hpp"
#include "voxcast/volume_integrator.hpp"

namespace voxcast::cli {
namespace {

// Scalar data (files): below 0.2 of the value range transparent, then a warm
// ramp to dense white (a CT's soft tissue to bone).
constexpr const char* kDefaultTransfer = "0.2:0:0.8,0.5,0.3;0.35:30:0.95,0.8,0.6;1:400:1,1,1";

struct VolumeArgs {
  std::string source, output, depth, size = "640x480", budget = "256M", passes = "exact";
  std::string transfer, background, dof, light, path;
  CameraArgs camera;
  int resolution = 256, frames = 1, threads = 0, brick_bits = 16;
  float lod = 1.f, step = 0.5f, light_radius = 0.05f, shadow_step = 1.f, shadow_lod = 1.f;
  bool shading = false, verbose = false, shadows = false, soft_shadows = false;
  std::string info_source;
  int info_resolution = 256;
};

/// Whether `path` ends with one of `exts` (ASCII case ignored).
bool has_extension(const std::string& path, std::initializer_list<const char*> exts) {
  std::string lower = path;
  for (char& c : lower) c = char(std::tolower(static_cast<unsigned char>(c)));
  for (const char* ext : exts)
    if (lower.ends_with(ext)) return true;
  return false;
}

bool is_volume_file(const std::string& path) {
  return has_extension(path, {".inr", ".inr.gz", ".mhd", ".mha"});
}

/// A volume file as it is, any other file as a mesh voxelized solid at
/// `resolution` voxels per axis (density 1 inside).
giga::ScalarVolume read_source_volume(const std::string& source, int resolution) {
  if (is_volume_file(source)) return giga::read_volume_file(source);
  if (resolution < 1 || resolution > 1024 || (resolution & (resolution - 1)) != 0)
    throw UsageError("--resolution must be a power of two in 1..1024 for a mesh source");
  return giga::solid_volume(load_mesh(source), resolution);
}

bool is_vdb(const std::string& path) {
  return has_extension(path, {".vdb"});
}

/// A SOURCE's producer and where its unit cube lies in the world.
struct Source {
  std::shared_ptr<giga::Producer> producer;
  Vec3 origin{0, 0, 0};
  float size = 1.f;
  std::optional<giga::VdbVolume> vdb;  // .vdb sources
  /// procedural:menger-recursive: a node graph instead of a producer.
  std::shared_ptr<giga::RecursiveVolume> recursive;
};

/// The producer of a SOURCE: procedural:NAME, a volume file, a .vdb grid or a mesh.
Source make_source(const std::string& source, int resolution) {
  Source s;
  if (source.rfind("procedural:", 0) == 0) {
    try {
      if (source == "procedural:menger-recursive")
        s.recursive =
            std::make_shared<giga::RecursiveVolume>(giga::make_recursive_menger(resolution));
      else
        s.producer = giga::make_procedural(source.substr(11), resolution);
    } catch (const Error& e) {
      throw UsageError(e.what());
    }
    return s;
  }
  require_regular_input(source, "volume");
  if (is_vdb(source)) {
    s.vdb = giga::read_vdb_volume(source);
    s.producer = s.vdb->producer, s.origin = s.vdb->origin, s.size = s.vdb->size;
    return s;
  }
  s.producer = giga::make_volume_producer(read_source_volume(source, resolution));
  return s;
}

bool is_scene_file(const std::string& path) {
  return has_extension(path, {".json"});
}

/// A scene file's objects (README "Volume scenes"), each on its own pools:
/// the budget is shared equally by the objects that stream (GigaVoxels).
struct LoadedScene {
  std::shared_ptr<giga::VolumeScene> scene;
  std::vector<std::shared_ptr<giga::GigaVoxels>> streamed;
};

LoadedScene load_volume_scene(const std::string& path, uint64_t budget, int brick_bits) {
  using nlohmann::json;
  require_regular_input(path, "volume scene");
  const std::string where = "volume scene " + in_quotes(path);
  auto fail = [&](const std::string& what) -> void { throw Error(where + ": " + what); };
  std::ifstream in(path, std::ios::binary);
  std::stringstream text;
  text << in.rdbuf();
  if (!in) fail("cannot be read");
  json doc;
  try {
    doc = json::parse(text.str());
  } catch (const json::exception& e) {
    fail("not valid JSON: " + meta::json_error_text(e));
  }
  if (!doc.is_object() || !doc.contains("objects") || !doc["objects"].is_array() ||
      doc["objects"].empty())
    fail("expected {\"objects\": [ ... ]} with at least one object");
  for (const auto& [key, value] : doc.items())
    if (key != "objects") fail("unknown key '" + printable(key) + "'");
  const json& list = doc["objects"];
  if (list.size() > size_t(giga::kMaxSceneObjects))
    fail("at most " + std::to_string(giga::kMaxSceneObjects) + " objects");
  const std::filesystem::path dir = std::filesystem::path(path).parent_path();
  struct Parsed {
    std::string source;
    int resolution = 256;
    giga::Affine transform;
    std::string transfer;
  };
  std::vector<Parsed> parsed;
  for (size_t i = 0; i < list.size(); ++i) {
    const json& o = list[i];
    const std::string at = "object " + std::to_string(i);
    auto bad = [&](const std::string& what) { fail(at + ": " + what); };
    if (!o.is_object()) bad("is not a JSON object");
    Parsed p;
    auto number = [&](const json& v, const char* what) {
      if (!v.is_number() || !std::isfinite(v.get<double>()))
        bad(std::string(what) + " is not a number");
      return v.get<float>();
    };
    auto vec3 = [&](const json& v, const char* what) {
      if (!v.is_array() || v.size() != 3) bad(std::string(what) + " is not [x, y, z]");
      return Vec3{number(v[0], what), number(v[1], what), number(v[2], what)};
    };
    auto matrix = [&](const json& v) {
      // 4x4 row-major, the last row 0 0 0 1 (an affine map).
      if (!v.is_array() || v.size() != 4) bad("'matrix' is not 4 rows of 4 numbers");
      giga::Affine m;
      for (int r = 0; r < 4; ++r) {
        if (!v[size_t(r)].is_array() || v[size_t(r)].size() != 4)
          bad("'matrix' is not 4 rows of 4 numbers");
        for (int c = 0; c < 4; ++c) {
          const float x = number(v[size_t(r)][size_t(c)], "a 'matrix' entry");
          if (r < 3)
            m.m[r][c] = x;
          else if (x != (c == 3 ? 1.f : 0.f))
            bad("'matrix' must end with the row 0, 0, 0, 1");
        }
      }
      return m;
    };
    for (const auto& [key, v] : o.items()) {
      if (key == "source") {
        if (!v.is_string() || v.get<std::string>().empty()) bad("'source' is not a string");
        p.source = v.get<std::string>();
      } else if (key == "resolution") {
        if (!v.is_number_integer()) bad("'resolution' is not an integer");
        const int64_t r = v.get<int64_t>();
        if (r < 1 || r > 8192) bad("'resolution' must be in 1..8192");
        p.resolution = int(r);
      } else if (key == "transform") {
        if (v.is_array()) {
          p.transform = matrix(v);
        } else if (v.is_object()) {
          // translate * rotate * scale: the object is scaled, then turned, then moved.
          giga::Affine t, r, sc;
          for (const auto& [k, x] : v.items()) {
            if (k == "translate")
              t = giga::Affine::translate(vec3(x, "'translate'"));
            else if (k == "scale")
              sc = giga::Affine::scale(x.is_array() ? vec3(x, "'scale'")
                                                    : Vec3{1, 1, 1} * number(x, "'scale'"));
            else if (k == "rotate") {
              if (!x.is_array() || x.size() != 4) bad("'rotate' is not [axis x, y, z, degrees]");
              const Vec3 axis{number(x[0], "'rotate'"), number(x[1], "'rotate'"),
                              number(x[2], "'rotate'")};
              if (!(length(axis) > 0.f)) bad("'rotate' has a zero axis");
              r = giga::Affine::rotate(axis, number(x[3], "'rotate'"));
            } else if (k == "matrix")
              t = matrix(x);
            else
              bad("unknown transform key '" + printable(k) + "'");
          }
          if (v.contains("matrix") && v.size() > 1)
            bad("'matrix' excludes the other transform keys");
          p.transform = t * r * sc;
        } else {
          bad("'transform' is not {translate, scale, rotate} or a 4x4 matrix");
        }
      } else if (key == "transfer") {
        if (!v.is_string()) bad("'transfer' is not a string v:density:r,g,b;...");
        p.transfer = v.get<std::string>();
      } else {
        bad("unknown key '" + printable(key) + "'");
      }
    }
    if (p.source.empty()) bad("has no 'source'");
    // Entries within +-1e18 (kMaxWorldCoordinate): the objects' world bounds
    // and the automatic camera stay finite (a scale of 1e38 overflowed them).
    for (const auto& row : p.transform.m)
      for (const float x : row)
        if (!(std::fabs(x) <= 1e18f)) bad("'transform' entries must be within +-1e18");
    parsed.push_back(std::move(p));
  }
  int streaming = 0;
  for (const Parsed& p : parsed) streaming += p.source != "procedural:menger-recursive";
  LoadedScene out;
  std::vector<giga::SceneObject> objects;
  for (size_t i = 0; i < parsed.size(); ++i) {
    const Parsed& p = parsed[i];
    const std::string at = "object " + std::to_string(i);
    const bool procedural = p.source.rfind("procedural:", 0) == 0;
    std::string file = p.source;
    if (!procedural && std::filesystem::path(file).is_relative()) file = (dir / file).string();
    giga::SceneObject obj;
    obj.name = p.source, obj.transform = p.transform;
    try {
      if (!p.transfer.empty())
        obj.transfer = TransferFunction::parse(p.transfer);
      else if (!procedural && !is_vdb(file))
        obj.transfer = TransferFunction::parse(kDefaultTransfer);
      Source s = make_source(file, p.resolution);
      if (s.recursive) {
        obj.structure = s.recursive;
      } else {
        giga::GigaOptions go;
        go.budget_bytes = budget / uint64_t(std::max(1, streaming));
        go.brick_bits = brick_bits;
        go.origin = s.origin, go.size = s.size;
        auto g = std::make_shared<giga::GigaVoxels>(s.producer, go);
        out.streamed.push_back(g);
        obj.structure = g;
      }
      (void)obj.transform.inverse();  // a singular map: the object's own error
    } catch (const Error& e) {
      fail(at + ": " + e.what());
    }
    objects.push_back(std::move(obj));
  }
  out.scene = std::make_shared<giga::VolumeScene>(std::move(objects));
  return out;
}

/// A SOURCE opened for rendering with pools of `budget` bytes: a scene
/// file's objects (the budget shared by those that stream), one GigaVoxels
/// over a producer, or the recursive node graph (no pools).
struct OpenedVolume {
  std::optional<LoadedScene> scene;
  Source source;
  std::unique_ptr<giga::GigaVoxels> giga;

  Structure& structure() {
    if (scene) return *scene->scene;
    if (giga) return *giga;
    return *source.recursive;
  }
  /// The structures whose pools stream (their per-pass statistics).
  std::vector<const giga::GigaVoxels*> streamed() const {
    std::vector<const giga::GigaVoxels*> out;
    if (giga) out.push_back(giga.get());
    if (scene)
      for (const auto& g : scene->streamed) out.push_back(g.get());
    return out;
  }
  /// `f` of every streamed structure, summed (pool bytes, capacities).
  template <class F>
  uint64_t sum(F f) const {
    uint64_t total = 0;
    for (const giga::GigaVoxels* g : streamed()) total += uint64_t(std::invoke(f, *g));
    return total;
  }
  uint64_t pool_bytes() const { return sum(&giga::GigaVoxels::pool_bytes); }
};

std::unique_ptr<OpenedVolume> open_volume(const std::string& path, int resolution, uint64_t budget,
                                          int brick_bits) {
  auto v = std::make_unique<OpenedVolume>();
  if (is_scene_file(path)) {
    v->scene = load_volume_scene(path, budget, brick_bits);
    return v;
  }
  v->source = make_source(path, resolution);
  if (v->source.producer) {
    giga::GigaOptions go;
    go.budget_bytes = budget;
    go.brick_bits = brick_bits;
    go.origin = v->source.origin, go.size = v->source.size;
    v->giga = std::make_unique<giga::GigaVoxels>(v->source.producer, go);
  }
  return v;
}

/// The transfer function a SOURCE is rendered with: --transfer, else the
/// default ramp for scalar files; none for procedural and .vdb sources
/// (densities already) and for scene files (each object has its own).
void set_transfer(const std::string& source, const std::string& transfer,
                  VolumeIntegratorOptions* io) {
  const bool procedural = source.rfind("procedural:", 0) == 0;
  if (is_scene_file(source)) {
    if (!transfer.empty())
      throw UsageError("--transfer: a scene file gives each object its own 'transfer'");
    return;
  }
  try {
    if (!transfer.empty())
      io->transfer = TransferFunction::parse(transfer);
    else if (!procedural && !is_vdb(source))
      io->transfer = TransferFunction::parse(kDefaultTransfer);
  } catch (const Error& e) {
    throw UsageError(std::string("--transfer: ") + e.what());
  }
}

/// Parses --dof APERTURE,FOCUS into `io`.
void parse_dof(const std::string& text, VolumeIntegratorOptions* io) {
  const size_t comma = text.find(',');
  char* end = nullptr;
  const std::string a = text.substr(0, comma),
                    f = comma == std::string::npos ? "" : text.substr(comma + 1);
  io->dof_aperture = std::strtof(a.c_str(), &end);
  bool ok = !a.empty() && *end == 0;
  io->dof_focus = std::strtof(f.c_str(), &end);
  ok = ok && !f.empty() && *end == 0;
  if (!ok || !std::isfinite(io->dof_aperture) || !(io->dof_aperture > 0.f) ||
      !std::isfinite(io->dof_focus) || !(io->dof_focus > 0.f))
    throw UsageError("--dof must be APERTURE,FOCUS with two positive numbers");
}

double rmse(const Image& a, const Image& b) {
  double s = 0;
  for (size_t i = 0; i < a.pixels.size(); ++i) {
    const double d = double(a.pixels[i]) - double(b.pixels[i]);
    s += d * d;
  }
  return std::sqrt(s / double(std::max<size_t>(1, a.pixels.size())));
}

struct BenchArgs {
  std::string source, output, peer_output, size = "640x480", budget = "256M", light, transfer, dof;
  CameraArgs camera;
  int frames = 5, threads = 0, resolution = 256, brick_bits = 16;
  float lod = 1.f, step = 0.5f, reference_step = 0.125f, shadow_step = 1.f, shadow_lod = 1.f,
        light_radius = 0.05f;
  bool effects = false;
};

/// One timed configuration of `voxcast volume bench`: a warm-up frame (the
/// pools fill; its wall and CPU time are the "first frame" columns), then
/// `frames` timed frames of the same view.
struct BenchRow {
  std::string name, budget;
  double first_seconds = 0, first_cpu = 0;
  double seconds = 0, cpu = 0, rays = 0;
  double passes = 0, requests = 0, uploads = 0;  // summed over the timed frames
  uint64_t pool_bytes = 0;
  Image image;
};

BenchRow bench_giga(OpenedVolume& volume, const VolumeIntegratorOptions& io, FrameView view,
                    int frames) {
  BenchRow row;
  row.pool_bytes = volume.pool_bytes();
  VolumeIntegrator integrator(io);
  FrameOptions fo;
  fo.max_passes = 100000;  // exact mode: each frame ends with nothing missing
  Film film;
  for (int f = 0; f <= frames; ++f) {
    view.frame = uint32_t(f);
    const double c0 = cpu_seconds();
    const auto t0 = std::chrono::steady_clock::now();
    const FrameStats fs = render_frame(volume.structure(), integrator, view, fo, &film);
    const double wall =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (f == 0) {
      row.first_seconds = wall, row.first_cpu = cpu_seconds() - c0;
      continue;
    }
    row.seconds += wall, row.cpu += cpu_seconds() - c0;
    row.rays += double(integrator.stats().rays);
    row.passes += double(fs.passes.size());
    for (const giga::GigaVoxels* g : volume.streamed())
      for (const giga::GigaPassStats& p : g->pass_stats())
        row.requests += double(p.data_requests + p.subdivide_requests),
            row.uploads += double(p.bricks_uploaded + p.constants);
  }
  row.image = film.color;
  return row;
}

/// Splits "256M,1G" into its budgets.
std::vector<std::string> split_budgets(const std::string& text) {
  std::vector<std::string> out;
  size_t at = 0;
  while (true) {
    const size_t comma = text.find(',', at);
    out.push_back(text.substr(at, comma == std::string::npos ? std::string::npos : comma - at));
    if (comma == std::string::npos) break;
    at = comma + 1;
  }
  return out;
}

/// voxcast volume bench SOURCE: GigaVoxels on any volume source (a file,
/// procedural:NAME, a .vdb grid, a scene file) at one or several pool
/// budgets, optionally the cost of each effect (§3.9) against the pinhole
/// camera with hard shadows, and, for a .vdb grid, OpenVDB's own volume ray
/// marcher (VolumeRender) on the same grid, view, step and light in the same
/// run, with each image's RMSE against OpenVDB's marcher at a finer step
/// (the reference).
int volume_bench(const BenchArgs& a) {
  ThreadLimit limit(a.threads);
  FrameView view;
  parse_size(a.size, &view.width, &view.height);
  require_range("--frames", a.frames, 1, 100000);
  require_range("--step", a.step, 0.01, 16);
  require_range("--reference-step", a.reference_step, 0.01, 16);
  require_range("--lod", a.lod, 0, 1e6);
  view.lod_pixels = a.lod;
  std::vector<std::pair<std::string, uint64_t>> budgets;
  for (const std::string& b : split_budgets(a.budget))
    budgets.emplace_back(b, parse_memory_budget(b, "--budget"));
  const bool peer_source = is_vdb(a.source);
  if (!peer_source && (!a.peer_output.empty() || a.reference_step != BenchArgs{}.reference_step))
    throw UsageError(
        "--peer-output and --reference-step need a .vdb SOURCE (the peer, OpenVDB's marcher, "
        "reads grids; 'voxcast volume export' writes one)");
  VolumeIntegratorOptions io;
  require_range("--shadow-step", a.shadow_step, 0.01, 16);
  require_range("--shadow-lod", a.shadow_lod, 0, 16);
  require_range("--light-radius", a.light_radius, 0, 1);
  // The peer's lighting model: hard shadows, no ambient.
  io.shadows = true, io.ambient = 0.f, io.step_scale = a.step;
  io.shadow_step_scale = a.shadow_step, io.shadow_footprint_scale = a.shadow_lod;
  if (!a.light.empty()) {
    io.light_dir = parse_vec3(a.light, "--light");
    if (!(length(io.light_dir) > 0.f)) throw UsageError("--light must not be zero");
  }
  set_transfer(a.source, a.transfer, &io);
  VolumeIntegratorOptions dof = io;
  if (!a.dof.empty()) {
    if (!a.effects) throw UsageError("--dof: the depth-of-field row needs --effects");
    parse_dof(a.dof, &dof);
  }
  check_camera_options(a.camera, view.width, view.height);
  OutputSet outputs(a.source.rfind("procedural:", 0) == 0 ? std::vector<std::string>{}
                                                          : std::vector<std::string>{a.source});
  if (!a.output.empty()) outputs.add("-o", a.output, {".png", ".pfm"});
  if (!a.peer_output.empty()) outputs.add("--peer-output", a.peer_output, {".png", ".pfm"});

  std::unique_ptr<OpenedVolume> volume =
      open_volume(a.source, a.resolution, budgets[0].second, a.brick_bits);
  auto print_pools = [&](const std::string& budget) {
    const OpenedVolume& v = *volume;
    std::printf(
        "pools       %s: node pool %s (%llu tiles of 8 nodes), brick pool %s (%llu bricks of "
        "%d^3 voxels + border, %d bits per channel)\n",
        budget.c_str(), format_bytes(double(v.sum(&giga::GigaVoxels::node_pool_bytes))).c_str(),
        (unsigned long long)v.sum(&giga::GigaVoxels::tile_capacity),
        format_bytes(double(v.sum(&giga::GigaVoxels::brick_pool_bytes))).c_str(),
        (unsigned long long)v.sum(&giga::GigaVoxels::brick_capacity), giga::kBrickSide,
        a.brick_bits);
  };
  if (volume->streamed().empty())
    throw UsageError("volume bench: " + printable(a.source) +
                     " is a node graph without pools (procedural:menger-recursive); bench "
                     "procedural:menger instead");
  const Aabb bounds = volume->structure().bounds();
  view.camera = resolve_camera(a.camera, bounds, view.width, view.height);
  if (a.effects && a.dof.empty()) {
    // Focused on the volume's center, a lens a fiftieth of its diagonal wide.
    dof.dof_focus = length((bounds.lo + bounds.hi) * 0.5f - view.camera.eye);
    dof.dof_aperture = 0.02f * length(bounds.extent());
  }
  print_bench_header();
  if (volume->scene) {
    std::printf("volume      %s: scene of %zu objects (%zu streamed)\n",
                printable(a.source).c_str(), volume->scene->scene->objects().size(),
                volume->scene->streamed.size());
  } else if (volume->source.vdb) {
    const giga::VdbVolume& v = *volume->source.vdb;
    std::printf("volume      %s: grid %s (%s), %lld x %lld x %lld voxels, %d levels\n",
                printable(a.source).c_str(), printable(v.grid_name).c_str(),
                v.level_set ? "level set" : "fog", (long long)v.extent[0], (long long)v.extent[1],
                (long long)v.extent[2], volume->source.producer->max_level() + 1);
  } else {
    const giga::Producer& p = *volume->source.producer;
    const int n = giga::kBrickSide << p.max_level();
    const double dense = double(n) * n * n * double(giga::pool_voxel_bytes(a.brick_bits));
    std::printf("volume      %s: %s, %d levels, finest %d^3 voxels (%s as dense bricks)\n",
                printable(a.source).c_str(), p.name().c_str(), p.max_level() + 1, n,
                format_bytes(dense).c_str());
  }
  std::printf("camera      %s\n", view.camera.to_string().c_str());
  std::printf(
      "image       %dx%d, step %g voxels, hard shadows (light cones: step %g of their voxel, "
      "%g x the pixel footprint), exact mode, %d timed frames after one warm-up\n",
      view.width, view.height, double(a.step), double(a.shadow_step), double(a.shadow_lod),
      a.frames);

  auto print_rows = [&](const char* title, const std::vector<BenchRow>& rows, const BenchRow* base,
                        const char* ratio_name) {
    std::printf("\n%s\n", title);
    std::printf("  %-24s %7s %11s %9s %9s %11s %8s %9s %10s %10s %9s\n", "renderer", "budget",
                "pools", "first s", "frames/s", "CPU s/frame", "Mrays/s", "passes/f", "requests/f",
                "uploads/f", ratio_name);
    for (const BenchRow& r : rows) {
      const double k = double(a.frames);
      const double ratio = base ? r.cpu / base->cpu : 1.0;
      std::printf("  %-24s %7s %11s %9.3f %9.3f %11.3f %8.3f %9.2f %10.0f %10.0f %9.3f\n",
                  r.name.c_str(), r.budget.c_str(), format_bytes(double(r.pool_bytes)).c_str(),
                  r.first_seconds, k / r.seconds, r.cpu / k, r.rays / r.seconds * 1e-6,
                  r.passes / k, r.requests / k, r.uploads / k, ratio);
    }
    for (const BenchRow& r : rows)
      if (r.requests > 0) {
        std::printf(
            "  (requests/f > 0: the view does not fit those pools; their frames keep asking and "
            "show coarser data)\n");
        break;
      }
  };

  // 1. The budgets: each a fresh set of pools, filled by its warm-up frame.
  std::vector<BenchRow> by_budget;
  for (size_t i = 0; i < budgets.size(); ++i) {
    if (i > 0) volume = open_volume(a.source, a.resolution, budgets[i].second, a.brick_bits);
    print_pools(budgets[i].first);
    BenchRow r = bench_giga(*volume, io, view, a.frames);
    r.name = "gigavoxels", r.budget = budgets[i].first;
    by_budget.push_back(std::move(r));
    if (i + 1 < budgets.size()) volume.reset();  // one set of pools at a time
  }
  print_rows("budgets (the first is the base; ratio: CPU s/frame over the base's)", by_budget,
             &by_budget[0], "CPU ratio");

  // 2. Effects at the last budget's pools (already warm for the base view).
  if (a.effects) {
    std::vector<BenchRow> rows;
    auto add = [&](const char* name, const VolumeIntegratorOptions& o) {
      BenchRow r = bench_giga(*volume, o, view, a.frames);
      r.name = name, r.budget = budgets.back().first;
      rows.push_back(std::move(r));
    };
    add("pinhole, hard shadows", io);
    VolumeIntegratorOptions none = io;
    none.shadows = false;
    add("pinhole, no shadows", none);
    VolumeIntegratorOptions soft = io;
    soft.light_radius = a.light_radius;
    add("pinhole, soft shadows", soft);
    add("dof, hard shadows", dof);
    VolumeIntegratorOptions dof_soft = dof;
    dof_soft.light_radius = a.light_radius;
    add("dof, soft shadows", dof_soft);
    std::printf("\neffects      soft shadows: light radius %g; dof: aperture %g, focus %g\n",
                double(a.light_radius), double(dof.dof_aperture), double(dof.dof_focus));
    print_rows("effects (ratio: CPU s/frame over pinhole with hard shadows)", rows, &rows[0],
               "CPU ratio");
  }

  // 3. The peer: OpenVDB's marcher on the same grid.
  const BenchRow& ours = by_budget[0];
  Image peer_image;
  if (peer_source) {
    const giga::VdbVolume& v = *volume->source.vdb;
    double peer_seconds = 0, peer_cpu = 0;
    giga::VdbPeer peer(v);
    giga::VdbPeerOptions po;
    po.light_dir = io.light_dir, po.step = a.step;
    for (int f = 0; f <= a.frames; ++f) {
      const double c0 = cpu_seconds();
      const auto t0 = std::chrono::steady_clock::now();
      Image img = peer.render(view.camera, view.width, view.height, po);
      if (f == 0) continue;  // warm-up, as ours
      peer_seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      peer_cpu += cpu_seconds() - c0;
      peer_image = std::move(img);
    }
    po.step = a.reference_step;
    const Image reference = peer.render(view.camera, view.width, view.height, po);
    std::printf("\nreference   openvdb VolumeRender at step %g voxels\n", double(a.reference_step));
    std::printf("  %-22s %9s %9s %12s %10s %7s\n", "renderer", "frames/s", "Mrays/s", "CPU s/frame",
                "RMSE ref", "ratio");
    const double k = double(a.frames);
    const double peer_fps = k / peer_seconds;
    const double peer_rays = double(view.width) * view.height * k;
    std::printf("  %-22s %9.3f %9.4f %12.3f %10.4f %7.3f\n", "gigavoxels", k / ours.seconds,
                ours.rays / ours.seconds * 1e-6, ours.cpu / k, rmse(ours.image, reference),
                k / ours.seconds / peer_fps);
    std::printf("  %-22s %9.3f %9.4f %12.3f %10.4f %7.3f\n", "openvdb VolumeRender", peer_fps,
                peer_rays / peer_seconds * 1e-6, peer_cpu / k, rmse(peer_image, reference), 1.0);
    std::printf(
        "  (gigavoxels at budget %s; ratio: frames/s over openvdb VolumeRender's; RMSE of linear "
        "RGB; gigavoxels vs openvdb at equal step: RMSE %.4f)\n",
        ours.budget.c_str(), rmse(ours.image, peer_image));
  } else {
    std::printf(
        "\npeer        none: OpenVDB's marcher reads one grid ('voxcast volume export SOURCE -o "
        "GRID.vdb', then bench GRID.vdb)\n");
  }
  if (!a.output.empty())
    outputs.write(a.output, [&](const std::filesystem::path& to) { write_image(to, ours.image); });
  if (!a.peer_output.empty())
    outputs.write(a.peer_output,
                  [&](const std::filesystem::path& to) { write_image(to, peer_image); });
  outputs.commit();
  return 0;
}

/// Per-pass statistics; `g` (null for a scene): a GigaVoxels' own per pass.
void print_pass_stats(uint32_t frame, const FrameStats& fs, const giga::GigaVoxels* g) {
  static const std::vector<giga::GigaPassStats> none;
  const auto& gs = g ? g->pass_stats() : none;
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
                   g->brick_capacity(), (unsigned long long)s.tiles_resident, g->tile_capacity());
    }
    std::fprintf(stderr, "; %.1f ms trace + %.1f ms serve\n", ps.seconds * 1e3,
                 ps.serve_seconds * 1e3);
  }
}

int volume_info(const std::string& source, int resolution) {
  std::shared_ptr<giga::Producer> producer;
  if (is_scene_file(source)) {
    const LoadedScene s = load_volume_scene(source, uint64_t(256) << 20, 16);
    const auto& objects = s.scene->objects();
    std::printf("source      %s (volume scene, %zu objects, %zu streamed)\n",
                printable(source).c_str(), objects.size(), s.streamed.size());
    for (size_t i = 0; i < objects.size(); ++i) {
      // The object's world box: its local bounds through its transform.
      giga::SceneObject one = objects[i];
      const Aabb b = giga::VolumeScene({one}).bounds();
      std::printf("object %-4zu %s: world box %g,%g,%g .. %g,%g,%g%s\n", i,
                  printable(objects[i].name).c_str(), double(b.lo.x), double(b.lo.y),
                  double(b.lo.z), double(b.hi.x), double(b.hi.y), double(b.hi.z),
                  objects[i].transfer.empty() ? "" : ", transfer function");
    }
    const Aabb b = s.scene->bounds();
    std::printf("bounds      %g,%g,%g .. %g,%g,%g\n", double(b.lo.x), double(b.lo.y),
                double(b.lo.z), double(b.hi.x), double(b.hi.y), double(b.hi.z));
    return 0;
  }
  if (source.rfind("procedural:", 0) == 0) {
    const Source s = make_source(source, resolution);
    std::printf("source      %s (procedural)\n", printable(source).c_str());
    if (s.recursive) {
      std::printf(
          "graph       1 node of 3^3 children (20 name the node itself), recursion depth "
          "%d: %.0f^3 finest cells, mean coverage %.4f\n",
          s.recursive->max_depth(), std::pow(3.0, s.recursive->max_depth()),
          double(s.recursive->coverage(0, 0)));
      return 0;
    }
    producer = s.producer;
  } else if (is_vdb(source)) {
    const Source s = make_source(source, resolution);
    const giga::VdbVolume& v = *s.vdb;
    std::printf("source      %s (OpenVDB grid)\n", printable(source).c_str());
    std::printf("grid        %s (%s)\n", printable(v.grid_name).c_str(),
                v.level_set ? "level set, as coverage clamp(0.5 - phi/voxel, 0, 1)" : "fog volume");
    std::printf("dimensions  %lld x %lld x %lld voxels of %g (non-zero box), %llu active\n",
                (long long)v.extent[0], (long long)v.extent[1], (long long)v.extent[2],
                v.voxel_size, (unsigned long long)v.active_voxels);
    std::printf("range       %g .. %g (extinction per voxel)\n", double(v.min_density),
                double(v.max_density));
    std::printf("data        %s grid + %s coarser levels in memory\n",
                format_bytes(double(v.grid_bytes)).c_str(),
                format_bytes(double(v.pyramid_bytes)).c_str());
    std::printf("placement   cube from %g,%g,%g, side %g\n", double(s.origin.x), double(s.origin.y),
                double(s.origin.z), double(s.size));
    producer = s.producer;
  } else {
    require_regular_input(source, "volume");
    const giga::ScalarVolume v = read_source_volume(source, resolution);
    const auto [lo, hi] = std::minmax_element(v.values.begin(), v.values.end());
    std::printf("source      %s (%s)\n", printable(source).c_str(),
                is_volume_file(source) ? "volume file" : "mesh, solid voxels = 1");
    std::printf("dimensions  %d x %d x %d voxels of %g x %g x %g\n", v.nx, v.ny, v.nz, v.vx, v.vy,
                v.vz);
    std::printf("range       %g .. %g (mapped to densities 0 .. 1)\n", double(*lo), double(*hi));
    std::printf("data        %s as floats\n", format_bytes(double(v.values.size()) * 4).c_str());
    producer = giga::make_volume_producer(v);
  }
  const int n = giga::kBrickSide << producer->max_level();
  // The octree the producer fills: every level's voxels and what a dense
  // copy of the finest level would take in the brick pool (8 bytes per
  // voxel, giga::PoolVoxel).
  const double dense = double(n) * n * n * double(sizeof(giga::PoolVoxel));
  std::printf("octree      %d levels, finest %d^3 voxels (bricks of %d^3 + border)\n",
              producer->max_level() + 1, n, giga::kBrickSide);
  std::printf("dense size  %s at the finest level (the pools hold what rays ask for)\n",
              format_bytes(dense).c_str());
  return 0;
}

}  // namespace

Runner add_volume(CLI::App& app) {
  auto args = std::make_shared<VolumeArgs>();
  CLI::App* vol =
      app.add_subcommand("volume", "GigaVoxels volumes (see 'voxcast volume render --help')");
  vol->require_subcommand(1);
  CLI::App* cmd = vol->add_subcommand("render", "Render a volume file or a procedural volume");
  cmd->add_option("SOURCE", args->source,
                  "A volume file (.inr, .inr.gz, .mhd, .mha), an OpenVDB FloatGrid (.vdb), a mesh "
                  "(voxelized solid at --resolution), "
                  "procedural:cloud|mandelbulb|menger|menger-recursive, or a scene of several "
                  "objects with their own transforms (.json, README 'Volume scenes')")
      ->required();
  cmd->add_option("-o,--output", args->output, "Output image (.png or .pfm)")->required();
  cmd->add_option("--depth", args->depth,
                  "Also write the distance at which opacity reaches 0.5 (.pfm; +inf elsewhere)");
  cmd->add_option("--size", args->size, "Image size WxH")->capture_default_str();
  add_camera_options(cmd, args->camera);
  cmd->add_option(
         "--resolution", args->resolution,
         "Procedural sources: voxels per axis at the finest level (power of two, 16..16384)")
      ->capture_default_str();
  cmd->add_option("--budget", args->budget, "Memory for the node and brick pools (e.g. 64M, 2G)")
      ->capture_default_str();
  cmd->add_option("--brick-bits", args->brick_bits,
                  "Bits per channel of the brick pool: 16 (half floats) or 8 (each brick's range "
                  "in 255 steps, the paper's RGBA8: half the memory, faster)")
      ->check(CLI::IsMember({8, 16}))
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
  cmd->add_flag("--shadows", args->shadows, "Hard shadows: a light cone as wide as the pixel cone");
  cmd->add_flag("--soft-shadows", args->soft_shadows,
                "Soft shadows: light cones widening by the light's size (--light-radius)");
  cmd->add_option("--shadow-step", args->shadow_step,
                  "Light cone step in its own voxels (with --shadows/--soft-shadows)")
      ->capture_default_str();
  cmd->add_option("--shadow-lod", args->shadow_lod,
                  "Light cone start width over the pixel footprint: below 1 reads finer levels "
                  "(0: the finest)")
      ->capture_default_str();
  cmd->add_option("--light-radius", args->light_radius,
                  "With --soft-shadows: tangent of the light's angular radius")
      ->capture_default_str();
  cmd->add_option("--light", args->light,
                  "Direction towards the light x,y,z (default 0.4,0.8,0.45)");
  cmd->add_option("--dof", args->dof,
                  "Depth of field: APERTURE,FOCUS (lens diameter and focus distance, world units)");
  cmd->add_option("--path", args->path,
                  "With --frames K: camera path (JSON, README 'Camera path JSON'); frame k looks "
                  "from the path at time start + k (end - start) / (K - 1)");
  cmd->add_option("--threads", args->threads, "Worker threads (0 = all cores)");
  cmd->add_flag("-v,--verbose", args->verbose, "Per-pass statistics on stderr");
  CLI::App* info =
      vol->add_subcommand("info", "Describe a volume source: dimensions, value range, bytes");
  info->add_option("SOURCE", args->info_source,
                   "A volume file (.inr, .inr.gz, .mhd, .mha), an OpenVDB FloatGrid (.vdb), a mesh "
                   "(voxelized solid at --resolution) or "
                   "procedural:cloud|mandelbulb|menger|menger-recursive")
      ->required();
  info->add_option("--resolution", args->info_resolution,
                   "Procedural sources: voxels per axis at the finest level")
      ->capture_default_str();
  auto bargs = std::make_shared<BenchArgs>();
  CLI::App* bench = vol->add_subcommand(
      "bench",
      "GigaVoxels on a volume source at one or several budgets (frames/s, Mrays/s, CPU s/frame, "
      "passes, requests, pools), the cost of each effect, and OpenVDB's own volume ray marcher "
      "on a .vdb grid (RMSE against a finer-step reference)");
  bench
      ->add_option("SOURCE", bargs->source,
                   "What volume render takes: a volume file, an OpenVDB FloatGrid (.vdb, also "
                   "rendered by the peer), a mesh, procedural:cloud|mandelbulb|menger, or a "
                   "scene file (.json)")
      ->required();
  bench->add_option("--size", bargs->size, "Image size WxH")->capture_default_str();
  add_camera_options(bench, bargs->camera);
  bench
      ->add_option("--resolution", bargs->resolution,
                   "Procedural and mesh sources: voxels per axis at the finest level")
      ->capture_default_str();
  bench
      ->add_option("--budget", bargs->budget,
                   "Memory for the node and brick pools; several, comma-separated (256M,1G), "
                   "give a row each")
      ->capture_default_str();
  bench
      ->add_option("--brick-bits", bargs->brick_bits,
                   "Bits per channel of the brick pool: 16 (half floats) or 8 (unorm8 of each "
                   "brick's range)")
      ->check(CLI::IsMember({8, 16}))
      ->capture_default_str();
  bench->add_option("--frames", bargs->frames, "Timed frames of each row after one warm-up")
      ->capture_default_str();
  bench
      ->add_option("--step", bargs->step,
                   "Step of both renderers (GigaVoxels: x the voxel or pixel cone; OpenVDB: "
                   "grid voxels), primary and shadow rays")
      ->capture_default_str();
  bench
      ->add_option("--reference-step", bargs->reference_step,
                   ".vdb sources: step of the reference image (OpenVDB's marcher), in grid voxels")
      ->capture_default_str();
  bench
      ->add_option("--lod", bargs->lod, "GigaVoxels: voxels projecting to at most this many pixels")
      ->capture_default_str();
  bench
      ->add_option("--shadow-step", bargs->shadow_step, "GigaVoxels: light cone step in its voxels")
      ->capture_default_str();
  bench
      ->add_option("--shadow-lod", bargs->shadow_lod,
                   "GigaVoxels: light cone start width over the pixel footprint (0: finest)")
      ->capture_default_str();
  bench->add_option("--light", bargs->light, "Direction towards the light x,y,z");
  bench->add_option("--transfer", bargs->transfer,
                    "Transfer function for scalar data: v:density:r,g,b;... (as volume render)");
  bench->add_flag("--effects", bargs->effects,
                  "Also time no shadows, soft shadows and depth of field against pinhole with "
                  "hard shadows (gigavoxels 3.9)");
  bench
      ->add_option("--light-radius", bargs->light_radius,
                   "With --effects: the soft shadows' light radius (tangent)")
      ->capture_default_str();
  bench->add_option("--dof", bargs->dof,
                    "With --effects: APERTURE,FOCUS of the depth-of-field rows (default: focus "
                    "on the volume's center, aperture 1/50 of its diagonal)");
  bench->add_option("-o,--output", bargs->output, "Also write GigaVoxels' image (first budget)");
  bench->add_option("--peer-output", bargs->peer_output, "Also write OpenVDB's last frame");
  bench->add_option("--threads", bargs->threads, "Worker threads (0 = all cores)");
  struct ExportArgs {
    std::string source, output;
    int resolution = 256;
    float density_scale = 1.f;
  };
  auto eargs = std::make_shared<ExportArgs>();
  CLI::App* exp = vol->add_subcommand(
      "export", "Write a volume source's finest level as an OpenVDB fog volume (.vdb)");
  exp->add_option("SOURCE", eargs->source,
                  "A volume file, a .vdb grid, a mesh or procedural:cloud|mandelbulb|menger")
      ->required();
  exp->add_option("-o,--output", eargs->output, "Output .vdb")->required();
  exp->add_option("--resolution", eargs->resolution,
                  "Procedural and mesh sources: voxels per axis at the finest level (<= 1024)")
      ->capture_default_str();
  exp->add_option("--density-scale", eargs->density_scale,
                  "Multiplies the densities (the grid holds extinction per voxel)")
      ->capture_default_str();
  return [args, bargs, eargs, cmd, info, bench, exp]() {
    if (info->parsed()) return volume_info(args->info_source, args->info_resolution);
    if (exp->parsed()) {
      require_range("--density-scale", eargs->density_scale, 1e-6, 1e6);
      require_range("--resolution", eargs->resolution, 1, 1024);  // export's largest grid
      const bool procedural = eargs->source.rfind("procedural:", 0) == 0;
      OutputSet outputs(procedural ? std::vector<std::string>{}
                                   : std::vector<std::string>{eargs->source});
      outputs.add("-o", eargs->output, {".vdb"});
      const Source s = make_source(eargs->source, eargs->resolution);
      if (!s.producer)
        throw UsageError("volume export: procedural:menger-recursive is a node graph, not voxels");
      outputs.write(eargs->output, [&](const std::filesystem::path& to) {
        giga::write_vdb_volume(*s.producer, to.string(), s.origin, s.size, eargs->density_scale);
      });
      outputs.commit();
      std::printf("%s: %d^3 voxels from %s\n", printable(eargs->output).c_str(),
                  giga::kBrickSide << s.producer->max_level(), s.producer->name().c_str());
      return 0;
    }
    if (bench->parsed()) return volume_bench(*bargs);
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
      if (!(b.x >= 0.f && b.y >= 0.f && b.z >= 0.f))
        throw UsageError("--background: a color is three numbers >= 0");
      io.background = {b.x, b.y, b.z, 1.f};
    }
    io.shadows = args->shadows || args->soft_shadows;
    if (args->shadows && args->soft_shadows)
      throw UsageError("--shadows and --soft-shadows exclude each other");
    require_range("--light-radius", args->light_radius, 0, 1);
    io.light_radius = args->soft_shadows ? args->light_radius : 0.f;
    require_range("--shadow-step", args->shadow_step, 0.01, 16);
    require_range("--shadow-lod", args->shadow_lod, 0, 16);
    io.shadow_step_scale = args->shadow_step, io.shadow_footprint_scale = args->shadow_lod;
    if (!args->light.empty()) {
      io.light_dir = parse_vec3(args->light, "--light");
      if (!(length(io.light_dir) > 0.f)) throw UsageError("--light must not be zero");
    }
    if (!args->dof.empty()) parse_dof(args->dof, &io);
    if (!args->path.empty()) {
      refuse_camera_options_with_path(args->camera, args->path);
      if (args->frames < 2) throw UsageError("--path needs --frames K with K >= 2");
    }
    const bool procedural = args->source.rfind("procedural:", 0) == 0;
    set_transfer(args->source, args->transfer, &io);
    const uint64_t budget = parse_memory_budget(args->budget, "--budget");
    check_camera_options(args->camera, view.width, view.height);
    OutputSet outputs(procedural ? std::vector<std::string>{}
                                 : std::vector<std::string>{args->source});
    outputs.add("-o", args->output, {".png", ".pfm"});
    if (!args->depth.empty()) outputs.add("--depth", args->depth, {".pfm"});

    std::optional<view::CameraPath> path;
    if (!args->path.empty()) {
      require_regular_input(args->path, "camera path");
      path = view::CameraPath::load(args->path);
    }
    const std::unique_ptr<OpenedVolume> opened =
        open_volume(args->source, args->resolution, budget, args->brick_bits);
    Structure& volume = opened->structure();
    const giga::GigaVoxels* giga_volume = opened->giga.get();
    const Aabb bounds = volume.bounds();
    bool derived = false;
    view.camera = resolve_camera(args->camera, bounds, view.width, view.height, &derived);
    if (derived) std::printf("camera: %s\n", view.camera.to_string().c_str());
    VolumeIntegrator integrator(io);
    Film film;
    double later_seconds = 0, later_cpu = 0;
    uint64_t later_rays = 0;
    // Per-pass statistics of the frames after the first (the warm ones).
    uint64_t later_passes = 0, later_requests = 0, later_uploads = 0;
    // One bar phase per frame; each pass adds its tiles to the frame's work.
    Progress progress("volume render",
                      std::vector<Progress::Phase>(size_t(args->frames), Progress::Phase{"", 1}));
    fo.progress = &progress;
    for (int f = 0; f < args->frames; ++f) {
      view.frame = uint32_t(f);
      progress.start_phase(size_t(f), 0);
      if (path)
        view.camera = path->at(path->start() + (path->end() - path->start()) * double(f) /
                                                   double(args->frames - 1));
      const double c0 = cpu_seconds();
      const auto t0 = std::chrono::steady_clock::now();
      const FrameStats fs = render_frame(volume, integrator, view, fo, &film);
      const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      if (args->verbose) {
        print_pass_stats(uint32_t(f), fs, giga_volume);
        const VolumeIntegratorStats is = integrator.stats();
        const double rays = double(std::max<uint64_t>(is.rays, 1));
        std::fprintf(stderr,
                     "frame %d: %llu rays (last pass), %.1f spans and %.1f brick samples per ray, "
                     "%llu stopped by opacity\n",
                     f, (unsigned long long)is.rays, double(is.spans) / rays,
                     double(is.samples) / rays, (unsigned long long)is.early_terminations);
      }
      if (f > 0) {
        later_seconds += s, later_rays += integrator.stats().rays;
        later_cpu += cpu_seconds() - c0;
        later_passes += fs.passes.size();
        for (const giga::GigaVoxels* v : opened->streamed())
          for (const giga::GigaPassStats& g : v->pass_stats())
            later_requests += g.data_requests + g.subdivide_requests,
                later_uploads += g.bricks_uploaded + g.constants;
      }
      if (f + 1 == args->frames && fo.max_passes > 1 && !fs.passes.empty() &&
          fs.passes.back().requests != 0 && !Progress::quiet())
        std::fprintf(stderr,
                     "voxcast: warning: the last pass still asked for %llu elements (the pool is "
                     "too small for the view or --passes too low): the image shows coarser data\n",
                     (unsigned long long)fs.passes.back().requests);
    }
    progress.finish();
    outputs.write(args->output,
                  [&](const std::filesystem::path& to) { write_image(to, film.color); });
    if (!args->depth.empty())
      outputs.write(args->depth,
                    [&](const std::filesystem::path& to) { write_image(to, film.depth); });
    outputs.commit();
    double covered = 0;
    for (float a : film.alpha.pixels) covered += a;
    const double opacity = covered / double(film.alpha.pixels.size());
    if (opened->scene) {
      std::printf("%s: %dx%d, scene of %zu objects (%zu streamed, pools %s), mean opacity %.3f\n",
                  printable(args->output).c_str(), view.width, view.height,
                  opened->scene->scene->objects().size(), opened->scene->streamed.size(),
                  format_bytes(double(opened->pool_bytes())).c_str(), opacity);
    } else if (giga_volume)
      std::printf(
          "%s: %dx%d, %s (max level %d), pools %s (%u %d-bit bricks, %u tiles), mean opacity "
          "%.3f\n",
          printable(args->output).c_str(), view.width, view.height,
          opened->source.producer->name().c_str(), opened->source.producer->max_level(),
          format_bytes(double(giga_volume->pool_bytes())).c_str(), giga_volume->brick_capacity(),
          giga_volume->brick_bits(), giga_volume->tile_capacity(), opacity);
    else
      std::printf("%s: %dx%d, recursive menger graph (depth %d), mean opacity %.3f\n",
                  printable(args->output).c_str(), view.width, view.height,
                  opened->source.recursive->max_depth(), opacity);
    if (args->frames > 1) {
      const double k = double(args->frames - 1);
      std::printf(
          "%d frames after the first: %.2f frames/s, %.2f Mrays/s, %.3f CPU s/frame; per frame "
          "%.2f passes, %.0f requests, %.0f uploads\n",
          args->frames - 1, k / later_seconds, double(later_rays) / later_seconds * 1e-6,
          later_cpu / k, double(later_passes) / k, double(later_requests) / k,
          double(later_uploads) / k);
    }
    return 0;
  };
}

}  // namespace voxcast::cli
