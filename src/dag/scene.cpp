// DAG scene files and the format-dispatching scene loader.
//
// A DAG scene is a Container (scene_file.hpp) with
//   'META' UTF-8 JSON: {"format": "dag", "grid": {"origin": [x,y,z],
//          "voxel_size": s, "resolution": N, "levels": L}, "attributes": bool,
//          "source": ..., "voxelization": ..., "source_triangles": ...,
//          "leaf_voxels": V}
//   'SDAG' the DAG words (little-endian u32, layout in dag.hpp)
//   'DATR' only if "attributes" and not compressed: V pairs of u32 (ABGR
//          color, cube-face normal), leaf voxels in Morton order (dag.hpp
//          "Attributes").
//   'DATC' only if "attributes" and META "attribute_format": "compressed":
//          ceil(V / 16) esvo §5.5 blocks of 6 u32 (dag.hpp "Compressed
//          attributes"). The key is written only for compressed scenes, so raw
//          scenes are unchanged and older files (no key = raw) still load.
// The voxel index (voxel_prefix) is derived at load time, never stored.
// Loading checks every META field and then SparseVoxelDag::finalize()
// validates the words (bounds, forward-only pointers, masks, tiling, depth),
// so a loaded DAG is safe to traverse.
#include <bit>
#include <cmath>
#include <cstring>
#include <nlohmann/json.hpp>
#include <string>

#include "io/meta_json.hpp"
#include "voxcast/brickmap.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/scene_file.hpp"

