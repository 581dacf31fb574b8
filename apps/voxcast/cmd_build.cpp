// voxcast build MESH -o SCENE: voxelize a mesh and store it as an ESVO scene.
#include <cmath>
#include <cstdio>
#include <filesystem>

#include "commands.hpp"
#include "pipeline.hpp"
#include "voxcast/error.hpp"
#include "voxcast/progress.hpp"
#include "voxcast/scene_file.hpp"
#include "voxcast/system.hpp"

namespace voxcast::cli {

namespace {
struct BuildArgs {
  std::string input, output, voxelization = "conservative", memory_budget;
  std::string attributes = "raw";
  std::string format = "esvo";
  uint32_t resolution = 1024;
  double voxel_size = std::nan("");
  int threads = 0;
  bool verbose = false;
};
}  // namespace

Runner add_build(CLI::App& app) {
  auto args = std::make_shared<BuildArgs>();
  CLI::App* cmd = app.add_subcommand(
      "build", "Voxelize a triangle mesh into a scene file (ESVO octree or sparse voxel DAG)");
  cmd->add_option("MESH", args->input, "Input mesh (OBJ, PLY, OFF, STL, glTF/GLB, FBX, DAE, ...)")
      ->required();
  cmd->add_option("-o,--output", args->output, "Output scene file (.vxc)")->required();
  auto* res = cmd->add_option("--resolution", args->resolution,
                              "Voxels per axis: a power of two, 1..1048576 (default 1024)");
  cmd->add_option("--voxel-size", args->voxel_size,
                  "Largest voxel size in world units (resolution rounded up to a power of two)")
      ->excludes(res);
  cmd->add_option("--voxelization", args->voxelization, "conservative | 6-separating")
      ->capture_default_str();
  cmd->add_option("--attributes", args->attributes,
                  "Color/normal storage: raw (8 B/voxel) | compressed (esvo §5.5 blocks, lossy)")
      ->capture_default_str();
  cmd->add_option("--format", args->format,
                  "Structure: esvo (ESVO octree) | dag (sparse voxel DAG, svdag paper section 3)")
      ->capture_default_str();
  cmd->add_option("--memory-budget", args->memory_budget,
                  "Refuse builds estimated to need more (e.g. 8G; default 90% of free memory)");
  cmd->add_option("--threads", args->threads, "Worker threads (0 = all cores)");
  cmd->add_flag("-v,--verbose", args->verbose, "Print timings per stage");
  return [args]() {
    ThreadLimit limit(args->threads);
    BuildSettings s;
    s.mesh_path = args->input;
    s.resolution = args->resolution;
    if (!std::isnan(args->voxel_size)) {
      if (!(args->voxel_size > 0) || !std::isfinite(args->voxel_size))
        throw Error("--voxel-size must be a positive number");
      s.voxel_size = args->voxel_size;
    }
    s.mode = parse_voxelization(args->voxelization);
    s.attributes = parse_attribute_format(args->attributes);
    if (!args->memory_budget.empty()) s.memory_budget = parse_byte_size(args->memory_budget.c_str());
    s.verbose = args->verbose;
    if (args->format != "esvo" && args->format != "dag")
      throw Error("--format: '" + args->format + "' is not esvo or dag");
    s.dag = args->format == "dag";
    if (s.dag && s.attributes != esvo::AttributeFormat::Raw)
      throw Error("--attributes compressed applies to --format esvo only");
    if (std::filesystem::is_directory(args->output))
      throw Error("output '" + args->output + "' is a directory");
    StageTimer total(false);
    BuiltScene built = build_scene(s);
    StageTimer timer(args->verbose);
    SceneInfo info;
    info.source = std::filesystem::path(args->input).filename().string();
    info.voxelization = voxelization_name(s.mode);
    info.source_triangles = built.mesh.triangle_count();
    info.leaf_voxels = built.leaf_voxels;
    if (s.dag) {
      save_dag_scene(args->output, built.dag, info);
      timer.mark("write scene");
      const dag::DagStats st = built.dag.stats();
      std::printf("%s: %u^3 grid (%d levels), %llu leaf voxels, DAG %s (%.3f bits/leaf voxel, "
                  "%llu nodes vs %llu SVO nodes), %.2f s\n",
                  args->output.c_str(), built.dag.grid.resolution, built.dag.levels(),
                  (unsigned long long)built.leaf_voxels, format_bytes(double(st.dag_bytes)).c_str(),
                  st.bits_per_voxel, (unsigned long long)st.dag_nodes,
                  (unsigned long long)st.svo_nodes, total.mark("total"));
      return 0;
    }
    save_esvo_scene(args->output, built.octree, info);
    timer.mark("write scene");
    auto mem = built.octree.memory_stats();
    std::printf("%s: %u^3 grid (%d levels), %llu leaf voxels, %s (%.2f bytes/leaf voxel), %.2f s\n",
                args->output.c_str(), built.octree.grid.resolution, built.octree.levels(),
                (unsigned long long)built.leaf_voxels, format_bytes(double(mem.total_bytes)).c_str(),
                double(mem.total_bytes) / double(built.leaf_voxels), total.mark("total"));
    return 0;
  };
}

}  // namespace voxcast::cli
