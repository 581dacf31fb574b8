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
#include <string>

#include <nlohmann/json.hpp>

#include "voxcast/esvo_structure.hpp"
#include "voxcast/error.hpp"
#include "voxcast/scene_file.hpp"

namespace voxcast {
namespace {

constexpr uint32_t kMeta = fourcc("META");
constexpr uint32_t kDagSection = fourcc("SDAG");
constexpr uint32_t kDagAttributes = fourcc("DATR");

[[noreturn]] void bad_meta(const std::string& what) {
  throw Error("corrupt scene: META section " + what);
}

const nlohmann::json& field(const nlohmann::json& j, const char* key) {
  if (!j.is_object()) bad_meta("is not a JSON object");
  auto it = j.find(key);
  if (it == j.end()) bad_meta(std::string("has no '") + key + "'");
  return *it;
}

uint64_t get_uint(const nlohmann::json& j, const char* key, uint64_t lo, uint64_t hi) {
  const nlohmann::json& v = field(j, key);
  if (!v.is_number_unsigned() && !(v.is_number_integer() && v.get<int64_t>() >= 0))
    bad_meta(std::string("'") + key + "' is not a non-negative integer");
  const uint64_t x = v.get<uint64_t>();
  if (x < lo || x > hi) bad_meta(std::string("'") + key + "' out of range");
  return x;
}

double get_finite(const nlohmann::json& v, const char* key) {
  if (!v.is_number()) bad_meta(std::string("'") + key + "' is not a number");
  const double x = v.get<double>();
  if (!std::isfinite(x)) bad_meta(std::string("'") + key + "' is not finite");
  return x;
}

std::string get_string(const nlohmann::json& j, const char* key) {
  const nlohmann::json& v = field(j, key);
  if (!v.is_string()) bad_meta(std::string("'") + key + "' is not a string");
  return v.get<std::string>();
}

nlohmann::json parse_meta(const Container& c) {
  const std::vector<uint8_t>& bytes = c.get(kMeta);
  try {
    return nlohmann::json::parse(bytes.begin(), bytes.end());
  } catch (const nlohmann::json::exception& e) {
    throw Error(std::string("corrupt scene: META section is not valid JSON: ") + e.what());
  }
}

std::vector<uint32_t> to_words(const std::vector<uint8_t>& bytes) {
  std::vector<uint32_t> w(bytes.size() / 4);
  if (!w.empty()) std::memcpy(w.data(), bytes.data(), w.size() * 4);
  return w;
}

}  // namespace

std::string scene_format(const Container& c) {
  const nlohmann::json meta = parse_meta(c);
  try {
    return get_string(meta, "format");
  } catch (const nlohmann::json::exception& e) {
    throw Error(std::string("corrupt scene: META section: ") + e.what());
  }
}

void save_dag_scene(const std::filesystem::path& path, const dag::SparseVoxelDag& dag,
                    const SceneInfo& info) {
  const GridTransform& g = dag.grid;
  nlohmann::json meta = {
      {"format", "dag"},
      {"grid",
       {{"origin", {g.origin.x, g.origin.y, g.origin.z}},
        {"voxel_size", g.voxel_size},
        {"resolution", g.resolution},
        {"levels", g.levels}}},
      {"attributes", dag.has_attributes()},
      {"source", info.source},
      {"voxelization", info.voxelization},
      {"source_triangles", info.source_triangles},
      {"leaf_voxels", dag.leaf_voxels},
  };
  const std::string text = meta.dump(2, ' ', false, nlohmann::json::error_handler_t::replace);
  static_assert(std::endian::native == std::endian::little, "scene files are little-endian");
  Container c;
  c.add(kMeta, std::vector<uint8_t>(text.begin(), text.end()));
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
  const nlohmann::json meta = parse_meta(c);
  dag::SparseVoxelDag dag;
  SceneInfo si;
  bool attributes = false;
  try {
    if (get_string(meta, "format") != "dag") bad_meta("format is not 'dag'");
    const nlohmann::json& grid = field(meta, "grid");
    const int levels = int(get_uint(grid, "levels", 2, kMaxGridLevels));
    const uint64_t resolution = get_uint(grid, "resolution", 4, uint64_t(1) << kMaxGridLevels);
    if (resolution != (uint64_t(1) << levels)) bad_meta("resolution is not 2^levels");
    const nlohmann::json& origin = field(grid, "origin");
    if (!origin.is_array() || origin.size() != 3) bad_meta("'origin' is not an array of 3 numbers");
    const double voxel_size = get_finite(field(grid, "voxel_size"), "voxel_size");
    if (!(voxel_size > 0)) bad_meta("'voxel_size' is not positive");
    dag.grid.levels = levels;
    dag.grid.resolution = uint32_t(resolution);
    dag.grid.voxel_size = voxel_size;
    for (int i = 0; i < 3; ++i) {
      const double o = get_finite(origin[size_t(i)], "origin");
      if (!std::isfinite(float(o))) bad_meta("'origin' is out of float range");
      dag.grid.origin[i] = float(o);
    }
    const nlohmann::json& a = field(meta, "attributes");
    if (!a.is_boolean()) bad_meta("'attributes' is not a boolean");
    attributes = a.get<bool>();
    si.source = get_string(meta, "source");
    si.voxelization = get_string(meta, "voxelization");
    si.source_triangles = get_uint(meta, "source_triangles", 0, UINT64_MAX);
    si.leaf_voxels = get_uint(meta, "leaf_voxels", 1, 0xFFFFFFFFull);
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
  const Container c = Container::read(path);
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
    throw Error("scene '" + path.string() + "' has unknown format '" + format + "'");
  }
  return out;
}

}  // namespace voxcast
