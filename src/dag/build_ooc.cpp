// Out-of-core sparse voxel DAG construction (svdag §3 "Implementation
// details": the voxel grid is split into sub-volumes, each one is voxelized
// and reduced to a sub-DAG, and the sub-DAGs are merged; Hitchhiker's guide
// to voxels, "bottom-up compression during construction": the full SVO never
// exists, only one sub-volume's voxels at a time plus the unique nodes).
//
// Cells are aligned cubes of 2^c voxels per axis, visited in Morton order of
// their cell index. Then a voxel's global Morton code is (cell code << 3c) |
// (code inside the cell), so concatenating the cells' voxels in visit order
// is the global Morton order, and so is the order in which every level's
// nodes are met. Each level keeps one global intern table (hash of the node's
// words -> id, ids handed out in order of first occurrence), which merges
// identical subtrees across cells as they arrive: the ids are exactly the
// ids build_dag() assigns with its sort-and-compact over the whole level
// (first occurrence in Morton order, svdag §3), so the layout below -- the
// same as build.cpp's -- produces the same words byte for byte. The cell
// roots are reduced like any other level to build the top of the DAG.
//
// Memory: the mesh, its grid-unit vertices, the (cell, triangle) bins, one
// cell's (voxel, triangle) pairs, the intern tables (the DAG's unique nodes)
// and, with attributes, 8 bytes per voxel for the DATR arrays. The cell size
// is the largest whose estimated working set leaves half of what the budget
// has left after the fixed parts for the DAG; the DAG is checked against the
// budget after every cell.
#include <fmt/format.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

#include <algorithm>
#include <bit>
#include <chrono>
#include <cmath>
#include <string>

#include "voxcast/dag.hpp"
#include "voxcast/error.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/progress.hpp"
#include "voxcast/system.hpp"
#include "voxelize/cell.hpp"

namespace voxcast::dag {
namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

std::string mib(double bytes) {
  return fmt::format("{:.1f} MiB", bytes / (1024.0 * 1024.0));
}

// Unique nodes of one level, interned by their words (svdag §3: one node per
// distinct subtree). Leaf-mask nodes are 2 words (mask bits 31..0, 63..32);
// interior nodes are the header plus the ids of the children in slot order.
// Ids are dense and in order of first interning.
class LevelTable {
 public:
  uint32_t intern(const uint32_t* w, uint32_t len) {
    if (uint64_t(start_.size() + 1) * 2 > slots_.size()) grow();
    const uint64_t mask = slots_.size() - 1;
    for (uint64_t s = hash(w, len) & mask;; s = (s + 1) & mask) {
      const uint32_t e = slots_[s];
      if (e == 0) {
        if (data_.size() + len > 0xFFFFFFFFull)
          throw Error("DAG build: the DAG exceeds 2^32 words");
        const uint32_t id = uint32_t(start_.size());
        start_.push_back(uint32_t(data_.size()));
        data_.insert(data_.end(), w, w + len);
        slots_[s] = id + 1;
        return id;
      }
      const uint32_t* o = data_.data() + start_[e - 1];
      if (node_len(e - 1) == len && std::equal(w, w + len, o)) return e - 1;
    }
  }
  size_t nodes() const { return start_.size(); }
  uint64_t words() const { return data_.size(); }
  const std::vector<uint32_t>& data() const { return data_; }
  const std::vector<uint32_t>& start() const { return start_; }
  uint64_t bytes() const {
    return uint64_t(data_.capacity() + start_.capacity() + slots_.capacity()) * 4;
  }
  void release() {
    data_ = {};
    start_ = {};
    slots_ = {};
  }
  void drop_index() { slots_ = {}; }