namespace voxcast {
namespace {

constexpr uint32_t kDagSection = fourcc("SDAG");
constexpr uint32_t kDagAttributes = fourcc("DATR");
constexpr uint32_t kDagCompressedAttributes = fourcc("DATC");

std::vector<uint32_t> to_words(const std::vector<uint8_t>& bytes) {
  std::vector<uint32_t> w(bytes.size() / 4);
  if (!w.empty()) std::memcpy(w.data(), bytes.data(), w.size() * 4);
  return w;
}

}  // namespace

std::string scene_format(const Container& c) {
  const nlohmann::json meta = meta::parse(c);
  try {
    return meta::get_string(meta, "format");
  } catch (const nlohmann::json::exception& e) {
    throw Error(std::string("corrupt scene: META section: ") + e.what());
  }
}

void save_dag_scene(const std::filesystem::path& path, const dag::SparseVoxelDag& dag,
                    const SceneInfo& info) {
  nlohmann::json meta = meta::info_to_json(info);
  meta.update({
      {"format", "dag"},
      {"grid", meta::grid_to_json(dag.grid)},
      {"attributes", dag.has_attributes()},
      {"leaf_voxels", dag.leaf_voxels},
  });
  if (dag.compressed_attributes()) meta["attribute_format"] = "compressed";
  static_assert(std::endian::native == std::endian::little, "scene files are little-endian");
  Container c;
  c.add(meta::kSection, meta::dump(meta));
  std::vector<uint8_t> words(dag.words.size() * 4);
  if (!words.empty()) std::memcpy(words.data(), dag.words.data(), words.size());
  c.add(kDagSection, std::move(words));
  if (dag.compressed_attributes()) {
    std::vector<uint8_t> blocks(dag.attribute_blocks.size() * 4);
    std::memcpy(blocks.data(), dag.attribute_blocks.data(), blocks.size());
    c.add(kDagCompressedAttributes, std::move(blocks));
  } else if (dag.has_attributes()) {
    std::vector<uint8_t> attr(dag.colors.size() * 8);
    for (size_t i = 0; i < dag.colors.size(); ++i) {
      std::memcpy(&attr[8 * i], &dag.colors[i], 4);
      std::memcpy(&attr[8 * i + 4], &dag.normals[i], 4);
    }
    c.add(kDagAttributes, std::move(attr));
  }
  c.write(path);
}

dag::SparseVoxelDag load_dag_scene(const std::filesystem::path& path, SceneInfo* info) {
  return dag_scene_from_container(Container::read(path), info);
}

dag::SparseVoxelDag dag_scene_from_container(const Container& c, SceneInfo* info) {
  const nlohmann::json meta = meta::parse(c);
  dag::SparseVoxelDag dag;
  SceneInfo si;
  bool attributes = false, compressed = false;
  try {
    using namespace meta;
    if (get_string(meta, "format") != "dag") bad("format is not 'dag'");
    dag.grid = grid_from_json(meta, 2);
    const nlohmann::json& a = field(meta, "attributes");
    if (!a.is_boolean()) bad("'attributes' is not a boolean");
    attributes = a.get<bool>();
    if (meta.contains("attribute_format")) {
      const std::string f = get_string(meta, "attribute_format");
      if (f != "raw" && f != "compressed") bad("'attribute_format' is not raw or compressed");
      compressed = f == "compressed";
      if (compressed && !attributes) bad("'attribute_format' is compressed without attributes");
    }
    info_from_json(meta, &si);
    // 64-bit voxel indices (dag.hpp): at most every voxel of a 2^20 grid.
    // Files from before 64-bit indices (< 2^32 voxels) load unchanged.
    si.leaf_voxels = get_uint(meta, "leaf_voxels", 1, uint64_t(1) << (3 * kMaxGridLevels));
  } catch (const nlohmann::json::exception& e) {
    throw Error(std::string("corrupt scene: META section: ") + e.what());
  }
  const std::vector<uint8_t>& bytes = c.get(kDagSection);
  if (bytes.size() % 4 != 0 || bytes.size() < 8)
    throw Error("corrupt scene: SDAG section size " + std::to_string(bytes.size()) +
                " is not a whole number of words of at least one node");
  dag.words = to_words(bytes);
  const bool raw = attributes && !compressed;
  if (raw != c.has(kDagAttributes))
    throw Error(raw ? "corrupt scene: META says attributes but there is no DATR section"
                    : "corrupt scene: unexpected DATR section");
  if (compressed != c.has(kDagCompressedAttributes))
    throw Error(compressed ? "corrupt scene: META says compressed attributes but there is no DATC "
                             "section"
                           : "corrupt scene: unexpected DATC section");
  if (compressed) {
    // Size checked against META before finalize() checks it against the DAG.
    const std::vector<uint8_t>& ab = c.get(kDagCompressedAttributes);
    const uint64_t blocks = (si.leaf_voxels + dag::SparseVoxelDag::kCompressedSlots - 1) /
                            dag::SparseVoxelDag::kCompressedSlots;
    const uint64_t expected = blocks * dag::SparseVoxelDag::kCompressedBlockWords * 4;
    if (ab.size() != expected)
      throw Error("corrupt scene: DATC section holds " + std::to_string(ab.size()) +
                  " bytes, expected " + std::to_string(expected) + " (24 per 16 leaf voxels, " +
                  std::to_string(si.leaf_voxels) + " voxels)");
    dag.attribute_blocks = to_words(ab);
  } else if (attributes) {
    const std::vector<uint8_t>& ab = c.get(kDagAttributes);
    if (ab.size() != si.leaf_voxels * 8)
      throw Error("corrupt scene: DATR section holds " + std::to_string(ab.size()) +
                  " bytes, expected 8 per leaf voxel (" + std::to_string(si.leaf_voxels) + ")");
    dag.colors.resize(size_t(si.leaf_voxels));
    dag.normals.resize(size_t(si.leaf_voxels));
    for (size_t i = 0; i < dag.colors.size(); ++i) {
      std::memcpy(&dag.colors[i], &ab[8 * i], 4);
      std::memcpy(&dag.normals[i], &ab[8 * i + 4], 4);
    }
  }
  dag.finalize();  // throws "corrupt DAG: ..."
  if (dag.leaf_voxels != si.leaf_voxels)
    throw Error("corrupt scene: META leaf_voxels " + std::to_string(si.leaf_voxels) +
                " but the DAG holds " + std::to_string(dag.leaf_voxels));
  if (info) *info = std::move(si);
  return dag;
}

LoadedScene load_scene(const std::filesystem::path& path) {
  try {
    return load_scene(Container::read(path));
  } catch (const Error& e) {
    // One line naming the file and what is wrong (the container's own
    // open/read errors already name it).
    const std::string what = e.what(), name = "'" + path.string() + "'";
    if (what.find(name) != std::string::npos) throw;
    throw Error("scene " + name + ": " + what);
  }
}

LoadedScene load_scene(const Container& c) {
  // The one gate between a file and every reader (render, info):
  // the format's full validator, then the walks done here, so every
  // subcommand accepts or refuses exactly the same files.
  const std::string format = scene_format(c);
  LoadedScene out;
  out.format = format;
  out.sections = c.section_ids();
  if (format == "esvo") {
    auto octree = std::make_shared<esvo::EsvoOctree>(esvo_scene_from_container(c, &out.info));
    out.occupied = esvo::occupied_bounds(*octree);
    out.structure = std::make_unique<esvo::EsvoStructure>(std::move(octree));
  } else if (format == "dag") {
    auto d = std::make_shared<dag::SparseVoxelDag>(dag_scene_from_container(c, &out.info));
    out.occupied = dag::occupied_bounds(*d);
    out.structure = std::make_unique<dag::DagStructure>(std::move(d));
  } else if (format == brickmap::kFormatName) {
    auto w = std::make_shared<brickmap::World>(brickmap::load_world(c, &out.info));
    out.occupied = w->occupied_bounds();
    out.structure = brickmap::make_voxel_structure(std::move(w));
  } else {
    throw Error("unknown scene format '" + format + "'");
  }
  return out;
}

}  // namespace voxcast
