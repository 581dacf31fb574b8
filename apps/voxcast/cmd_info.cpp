// voxcast info SCENE: what a scene file holds and what it costs (esvo §8.1-8.2).
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <nlohmann/json.hpp>

#include "commands.hpp"
#include "voxcast/error.hpp"
#include "voxcast/scene_file.hpp"

namespace voxcast::cli {

namespace {
struct InfoArgs {
  std::string input;
  bool json = false;
};

std::string fourcc_name(uint32_t id) {
  std::string s(4, ' ');
  for (int i = 0; i < 4; ++i) {
    char c = char((id >> (8 * i)) & 0xFF);
    s[i] = (c >= 32 && c < 127) ? c : '?';
  }
  return s;
}
}  // namespace

Runner add_info(CLI::App& app) {
  auto args = std::make_shared<InfoArgs>();
  CLI::App* cmd = app.add_subcommand("info", "Describe a scene file: levels, voxels, memory");
  cmd->add_option("SCENE", args->input, "Scene file")->required();
  cmd->add_flag("--json", args->json, "Print the same facts as JSON");
  return [args]() {
    Container container = Container::read(args->input);
    SceneInfo info;
    esvo::EsvoOctree octree = load_esvo_scene(args->input, &info);
    auto levels = octree.level_stats();
    auto mem = octree.memory_stats();
    uint64_t total_voxels = 0;
    for (auto& l : levels) total_voxels += l.voxels;
    uint64_t leaves = levels.empty() ? 0 : levels.back().voxels;
    uint64_t file_bytes = std::filesystem::file_size(args->input);
    double hierarchy = double(mem.descriptor_bytes + mem.far_pointer_bytes +
                              mem.page_header_bytes + mem.info_bytes);
    double attributes = double(mem.attribute_lookup_bytes + mem.attribute_value_bytes);
    double overhead = double(mem.padding_bytes);

    nlohmann::json j;
    j["file"] = args->input;
    j["file_bytes"] = file_bytes;
    j["format"] = "esvo";
    std::vector<std::string> sections;
    for (uint32_t id : container.section_ids()) sections.push_back(fourcc_name(id));
    j["sections"] = sections;
    j["source"] = info.source;
    j["source_triangles"] = info.source_triangles;
    j["voxelization"] = info.voxelization;
    j["resolution"] = octree.grid.resolution;
    j["levels"] = octree.levels();
    j["voxel_size"] = octree.grid.voxel_size;
    j["origin"] = {octree.grid.origin.x, octree.grid.origin.y, octree.grid.origin.z};
    j["blocks"] = octree.block_count;
    j["voxels_total"] = total_voxels;
    j["leaf_voxels"] = leaves;
    for (size_t l = 0; l < levels.size(); ++l) {
      nlohmann::json row{{"level", l}, {"voxels", levels[l].voxels},
                         {"non_leaf", levels[l].non_leaf}};
      if (l + 1 < levels.size() && levels[l].non_leaf) {
        double branching = double(levels[l + 1].voxels) / double(levels[l].non_leaf);
        row["branching"] = branching;
        row["dimensionality"] = std::log2(branching);
      }
      j["per_level"].push_back(row);
    }
    j["memory"] = {{"descriptors", mem.descriptor_bytes},
                   {"far_pointers", mem.far_pointer_bytes},
                   {"page_headers", mem.page_header_bytes},
                   {"info_sections", mem.info_bytes},
                   {"attribute_lookup", mem.attribute_lookup_bytes},
                   {"attribute_values", mem.attribute_value_bytes},
                   {"padding", mem.padding_bytes},
                   {"total", mem.total_bytes}};
    if (args->json) {
      std::printf("%s\n", j.dump(2).c_str());
      return 0;
    }

    std::printf("scene       %s (%s)\n", args->input.c_str(), format_bytes(double(file_bytes)).c_str());
    std::printf("sections    ");
    for (auto& s : sections) std::printf("%s ", s.c_str());
    std::printf("\nstructure   esvo, %u block(s)\n", octree.block_count);
    std::printf("source      %s, %llu triangles, %s voxelization\n", info.source.c_str(),
                (unsigned long long)info.source_triangles, info.voxelization.c_str());
    std::printf("grid        %u^3 (%d levels), voxel size %.6g, origin %.6g,%.6g,%.6g\n",
                octree.grid.resolution, octree.levels(), octree.grid.voxel_size,
                octree.grid.origin.x, octree.grid.origin.y, octree.grid.origin.z);
    std::printf("voxels      %llu in all levels, %llu leaves\n\n", (unsigned long long)total_voxels,
                (unsigned long long)leaves);
    std::printf("level       voxels     non-leaf  branching  dimensionality\n");
    for (size_t l = 0; l < levels.size(); ++l) {
      std::printf("%5zu %12llu %12llu", l, (unsigned long long)levels[l].voxels,
                  (unsigned long long)levels[l].non_leaf);
      if (l + 1 < levels.size() && levels[l].non_leaf) {
        double branching = double(levels[l + 1].voxels) / double(levels[l].non_leaf);
        std::printf("  %9.2f  %14.2f", branching, std::log2(branching));
      }
      std::printf("\n");
    }
    auto row = [&](const char* name, double bytes, const char* what) {
      std::printf("  %-11s %12s  %6.2f  %6.2f   %s\n", name, format_bytes(bytes).c_str(),
                  bytes / double(total_voxels), bytes / double(leaves), what);
    };
    std::printf("\nmemory             bytes  B/voxel  B/leaf\n");
    row("hierarchy", hierarchy, "child descriptors, far pointers, page headers, info sections");
    row("attributes", attributes, "lookup entries, 32-bit colors + 32-bit normals");
    row("overhead", overhead, "padding (page alignment, unused far-pointer slots)");
    row("total", double(mem.total_bytes), "");
    return 0;
  };
}

}  // namespace voxcast::cli
