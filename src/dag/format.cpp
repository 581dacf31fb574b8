// DAG scene files and the DAG entry of the format registry (register_format).
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
#include <fmt/printf.h>

#include <bit>
#include <cmath>
#include <cstring>
#include <nlohmann/json.hpp>
#include <string>

#include "io/meta_json.hpp"
#include "voxcast/dag_format.hpp"
#include "voxcast/error.hpp"
#include "voxcast/format_registry.hpp"
#include "voxcast/system.hpp"

namespace voxcast {
namespace {

constexpr uint32_t kDagSection = fourcc("SDAG");
constexpr uint32_t kDagAttributes = fourcc("DATR");
constexpr uint32_t kDagCompressedAttributes = fourcc("DATC");

// A section of whole words, read straight into the array that keeps it (no
// second copy of the section is held).
std::vector<uint32_t> read_words(const ContainerReader& c, uint32_t id, HugePages kind) {
  const uint64_t size = c.section(id).size;
  std::vector<uint32_t> w;  // read at random by rays: huge pages
  assign_huge(w, size_t(size / 4), 0u, kind);
  c.read_into(id, w.data(), size);
  return w;
}

}  // namespace

void write_dag_scene(ContainerWriter& w, const dag::SparseVoxelDag& dag, const SceneInfo& info) {
  nlohmann::json meta = meta::info_to_json(info);
  meta.update({
      {"format", "dag"},
      {"grid", meta::grid_to_json(dag.grid)},
      {"attributes", dag.has_attributes()},
      {"leaf_voxels", dag.leaf_voxels},
  });
  if (dag.compressed_attributes()) meta["attribute_format"] = "compressed";
  static_assert(std::endian::native == std::endian::little, "scene files are little-endian");
  w.add(meta::kSection, meta::dump(meta));
  // Straight from the arrays: no second copy of a section is held.
  w.add(kDagSection, dag.words.data(), dag.words.size() * 4);
  if (dag.compressed_attributes()) {
    w.add(kDagCompressedAttributes, dag.attribute_blocks.data(), dag.attribute_blocks.size() * 4);
  } else if (dag.has_attributes()) {
    // Interleaved (color, normal) pairs, produced a piece at a time.
    w.begin_section(kDagAttributes);
    uint32_t piece[2 * 4096];
    for (size_t i = 0; i < dag.colors.size();) {
      const size_t n = std::min<size_t>(4096, dag.colors.size() - i);
      for (size_t k = 0; k < n; ++k) {
        std::memcpy(&piece[2 * k], &dag.colors[i + k], 4);
        std::memcpy(&piece[2 * k + 1], &dag.normals[i + k], 4);
      }
      w.append(piece, n * 8);
      i += n;
    }
    w.end_section();
  }
}

void save_dag_scene(const std::filesystem::path& path, const dag::SparseVoxelDag& dag,
                    const SceneInfo& info) {
  ContainerWriter writer(path);
  write_dag_scene(writer, dag, info);
  writer.commit();
}

dag::SparseVoxelDag load_dag_scene(const std::filesystem::path& path, SceneInfo* info) {
  return dag_scene_from_container(ContainerReader::open(path), info);
}

dag::SparseVoxelDag dag_scene_from_container(const Container& c, SceneInfo* info) {
  return dag_scene_from_container(ContainerReader::from_bytes(c.serialize()), info);
}

dag::SparseVoxelDag dag_scene_from_container(const ContainerReader& c, SceneInfo* info) {
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
  // Sizes are checked from the directory before a section is read.
  const uint64_t dag_size = c.section(kDagSection).size;
  if (dag_size % 4 != 0 || dag_size < 8)
    throw Error("corrupt scene: SDAG section size " + std::to_string(dag_size) +
                " is not a whole number of words of at least one node");
  dag.words = read_words(c, kDagSection, HugePages::kHot);  // every ray walks them
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
    const uint64_t size = c.section(kDagCompressedAttributes).size;
    const uint64_t blocks = (si.leaf_voxels + dag::SparseVoxelDag::kCompressedSlots - 1) /
                            dag::SparseVoxelDag::kCompressedSlots;
    const uint64_t expected = blocks * dag::SparseVoxelDag::kCompressedBlockWords * 4;
    if (size != expected)
      throw Error("corrupt scene: DATC section holds " + std::to_string(size) +
                  " bytes, expected " + std::to_string(expected) + " (24 per 16 leaf voxels, " +
                  std::to_string(si.leaf_voxels) + " voxels)");
    dag.attribute_blocks = read_words(c, kDagCompressedAttributes, HugePages::kBulk);
  } else if (attributes) {
    const uint64_t size = c.section(kDagAttributes).size;
    if (size != si.leaf_voxels * 8)
      throw Error("corrupt scene: DATR section holds " + std::to_string(size) +
                  " bytes, expected 8 per leaf voxel (" + std::to_string(si.leaf_voxels) + ")");
    // Interleaved (color, normal) pairs into the two arrays, a chunk at a
    // time where chunks hold whole pairs (every file this writer makes), so
    // that the section is not held beside them.
    assign_huge(dag.colors, size_t(si.leaf_voxels));
    assign_huge(dag.normals, size_t(si.leaf_voxels));
    const SectionInfo& sec = c.section(kDagAttributes);
    auto split = [&](const uint8_t* pairs, size_t first, size_t n) {
      for (size_t i = 0; i < n; ++i) {
        std::memcpy(&dag.colors[first + i], pairs + 8 * i, 4);
        std::memcpy(&dag.normals[first + i], pairs + 8 * i + 4, 4);
      }
    };
    if (sec.chunk_bytes % 8 == 0) {
      for (uint32_t k = 0; k < sec.chunk_count; ++k) {
        const std::vector<uint8_t> chunk = c.read_chunk(kDagAttributes, k);
        split(chunk.data(), size_t(uint64_t(k) * sec.chunk_bytes / 8), chunk.size() / 8);
      }
    } else {
      const std::vector<uint8_t> ab = c.read(kDagAttributes);
      split(ab.data(), 0, dag.colors.size());
    }
  }
  dag.finalize();  // throws "corrupt DAG: ..."
  if (dag.leaf_voxels != si.leaf_voxels)
    throw Error("corrupt scene: META leaf_voxels " + std::to_string(si.leaf_voxels) +
                " but the DAG holds " + std::to_string(dag.leaf_voxels));
  if (info) *info = std::move(si);
  return dag;
}

