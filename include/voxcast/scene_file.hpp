#pragma once
// Scene files (.vxc): a container (container.hpp) whose 'META' section
// (JSON) names the scene's format ("format": "esvo", "dag", ...) and whose
// other sections hold that format's data. Which formats exist is the format
// registry's business (format_registry.hpp): this header, like the
// container, names no structure. Writes go to a temporary file renamed into
// place; reads verify the directory, every chunk hash and then the
// structure itself before anything renders.
#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "voxcast/container.hpp"
#include "voxcast/math.hpp"
#include "voxcast/structure.hpp"

namespace voxcast {

/// What the scene loader hands out: the one place naming the structure base
/// class of loaded scenes (structure.hpp; its queries by capability).
using LoadedStructure = std::unique_ptr<Structure>;

/// What a scene file says about how it was made (shown by `voxcast info`).
struct SceneInfo {
  std::string source;        // input mesh file name
  std::string voxelization;  // "conservative" / "6-separating"
  uint64_t source_triangles = 0;
  uint64_t leaf_voxels = 0;
};

/// The META "format" string of a container ("corrupt scene: ..." when META
/// is missing, not JSON or has no string "format").
std::string scene_format(const ContainerReader& reader);
std::string scene_format(const Container& container);

/// Any scene file, loaded and validated, as the renderer's interface.
struct LoadedScene {
  std::string format;         // META "format"
  LoadedStructure structure;  // the format's structure (format_registry.hpp)
  Aabb occupied;              // occupied bounds for automatic cameras
  SceneInfo info;
  std::vector<uint32_t> sections;  // fourccs of the file's sections, ascending
};
/// How load_scene(path) opens a streamed structure (a format with
/// SceneFormat::open_file: ESVO slice files, esvo_slices.hpp). Container
/// formats ignore it.
struct SceneLoadOptions {
  /// Bytes the resident data may occupy (0: unlimited).
  uint64_t stream_budget = 0;
  /// true: every part is loaded and verified at open when it fits the budget
  /// (the in-core equivalent; a damaged part refuses the file, as every
  /// container format's loader does); a scene that does not fit opens with
  /// its root resident and streams. false: the root only, the rest is loaded
  /// on request between passes and a damaged part is refused on its own.
  bool load_all = true;
  /// The bar of the load (tests inject one with a fake terminal); null: a
  /// "load scene" bar on the terminal. Re-planned into the read (bytes of the
  /// file read and hashed, with the format's validation) and bounds phases.
  Progress* progress = nullptr;
};

/// Every subcommand reads scenes through this (one validator: a file is
/// accepted by all of them or refused by all with the same one-line error,
/// which names the file). The format comes from META through the registry,
/// or, for a file that is not a container, from the format whose
/// SceneFormat::sniff recognizes it; every chunk of a container is
/// verified, also those the format did not read.
LoadedScene load_scene(const std::filesystem::path& path, const SceneLoadOptions& options = {});
/// The same from an open reader or an already parsed container.
LoadedScene load_scene(const ContainerReader& reader);
LoadedScene load_scene(const Container& container);

}  // namespace voxcast
