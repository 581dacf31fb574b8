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
/// Every subcommand reads scenes through this (one validator: a file is
/// accepted by all of them or refused by all with the same one-line error,
/// which names the file). The format comes from META through the registry;
/// every chunk of the file is verified, also those the format did not read.
LoadedScene load_scene(const std::filesystem::path& path);
/// The same from an open reader or an already parsed container.
LoadedScene load_scene(const ContainerReader& reader);
LoadedScene load_scene(const Container& container);

}  // namespace voxcast
