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
// register_format() below is the ESVO entry of the format registry.
#include <fmt/printf.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <nlohmann/json.hpp>
#include <string>

#include "esvo/build_cells.hpp"
#include "io/meta_json.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo_format.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/format_registry.hpp"
#include "voxcast/progress.hpp"

namespace voxcast {
namespace {

constexpr uint32_t kEsvo = fourcc("ESVO");

}  // namespace

void write_esvo_scene(ContainerWriter& writer, const esvo::EsvoOctree& octree,
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
  writer.add(meta::kSection, meta::dump(meta));
  // Straight from the octree's words: no second copy of the section.
  static_assert(std::endian::native == std::endian::little, "scene files are little-endian");
  writer.add(kEsvo, octree.words.data(), octree.words.size() * 4);
}

void save_esvo_scene(const std::filesystem::path& path, const esvo::EsvoOctree& octree,
                     const SceneInfo& info) {
  ContainerWriter writer(path);
  write_esvo_scene(writer, octree, info);
  writer.commit();
}

esvo::EsvoOctree load_esvo_scene(const std::filesystem::path& path, SceneInfo* info) {
  return esvo_scene_from_container(ContainerReader::open(path), info);
}

esvo::EsvoOctree esvo_scene_from_container(const Container& c, SceneInfo* info) {
  return esvo_scene_from_container(ContainerReader::from_bytes(c.serialize()), info);
}

esvo::EsvoOctree esvo_scene_from_container(const ContainerReader& c, SceneInfo* info) {
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
  // Size checked from the directory before anything is read or allocated.
  const uint64_t esvo_size = c.section(kEsvo).size;
  if (esvo_size % 8 != 0 || esvo_size < esvo::kPageWords * 4)
    throw Error("corrupt scene: ESVO section size " + std::to_string(esvo_size) +
                " is not a whole number of slots of at least one page");
  // Straight into the octree's words: the section is not held twice.
  octree.words.resize(size_t(esvo_size / 4));
  c.read_into(kEsvo, octree.words.data(), esvo_size);
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

namespace esvo {
namespace {

const EsvoOctree& octree_of(const Structure& s) {
  const auto* e = dynamic_cast<const EsvoStructure*>(&s);
  if (!e) throw Error("internal: the esvo format was handed a " + s.name() + " structure");
  return e->octree();
}

// `voxcast info` for ESVO scenes: voxels and branching per level and the
// memory split of esvo §8.1-8.2.
SceneDescription describe(const Structure& s, const DescribeStyle& style) {
  const EsvoOctree& octree = octree_of(s);
  auto levels = octree.level_stats();
  auto mem = octree.memory_stats();
  uint64_t total_voxels = 0;
  for (auto& l : levels) total_voxels += l.voxels;
  // Leaves on every level (variable-depth contour builds stop early, esvo
  // §7.1); equals the finest level's count for full-depth octrees.
  uint64_t leaves = 0;
  for (auto& l : levels) leaves += l.voxels - l.non_leaf;
  const double hierarchy =
      double(mem.descriptor_bytes + mem.far_pointer_bytes + mem.page_header_bytes + mem.info_bytes);
  const double attributes = double(mem.attribute_lookup_bytes + mem.attribute_value_bytes);
  const double overhead = double(mem.padding_bytes);
  const bool compressed = mem.attribute_format == AttributeFormat::Compressed;

  nlohmann::json j;
  j["blocks"] = octree.block_count;
  j["voxels_total"] = total_voxels;
  j["leaf_voxels"] = leaves;
  for (size_t l = 0; l < levels.size(); ++l) {
    nlohmann::json row{
        {"level", l}, {"voxels", levels[l].voxels}, {"non_leaf", levels[l].non_leaf}};
    if (l + 1 < levels.size() && levels[l].non_leaf) {
      const double branching = double(levels[l + 1].voxels) / double(levels[l].non_leaf);
      row["branching"] = branching;
      row["dimensionality"] = std::log2(branching);
    }
    j["per_level"].push_back(row);
  }
  j["memory"] = {{"descriptors", mem.descriptor_bytes},
                 {"far_pointers", mem.far_pointer_bytes},
                 {"page_headers", mem.page_header_bytes},
                 {"info_sections", mem.info_bytes},
                 {"attribute_lookup", mem.attribute_lookup_bytes},
                 {"attribute_values", mem.attribute_value_bytes},
                 {"padding", mem.padding_bytes},
                 {"pair_padding", mem.pair_padding_bytes},
                 {"colors", mem.color_bytes},
                 {"normals", mem.normal_bytes},
                 {"contours", mem.contour_bytes},
                 {"total", mem.total_bytes}};
  j["contours"] = octree.has_contours();
  j["contour_count"] = mem.contour_count;
  j["attributes"] = compressed ? "compressed" : "raw";

  SceneDescription d;
  d.grid = octree.grid;
  d.json = j.dump();
  d.summary = fmt::sprintf(
      "structure   esvo, %u block(s), %s attributes (%s)\n", octree.block_count,
      compressed ? "compressed" : "raw",
      compressed ? "esvo 5.5: 24 B per descriptor pair" : "esvo 5.4: 8 B per voxel + lookup");
  d.summary += fmt::sprintf("contours    %s\n",
                            octree.has_contours() ? "yes, " + std::to_string(mem.contour_count) +
                                                        " contour values (esvo 5.2, variable depth)"
                                                  : std::string("no"));
  d.voxels = fmt::sprintf("%llu in all levels, %llu leaves", (unsigned long long)total_voxels,
                          (unsigned long long)leaves);
  std::string& t = d.details;
  t += "level       voxels     non-leaf  branching  dimensionality\n";
  for (size_t l = 0; l < levels.size(); ++l) {
    t += fmt::sprintf("%5zu %12llu %12llu", l, (unsigned long long)levels[l].voxels,
                      (unsigned long long)levels[l].non_leaf);
    if (l + 1 < levels.size() && levels[l].non_leaf) {
      const double branching = double(levels[l + 1].voxels) / double(levels[l].non_leaf);
      t += fmt::sprintf("  %9.2f  %14.2f", branching, std::log2(branching));
    }
    t += "\n";
  }
  auto row = [&](const char* name, double bytes, const char* what) {
    t += fmt::sprintf("  %-11s %12s  %6.2f  %6.2f   %s\n", name, style.bytes(bytes),
                      bytes / double(total_voxels), bytes / double(leaves), what);
  };
  t += "\nmemory             bytes  B/voxel  B/leaf\n";
  row("hierarchy", hierarchy, "child descriptors, far pointers, page headers, info sections");
  row("attributes", attributes,
      compressed ? "compressed blocks (DXT1 colors + 4x4-grid normals)"
                 : "lookup entries, 32-bit colors + 32-bit normals");
  row(" colors", double(mem.color_bytes), compressed ? "2 words per block" : "32-bit ABGR");
  row(" normals", double(mem.normal_bytes),
      compressed ? "4 words per block" : "32-bit cube normals");
  if (octree.has_contours())
    row("contours", double(mem.contour_bytes),
        "CONT: 32-bit contour values (pointer/mask word: hierarchy)");
  row("overhead", overhead + double(mem.pair_padding_bytes),
      compressed ? "padding (page alignment, far slots, sibling-pair gaps)"
                 : "padding (page alignment, unused far-pointer slots)");
  row("total", double(mem.total_bytes), "");
  return d;
}

BuildOptions build_options(const FormatBuildOptions& o) {
  BuildOptions b;
  b.attributes = o.compress_attributes ? AttributeFormat::Compressed : AttributeFormat::Raw;
  if (o.contours.enabled) {
    b.contours = true;
    b.max_level = o.contours.max_level;
    b.geometry_error = o.contours.geometry_error;
    b.color_error = o.contours.color_error;
    b.normal_error = o.contours.normal_error;
  }
  return b;
}

LoadedStructure build(const VoxelSet& voxels, const FormatBuildOptions& o) {
  BuildOptions b = build_options(o);
  b.progress = o.progress;  // the in-core build's bar (levels, [contours,] layout)
  if (!b.contours)
    return std::make_unique<EsvoStructure>(std::make_shared<EsvoOctree>(build_octree(voxels, b)));
  // Contours are shaped by the mesh (esvo §5.2).
  if (!o.mesh) throw Error("contours need the source mesh (not a voxel file)");
  return std::make_unique<EsvoStructure>(
      std::make_shared<EsvoOctree>(build_octree(voxels, *o.mesh, b)));
}

// esvo §7.1-7.3 "memory bounded": one cell's full-depth voxels at a time,
// only the kept (variable-depth) octree is held; same bytes as in core.
// Without a color/normal tolerance it voxelizes every cell once and is as
// fast as the in-core build (docs/notes-vardepth.md), so it is the default
// there; with one, the attribute tests stream the cells two more times
// (with compressed attributes also once per §7.3 decoded-leaf round for the
// cells holding a leaf to test), so only when the in-core estimate exceeds
// the budget (or when asked). Without contours there is no cell build: the
// caller voxelizes in core and calls build().
MeshBuild build_from_mesh(const Mesh& mesh, const GridTransform& grid, const MeshBuildRequest& r) {
  MeshBuild out;
  const FormatBuildOptions::Contours& c = r.options.contours;
  const bool attribute_tolerance = c.color_error >= 0 || c.normal_error >= 0;
  if (!c.enabled || !(r.out_of_core || (r.memory_budget && r.in_core_estimate > r.memory_budget) ||
                      !attribute_tolerance))
    return out;
  VoxelizeOptions vo;
  vo.mode = r.mode;
  vo.attributes = true;
  Progress progress("cell-by-cell build", uint64_t(0));  // a bar on a terminal only
  vo.progress = &progress;
  CellBuildStats st;
  const auto start = std::chrono::steady_clock::now();
  out.structure = std::make_unique<EsvoStructure>(std::make_shared<EsvoOctree>(build_octree_cells(
      mesh, grid, vo, build_options(r.options), r.cell_size, r.memory_budget, &st)));
  out.build_seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  out.out_of_core = true;
  out.leaf_voxels = st.voxels;
  out.stage = "cell-by-cell octree build";
  if (!st.in_core)
    out.report = fmt::sprintf(
        "out-of-core: %llu cells of %u^3 (%llu planned below their root), "
        "%.2f s\n",
        (unsigned long long)st.cells, st.cell_size, (unsigned long long)st.refined_cells,
        out.build_seconds);
  out.stats = {{"cell size", std::to_string(st.cell_size)},
               {"cells", std::to_string(st.cells)},
               {"cells planned below their root", std::to_string(st.refined_cells)},
               {"fullest cell voxels", std::to_string(st.max_cell_voxels)},
               {"full-depth voxels", std::to_string(st.voxels)},
               {"working set (estimate)", std::to_string(st.estimated_bytes) + " B"},
               {"decoded-leaf rounds", std::to_string(st.decoded_rounds)},
               {"cells replanned", std::to_string(st.replanned_cells)},
               {"top leaves forced", std::to_string(st.forced_top_leaves)}};
  return out;
}

}  // namespace

void register_format(FormatRegistry& registry) {
  SceneFormat f;
  f.name = "esvo";
  f.description = "ESVO octree (Laine & Karras 2010)";
  f.contours = true;
  f.min_levels = 1;  // a root with children (2^3)
  f.build = build;
  f.build_from_mesh = build_from_mesh;
  f.bounded_mesh_build = [](const FormatBuildOptions& o) { return o.contours.enabled; };
  f.save = [](ContainerWriter& w, const Structure& s, const SceneInfo& info) {
    write_esvo_scene(w, octree_of(s), info);
  };
  f.load = [](const ContainerReader& r, SceneInfo* info) -> LoadedStructure {
    return std::make_unique<EsvoStructure>(
        std::make_shared<EsvoOctree>(esvo_scene_from_container(r, info)));
  };
  f.occupied = [](const Structure& s) { return occupied_bounds(octree_of(s)); };
  f.memory_bytes = [](const Structure& s) { return octree_of(s).memory_stats().total_bytes; };
  f.describe = describe;
  f.build_summary = [](const Structure& s, const SceneInfo& info, const DescribeStyle& style) {
    const EsvoOctree& octree = octree_of(s);
    const auto mem = octree.memory_stats();
    return fmt::sprintf("%u^3 grid (%d levels), %llu leaf voxels, %s (%.2f bytes/leaf voxel)",
                        octree.grid.resolution, octree.levels(),
                        (unsigned long long)info.leaf_voxels, style.bytes(double(mem.total_bytes)),
                        double(mem.total_bytes) / double(info.leaf_voxels));
  };
  registry.add(std::move(f));
}

}  // namespace esvo
}  // namespace voxcast
