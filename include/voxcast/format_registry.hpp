#pragma once
// The scene format registry: one entry per stored structure (ESVO octree,
// sparse voxel DAG, ...) saying how to build it from voxels, write it into a
// container, load it back and describe it for `voxcast info`. The registry,
// like the container (container.hpp), knows no structure: each structure
// module registers its own entry (src/esvo/format.cpp, src/dag/format.cpp)
// and register_builtin_formats() (src/formats/builtin.cpp, outside src/io)
// is the one list that calls them. The CLI and load_scene() find formats
// here by name (the META "format" string, `build --format`).
//
// Adding a structure: write src/<module>/format.cpp with a
// `void register_format(FormatRegistry&)` that adds its SceneFormat, and
// call it from src/formats/builtin.cpp. Nothing else names the structure.
#include <cstdint>
#include <functional>
#include <string>
#include <string_view>
#include <vector>

#include "voxcast/container.hpp"
#include "voxcast/math.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/scene_file.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast {

/// What every format's build understands (a format ignores what it has no
/// use for, e.g. attributes for a geometry-only structure).
/// Whether colors and normals are stored is decided by the voxel set (built
/// with or without attributes, see SceneFormat::attributes_optional).
struct FormatBuildOptions {
  bool compress_attributes = false;  // esvo §5.5 blocks instead of raw 8 B/voxel
  /// Contours and variable depth (esvo §5.2, §7.1-7.3), for a format with
  /// SceneFormat::contours; the others are never handed `contours.enabled`.
  struct Contours {
    bool enabled = false;
    int max_level = 0;          // deepest level (0: the grid's levels)
    double geometry_error = 0;  // <= 0: unset (full depth)
    double color_error = -1;    // < 0: unset
    double normal_error = -1;   // < 0: unset
  } contours;
  /// The mesh the voxel set was voxelized from, when there is one (null for a
  /// voxel file): contours are shaped by its triangles (esvo §5.2).
  const Mesh* mesh = nullptr;
  /// The caller's progress bar for the build (null: none); the format
  /// re-plans its phases.
  Progress* progress = nullptr;
};

/// What a build from a mesh (SceneFormat::build_from_mesh) is handed besides
/// the mesh and its grid.
struct MeshBuildRequest {
  VoxelizationMode mode = VoxelizationMode::Conservative;
  /// Colors and normals; false only for a format with attributes_optional.
  bool attributes = true;
  FormatBuildOptions options;
  uint64_t memory_budget = 0;  // bytes the build may hold (0: 90% of free memory)
  /// The caller's estimate of the peak of voxelizing in core and building
  /// from the voxel set (mesh included): the format's memory-bounded build
  /// is due when it exceeds memory_budget.
  uint64_t in_core_estimate = 0;
  bool out_of_core = false;  // the memory-bounded build was asked for (`--out-of-core`)
  uint32_t cell_size = 0;    // its sub-volume side in voxels (0: from the budget)
};

/// One statistic of a build, for `voxcast build -v` ("cells": "194").
struct BuildStat {
  std::string key, value;
};

/// What SceneFormat::build_from_mesh produced. No structure: the format has
/// no build of its own for this request, and the caller voxelizes in core and
/// calls SceneFormat::build.
struct MeshBuild {
  LoadedStructure structure;
  uint64_t leaf_voxels = 0;  // the voxels the build consumed (SceneInfo::leaf_voxels)
  double voxelize_seconds = 0, build_seconds = 0;
  bool out_of_core = false;  // sub-volume by sub-volume, within the budget
  std::string stage;         // the stage's name for the CLI's timings ("out-of-core DAG build")
  std::string report;        // printed after `voxcast build` as it is (each line ends in '\n')
  std::vector<BuildStat> stats;
};

/// How `voxcast info` writes sizes (the CLI's units), handed to describe().
struct DescribeStyle {
  std::function<std::string(double bytes)> bytes = [](double b) {
    return std::to_string(uint64_t(b)) + " B";
  };
};

/// A format's part of `voxcast info`. The CLI prints the facts every scene
/// shares (file, sections, source, grid) around these.
struct SceneDescription {
  GridTransform grid;
  std::string json;     // a JSON object of the format's own fields, merged into `info --json`
  std::string summary;  // lines printed after "sections" (each ends in '\n'): "structure ..."
  std::string voxels;   // the value of the "voxels" line
  std::string details;  // printed after the shared lines: per-level and memory tables
};

/// What a streamed structure's loading did (SceneFormat::stream_counters):
/// counts since it was opened, sizes now.
struct StreamCounters {
  uint64_t loaded = 0, unloaded = 0, refused = 0;  // parts (ESVO: slices)
  uint64_t pending = 0;                            // requests the last pass left unserved
  uint64_t bytes_read = 0;                         // from the file
  uint64_t resident_parts = 0;                     // now
  uint64_t resident_bytes = 0;                     // now (what the budget counts)
  uint64_t peak_resident_bytes = 0;
};

