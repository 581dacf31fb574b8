#include "support/scene_damage.hpp"

#include <unistd.h>

#include <algorithm>
#include <array>
#include <cstring>
#include <filesystem>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <random>

#include "voxcast/camera.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/dag_format.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo_format.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/format_registry.hpp"
#include "voxcast/generate.hpp"
#include "voxcast/render.hpp"
#include "voxcast/scene_file.hpp"

namespace voxcast::testing {
namespace {

namespace fs = std::filesystem;

std::vector<uint8_t> read_all(const fs::path& p) {
  const Container c = Container::read(p);
  return c.serialize();  // current-version bytes, sections in ascending id order
}

// The scene bytes as `voxcast build` would write them: through the real
// writers (save_*_scene), then read back.
std::vector<uint8_t> build_sample(SceneKind kind) {
  generate::TerrainOptions to;
  to.seed = 7;
  to.size = 24;
  to.octaves = 3;
  to.height = 0.35;
  const Mesh mesh = generate::terrain(to);
  const GridTransform grid = GridTransform::fit(mesh.bounds(), 32);
  VoxelizeOptions vo;
  vo.attributes = true;
  const VoxelSet voxels = voxelize(mesh, grid, vo);
  SceneInfo info;
  info.source = "terrain.obj";
  info.voxelization = "conservative";
  info.source_triangles = mesh.triangle_count();
  info.leaf_voxels = voxels.size();
  const fs::path path =
      fs::temp_directory_path() /
      ("voxcast-damage-" + std::to_string(::getpid()) + "-" + scene_kind_name(kind) + ".vxc");
  if (kind == SceneKind::DagRaw || kind == SceneKind::DagCompressed) {
    dag::SparseVoxelDag d = dag::build_dag(voxels);
    if (kind == SceneKind::DagCompressed) d.compress_attributes();
    save_dag_scene(path, d, info);
  } else {
    esvo::BuildOptions bo;
    // Tiny blocks: several blocks, info sections and attachments, and far
    // pointers between them, so every kind of word is in the file.
    bo.max_block_slots = 96;
    bo.max_block_values = 512;
    const bool compressed =
        kind == SceneKind::EsvoCompressed || kind == SceneKind::EsvoContoursCompressed;
    if (compressed) bo.attributes = esvo::AttributeFormat::Compressed;
    esvo::EsvoOctree o;
    if (kind == SceneKind::EsvoRaw || kind == SceneKind::EsvoCompressed) {
      o = esvo::build_octree(voxels, bo);
    } else {
      bo.contours = true;
      if (kind == SceneKind::EsvoVariableDepth) bo.geometry_error = 1.5;  // stops early (§7.1)
      o = esvo::build_octree(voxels, mesh, bo);
    }
    save_esvo_scene(path, o, info);
  }
  std::vector<uint8_t> bytes = read_all(path);
  std::error_code ec;
  fs::remove(path, ec);
  return bytes;
}

uint32_t load_word(const std::vector<uint8_t>& b, uint64_t word) {
  uint32_t v = 0;
  const uint64_t at = word * 4;
  for (uint64_t i = 0; i < 4 && at + i < b.size(); ++i) v |= uint32_t(b[size_t(at + i)]) << (8 * i);
  return v;
}

}  // namespace

const char* scene_kind_name(SceneKind kind) {
  switch (kind) {
    case SceneKind::EsvoRaw:
      return "esvo_raw";
    case SceneKind::EsvoCompressed:
      return "esvo_compressed";
    case SceneKind::EsvoContours:
      return "esvo_contours";
    case SceneKind::EsvoContoursCompressed:
      return "esvo_contours_compressed";
    case SceneKind::EsvoVariableDepth:
      return "esvo_variable_depth";
    case SceneKind::DagRaw:
      return "dag_raw";
    case SceneKind::DagCompressed:
      return "dag_compressed";
  }
  return "?";
}

const std::vector<uint8_t>& damage_sample(SceneKind kind) {
  static std::mutex mutex;
  static std::map<SceneKind, std::vector<uint8_t>> cache;
  const std::lock_guard<std::mutex> lock(mutex);
  auto it = cache.find(kind);
  if (it == cache.end()) it = cache.emplace(kind, build_sample(kind)).first;
  return it->second;
}

std::string describe(const Mutation& m) {
  static constexpr const char* kNames[] = {"0xFFFFFFFF", "0",  "0x80000000", "random",
                                           "+1",         "-1", "bit flip"};
  // Appended piece by piece: GCC 12 warns (-Wrestrict, a false positive) on
  // the operator+ chain.
  std::string s = fourcc_name(m.section);
  s.append(" word ").append(std::to_string(m.word)).append(": ").append(kNames[int(m.edit)]);
  if (m.edit == WordEdit::Random || m.edit == WordEdit::BitFlip)
    s.append(" ").append(std::to_string(m.arg));
  return s;
}

std::vector<uint8_t> apply_mutation(const std::vector<uint8_t>& file, const Mutation& m) {
  Container c = Container::parse(file.data(), file.size());
  if (!c.has(m.section)) return file;
  std::vector<uint8_t> bytes = c.get(m.section);
  const uint64_t at = m.word * 4;
  if (at >= bytes.size()) return file;
  uint32_t v = load_word(bytes, m.word);
  switch (m.edit) {
    case WordEdit::AllOnes:
      v = 0xFFFFFFFFu;
      break;
    case WordEdit::Zero:
      v = 0;
      break;
    case WordEdit::HighBit:
      v = 0x80000000u;
      break;
    case WordEdit::Random:
      v = m.arg;
      break;
    case WordEdit::PlusOne:
      ++v;
      break;
    case WordEdit::MinusOne:
      --v;
      break;
    case WordEdit::BitFlip:
      v ^= 1u << (m.arg & 31);
      break;
  }
  // A trailing partial word (META text) only takes the bytes that exist.
  for (uint64_t i = 0; i < 4 && at + i < bytes.size(); ++i)
    bytes[size_t(at + i)] = uint8_t(v >> (8 * i));
  c.add(m.section, std::move(bytes));
  return c.serialize();  // every section hash recomputed
}

std::vector<Mutation> sweep_mutations(const std::vector<uint8_t>& file, size_t positions,
                                      uint64_t seed) {
  const Container c = Container::parse(file.data(), file.size());
  std::mt19937_64 rng(seed);
  std::vector<Mutation> out;
  for (const uint32_t id : c.section_ids()) {
    const std::vector<uint8_t>& bytes = c.get(id);
    const uint64_t words = (bytes.size() + 3) / 4;
    if (words == 0) continue;
    // Structure words are the non-zero ones (zero words are padding, empty
    // slots, or the zero high halves of small counts: a sample of them is
    // enough).
    std::vector<uint64_t> nonzero, chosen;
    for (uint64_t w = 0; w < words; ++w)
      if (load_word(bytes, w) != 0) nonzero.push_back(w);
    const size_t structural = std::min(nonzero.size(), positions - positions / 8);
    for (size_t k = 0; k < structural; ++k)
      chosen.push_back(nonzero[k * nonzero.size() / structural]);
    while (chosen.size() < positions && chosen.size() < words) chosen.push_back(rng() % words);
    for (const uint64_t w : chosen)
      for (int e = 0; e < kWordEditCount; ++e) {
        Mutation m;
        m.section = id;
        m.word = w;
        m.edit = WordEdit(e);
        m.arg = m.edit == WordEdit::Random ? uint32_t(rng()) : uint32_t(rng() % 32);
        out.push_back(m);
      }
  }
  return out;
}

Verdict check_scene(const std::vector<uint8_t>& file) {
  register_builtin_formats();  // idempotent; the fuzz targets have no other start-up
  Verdict v;
  LoadedScene scene;
  try {
    // The streaming reader over the bytes, as load_scene(path) reads a file.
    scene = load_scene(ContainerReader::from_memory(file.data(), file.size()));
  } catch (const Error& e) {
    v.error = e.what();
    return v;
  }
  v.accepted = true;
  // An accepted scene must work for every subcommand: an error from here on
  // means the loader let through something a reader cannot use (info would
  // accept the file and render refuse it).
  try {
    // What `info` computes from the loaded structure: the format's describe().
    DescribeStyle style;
    style.bytes = [](double b) { return std::to_string(b); };
    const SceneDescription d =
        format_registry().get(scene.format).describe(*scene.structure, style);
    v.voxels = nlohmann::json::parse(d.json).at("leaf_voxels").get<uint64_t>();
    // What `render` does: auto camera from the occupied bounds, beam, shadow
    // and AO rays; every hit shades (attribute lookup).
    RenderOptions ro;
    ro.width = 16;
    ro.height = 12;
    ro.camera = Camera::frame(scene.occupied, ro.width, ro.height);
    ro.beam = 4;
    ro.want_depth = ro.want_normal = true;
    ro.effects.shadows = ShadowMode::Hard;
    ro.effects.ao_rays = 2;  // radius 0: 5% of the bounds' diagonal
    const RenderResult r = render(*scene.structure, ro);
    v.hits = r.hits;
  } catch (const Error& e) {
    v.use_error = e.what();
  }
  return v;
}

}  // namespace voxcast::testing