namespace dag {
namespace {

const SparseVoxelDag& dag_of(const Structure& s) {
  const auto* d = dynamic_cast<const DagStructure*>(&s);
  if (!d) throw Error("internal: the dag format was handed a " + s.name() + " structure");
  return d->dag();
}

// `voxcast info` for DAG scenes: nodes per level DAG vs SVO and memory DAG
// vs pointer-less SVO (1 B/node) vs ESVO (8 B/node), bits per voxel: the
// shape of svdag Table 2.
SceneDescription describe(const Structure& s, const DescribeStyle& style) {
  const SparseVoxelDag& d = dag_of(s);
  const DagStats st = d.stats();
  const int L = d.levels();
  nlohmann::json j;
  j["leaf_voxels"] = st.leaf_voxels;
  j["attributes"] = d.has_attributes();
  for (int l = 0; l <= L; ++l) {
    const LevelStats& ls = st.levels[size_t(l)];
    j["per_level"].push_back({{"level", l},
                              {"dag_nodes", ls.dag_nodes},
                              {"svo_nodes", ls.svo_nodes},
                              {"dag_bytes", ls.dag_bytes}});
  }
  j["nodes"] = {{"dag", st.dag_nodes}, {"svo", st.svo_nodes}};
  j["memory"] = {{"dag", st.dag_bytes},
                 {"svo_1byte", st.svo_bytes},
                 {"esvo_8byte", st.esvo_bytes},
                 {"voxel_index", st.index_bytes},
                 {"lod_means", st.lod_mean_bytes},
                 {"attributes", st.attribute_bytes}};
  j["bits_per_voxel"] = st.bits_per_voxel;
  // Raw 8 B/voxel or esvo §5.5 blocks of 16 voxels in Morton order (dag.hpp).
  if (d.has_attributes()) {
    j["attribute_format"] = st.compressed_attributes ? "compressed" : "raw";
    j["attribute_bytes_per_voxel"] =
        st.leaf_voxels ? double(st.attribute_bytes) / double(st.leaf_voxels) : 0.0;
  }
  // 64-bit voxel indices (dag.hpp): words of the top levels whose nodes hold
  // >= 2^32 voxels carry 64-bit prefix entries (0 below 2^32 voxels).
  j["voxel_index_wide_words"] = d.wide_words;

  SceneDescription out;
  out.grid = d.grid;
  out.json = j.dump();
  out.summary = fmt::sprintf("structure   sparse voxel DAG (svdag), 4^3 leaf masks, %s\n",
                             d.has_attributes() ? "colors + normals per voxel (Morton-rank index)"
                                                : "geometry only (gray, face normals)");
  out.voxels = fmt::sprintf("%llu leaves", (unsigned long long)st.leaf_voxels);
  std::string& t = out.details;
  t += "level    DAG nodes     SVO nodes   reduction   DAG bytes\n";
  for (int l = 0; l < L; ++l) {
    const LevelStats& ls = st.levels[size_t(l)];
    if (l < L - 1)
      t += fmt::sprintf("%5d %12llu  %12llu  %9.1fx  %10s\n", l, (unsigned long long)ls.dag_nodes,
                        (unsigned long long)ls.svo_nodes,
                        double(ls.svo_nodes) / double(ls.dag_nodes),
                        style.bytes(double(ls.dag_bytes)));
    else
      t += fmt::sprintf("%5d %12s  %12llu  (in the level %d 64-bit masks)\n", l, "-",
                        (unsigned long long)ls.svo_nodes, L - 2);
  }
  t += fmt::sprintf("total %12llu  %12llu  %9.1fx\n\n", (unsigned long long)st.dag_nodes,
                    (unsigned long long)st.svo_nodes, double(st.svo_nodes) / double(st.dag_nodes));
  const double v = double(st.leaf_voxels);
  t += "memory (geometry)          bytes  bits/voxel\n";
  t += fmt::sprintf("  DAG              %14s  %10.3f\n", style.bytes(double(st.dag_bytes)),
                    double(st.dag_bytes) * 8 / v);
  t += fmt::sprintf("  SVO  (1 B/node)  %14s  %10.3f   pointer-less (Schnabel & Klein)\n",
                    style.bytes(double(st.svo_bytes)), double(st.svo_bytes) * 8 / v);
  t += fmt::sprintf("  ESVO (8 B/node)  %14s  %10.3f   descriptor + contour word\n",
                    style.bytes(double(st.esvo_bytes)), double(st.esvo_bytes) * 8 / v);
  if (d.has_attributes())
    t += fmt::sprintf(
        "attributes  %s colors + normals, %s (%.3f B/voxel), %s voxel index (derived at "
        "load)\n",
        style.bytes(double(st.attribute_bytes)),
        st.compressed_attributes ? "compressed esvo §5.5 blocks of 16 voxels" : "raw",
        double(st.attribute_bytes) / v, style.bytes(double(st.index_bytes)));
  if (st.lod_mean_bytes)
    t += fmt::sprintf(
        "LOD means   %s of the voxel index (%.3f bits/voxel): cubes of > 32 voxels at levels "
        "0..L-4, every cube at L-3\n",
        style.bytes(double(st.lod_mean_bytes)), double(st.lod_mean_bytes) * 8 / v);
  if (d.wide_words)
    t += fmt::sprintf(
        "voxel index 64-bit prefix entries for the %u words of the levels whose nodes "
        "hold >= 2^32 voxels\n",
        d.wide_words);
  return out;
}

// svdag §3 "Implementation details": sub-volumes voxelized and reduced one
// at a time, peak memory bounded by the budget; when asked, or when the
// in-core estimate exceeds the budget. Otherwise the in-core build
// (voxelize, then build_dag) is the caller's.
MeshBuild build_from_mesh(const Mesh& mesh, const GridTransform& grid, const MeshBuildRequest& r) {
  MeshBuild out;
  if (!r.out_of_core && !(r.memory_budget && r.in_core_estimate > r.memory_budget)) return out;
  OutOfCoreOptions oo;
  oo.mode = r.mode;
  oo.attributes = r.attributes;
  oo.memory_budget = r.memory_budget;
  oo.cell_size = r.cell_size;
  // esvo §5.5 blocks over the Morton-order array (dag.hpp), encoded cell by
  // cell from the same raw values as in core, so the scene bytes stay
  // identical and the raw arrays are never held whole.
  oo.compress_attributes = r.options.compress_attributes;
  OutOfCoreReport rep;
  auto d = std::make_shared<SparseVoxelDag>(build_dag_out_of_core(mesh, grid, oo, &rep));
  out.leaf_voxels = d->leaf_voxels;
  out.structure = std::make_unique<DagStructure>(std::move(d));
  out.out_of_core = true;
  out.voxelize_seconds = rep.voxelize_seconds;
  out.build_seconds = rep.reduce_seconds;
  out.stage = "out-of-core DAG build";
  // bench/dag_scaling.sh reads the cell size from this line.
  out.report = fmt::sprintf("out-of-core: %llu cells of %u^3, voxelize %.2f s, reduce %.2f s\n",
                            (unsigned long long)rep.cells, rep.cell_size, rep.voxelize_seconds,
                            rep.reduce_seconds);
  out.stats = {
      {"cell size", std::to_string(rep.cell_size)},
      {"cells", std::to_string(rep.cells)},
      {"fullest cell voxels", std::to_string(rep.max_cell_voxels)},
      {"fullest cell working set (estimate)", std::to_string(rep.estimated_cell_bytes) + " B"},
      {"fixed (mesh, grid-unit vertices, bins)", std::to_string(rep.fixed_bytes) + " B"},
      {"total seconds", fmt::sprintf("%.2f", rep.total_seconds)}};
  return out;
}

}  // namespace

void register_format(FormatRegistry& registry) {
  SceneFormat f;
  f.name = "dag";
  f.description = "sparse voxel DAG (Kämpe et al. 2013)";
  f.attributes_optional = true;
  f.min_levels = 2;  // a leaf-mask level (4^3) below the root
  f.build = [](const VoxelSet& voxels, const FormatBuildOptions& o) -> LoadedStructure {
    SparseVoxelDag d = build_dag(voxels, o.progress);
    if (o.compress_attributes && d.has_attributes()) d.compress_attributes();
    return std::make_unique<DagStructure>(std::make_shared<SparseVoxelDag>(std::move(d)));
  };
  f.build_from_mesh = build_from_mesh;
  f.bounded_mesh_build = [](const FormatBuildOptions&) { return true; };
  f.save = [](ContainerWriter& w, const Structure& s, const SceneInfo& info) {
    write_dag_scene(w, dag_of(s), info);
  };
  f.load = [](const ContainerReader& r, SceneInfo* info) -> LoadedStructure {
    return std::make_unique<DagStructure>(
        std::make_shared<SparseVoxelDag>(dag_scene_from_container(r, info)));
  };
  f.occupied = [](const Structure& s) { return occupied_bounds(dag_of(s)); };
  // The DAG words, the attributes and the voxel index derived at load.
  f.memory_bytes = [](const Structure& s) {
    const DagStats st = dag_of(s).stats();
    return st.dag_bytes + st.attribute_bytes + st.index_bytes;
  };
  f.describe = describe;
  f.build_summary = [](const Structure& s, const SceneInfo& info, const DescribeStyle& style) {
    const SparseVoxelDag& d = dag_of(s);
    const DagStats st = d.stats();
    return fmt::sprintf(
        "%u^3 grid (%d levels), %llu leaf voxels, DAG %s (%.3f bits/leaf voxel, %llu nodes vs "
        "%llu SVO nodes)",
        d.grid.resolution, d.levels(), (unsigned long long)info.leaf_voxels,
        style.bytes(double(st.dag_bytes)), st.bits_per_voxel, (unsigned long long)st.dag_nodes,
        (unsigned long long)st.svo_nodes);
  };
  registry.add(std::move(f));
}

}  // namespace dag
}  // namespace voxcast
