// voxcast generate hairball|menger|terrain -o MESH: procedural stress meshes
// for the voxelizer and the DAG (generate.hpp); generate terrain -o WORLD.vxc
// --size WxDxH: a brickmap world written chunk by chunk (brickmap_terrain.hpp);
// generate sky -o ENV.hdr: the procedural environment map of environment.hpp.
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <thread>
#include <vector>

#include "cli_io.hpp"
#include "commands.hpp"
#include "pipeline.hpp"
#include "voxcast/brickmap_terrain.hpp"
#include "voxcast/environment.hpp"
#include "voxcast/error.hpp"
#include "voxcast/exr.hpp"
#include "voxcast/generate.hpp"
#include "voxcast/progress.hpp"
#include "voxcast/system.hpp"

namespace voxcast::cli {

namespace {
struct GenerateArgs {
  std::string kind, output;
  uint64_t seed = 1;
  int tubes = 200, segments = 64, sides = 6, level = 3, size = 256, octaves = 6, threads = 0;
  std::string size_text = "256";
  double radius = 0.004, step = 0.04, height = 0.25, persistence = 0.5;
  std::string memory_budget;
  std::string sky_size = "256x128", sun;  // sky
  // Options of the terrain mesh that a .vxc terrain has no use for.
  std::vector<const CLI::Option*> mesh_terrain_options;
};

// generate sky: a lat-long HDR environment map for `render --gi --env`.
int generate_sky(const GenerateArgs& a) {
  int w = 0, h = 0;
  parse_size(a.sky_size, &w, &h, "--sky-size");
  Vec3 sun = normalize(Vec3{-0.4f, -1.0f, -0.6f});  // the default light direction
  if (!a.sun.empty()) {
    sun = parse_vec3(a.sun, "--sun");
    if (!(length(sun) > 0) || !std::isfinite(length(sun)))
      throw UsageError("--sun must be a non-zero, finite vector");
  }
  OutputSet outputs({});
  outputs.add("-o", a.output, {".hdr", ".exr"});
  const Image sky = procedural_sky(w, h, sun);
  const bool exr = std::filesystem::path(a.output).extension() == ".exr";
  outputs.write(a.output, [&](const std::filesystem::path& to) {
    exr ? write_exr_image(to, sky) : write_hdr(to, sky);
  });
  outputs.commit();
  std::printf("%s: sky, %dx%d lat-long\n", printable(a.output).c_str(), w, h);
  return 0;
}

// generate terrain -o WORLD.vxc: the brickmap terrain, --size WxDxH voxels
// (x, z, then the height along y, the up axis).
int generate_terrain_world(const GenerateArgs& a) {
  brickmap::TerrainOptions o;
  int64_t v[3];
  if (!parse_dims(a.size_text, 3, 16, 65536, v))
    throw UsageError("--size: '" + printable(a.size_text) +
                     "' is not WxDxH voxels (each 16 .. 65536) for a brickmap terrain");
  const unsigned w = unsigned(v[0]), d = unsigned(v[1]), h = unsigned(v[2]);
  for (const CLI::Option* opt : a.mesh_terrain_options)
    if (opt->count() > 0)
      throw UsageError(opt->get_name() +
                       " is for a terrain mesh (.obj, .ply); a brickmap terrain (.vxc) takes "
                       "--size, --seed and --threads");
  require_range("--threads", a.threads, 0, 4096);
  o.size[0] = w, o.size[1] = h, o.size[2] = d;
  o.seed = a.seed;
  o.threads = a.threads;
  uint64_t columns = 0;
  try {
    brickmap::terrain_grid(o);  // size limits
    columns = uint64_t((w + 127) / 128) * ((d + 127) / 128);
  } catch (const Error& e) {
    throw UsageError(e.what());
  }
  {
    // write_terrain's memory: the brickgrid header (4 B per cell) and chunk
    // table (24 B per chunk), and per chunk column in flight (2 per worker)
    // its solid slab (130^3 B) and its chunks' bricks (~128 B each).
    const uint64_t side = std::bit_ceil(std::max<uint64_t>({w, d, h, 128}));  // terrain_grid()
    const uint64_t n = side / 8, ny = (h + 7) / 8;                            // brickgrid cells
    const uint64_t chunks = ((n + 15) / 16) * ((n + 15) / 16) * ((ny + 15) / 16);
    const int threads =
        a.threads > 0 ? a.threads : std::max(1, int(std::thread::hardware_concurrency()));
    const double need = 4.0 * double(n * n * ny) + 24.0 * double(chunks) +
                        2.0 * threads * (130.0 * 130 * 130 + 16.0 * 16 * double(ny) * 128);
    const uint64_t budget =
        effective_budget(a.memory_budget.empty() ? 0 : parse_memory_budget(a.memory_budget));
    if (budget && need > double(budget))
      throw Error("this terrain needs an estimated " + format_bytes(need) + ", more than the " +
                  format_bytes(double(budget)) +
                  " memory budget; use a smaller --size or fewer --threads, or raise "
                  "--memory-budget");
  }
  OutputSet outputs({});
  outputs.add("-o", a.output, {".vxc"});
  brickmap::TerrainStats st;
  Progress progress("terrain", columns);
  o.progress = &progress;
  outputs.write(a.output,
                [&](const std::filesystem::path& to) { st = brickmap::write_terrain(to, o); });
  outputs.commit();
  std::printf(
      "%s: brickmap terrain %ux%ux%u, %llu voxels in %llu bricks, %llu chunks, %s of LZ4 chunks "
      "(%.2f x), brickgrid header %s\n",
      printable(a.output).c_str(), w, d, h, (unsigned long long)st.voxels,
      (unsigned long long)st.bricks, (unsigned long long)st.chunks,
      format_bytes(double(st.chunk_bytes)).c_str(),
      st.chunk_bytes ? double(st.raw_bytes) / double(st.chunk_bytes) : 0.0,
      format_bytes(4.0 * double(st.header_cells)).c_str());
  return 0;
}

// Bytes the mesh and its file text take, from the vertex and triangle counts
// generate.hpp documents; 0 while the parameters are outside the documented
// ranges (the generator refuses those itself, as usage errors).
double estimated_bytes(const GenerateArgs& a, bool obj) {
  double verts = 0, tris = 0;
  if (a.kind == "hairball") {
    if (a.tubes < 1 || a.tubes > 1000000 || a.segments < 1 || a.segments > 100000 || a.sides < 3 ||
        a.sides > 64)
      return 0;
    verts = double(a.tubes) * ((double(a.segments) + 1) * a.sides + 2);
    tris = double(a.tubes) * (2.0 * a.segments + 2) * a.sides;
  } else if (a.kind == "terrain") {
    if (a.size < 2 || a.size > 8192) return 0;
    verts = double(a.size) * a.size;
    tris = 2.0 * (a.size - 1.0) * (a.size - 1.0);
  } else {
    // menger (generate.hpp): 2 * 20^L + 4 * 8^L square faces, two triangles
    // each, vertices shared (level 5: 5.5 M for 6.5 M faces).
    if (a.level < 0 || a.level > 5) return 0;
    const double faces = 2.0 * std::pow(20.0, a.level) + 4.0 * std::pow(8.0, a.level);
    verts = faces;
    tris = 2.0 * faces;
  }
  // Positions and indices, then the file: OBJ lines of up to ~40 bytes,
  // PLY 12 bytes per vertex and 13 per triangle.
  return 12 * verts + 12 * tris + (obj ? 40 * (verts + tris) : 12 * verts + 13 * tris);
}
}  // namespace

Runner add_generate(CLI::App& app) {
  auto args = std::make_shared<GenerateArgs>();
  CLI::App* cmd = app.add_subcommand(
      "generate",
      "Write a procedural stress mesh: hairball (random tubes), menger (sponge), "
      "terrain (fBm height field); or an HDR environment map: sky");
  cmd->add_option("KIND", args->kind, "hairball | menger | terrain | sky")->required();
  cmd->add_option("-o,--output", args->output,
                  "Output mesh (.obj or binary .ply); terrain also a brickmap world (.vxc); "
                  "sky: .hdr or .exr")
      ->required();
  cmd->add_option("--sky-size", args->sky_size, "sky: image size WxH")->capture_default_str();
  cmd->add_option("--sun", args->sun, "sky: glow around the sun travelling along dx,dy,dz");
  cmd->add_option("--seed", args->seed, "Random seed (hairball, terrain)")
      ->capture_default_str()
      ->check(not_negative());  // an unsigned option would take "-1" as 2^64-1
  cmd->add_option("--tubes", args->tubes, "hairball: number of tubes")->capture_default_str();
  cmd->add_option("--segments", args->segments, "hairball: steps per tube")->capture_default_str();
  cmd->add_option("--sides", args->sides, "hairball: sides of the tube cross-section")
      ->capture_default_str();
  cmd->add_option("--radius", args->radius, "hairball: tube radius (ball radius 1)")
      ->capture_default_str();
  cmd->add_option("--step", args->step, "hairball: random-walk step length")->capture_default_str();
  cmd->add_option("--level", args->level, "menger: recursion level 0..5")->capture_default_str();
  cmd->add_option("--size", args->size_text,
                  "terrain: vertices per side N (a mesh); WxDxH voxels (a .vxc brickmap world, "
                  "H the height)")
      ->capture_default_str();
  cmd->add_option("--threads", args->threads,
                  "terrain .vxc: worker threads (0 = all cores; same bytes for any count)");
  args->mesh_terrain_options = {
      cmd->add_option("--octaves", args->octaves, "terrain: fBm octaves")->capture_default_str(),
      cmd->add_option("--height", args->height, "terrain: height scale (extent 1)")
          ->capture_default_str(),
      cmd->add_option("--persistence", args->persistence, "terrain: amplitude factor per octave")
          ->capture_default_str()};
  cmd->add_option("--memory-budget", args->memory_budget,
                  "Refuse meshes and .vxc terrains estimated to need more (e.g. 2G; default 90% of "
                  "free memory)");
  return [args]() {
    if (args->kind == "sky") return generate_sky(*args);
    if (args->kind != "hairball" && args->kind != "menger" && args->kind != "terrain")
      throw UsageError("generate: '" + printable(args->kind) +
                       "' is not hairball, menger, terrain or sky");
    if (args->kind == "terrain" && std::filesystem::path(args->output).extension() == ".vxc")
      return generate_terrain_world(*args);
    {
      int64_t n = 0;  // (the range is checked below; only what fits an int here)
      if (!parse_dims(args->size_text, 1, 0, INT32_MAX, &n))
        throw UsageError("--size: '" + printable(args->size_text) +
                         "' is not a vertex count (WxDxH is for a .vxc terrain)");
      args->size = int(n);
    }
    uint64_t budget = 0;
    if (!args->memory_budget.empty()) budget = parse_memory_budget(args->memory_budget);
    OutputSet outputs({});
    // (A terrain's .vxc went to generate_terrain_world above.)
    if (args->kind == "terrain")
      outputs.add("-o", args->output, {".obj", ".ply", ".vxc"});
    else
      outputs.add("-o", args->output, {".obj", ".ply"});
    {
      budget = effective_budget(budget);
      const bool obj = std::filesystem::path(args->output).extension() != ".ply" &&
                       std::filesystem::path(args->output).extension() != ".PLY";
      const double need = estimated_bytes(*args, obj);
      if (budget && need > double(budget))
        throw Error("this " + args->kind + " needs an estimated " + format_bytes(need) +
                    ", more than the " + format_bytes(double(budget)) +
                    " memory budget; use fewer or smaller parts or raise --memory-budget");
    }
    Mesh mesh;
    try {
      if (args->kind == "hairball") {
        generate::HairballOptions o;
        o.seed = args->seed;
        o.tubes = args->tubes;
        o.segments = args->segments;
        o.sides = args->sides;
        o.radius = args->radius;
        o.step = args->step;
        mesh = generate::hairball(o);
      } else if (args->kind == "menger") {
        mesh = generate::menger(args->level);
      } else {
        generate::TerrainOptions o;
        o.seed = args->seed;
        o.size = args->size;
        o.octaves = args->octaves;
        o.height = args->height;
        o.persistence = args->persistence;
        mesh = generate::terrain(o);
      }
    } catch (const Error& e) {
      // The generators check their parameters (NaN-safe ranges, triangle
      // counts that fit 32-bit indices) before building anything, and
      // nothing else they do can fail with voxcast::Error: a bad option.
      throw UsageError(e.what());
    }
    outputs.write(args->output,
                  [&](const std::filesystem::path& to) { generate::write_mesh(to, mesh); });
    outputs.commit();
    std::printf("%s: %s, %zu triangles, %zu vertices\n", printable(args->output).c_str(),
                args->kind.c_str(), mesh.triangle_count(), mesh.positions.size());
    return 0;
  };
}

}  // namespace voxcast::cli
