// voxcast convert IN OUT: between voxel formats (.vox, .binvox, .vdb in;
// .vox, .binvox, .vdb, .raw out), or from a mesh through the voxelizer (as
// `build`).
#include <cstdio>
#include <filesystem>
#include <memory>

#include "cli_io.hpp"
#include "commands.hpp"
#include "pipeline.hpp"
#include "voxcast/error.hpp"
#include "voxcast/image.hpp"
#include "voxcast/progress.hpp"
#include "voxcast/system.hpp"
#include "voxcast/voxel_io.hpp"

namespace voxcast::cli {

namespace {
struct ConvertArgs {
  std::string input, output, voxelization = "conservative", fill = "surface", memory_budget;
  uint32_t resolution = 256;
  double voxel_size = 0;
  int threads = 0;
  bool verbose = false;
  CLI::Option *voxel_size_opt = nullptr, *resolution_opt = nullptr, *voxelization_opt = nullptr,
              *fill_opt = nullptr;
};
}  // namespace

Runner add_convert(CLI::App& app) {
  auto args = std::make_shared<ConvertArgs>();
  CLI::App* cmd = app.add_subcommand(
      "convert",
      "Convert voxels between formats (.vox, .binvox, .vdb -> .vox, .binvox, .vdb, .raw), or "
      "voxelize a mesh into one");
  cmd->add_option("IN", args->input, "Voxel file (.vox, .binvox, .vdb) or mesh (as for build)")
      ->required();
  cmd->add_option(
         "OUT", args->output,
         "Output: .vox (MagicaVoxel), .binvox, .vdb (OpenVDB), .raw (uint8 grid + OUT.raw.json)")
      ->required();
  args->resolution_opt =
      cmd->add_option("--resolution", args->resolution,
                      "Mesh input: voxels per axis, a power of two (default 256)")
          ->check(not_negative());
  args->voxel_size_opt = cmd->add_option("--voxel-size", args->voxel_size,
                                         "Mesh input: largest voxel size in world units")
                             ->excludes(args->resolution_opt);
  args->voxelization_opt = cmd->add_option("--voxelization", args->voxelization,
                                           "Mesh input: conservative | 6-separating");
  args->fill_opt = cmd->add_option("--fill", args->fill, "Mesh input: surface | solid");
  cmd->add_option("--memory-budget", args->memory_budget,
                  "Refuse inputs and outputs estimated to need more (default 90% of free memory)");
  cmd->add_option("--threads", args->threads, "Worker threads (0 = all cores)");
  cmd->add_flag("-v,--verbose", args->verbose, "Print timings per stage");
  return [args]() {
    ThreadLimit limit(args->threads);
    BuildSettings s;
    s.mesh_path = args->input;
    s.verbose = args->verbose;
    const bool voxel_input = is_voxel_input(args->input);
    if (voxel_input && (args->resolution_opt->count() || args->voxel_size_opt->count() ||
                        args->voxelization_opt->count() || args->fill_opt->count()))
      throw UsageError(
          "--resolution, --voxel-size, --voxelization and --fill apply to mesh inputs only");
    set_voxelization_options(s, args->resolution, args->voxel_size_opt->count() > 0,
                             args->voxel_size, args->voxelization, args->fill);
    if (!args->memory_budget.empty()) s.memory_budget = parse_memory_budget(args->memory_budget);
    OutputSet outputs({args->input});
    outputs.add("OUT", args->output, {".vox", ".binvox", ".vdb", ".raw"});
    const bool raw = std::filesystem::path(args->output).extension() == ".raw";
    const std::string sidecar = args->output + ".json";
    if (raw) outputs.add("OUT", sidecar, {".json"});
    require_regular_input(args->input, voxel_input ? "voxel file" : "mesh");
    StageTimer total(false);
    const VoxelSet voxels = input_voxels(s);
    StageTimer timer(args->verbose);
    if (raw) {
      const RawGrid grid = encode_raw_grid(voxels, s.memory_budget);
      outputs.write(args->output, [&](const std::filesystem::path& to) {
        write_file_atomic(to, grid.cells.data(), grid.cells.size());
      });
      outputs.write(sidecar, [&](const std::filesystem::path& to) {
        write_file_atomic(to, grid.json.data(), grid.json.size());
      });
    } else {
      outputs.write(args->output,
                    [&](const std::filesystem::path& to) { write_voxels(to, voxels); });
    }
    outputs.commit();
    timer.mark("write");
    std::printf("%s: %llu voxels (%u^3 grid), %.2f s\n", printable(args->output).c_str(),
                (unsigned long long)voxels.size(), voxels.grid.resolution, total.mark("total"));
    return 0;
  };
}

}  // namespace voxcast::cli