 private:
  uint32_t node_len(uint32_t id) const {
    const size_t end = id + 1 < start_.size() ? start_[id + 1] : data_.size();
    return uint32_t(end - start_[id]);
  }
  static uint64_t hash(const uint32_t* w, uint32_t len) {
    uint64_t h = 0x9E3779B97F4A7C15ull ^ len;
    for (uint32_t i = 0; i < len; ++i) {
      h ^= w[i];
      h *= 0xBF58476D1CE4E5B9ull;
      h ^= h >> 31;
    }
    h *= 0x94D049BB133111EBull;
    return h ^ (h >> 29);
  }
  void grow() {
    const size_t cap = std::max<size_t>(1024, slots_.size() * 2);
    slots_.assign(cap, 0);
    const uint64_t mask = cap - 1;
    for (uint32_t id = 0; id < start_.size(); ++id) {
      uint64_t s = hash(data_.data() + start_[id], node_len(id)) & mask;
      while (slots_[s] != 0) s = (s + 1) & mask;
      slots_[s] = id + 1;
    }
  }
  std::vector<uint32_t> data_;
  std::vector<uint32_t> start_;
  std::vector<uint32_t> slots_;  // id + 1, 0 = empty; linear probing, load <= 1/2
};

// One level up: groups the level l+1 nodes (ascending Morton keys, merged ids)
// under their parents and interns the parents into `table` (level l).
void reduce_level(LevelTable& table, const std::vector<uint64_t>& keys,
                  const std::vector<uint32_t>& ids, std::vector<uint64_t>* parent_keys,
                  std::vector<uint32_t>* parent_ids) {
  parent_keys->clear();
  parent_ids->clear();
  uint32_t node[9];
  uint32_t len = 0;
  auto flush = [&]() { parent_ids->push_back(table.intern(node, len)); };
  for (size_t i = 0; i < keys.size(); ++i) {
    const uint64_t pk = keys[i] >> 3;
    if (parent_keys->empty() || parent_keys->back() != pk) {
      if (!parent_keys->empty()) flush();
      parent_keys->push_back(pk);
      node[0] = 0;
      len = 1;
    }
    // Keys ascend, so the children arrive in slot order (packed, as build.cpp).
    node[0] |= 1u << (keys[i] & 7);
    node[len++] = ids[i];
  }
  if (!parent_keys->empty()) flush();
}

using detail::CellPlan;

// Bytes one cell holds per estimated pair: geometry = the per-block code
// vectors and their concatenation (8 + 8) plus the leaf keys/masks/ids of the
// cell (~12); attributes = 16-byte pairs twice, the VoxelSet (~40 B per voxel,
// about half a voxel per pair) and the pair index.
double bytes_per_pair(bool attributes) {
  return attributes ? 32.0 + 24.0 + 12.0 : 28.0;
}

}  // namespace