struct SceneFormat {
  std::string name;         // META "format" and `voxcast build --format`
  std::string description;  // one line, for --help
  std::vector<std::string> extensions = {".vxc"};
  /// The format can store geometry without colors and normals (`build
  /// --no-attributes`); otherwise its build needs a voxel set with attributes.
  bool attributes_optional = false;
  /// The format stores contours (FormatBuildOptions::contours: `build
  /// --contours` and the variable-depth options).
  bool contours = false;
  /// The fewest grid levels its build takes (a grid of 2^min_levels voxels
  /// per axis; `build --resolution` below it is a usage error).
  int min_levels = 0;
  /// Voxels -> structure (the in-core build).
  std::function<LoadedStructure(const VoxelSet&, const FormatBuildOptions&)> build;
  /// Optional: the format's own build from the mesh (memory-bounded builds
  /// that voxelize sub-volume by sub-volume). Returns a MeshBuild without a
  /// structure when the request is the in-core one (voxelize, then build).
  std::function<MeshBuild(const Mesh&, const GridTransform&, const MeshBuildRequest&)>
      build_from_mesh;
  /// Whether build_from_mesh can bound its memory for these options (`build
  /// --out-of-core`, `--cell-size`); null: never.
  std::function<bool(const FormatBuildOptions&)> bounded_mesh_build;
  /// Writes META (with "format": name) and the data sections. The structure
  /// is one this format built or loaded.
  std::function<void(ContainerWriter&, const Structure&, const SceneInfo&)> save;
  /// Reads and fully validates a container whose META names this format;
  /// throws voxcast::Error with a one-line reason.
  std::function<LoadedStructure(const ContainerReader&, SceneInfo*)> load;
  /// Optional: loads a scene file by its path, for a format whose saved state
  /// is more than the container (brickmap worlds: the container and the edit
  /// journal beside it, brickmap_file.hpp). load_scene(path) calls it instead
  /// of `load` when set; it validates as `load` does.
  std::function<LoadedStructure(const std::filesystem::path&, const ContainerReader&, SceneInfo*)>
      load_file;
  /// Optional, for a format whose files are not containers but a file type
  /// of their own (ESVO slice files, esvo_slices.hpp): whether the file at
  /// the path is one (by its magic; cheap). load_scene(path) asks every
  /// format's sniff before it reads the file as a container, and opens a
  /// recognized file with open_file (full validation, one-line errors). Such
  /// a format has no build, save or load: its files are written by its own
  /// builder (`build --slices`), and `build --format`, bench and the Python
  /// build skip it (builds() is false).
  std::function<bool(const std::filesystem::path&)> sniff;
  std::function<LoadedStructure(const std::filesystem::path&, const SceneLoadOptions&, SceneInfo*)>
      open_file;
  /// Optional, for a streamed structure: its streaming counters now
  /// (`render --budget --frames` prints their per-frame differences).
  std::function<StreamCounters(const Structure&)> stream_counters;
  bool builds() const { return bool(build); }
  /// Bounds of the occupied voxels (automatic cameras).
  std::function<Aabb(const Structure&)> occupied;
  std::function<SceneDescription(const Structure&, const DescribeStyle&)> describe;
  /// Optional: bytes the structure holds in memory (`voxcast bench`'s
  /// memory lines).
  std::function<uint64_t(const Structure&)> memory_bytes;
  /// One line after `voxcast build`: size and what it costs per voxel.
  /// (SceneInfo::leaf_voxels: the voxels the build consumed.)
  std::function<std::string(const Structure&, const SceneInfo&, const DescribeStyle&)>
      build_summary;
};

/// Formats by name. Filled once at start-up (register_builtin_formats), then
/// only read: lookups from several threads are safe, registration is not.
class FormatRegistry {
 public:
  /// Throws voxcast::Error for a duplicate name or a missing function (a
  /// container format needs build, save, load and build_summary, a format
  /// of its own files sniff and open_file; both occupied and describe).
  void add(SceneFormat format);
  const SceneFormat* find(std::string_view name) const;
  /// The format whose sniff recognizes the file at `path` (a file type of
  /// its own, not a container), or null.
  const SceneFormat* recognize(const std::filesystem::path& path) const;
  /// Throws voxcast::Error "unknown scene format 'X' (known: a, b)".
  const SceneFormat& get(std::string_view name) const;
  std::vector<std::string> names() const;  // in registration order
  const std::vector<SceneFormat>& formats() const { return formats_; }

 private:
  std::vector<SceneFormat> formats_;
};

/// The process-wide registry load_scene() and the CLI use.
FormatRegistry& format_registry();

/// Registers every built-in format with format_registry() (once; later calls
/// do nothing). Lives outside src/io, in src/formats/builtin.cpp: the one list
/// of structures. Programs call it before loading or saving scenes.
void register_builtin_formats();

/// `structure` (of format `format`) into a container at `path`, streamed to
/// a temporary file and renamed into place.
void save_scene(const std::filesystem::path& path, const std::string& format,
                const Structure& structure, const SceneInfo& info);

}  // namespace voxcast
