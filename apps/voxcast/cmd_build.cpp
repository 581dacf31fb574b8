// voxcast build MESH -o SCENE: voxelize a mesh and store it as a scene of any
// registered format (format_registry.hpp).
#include <cmath>
#include <cstdio>
#include <filesystem>

#include "build_slices.hpp"
#include "cli_io.hpp"
#include "commands.hpp"
#include "pipeline.hpp"
#include "voxcast/error.hpp"
#include "voxcast/format_registry.hpp"
#include "voxcast/progress.hpp"
#include "voxcast/scene_file.hpp"
#include "voxcast/system.hpp"
#include "voxcast/voxel_io.hpp"

namespace voxcast::cli {

namespace {
struct BuildArgs {
  std::string input, output, voxelization = "conservative", memory_budget;
  std::string attributes = "raw";
  std::string format;  // the first registered format unless given
  std::string fill = "surface";
  uint32_t resolution = 1024;
  double voxel_size = 0;
  int threads = 0;
  bool verbose = false;
  bool contours = false;
  int max_level = 0;
  double geometry_error = 0, color_error = 0, normal_error = 0;
  bool out_of_core = false, no_attributes = false;
  uint32_t cell_size = 0;
  bool slices = false;  // esvo §7: write a slice file (.vxs)
  std::string slice_size = "1M";
  std::string displacement;  // esvo §7.4: a height map (PNG/PFM)
  double displacement_scale = 0;
  CLI::Option* displacement_scale_opt = nullptr;
  // Presence, not a sentinel value: "--voxel-size nan" must be refused, not
  // taken for "not given".
  CLI::Option *voxel_size_opt = nullptr, *max_level_opt = nullptr, *geometry_error_opt = nullptr,
              *color_error_opt = nullptr, *normal_error_opt = nullptr, *cell_size_opt = nullptr;
};
// The registered formats `build` writes that `pred` holds for: "a, b"
// (formats of their own file type, such as slice files, are written by
// other options).
template <class Pred>
std::string names_of(const Pred& pred) {
  std::string n;
  for (const SceneFormat& f : format_registry().formats())
    if (f.builds() && pred(f)) n += (n.empty() ? "" : ", ") + f.name;
  return n;
}

// What a memory-bounded build applies to: "--format dag or --contours".
std::string bounded_builds() {
  FormatBuildOptions plain, contoured;
  contoured.contours.enabled = true;
  auto bounded = [](const SceneFormat& f, const FormatBuildOptions& o) {
    return f.bounded_mesh_build && f.bounded_mesh_build(o);
  };
  std::string n = names_of([&](const SceneFormat& f) { return bounded(f, plain); });
  if (!n.empty()) n = "--format " + n;
  if (!names_of([&](const SceneFormat& f) { return f.contours && bounded(f, contoured); }).empty())
    n += (n.empty() ? "" : " or ") + std::string("--contours");
  return n;
}
}  // namespace

Runner add_build(CLI::App& app) {
  auto args = std::make_shared<BuildArgs>();
  CLI::App* cmd = app.add_subcommand(
      "build", "Voxelize a triangle mesh into a scene file (ESVO octree or sparse voxel DAG)");
  cmd->add_option("MESH", args->input,
                  "Input mesh (OBJ, PLY, OFF, STL, glTF/GLB, FBX, DAE, ...) or voxel file "
                  "(.vox, .binvox, .vdb: built as it is)")
      ->required();
  cmd->add_option("-o,--output", args->output, "Output scene file (.vxc)")->required();
  auto* res =
      cmd->add_option(
             "--resolution", args->resolution,
             "Voxels per axis: a power of two, 1..1048576 (esvo from 2, dag from 4; default 1024)")
          // Unsigned options would take "-1" as 2^32-1.
          ->check(not_negative());
  args->voxel_size_opt =
      cmd->add_option("--voxel-size", args->voxel_size,
                      "Largest voxel size in world units (resolution rounded up to a power of two)")
          ->excludes(res);
  cmd->add_option("--voxelization", args->voxelization, "conservative | 6-separating")
      ->capture_default_str();
  cmd->add_option("--fill", args->fill,
                  "surface | solid (also the interior of closed meshes; parity per column, "
                  "winding number where the mesh is not watertight)")
      ->capture_default_str();
  cmd->add_option("--attributes", args->attributes,
                  "Color/normal storage: raw (8 B/voxel) | compressed (esvo §5.5 blocks, lossy; "
                  "dag: 16 Morton-order voxels per 24 B block; --slices: one block per two "
                  "descriptors of a slice)")
      ->capture_default_str();
  if (!format_registry().formats().empty()) args->format = format_registry().formats().front().name;
  std::string formats;
  for (const SceneFormat& f : format_registry().formats())
    if (f.builds())  // not the file types of their own (slice files: --slices)
      formats += (formats.empty() ? "" : " | ") + f.name + " (" + f.description + ")";
  cmd->add_option("--format", args->format, "Structure: " + formats)->capture_default_str();
  cmd->add_option("--memory-budget", args->memory_budget,
                  "Refuse builds estimated to need more (e.g. 8G; default 90% of free memory)");
  cmd->add_flag("--out-of-core", args->out_of_core,
                "DAG or --contours: build sub-volume by sub-volume within --memory-budget "
                "(svdag section 3, esvo 7.1; automatic when the in-core estimate exceeds the "
                "budget)");
  args->cell_size_opt =
      cmd->add_option(
             "--cell-size", args->cell_size,
             "Out-of-core: sub-volume side in voxels (power of two; default from the budget)")
          ->check(not_negative());
  cmd->add_flag("--no-attributes", args->no_attributes,
                "DAG: geometry only (no colors/normals; needed at very high resolutions)");
  cmd->add_option("--threads", args->threads, "Worker threads (0 = all cores)");
  cmd->add_flag(
      "--contours", args->contours,
      "Build contours (esvo 5.2, 7.2): voxels shaped by slabs; enables the options below");
  args->max_level_opt =
      cmd->add_option("--max-level", args->max_level,
                      "With --contours: deepest octree level (default: the grid's levels)");
  args->geometry_error_opt = cmd->add_option(
      "--geometry-error", args->geometry_error,
      "With --contours: variable depth; refine where the contoured shape is farther than "
      "this from the surface, in finest-level voxels (esvo 7.1)");
  args->color_error_opt = cmd->add_option(
      "--color-error", args->color_error,
      "With --contours: variable depth; refine where a voxel's stored color, as decoded "
      "(after --attributes compression), differs from a finest-level voxel's below it by "
      "more (8-bit sRGB, 0-255) (esvo 7.3)");
  args->normal_error_opt =
      cmd->add_option("--normal-error", args->normal_error,
                      "With --contours: variable depth; the same for normals (degrees)");
  cmd->add_flag("-v,--verbose", args->verbose, "Print timings per stage");
  cmd->add_flag("--slices", args->slices,
                "Write the ESVO as a slice file (-o X.vxs) for streaming (esvo section 7)");
  cmd->add_option("--slice-size", args->slice_size, "With --slices: target bytes per slice")
      ->capture_default_str();
  cmd->add_option("--displacement", args->displacement,
                  "Height map (.png gray, or .pfm, values in [0,1]) displacing the mesh along its "
                  "normals by the mesh's texture coordinates (esvo paper section 7.4)");
  args->displacement_scale_opt = cmd->add_option(
      "--displacement-scale", args->displacement_scale,
      "World units of displacement at height 1 (negative: inwards); without --displacement "
      "the height map is the mesh material's height/displacement texture");
  return [args]() {
    ThreadLimit limit(args->threads);
    // Every option value first (usage errors, exit 2), then the files.
    BuildSettings s;
    s.mesh_path = args->input;
    set_voxelization_options(s, args->resolution, args->voxel_size_opt->count() > 0,
                             args->voxel_size, args->voxelization, args->fill);
    s.compress_attributes = parse_compressed_attributes(args->attributes);
    if (!args->memory_budget.empty()) s.memory_budget = parse_memory_budget(args->memory_budget);
    s.verbose = args->verbose;
    const SceneFormat* format = format_registry().find(args->format);
    if (format && !format->builds())
      throw UsageError("--format: " + format->name + " files are written by --slices");
    if (!format) {
      throw UsageError("--format: '" + printable(args->format) + "' is not a scene format (" +
                       names_of([](const SceneFormat&) { return true; }) + ")");
    }
    s.format = format->name;
    if (!args->voxel_size_opt->count() && args->resolution < (1u << format->min_levels))
      throw UsageError("--resolution: " + format->name + " needs at least " +
                       std::to_string(1u << format->min_levels));
    const bool variable = args->max_level_opt->count() || args->geometry_error_opt->count() ||
                          args->color_error_opt->count() || args->normal_error_opt->count();
    if (variable && !args->contours) throw UsageError("--max-level and --*-error need --contours");
    if (args->contours) {
      if (!format->contours)
        throw UsageError("--contours applies to --format " +
                         names_of([](const SceneFormat& f) { return f.contours; }) + " only");
      if (args->max_level_opt->count()) require_range("--max-level", args->max_level, 0, 20);
      auto tolerance = [](CLI::Option* opt, double v, const char* name, double lo, double hi) {
        if (!opt->count()) return -1.0;
        require_range(name, v, lo, hi);
        return v;
      };
      // 0 would refine everywhere: the full-depth build, asked for by
      // leaving the option out.
      const double ge =
          tolerance(args->geometry_error_opt, args->geometry_error, "--geometry-error", 1e-6, 1e6);
      s.contours = true;
      s.max_level = args->max_level;
      s.geometry_error = ge > 0 ? ge : 0;
      s.color_error = tolerance(args->color_error_opt, args->color_error, "--color-error", 0, 255);
      s.normal_error =
          tolerance(args->normal_error_opt, args->normal_error, "--normal-error", 0, 180);
    }
    if (s.compress_attributes && args->no_attributes)
      throw UsageError("--attributes compressed and --no-attributes exclude each other");
    if (!format->attributes_optional && args->no_attributes)
      throw UsageError("--no-attributes applies to formats that can store geometry only (" +
                       names_of([](const SceneFormat& f) { return f.attributes_optional; }) + ")");
    // Whether the format's mesh build can bound its memory may depend on the
    // options (a format may have a cell build only with contours).
    if (!args->slices && (args->out_of_core || args->cell_size_opt->count()) &&
        !(format->bounded_mesh_build &&
          format->bounded_mesh_build(format_build_options(s, nullptr))))
      throw UsageError("--out-of-core and --cell-size apply to " + bounded_builds());
    // The grid decides the upper bound (the library checks it against the
    // resolution); a non-power of two or a cell below 4^3 is never valid.
    if (args->cell_size_opt->count())
      require_power_of_two("--cell-size", args->cell_size, 4, uint64_t(1) << 20);
    s.out_of_core = args->out_of_core || args->cell_size != 0;
    if (s.fill_solid && (s.contours || s.out_of_core))
      throw UsageError("--fill solid applies to in-core builds without --contours");
    if (is_voxel_input(args->input) && (s.contours || s.fill_solid || s.out_of_core))
      throw UsageError(
          "a voxel file input is built as it is: no --contours, --fill or --out-of-core");
    s.cell_size = args->cell_size;
    s.dag_attributes = !args->no_attributes;
    if (!args->displacement.empty() || args->displacement_scale_opt->count()) {
      if (!args->displacement_scale_opt->count())
        throw UsageError("--displacement needs --displacement-scale S");
      require_range("--displacement-scale", args->displacement_scale, -1e30, 1e30);
      // With --slices the top-down builder bounds the memory (its cells
      // from --memory-budget's default or --cell-size).
      if (s.contours || (s.out_of_core && !args->slices) || s.fill_solid ||
          is_voxel_input(args->input))
        throw UsageError(
            "--displacement applies to mesh builds in core or with --slices: no --contours, "
            "--out-of-core, --cell-size (without --slices), --fill solid or voxel file input");
      s.displacement = args->displacement;
      s.displacement_scale = args->displacement_scale;
      s.displacement_from_mesh = args->displacement.empty();
    }
    uint64_t slice_bytes = 0;
    bool slice_compressed = false;
    if (args->slices) {
      check_slice_settings(s);
      try {
        slice_bytes = parse_byte_size(args->slice_size.c_str());
      } catch (const Error& e) {
        throw UsageError(std::string("--slice-size: ") + e.what());
      }
      // A slice file compresses its own slices (esvo_slices.hpp): an
      // in-core build to be sliced keeps raw attributes.
      slice_compressed = s.compress_attributes;
      s.compress_attributes = false;
    }
    OutputSet outputs(s.displacement.empty()
                          ? std::vector<std::string>{args->input}
                          : std::vector<std::string>{args->input, s.displacement});
    if (args->slices)
      outputs.add("-o", args->output, {".vxs"});
    else
      outputs.add("-o", args->output, {".vxc"});
    require_regular_input(args->input, is_voxel_input(args->input) ? "voxel file" : "mesh");
    if (!s.displacement.empty()) require_regular_input(s.displacement, "displacement map");
    StageTimer total(false);
    if (args->slices && !s.fill_solid && !is_voxel_input(args->input)) {
      // The top-down slice builder (esvo §7.1), which never holds the octree
      // (with contours and every variable-depth tolerance, and displaced);
      // solid fill and voxel files slice the in-core build below.
      std::string summary;
      outputs.write(args->output, [&](const std::filesystem::path& to) {
        summary = build_slices_top_down(s, slice_bytes, slice_compressed, to);
      });
      outputs.commit();
      std::printf("%s: %s, %.2f s\n", printable(args->output).c_str(), summary.c_str(),
                  total.mark("total"));
      return 0;
    }
    BuiltScene built = build_scene(s);
    StageTimer timer(args->verbose);
    SceneInfo info;
    info.source = std::filesystem::path(args->input).filename().string();
    // A voxel file is not voxelized here: its format names the source.
    info.voxelization = is_voxel_input(args->input) ? "voxel file"
                        : s.fill_solid ? std::string(voxelization_name(s.mode)) + ", solid"
                                       : voxelization_name(s.mode);
    info.source_triangles = built.mesh.triangle_count();
    info.leaf_voxels = built.leaf_voxels;
    outputs.write(args->output, [&](const std::filesystem::path& to) {
      if (args->slices)
        write_slice_file(*built.structure, slice_bytes, slice_compressed, to);
      else
        save_scene(to, s.format, *built.structure, info);
    });
    outputs.commit();
    timer.mark("write scene");
    // The format's memory-bounded build reports itself (MeshBuild).
    std::fputs(built.build_report.c_str(), stdout);
    if (args->verbose)
      for (const BuildStat& st : built.build_stats)
        std::fprintf(stderr, "build: %s: %s\n", printable(st.key).c_str(),
                     printable(st.value).c_str());
    if (args->slices) {
      std::printf("%s: %s, %.2f s\n", printable(args->output).c_str(),
                  describe_slice_file(args->output, slice_bytes).c_str(), total.mark("total"));
      return 0;
    }
    DescribeStyle style;
    style.bytes = [](double b) { return format_bytes(b); };
    std::printf("%s: %s, %.2f s\n", printable(args->output).c_str(),
                format->build_summary(*built.structure, info, style).c_str(), total.mark("total"));
    return 0;
  };
}

}  // namespace voxcast::cli
