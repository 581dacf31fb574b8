// voxcast info SCENE: what a scene file holds and what it costs (esvo §8.1-8.2).
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <nlohmann/json.hpp>

#include "cli_io.hpp"
#include "commands.hpp"
#include "voxcast/brickmap.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/scene_file.hpp"

namespace voxcast::cli {

namespace {
struct InfoArgs {
  std::string input;
  bool json = false;
};

// The facts every scene format shares, as JSON.
nlohmann::json scene_json(const std::string& path, uint64_t file_bytes, const char* format,
                          const LoadedScene& scene, const GridTransform& grid) {
  const SceneInfo& info = scene.info;
  nlohmann::json j;
  j["file"] = printable(path);
  j["file_bytes"] = file_bytes;
  j["format"] = format;
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
  return j;
}

// DAG scenes: nodes per level DAG vs SVO and memory DAG vs pointer-less SVO
// (1 B/node) vs ESVO (8 B/node), bits per voxel: the shape of svdag Table 2.
int print_dag_info(const InfoArgs& args, const LoadedScene& scene) {
  const SceneInfo& info = scene.info;
  const dag::SparseVoxelDag& d = dynamic_cast<const dag::DagStructure&>(*scene.structure).dag();
  const dag::DagStats st = d.stats();
  const uint64_t file_bytes = std::filesystem::file_size(args.input);
  const int L = d.levels();
  nlohmann::json j = scene_json(args.input, file_bytes, "dag", scene, d.grid);
  j["leaf_voxels"] = st.leaf_voxels;
  j["attributes"] = d.has_attributes();
  for (int l = 0; l <= L; ++l) {
    const dag::LevelStats& ls = st.levels[size_t(l)];
    j["per_level"].push_back({{"level", l},
                              {"dag_nodes", ls.dag_nodes},
                              {"svo_nodes", ls.svo_nodes},
                              {"dag_bytes", ls.dag_bytes}});
  }
  j["nodes"] = {{"dag", st.dag_nodes}, {"svo", st.svo_nodes}};
  j["memory"] = {{"dag", st.dag_bytes},
                 {"svo_1byte", st.svo_bytes},
                 {"esvo_8byte", st.esvo_bytes},
                 {"voxel_index", st.index_bytes},
                 {"attributes", st.attribute_bytes}};
  j["bits_per_voxel"] = st.bits_per_voxel;
  // Raw 8 B/voxel or esvo §5.5 blocks of 16 voxels in Morton order (dag.hpp).
  if (d.has_attributes()) {
    j["attribute_format"] = st.compressed_attributes ? "compressed" : "raw";
    j["attribute_bytes_per_voxel"] =
        st.leaf_voxels ? double(st.attribute_bytes) / double(st.leaf_voxels) : 0.0;
  }
  // 64-bit voxel indices (dag.hpp): words of the top levels whose nodes hold
  // >= 2^32 voxels carry 64-bit prefix entries (0 below 2^32 voxels).
  j["voxel_index_wide_words"] = d.wide_words;
  if (args.json) {
    std::printf("%s\n", j.dump(2, ' ', false, nlohmann::json::error_handler_t::replace).c_str());
    return 0;
  }
  std::printf("scene       %s (%s)\n", printable(args.input).c_str(),
              format_bytes(double(file_bytes)).c_str());
  std::printf("sections    ");
  for (const auto& s : j["sections"]) std::printf("%s ", s.get<std::string>().c_str());
  std::printf("\nstructure   sparse voxel DAG (svdag), 4^3 leaf masks, %s\n",
              d.has_attributes() ? "colors + normals per voxel (Morton-rank index)"
                                 : "geometry only (gray, face normals)");
  std::printf("source      %s, %llu triangles, %s voxelization\n", printable(info.source).c_str(),
              (unsigned long long)info.source_triangles, info.voxelization.c_str());
  std::printf("grid        %u^3 (%d levels), voxel size %.6g, origin %.6g,%.6g,%.6g\n",
              d.grid.resolution, L, d.grid.voxel_size, d.grid.origin.x, d.grid.origin.y,
              d.grid.origin.z);
  std::printf("voxels      %llu leaves\n\n", (unsigned long long)st.leaf_voxels);
  std::printf("level    DAG nodes     SVO nodes   reduction   DAG bytes\n");
  for (int l = 0; l < L; ++l) {
    const dag::LevelStats& ls = st.levels[size_t(l)];
    if (l < L - 1)
      std::printf("%5d %12llu  %12llu  %9.1fx  %10s\n", l, (unsigned long long)ls.dag_nodes,
                  (unsigned long long)ls.svo_nodes, double(ls.svo_nodes) / double(ls.dag_nodes),
                  format_bytes(double(ls.dag_bytes)).c_str());
    else
      std::printf("%5d %12s  %12llu  (in the level %d 64-bit masks)\n", l, "-",
                  (unsigned long long)ls.svo_nodes, L - 2);
  }
  std::printf("total %12llu  %12llu  %9.1fx\n\n", (unsigned long long)st.dag_nodes,
              (unsigned long long)st.svo_nodes, double(st.svo_nodes) / double(st.dag_nodes));
  const double v = double(st.leaf_voxels);
  std::printf("memory (geometry)          bytes  bits/voxel\n");
  std::printf("  DAG              %14s  %10.3f\n", format_bytes(double(st.dag_bytes)).c_str(),
              double(st.dag_bytes) * 8 / v);
  std::printf("  SVO  (1 B/node)  %14s  %10.3f   pointer-less (Schnabel & Klein)\n",
              format_bytes(double(st.svo_bytes)).c_str(), double(st.svo_bytes) * 8 / v);
  std::printf("  ESVO (8 B/node)  %14s  %10.3f   descriptor + contour word\n",
              format_bytes(double(st.esvo_bytes)).c_str(), double(st.esvo_bytes) * 8 / v);
  if (d.has_attributes())
    std::printf(
        "attributes  %s colors + normals, %s (%.3f B/voxel), %s voxel index (derived at "
        "load)\n",
        format_bytes(double(st.attribute_bytes)).c_str(),
        st.compressed_attributes ? "compressed esvo §5.5 blocks of 16 voxels" : "raw",
        double(st.attribute_bytes) / v, format_bytes(double(st.index_bytes)).c_str());
  if (d.wide_words)
    std::printf(
        "voxel index 64-bit prefix entries for the %u words of the levels whose nodes "
        "hold >= 2^32 voxels\n",
        d.wide_words);
  return 0;
}

// Brickmap worlds: bricks and memory per component (brickmap §5.1, Table 2).
int print_brickmap_info(const InfoArgs& args, const LoadedScene& scene) {
  const brickmap::World* w = brickmap::adapted_world(*scene.structure);
  if (w == nullptr) throw Error("internal: a brickmap scene without its world");
  const brickmap::WorldStats st = w->stats();
  const uint64_t file_bytes = std::filesystem::file_size(args.input);
  nlohmann::json j = scene_json(args.input, file_bytes, brickmap::kFormatName, scene, w->grid());
  j["leaf_voxels"] = st.voxels;
  j["bricks"] = st.bricks;
  j["brickgrid_dims"] = {w->dims()[0], w->dims()[1], w->dims()[2]};
  j["occupancy_dims"] = {w->occupancy_dims()[0], w->occupancy_dims()[1], w->occupancy_dims()[2]};
  j["normals"] = w->has_normals();
  j["memory"] = {{"brickgrid", st.grid_bytes}, {"occupancy", st.occupancy_bytes},
                 {"bricks", st.brick_bytes},   {"colors", st.color_bytes},
                 {"normals", st.normal_bytes}, {"total", st.total_bytes()}};
  j["bits_per_voxel"] = st.bits_per_voxel();
  if (args.json) {
    std::printf("%s\n", j.dump(2).c_str());
    return 0;
  }
  const SceneInfo& info = scene.info;
  std::printf("%s: %s, from %s (%llu triangles, %s voxelization)\n", printable(args.input).c_str(),
              format_bytes(double(file_bytes)).c_str(), printable(info.source).c_str(),
              (unsigned long long)info.source_triangles, info.voxelization.c_str());
  std::printf("structure   brickmap world: 8^3 brickmaps, brickgrid %ux%ux%u, occupancy %ux%ux%u\n",
              w->dims()[0], w->dims()[1], w->dims()[2], w->occupancy_dims()[0],
              w->occupancy_dims()[1], w->occupancy_dims()[2]);
  std::printf("grid        %u^3 (%d levels), voxel size %g\n", w->grid().resolution,
              w->grid().levels, w->grid().voxel_size);
  std::printf("voxels      %llu in %llu bricks (%.1f per brick)\n", (unsigned long long)st.voxels,
              (unsigned long long)st.bricks,
              st.bricks ? double(st.voxels) / double(st.bricks) : 0.0);
  const double v = st.voxels ? double(st.voxels) : 1.0;
  std::printf("\nmemory                    bytes   bits/voxel\n");
  const auto row = [&](const char* name, uint64_t bytes) {
    std::printf("  %-14s %14s  %10.3f\n", name, format_bytes(double(bytes)).c_str(),
                double(bytes) * 8 / v);
  };
  row("brickgrid", st.grid_bytes);
  row("occupancy", st.occupancy_bytes);
  row("bricks", st.brick_bytes);
  row("colors", st.color_bytes);
  row("normals", st.normal_bytes);
  row("total", st.total_bytes());
  return 0;
}
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
    const LoadedScene scene = load_scene(args->input);
    if (scene.format == "dag") return print_dag_info(*args, scene);
    if (scene.format == brickmap::kFormatName) return print_brickmap_info(*args, scene);
    const SceneInfo& info = scene.info;
    const esvo::EsvoOctree& octree =
        dynamic_cast<const esvo::EsvoStructure&>(*scene.structure).octree();
    auto levels = octree.level_stats();
    auto mem = octree.memory_stats();
    uint64_t total_voxels = 0;
    for (auto& l : levels) total_voxels += l.voxels;
    // Leaves on every level (variable-depth contour builds stop early, esvo
    // §7.1); equals the finest level's count for full-depth octrees.
    uint64_t leaves = 0;
    for (auto& l : levels) leaves += l.voxels - l.non_leaf;
    uint64_t file_bytes = std::filesystem::file_size(args->input);
    double hierarchy = double(mem.descriptor_bytes + mem.far_pointer_bytes + mem.page_header_bytes +
                              mem.info_bytes);
    double attributes = double(mem.attribute_lookup_bytes + mem.attribute_value_bytes);
    double overhead = double(mem.padding_bytes);

