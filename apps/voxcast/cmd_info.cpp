// voxcast info SCENE: what a scene file holds and what it costs (esvo §8.1-8.2,
// svdag Table 2): the shared facts here, the format's own from its registry
// entry's describe().
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <nlohmann/json.hpp>

#include "cli_io.hpp"
#include "commands.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo_slices.hpp"
#include "voxcast/format_registry.hpp"
#include "voxcast/progress.hpp"
#include "voxcast/scene_file.hpp"

namespace voxcast::cli {

namespace {
struct InfoArgs {
  std::string input;
  bool json = false;
};

}  // namespace

Runner add_info(CLI::App& app) {
  auto args = std::make_shared<InfoArgs>();
  CLI::App* cmd = app.add_subcommand("info", "Describe a scene file: levels, voxels, memory");
  cmd->add_option("SCENE", args->input, "Scene file")->required();
  cmd->add_flag("--json", args->json, "Print the same facts as JSON");
  return [args]() {
    require_regular_input(args->input, "scene");
    // The same loader (and so the same validator) as render: both accept or
    // refuse a file alike, and the file is read once.
    // A streamed scene (slice files) is described from what it keeps in
    // memory at open (the hierarchy and the root), not loaded whole.
    SceneLoadOptions lo;
    lo.load_all = false;
    const LoadedScene scene = load_scene(args->input, lo);
    if (scene.format == "esvo-sliced") {
      // Still refused like render refuses it whole: every slice's hash, one
      // slice in memory at a time.
      const auto file = esvo::SliceFile::open(args->input);
      uint64_t bytes = 0;
      for (const auto& e : file->slices()) bytes += e.data_bytes;
      Progress progress("verify", bytes);
      file->verify_hashes(&progress);
      progress.finish();
    }
    DescribeStyle style;
    style.bytes = [](double b) { return format_bytes(b); };
    const SceneDescription d =
        format_registry().get(scene.format).describe(*scene.structure, style);
    const SceneInfo& info = scene.info;
    const GridTransform& grid = d.grid;
    const uint64_t file_bytes = std::filesystem::file_size(args->input);
    // The facts every scene format shares, then the format's own.
    nlohmann::json j = nlohmann::json::parse(d.json);
    j["file"] = printable(args->input);
    j["file_bytes"] = file_bytes;
    j["format"] = scene.format;
    std::vector<std::string> sections;
    for (uint32_t id : scene.sections) sections.push_back(fourcc_name(id));
    j["sections"] = sections;
    j["source"] = printable(info.source);
    j["source_triangles"] = info.source_triangles;
    j["voxelization"] = info.voxelization;
    j["resolution"] = grid.resolution;
    j["levels"] = grid.levels;
    j["voxel_size"] = grid.voxel_size;
    j["origin"] = {grid.origin.x, grid.origin.y, grid.origin.z};
    if (args->json) {
      std::printf("%s\n", j.dump(2, ' ', false, nlohmann::json::error_handler_t::replace).c_str());
      return 0;
    }
    std::printf("scene       %s (%s)\n", printable(args->input).c_str(),
                format_bytes(double(file_bytes)).c_str());
    if (!sections.empty()) {  // a container's (not a file type of its own, e.g. slices)
      std::printf("sections    ");
      for (const std::string& name : sections) std::printf("%s ", name.c_str());
      std::printf("\n");
    }
    std::printf("%s", d.summary.c_str());
    if (sections.empty() && info.source.empty())  // slice files record no source
      std::printf("source      not recorded\n");
    else
      std::printf("source      %s, %llu triangles, %s voxelization\n",
                  printable(info.source).c_str(), (unsigned long long)info.source_triangles,
                  info.voxelization.c_str());
    std::printf("grid        %u^3 (%d levels), voxel size %.6g, origin %.6g,%.6g,%.6g\n",
                grid.resolution, grid.levels, grid.voxel_size, grid.origin.x, grid.origin.y,
                grid.origin.z);
    std::printf("voxels      %s\n\n%s", d.voxels.c_str(), d.details.c_str());
    return 0;
  };
}

}  // namespace voxcast::cli