SparseVoxelDag build_dag_out_of_core(const Mesh& mesh, const GridTransform& grid,
                                     const OutOfCoreOptions& options, OutOfCoreReport* report) {
  const Clock::time_point t_start = Clock::now();
  const int L = grid.levels;
  if (L < 2 || L > kMaxGridLevels)
    throw Error("DAG build: the grid must have 2.." + std::to_string(kMaxGridLevels) +
                " levels (at least 4^3 voxels), not " + std::to_string(L));
  if (grid.resolution != (1u << L)) throw Error("DAG build: grid resolution is not 2^levels");
  if (!(grid.voxel_size > 0) || !std::isfinite(grid.voxel_size) || !is_finite(grid.origin))
    throw Error("grid voxel size must be positive and its origin finite");
  validate_mesh(mesh);
  if (mesh.triangle_count() > size_t(UINT32_MAX))
    throw Error(fmt::format("mesh has {} triangles, more than 2^32-1", mesh.triangle_count()));
  uint64_t budget = options.memory_budget;
  if (budget == 0) budget = uint64_t(double(available_memory_bytes()) * 0.9);
  if (budget == 0) throw Error("out-of-core DAG build: no memory budget and free memory unknown");

  const std::vector<std::array<double, 3>> gv = detail::grid_vertices(mesh, grid);

  // Cell size (svdag §3: sub-volumes sized to fit memory): the largest cell
  // whose estimated working set is at most half of what the fixed parts leave.
  constexpr int kMinCellBits = 5;  // 32^3: smaller cells only multiply the bins
  CellPlan plan;
  if (options.cell_size != 0) {
    if (!std::has_single_bit(options.cell_size) || options.cell_size < 4 ||
        options.cell_size > grid.resolution)
      throw Error(fmt::format("cell size {} is not a power of two between 4 and the resolution {}",
                              options.cell_size, grid.resolution));
    plan = detail::plan_cells(mesh, gv, grid, std::countr_zero(options.cell_size),
                              bytes_per_pair(options.attributes));
  } else {
    const int min_bits = std::min(L, kMinCellBits);
    for (int bits = L; bits >= min_bits; --bits) {
      plan = detail::plan_cells(mesh, gv, grid, bits, bytes_per_pair(options.attributes));
      if (plan.fixed_bytes < budget && plan.cell_bytes <= (budget - plan.fixed_bytes) / 2) break;
      if (bits == min_bits)
        throw Error(fmt::format(
            "out-of-core DAG build: even {}^3 cells need an estimated {} (mesh and triangle bins "
            "{} + fullest cell {} + as much again for the DAG), more than the {} memory budget; "
            "raise --memory-budget or lower --resolution",
            1u << bits, mib(double(plan.fixed_bytes + 2 * plan.cell_bytes)),
            mib(double(plan.fixed_bytes)), mib(double(plan.cell_bytes)), mib(double(budget))));
    }
  }
  const int c = plan.bits;
  const int cell_level = L - c;  // node level of a cell's root

  // Bin every triangle into the cells its voxel bounding box overlaps, then
  // sort by (cell Morton code, triangle): cells in Morton order, each cell's
  // triangles ascending (voxelize_cell sums attributes in that order).
  std::vector<detail::CellBin> bins = detail::bin_triangles(mesh, gv, grid, c);

  std::vector<LevelTable> tables(size_t(L - 1));  // levels 0 .. L-2
  SparseVoxelDag dag;
  dag.grid = grid;
  std::vector<uint64_t> roots_keys;  // cell codes at level cell_level, ascending
  std::vector<uint32_t> roots_ids;
  uint64_t voxel_total = 0, cells = 0, max_cell_voxels = 0;
  double voxelize_s = 0, reduce_s = 0;
  std::vector<uint32_t> tri_list;
  std::vector<uint64_t> keys, pkeys;
  std::vector<uint32_t> ids, pids;
  std::vector<uint32_t> pending_colors, pending_normals;  // compressed: < 16 voxels between cells
  {
    Progress progress("DAG cells", bins.size(), options.progress);
    VoxelizeOptions vo;
    vo.mode = options.mode;
    vo.attributes = options.attributes;
    for (size_t b = 0; b < bins.size();) {
      size_t e = b;
      tri_list.clear();
      while (e < bins.size() && bins[e].cell == bins[b].cell) tri_list.push_back(bins[e++].tri);
      const uint64_t cell = bins[b].cell;
      const MortonCoord cc = morton_decode(cell);
      const uint32_t cell_lo[3] = {cc.x << c, cc.y << c, cc.z << c};
      Clock::time_point t0 = Clock::now();
      VoxelSet vs = detail::voxelize_cell(mesh, grid, gv, tri_list.data(), tri_list.size(), cell_lo,
                                          1u << c, vo);
      voxelize_s += seconds_since(t0);
      t0 = Clock::now();
      progress.advance(e - b);
      b = e;
      if (vs.codes.empty()) continue;
      ++cells;
      max_cell_voxels = std::max<uint64_t>(max_cell_voxels, vs.codes.size());
      voxel_total += vs.codes.size();
      if (options.attributes) {
        // Raw: appended to the DAG's arrays. Compressed: to `pending`, whose
        // whole 16-voxel blocks are encoded right away (blocks start at
        // multiples of 16 of the global Morton order, as compress_attributes'
        // do); fewer than 16 voxels wait for the next cell.
        std::vector<uint32_t>& to_c = options.compress_attributes ? pending_colors : dag.colors;
        std::vector<uint32_t>& to_n = options.compress_attributes ? pending_normals : dag.normals;
        const size_t base = to_c.size();
        to_c.resize(base + vs.size());
        to_n.resize(base + vs.size());
        tbb::parallel_for(size_t(0), vs.size(), [&](size_t i) {
          to_c[base + i] = esvo::encode_color_abgr(vs.colors[i]);
          to_n[base + i] = esvo::encode_normal_cube(vs.normals[i]);
        });
        if (options.compress_attributes) {
          constexpr size_t S = SparseVoxelDag::kCompressedSlots;
          const size_t whole = to_c.size() / S * S, at = dag.attribute_blocks.size();
          dag.attribute_blocks.resize(at + whole / S * SparseVoxelDag::kCompressedBlockWords);
          SparseVoxelDag::encode_compressed_blocks(to_c.data(), to_n.data(), whole,
                                                   dag.attribute_blocks.data() + at);
          to_c.erase(to_c.begin(), to_c.begin() + ptrdiff_t(whole));
          to_n.erase(to_n.begin(), to_n.begin() + ptrdiff_t(whole));
        }
      }
      // Leaf masks (level L-2), then up to the cell's root (svdag §3).
      keys.clear();
      ids.clear();
      {
        uint64_t cur = ~0ull, m = 0;
        auto flush = [&]() {
          const uint32_t w[2] = {uint32_t(m), uint32_t(m >> 32)};
          ids.push_back(tables[size_t(L - 2)].intern(w, 2));
        };
        for (uint64_t code : vs.codes) {
          const uint64_t k = layout::LeafBlockCode::get(code);
          if (k != cur) {
            if (cur != ~0ull) flush();
            keys.push_back(k);
            cur = k;
            m = 0;
          }
          m |= 1ull << layout::LeafMaskBit::get(code);
        }
        flush();
      }
      vs = VoxelSet{};
      for (int l = L - 3; l >= cell_level; --l) {
        reduce_level(tables[size_t(l)], keys, ids, &pkeys, &pids);
        std::swap(keys, pkeys);
        std::swap(ids, pids);
      }
      if (keys.size() != 1 || keys[0] != cell)
        throw Error("DAG build: internal error, a cell did not reduce to one root");
      roots_keys.push_back(cell);
      roots_ids.push_back(ids[0]);
      reduce_s += seconds_since(t0);
      uint64_t held =
          plan.fixed_bytes + uint64_t(dag.colors.capacity() + dag.normals.capacity() +
                                      dag.attribute_blocks.capacity() + pending_colors.capacity() +
                                      pending_normals.capacity()) *
                                 4;
      for (const LevelTable& t : tables) held += t.bytes();
      if (held > budget)
        throw Error(
            fmt::format("out-of-core DAG build: the DAG so far plus the mesh hold {}, more "
                        "than the {} memory budget; raise --memory-budget or lower "
                        "--resolution",
                        mib(double(held)), mib(double(budget))));
    }
    progress.finish();
  }
  if (voxel_total == 0) throw Error("DAG build: no voxels");
  if (!pending_colors.empty()) {  // the last, partial block
    const size_t at = dag.attribute_blocks.size();
    dag.attribute_blocks.resize(at + SparseVoxelDag::kCompressedBlockWords);
    SparseVoxelDag::encode_compressed_blocks(pending_colors.data(), pending_normals.data(),
                                             pending_colors.size(),
                                             dag.attribute_blocks.data() + at);
  }
  pending_colors = {};
  pending_normals = {};
  bins = {};

  // The top levels above the cells, from the cell roots (Morton order).
  const Clock::time_point t_top = Clock::now();
  keys = std::move(roots_keys);
  ids = std::move(roots_ids);
  for (int l = cell_level - 1; l >= 0; --l) {
    reduce_level(tables[size_t(l)], keys, ids, &pkeys, &pids);
    std::swap(keys, pkeys);
    std::swap(ids, pids);
  }
  for (LevelTable& t : tables) t.drop_index();

  // Layout exactly as build.cpp: levels back to back from the root, nodes in
  // id order, child ids replaced by absolute word indices.
  uint64_t total = 0;
  dag.level_start.assign(size_t(L), 0);
  for (int l = 0; l <= L - 2; ++l) {
    dag.level_start[size_t(l)] = uint32_t(std::min<uint64_t>(total, 0xFFFFFFFFull));
    total += tables[size_t(l)].words();
    if (total > 0xFFFFFFFFull) throw Error("DAG build: the DAG exceeds 2^32 words");
  }
  dag.level_start[size_t(L - 1)] = uint32_t(total);
  assign_huge(dag.words, size_t(total), 0u, HugePages::kHot);  // every ray walks them
  for (int l = 0; l <= L - 2; ++l) {
    const std::vector<uint32_t>& src = tables[size_t(l)].data();
    uint32_t* dst = dag.words.data() + dag.level_start[size_t(l)];
    if (l == L - 2) {
      std::copy(src.begin(), src.end(), dst);
    } else {
      const std::vector<uint32_t>& starts = tables[size_t(l)].start();
      const std::vector<uint32_t>& child_start = tables[size_t(l + 1)].start();
      const uint32_t child_base = dag.level_start[size_t(l + 1)];
      tbb::parallel_for(size_t(0), starts.size(), [&](size_t i) {
        const uint32_t s = starts[i];
        const uint32_t h = src[s];
        dst[s] = h;
        const int k = std::popcount(h);
        for (int j = 1; j <= k; ++j)
          dst[s + uint32_t(j)] = child_base + child_start[src[s + uint32_t(j)]];
      });
    }
    // Level l's ids were needed only by level l-1, done before.
    if (l > 0) tables[size_t(l - 1)].release();
  }
  tables.clear();
  dag.finalize();
  reduce_s += seconds_since(t_top);
  if (report) {
    report->cell_size = 1u << c;
    report->cells = cells;
    report->max_cell_voxels = max_cell_voxels;
    report->estimated_cell_bytes = plan.cell_bytes;
    report->fixed_bytes = plan.fixed_bytes;
    report->voxelize_seconds = voxelize_s;
    report->reduce_seconds = reduce_s;
    report->total_seconds = seconds_since(t_start);
  }
  return dag;
}

}  // namespace voxcast::dag
