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
    if (esvo::is_slice_file(args->input)) {
      // A slice file (esvo §7): its grid and the slice hierarchy.
      const auto file = esvo::SliceFile::open(args->input);
      const GridTransform grid = file->grid();
      const uint64_t bytes = std::filesystem::file_size(args->input);
      if (args->json) {
        nlohmann::json j;
        j["file"] = printable(args->input);
        j["file_bytes"] = bytes;
        j["format"] = "esvo-sliced";
        j["slices"] = file->slices().size();
        j["slice_bytes"] = file->header().slice_bytes;
        j["descriptors"] = file->header().total_nodes;
        j["voxels"] = file->header().total_voxels;
        j["contours"] = file->has_contours();
        j["resolution"] = grid.resolution;
        j["levels"] = grid.levels;
        uint64_t resident = 0;
        for (const auto& e : file->slices()) resident += esvo::StreamedEsvo::block_bytes(e);
        j["resident_bytes_all"] = resident;
        std::printf("%s\n",
                    j.dump(2, ' ', false, nlohmann::json::error_handler_t::replace).c_str());
        return 0;
      }
      std::printf("scene       %s (%s)\n", printable(args->input).c_str(),
                  format_bytes(double(bytes)).c_str());
      std::printf("format      esvo-sliced (slices on disk, esvo section 7)\n");
      std::printf("grid        %u^3 (%d levels), voxel size %.6g, origin %.6g,%.6g,%.6g\n\n",
                  grid.resolution, grid.levels, grid.voxel_size, grid.origin.x, grid.origin.y,
                  grid.origin.z);
      std::printf("%s", file->describe().c_str());
      uint64_t resident = 0;
      for (const auto& e : file->slices()) resident += esvo::StreamedEsvo::block_bytes(e);
      std::printf("all slices resident (streamed blocks): %s\n",
                  format_bytes(double(resident)).c_str());
      return 0;
    }
    // The same loader (and so the same validator) as render: both accept or
    // refuse a file alike, and the file is read once.
    const LoadedScene scene = load_scene(args->input);
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
    std::printf("sections    ");
    for (const std::string& name : sections) std::printf("%s ", name.c_str());
    std::printf("\n%s", d.summary.c_str());
    std::printf("source      %s, %llu triangles, %s voxelization\n", printable(info.source).c_str(),
                (unsigned long long)info.source_triangles, info.voxelization.c_str());
    std::printf("grid        %u^3 (%d levels), voxel size %.6g, origin %.6g,%.6g,%.6g\n",
                grid.resolution, grid.levels, grid.voxel_size, grid.origin.x, grid.origin.y,
                grid.origin.z);
    std::printf("voxels      %s\n\n%s", d.voxels.c_str(), d.details.c_str());
    return 0;
  };
}

}  // namespace voxcast::cli
