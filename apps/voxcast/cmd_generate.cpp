// voxcast generate hairball|menger|terrain -o MESH: procedural stress meshes
// for the voxelizer and the DAG (generate.hpp).
#include <cstdio>
#include <filesystem>
#include <memory>

#include "cli_io.hpp"
#include "commands.hpp"
#include "voxcast/error.hpp"
#include "voxcast/generate.hpp"

namespace voxcast::cli {

namespace {
struct GenerateArgs {
  std::string kind, output;
  uint64_t seed = 1;
  int tubes = 200, segments = 64, sides = 6, level = 3, size = 256, octaves = 6;
  double radius = 0.004, step = 0.04, height = 0.25, persistence = 0.5;
};
}  // namespace

Runner add_generate(CLI::App& app) {
  auto args = std::make_shared<GenerateArgs>();
  CLI::App* cmd = app.add_subcommand(
      "generate",
      "Write a procedural stress mesh: hairball (random tubes), menger (sponge), "
      "terrain (fBm height field)");
  cmd->add_option("KIND", args->kind, "hairball | menger | terrain")->required();
  cmd->add_option("-o,--output", args->output, "Output mesh (.obj or binary .ply)")->required();
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
  cmd->add_option("--size", args->size, "terrain: vertices per side (N x N)")
      ->capture_default_str();
  cmd->add_option("--octaves", args->octaves, "terrain: fBm octaves")->capture_default_str();
  cmd->add_option("--height", args->height, "terrain: height scale (extent 1)")
      ->capture_default_str();
  cmd->add_option("--persistence", args->persistence, "terrain: amplitude factor per octave")
      ->capture_default_str();
  return [args]() {
    if (args->kind != "hairball" && args->kind != "menger" && args->kind != "terrain")
      throw UsageError("generate: '" + printable(args->kind) +
                       "' is not hairball, menger or terrain");
    OutputSet outputs({});
    outputs.add("-o", args->output, {".obj", ".ply"});
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
