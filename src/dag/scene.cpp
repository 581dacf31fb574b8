// DAG scene files and the format-dispatching scene loader.
//
// A DAG scene is a Container (scene_file.hpp) with
//   'META' UTF-8 JSON: {"format": "dag", "grid": {"origin": [x,y,z],
//          "voxel_size": s, "resolution": N, "levels": L}, "attributes": bool,
//          "source": ..., "voxelization": ..., "source_triangles": ...,
//          "leaf_voxels": V}
//   'SDAG' the DAG words (little-endian u32, layout in dag.hpp)
//   'DATR' only if "attributes": V pairs of u32 (ABGR color, cube-face
//          normal), leaf voxels in Morton order (dag.hpp "Attributes").
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
#include "voxcast/error.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/scene_file.hpp"

namespace voxcast {
namespace {

constexpr uint32_t kDagSection = fourcc("SDAG");
constexpr uint32_t kDagAttributes = fourcc("DATR");

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
  static_assert(std::endian::native == std::endian::little, "scene files are little-endian");
  Container c;
  c.add(meta::kSection, meta::dump(meta));
  std::vector<uint8_t> words(dag.words.size() * 4);
  if (!words.empty()) std::memcpy(words.data(), dag.words.data(), words.size());
  c.add(kDagSection, std::move(words));
  if (dag.has_attributes()) {
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
  bool attributes = false;
  try {
    using namespace meta;
    if (get_string(meta, "format") != "dag") bad("format is not 'dag'");
    dag.grid = grid_from_json(meta, 2);
    const nlohmann::json& a = field(meta, "attributes");
    if (!a.is_boolean()) bad("'attributes' is not a boolean");
    attributes = a.get<bool>();
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
  if (attributes != c.has(kDagAttributes))
    throw Error(attributes ? "corrupt scene: META says attributes but there is no DATR section"
                           : "corrupt scene: unexpected DATR section");
  if (attributes) {
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
    const std::string what = e.what();
    if (what.rfind("unknown scene format", 0) == 0)
      throw Error("scene '" + path.string() + "' has an " + what);
    throw;
  }
}

LoadedScene load_scene(const Container& c) {
  const std::string format = scene_format(c);
  LoadedScene out;
  out.format = format;
  if (format == "esvo") {
    auto octree = std::make_shared<esvo::EsvoOctree>(esvo_scene_from_container(c, &out.info));
    out.occupied = esvo::occupied_bounds(*octree);
    out.structure = std::make_unique<esvo::EsvoStructure>(std::move(octree));
  } else if (format == "dag") {
    auto d = std::make_shared<dag::SparseVoxelDag>(dag_scene_from_container(c, &out.info));
    out.occupied = dag::occupied_bounds(*d);
    out.structure = std::make_unique<dag::DagStructure>(std::move(d));
  } else {
    throw Error("unknown scene format '" + format + "'");
  }
  return out;
}

}  // namespace voxcast
