// ESVO scene files: a Container (scene_file.hpp) with
//   'META' UTF-8 JSON: {"format": "esvo", "grid": {"origin": [x,y,z],
//          "voxel_size": s, "resolution": N, "levels": L}, "block_count": B,
//          "source": ..., "voxelization": ..., "source_triangles": ...,
//          "leaf_voxels": ..., "attributes": "raw" | "compressed"}
//   ("attributes" names the color/normal attachment, esvo §5.4/§5.5; optional
//   for older files, and must agree with the info sections when present)
//   'ESVO' the octree words (little-endian u32, layout in esvo.hpp).
// Loading checks every META field's type and range and then runs
// EsvoOctree::validate(), so a loaded octree is safe to traverse.
#include <cmath>
#include <cstring>
#include <string>

#include <nlohmann/json.hpp>

#include "voxcast/error.hpp"
#include "voxcast/scene_file.hpp"

namespace voxcast {
namespace {

constexpr uint32_t kMeta = fourcc("META");
constexpr uint32_t kEsvo = fourcc("ESVO");

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

}  // namespace

void save_esvo_scene(const std::filesystem::path& path, const esvo::EsvoOctree& octree,
                     const SceneInfo& info) {
  const GridTransform& g = octree.grid;
  nlohmann::json meta = {
      {"format", "esvo"},
      {"grid",
       {{"origin", {g.origin.x, g.origin.y, g.origin.z}},
        {"voxel_size", g.voxel_size},
        {"resolution", g.resolution},
        {"levels", g.levels}}},
      {"block_count", octree.block_count},
      {"source", info.source},
      {"voxelization", info.voxelization},
      {"source_triangles", info.source_triangles},
      {"leaf_voxels", info.leaf_voxels},
      {"attributes", octree.attribute_format() == esvo::AttributeFormat::Compressed ? "compressed" : "raw"},
  };
  // Replace invalid UTF-8 (e.g. odd file names) instead of throwing.
  const std::string text = meta.dump(2, ' ', false, nlohmann::json::error_handler_t::replace);
  Container c;
  c.add(kMeta, std::vector<uint8_t>(text.begin(), text.end()));
  std::vector<uint8_t> words(octree.words.size() * 4);
  static_assert(std::endian::native == std::endian::little, "scene files are little-endian");
  if (!words.empty()) std::memcpy(words.data(), octree.words.data(), words.size());
  c.add(kEsvo, std::move(words));
  c.write(path);
}

esvo::EsvoOctree load_esvo_scene(const std::filesystem::path& path, SceneInfo* info) {
  return esvo_scene_from_container(Container::read(path), info);
}

esvo::EsvoOctree esvo_scene_from_container(const Container& c, SceneInfo* info) {
  const std::vector<uint8_t>& meta_bytes = c.get(kMeta);
  esvo::EsvoOctree octree;
  SceneInfo si;
  std::string meta_attributes;
  try {
    const nlohmann::json meta = nlohmann::json::parse(meta_bytes.begin(), meta_bytes.end());
    if (get_string(meta, "format") != "esvo") bad_meta("format is not 'esvo'");
    const nlohmann::json& grid = field(meta, "grid");
    const int levels = int(get_uint(grid, "levels", 1, kMaxGridLevels));
    const uint64_t resolution = get_uint(grid, "resolution", 2, uint64_t(1) << kMaxGridLevels);
    if (resolution != (uint64_t(1) << levels)) bad_meta("resolution is not 2^levels");
    const nlohmann::json& origin = field(grid, "origin");
    if (!origin.is_array() || origin.size() != 3) bad_meta("'origin' is not an array of 3 numbers");
    const double voxel_size = get_finite(field(grid, "voxel_size"), "voxel_size");
    if (!(voxel_size > 0)) bad_meta("'voxel_size' is not positive");
    octree.grid.levels = levels;
    octree.grid.resolution = uint32_t(resolution);
    octree.grid.voxel_size = voxel_size;
    for (int i = 0; i < 3; ++i) {
      const double o = get_finite(origin[size_t(i)], "origin");
      if (!std::isfinite(float(o))) bad_meta("'origin' is out of float range");
      octree.grid.origin[i] = float(o);
    }
    octree.block_count = uint32_t(get_uint(meta, "block_count", 1, 0xFFFFFFFFu));
    si.source = get_string(meta, "source");
    si.voxelization = get_string(meta, "voxelization");
    si.source_triangles = get_uint(meta, "source_triangles", 0, UINT64_MAX);
    si.leaf_voxels = get_uint(meta, "leaf_voxels", 0, UINT64_MAX);
    if (meta.contains("attributes")) {
      const std::string a = get_string(meta, "attributes");
      if (a != "raw" && a != "compressed") bad_meta("'attributes' is not 'raw' or 'compressed'");
      meta_attributes = a;
    }
  } catch (const nlohmann::json::exception& e) {
    // nlohmann messages are one line: "[json.exception.parse_error.101] ...".
    throw Error(std::string("corrupt scene: META section is not valid JSON: ") + e.what());
  }
  const std::vector<uint8_t>& esvo_bytes = c.get(kEsvo);
  if (esvo_bytes.size() % 8 != 0 || esvo_bytes.size() < esvo::kPageWords * 4)
    throw Error("corrupt scene: ESVO section size " + std::to_string(esvo_bytes.size()) +
                " is not a whole number of slots of at least one page");
  octree.words.resize(esvo_bytes.size() / 4);
  std::memcpy(octree.words.data(), esvo_bytes.data(), esvo_bytes.size());
  octree.validate();
  if (!meta_attributes.empty() &&
      (meta_attributes == "compressed") != (octree.attribute_format() == esvo::AttributeFormat::Compressed))
    bad_meta("'attributes' does not match the ESVO attachments");
  if (info) *info = std::move(si);
  return octree;
}

}  // namespace voxcast