    nlohmann::json j = scene_json(args->input, file_bytes, "esvo", scene, octree.grid);
    j["blocks"] = octree.block_count;
    j["voxels_total"] = total_voxels;
    j["leaf_voxels"] = leaves;
    for (size_t l = 0; l < levels.size(); ++l) {
      nlohmann::json row{
          {"level", l}, {"voxels", levels[l].voxels}, {"non_leaf", levels[l].non_leaf}};
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
                   {"pair_padding", mem.pair_padding_bytes},
                   {"colors", mem.color_bytes},
                   {"normals", mem.normal_bytes},
                   {"contours", mem.contour_bytes},
                   {"total", mem.total_bytes}};
    j["contours"] = octree.has_contours();
    j["contour_count"] = mem.contour_count;
    const bool compressed = mem.attribute_format == esvo::AttributeFormat::Compressed;
    j["attributes"] = compressed ? "compressed" : "raw";
    if (args->json) {
      std::printf("%s\n", j.dump(2, ' ', false, nlohmann::json::error_handler_t::replace).c_str());
      return 0;
    }

    std::printf("scene       %s (%s)\n", printable(args->input).c_str(),
                format_bytes(double(file_bytes)).c_str());
    std::printf("sections    ");
    for (const auto& s : j["sections"]) std::printf("%s ", s.get<std::string>().c_str());
    std::printf(
        "\nstructure   esvo, %u block(s), %s attributes (%s)\n", octree.block_count,
        compressed ? "compressed" : "raw",
        compressed ? "esvo 5.5: 24 B per descriptor pair" : "esvo 5.4: 8 B per voxel + lookup");
    std::printf("contours    %s\n", octree.has_contours()
                                        ? ("yes, " + std::to_string(mem.contour_count) +
                                           " contour values (esvo 5.2, variable depth)")
                                              .c_str()
                                        : "no");
    std::printf("source      %s, %llu triangles, %s voxelization\n", printable(info.source).c_str(),
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
    row("attributes", attributes,
        compressed ? "compressed blocks (DXT1 colors + 4x4-grid normals)"
                   : "lookup entries, 32-bit colors + 32-bit normals");
    row(" colors", double(mem.color_bytes), compressed ? "2 words per block" : "32-bit ABGR");
    row(" normals", double(mem.normal_bytes),
        compressed ? "4 words per block" : "32-bit cube normals");
    if (octree.has_contours())
      row("contours", double(mem.contour_bytes),
          "CONT: 32-bit contour values (pointer/mask word: hierarchy)");
    row("overhead", overhead + double(mem.pair_padding_bytes),
        compressed ? "padding (page alignment, far slots, sibling-pair gaps)"
                   : "padding (page alignment, unused far-pointer slots)");
    row("total", double(mem.total_bytes), "");
    return 0;
  };
}

}  // namespace voxcast::cli
