// ESVO scene files: a Container (scene_file.hpp) with
//   'META' UTF-8 JSON: {"format": "esvo", "grid": {"origin": [x,y,z],
//          "voxel_size": s, "resolution": N, "levels": L}, "block_count": B,
//          "source": ..., "voxelization": ..., "source_triangles": ...,
//          "leaf_voxels": ..., "attributes": "raw" | "compressed"}
//   ("attributes" names the color/normal attachment, esvo §5.4/§5.5; optional
//   for older files, and must agree with the info sections when present;
//   "contours": true is written for octrees with contour attachments (§5.2),
//   absent otherwise, and must agree with the info sections when present)
//   'ESVO' the octree words (little-endian u32, layout in esvo.hpp).
// Loading checks every META field's type and range and then runs
// EsvoOctree::validate(), so a loaded octree is safe to traverse.
#include "voxcast/scene_file.hpp"

#include <cmath>
#include <cstring>
#include <nlohmann/json.hpp>
#include <string>

#include "io/meta_json.hpp"
#include "voxcast/error.hpp"

namespace voxcast {
namespace {

constexpr uint32_t kEsvo = fourcc("ESVO");

}  // namespace

void save_esvo_scene(const std::filesystem::path& path, const esvo::EsvoOctree& octree,
                     const SceneInfo& info) {
  nlohmann::json meta = meta::info_to_json(info);
  meta.update({
      {"format", "esvo"},
      {"grid", meta::grid_to_json(octree.grid)},
      {"block_count", octree.block_count},
      {"leaf_voxels", info.leaf_voxels},
      {"attributes",
       octree.attribute_format() == esvo::AttributeFormat::Compressed ? "compressed" : "raw"},
  });
  if (octree.has_contours()) meta["contours"] = true;
  Container c;
  c.add(meta::kSection, meta::dump(meta));
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
  esvo::EsvoOctree octree;
  SceneInfo si;
  std::string meta_attributes;
  int meta_contours = -1;  // absent
  const nlohmann::json meta = meta::parse(c);
  try {
    using namespace meta;
    if (get_string(meta, "format") != "esvo") bad("format is not 'esvo'");
    octree.grid = grid_from_json(meta, 1);
    octree.block_count = uint32_t(get_uint(meta, "block_count", 1, 0xFFFFFFFFu));
    info_from_json(meta, &si);
    si.leaf_voxels = get_uint(meta, "leaf_voxels", 0, UINT64_MAX);
    if (meta.contains("attributes")) {
      const std::string a = get_string(meta, "attributes");
      if (a != "raw" && a != "compressed") bad("'attributes' is not 'raw' or 'compressed'");
      meta_attributes = a;
    }
    if (meta.contains("contours")) {
      if (!meta["contours"].is_boolean()) bad("'contours' is not a boolean");
      meta_contours = meta["contours"].get<bool>() ? 1 : 0;
    }
  } catch (const nlohmann::json::exception& e) {
    throw Error("corrupt scene: META section is not valid JSON: " + meta::json_error_text(e));
  }
  const std::vector<uint8_t>& esvo_bytes = c.get(kEsvo);
  if (esvo_bytes.size() % 8 != 0 || esvo_bytes.size() < esvo::kPageWords * 4)
    throw Error("corrupt scene: ESVO section size " + std::to_string(esvo_bytes.size()) +
                " is not a whole number of slots of at least one page");
  octree.words.resize(esvo_bytes.size() / 4);
  std::memcpy(octree.words.data(), esvo_bytes.data(), esvo_bytes.size());
  octree.validate();
  if (!meta_attributes.empty() &&
      (meta_attributes == "compressed") !=
          (octree.attribute_format() == esvo::AttributeFormat::Compressed))
    meta::bad("'attributes' does not match the ESVO attachments");
  if (meta_contours >= 0 && (meta_contours == 1) != octree.has_contours())
    meta::bad("'contours' does not match the ESVO attachments");
  if (info) *info = std::move(si);
  return octree;
}

}  // namespace voxcast
