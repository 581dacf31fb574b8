#pragma once
// The .vxc scene container: magic "VOXCAST\0", u32 version, u32 section count,
// then a section table of {u32 fourcc, u32 reserved, u64 offset, u64 size,
// u64 xxh64(section bytes)}, then the sections, each 8-byte aligned. A 'META'
// section (JSON) describes the scene; structure sections hold the data.
// Writes go to a temporary file renamed into place; reads verify sizes,
// offsets, hashes and then the structure itself before anything renders.
#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "voxcast/dag.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/structure.hpp"

namespace voxcast {

inline constexpr uint32_t kSceneFormatVersion = 1;

constexpr uint32_t fourcc(const char (&s)[5]) {
  return uint32_t(uint8_t(s[0])) | uint32_t(uint8_t(s[1])) << 8 | uint32_t(uint8_t(s[2])) << 16 |
         uint32_t(uint8_t(s[3])) << 24;
}

/// The four characters of a section id ('?' for unprintable bytes).
std::string fourcc_name(uint32_t fourcc);

/// Generic section container.
class Container {
 public:
  void add(uint32_t fourcc, std::vector<uint8_t> bytes);
  bool has(uint32_t fourcc) const { return sections_.count(fourcc) != 0; }
  /// Throws voxcast::Error when missing.
  const std::vector<uint8_t>& get(uint32_t fourcc) const;
  std::vector<uint32_t> section_ids() const;

  std::vector<uint8_t> serialize() const;
  static Container parse(const uint8_t* data, size_t size);  // throws voxcast::Error
  void write(const std::filesystem::path& path) const;       // atomic
  static Container read(const std::filesystem::path& path);  // throws voxcast::Error

 private:
  std::map<uint32_t, std::vector<uint8_t>> sections_;
};

/// What a scene file says about how it was made (shown by `voxcast info`).
struct SceneInfo {
  std::string source;        // input mesh file name
  std::string voxelization;  // "conservative" / "6-separating"
  uint64_t source_triangles = 0;
  uint64_t leaf_voxels = 0;
};

void save_esvo_scene(const std::filesystem::path& path, const esvo::EsvoOctree& octree,
                     const SceneInfo& info);
/// Loads and fully validates; throws voxcast::Error with a one-line reason.
esvo::EsvoOctree load_esvo_scene(const std::filesystem::path& path, SceneInfo* info = nullptr);
/// load_esvo_scene() without the file: interprets and fully validates the
/// META and ESVO sections of an already parsed container (e.g. from memory).
esvo::EsvoOctree esvo_scene_from_container(const Container& container, SceneInfo* info = nullptr);

// ---- Sparse voxel DAG scenes (sections META + 'SDAG' [+ 'DATR'], layout in
// src/dag/scene.cpp and dag.hpp) and the format dispatch. ----

/// The META "format" string ("esvo", "dag") of a parsed container.
std::string scene_format(const Container& container);
void save_dag_scene(const std::filesystem::path& path, const dag::SparseVoxelDag& dag,
                    const SceneInfo& info);
/// Loads and fully validates (SparseVoxelDag::finalize); throws voxcast::Error.
dag::SparseVoxelDag load_dag_scene(const std::filesystem::path& path, SceneInfo* info = nullptr);
dag::SparseVoxelDag dag_scene_from_container(const Container& container, SceneInfo* info = nullptr);

/// Any scene file, loaded and validated, as the renderer's interface.
struct LoadedScene {
  std::string format;                    // META "format"
  std::unique_ptr<Structure> structure;  // EsvoStructure or DagStructure
  Aabb occupied;                         // occupied bounds for automatic cameras
  SceneInfo info;
  std::vector<uint32_t> sections;  // fourccs of the file's sections, ascending
};
/// Every subcommand reads scenes through this (one validator: a file is
/// accepted by all of them or refused by all with the same one-line error,
/// which names the file).
LoadedScene load_scene(const std::filesystem::path& path);
/// The same from an already parsed container (e.g. bytes in memory).
LoadedScene load_scene(const Container& container);

}  // namespace voxcast
