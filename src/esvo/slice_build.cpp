// The top-down slice builder (esvo §7.1): the slice file of a mesh without
// ever holding its octree. Slices are built one octree level at a time; the
// slices of a level have no dependencies between them and are built in
// parallel, each written as soon as it is done. A slice's "build data" is
// its region: the builder voxelizes the region cell by cell
// (voxelize/cell.hpp, exact restriction of voxelize()) and reduces the
// voxels, streamed in Morton order, up to the slice's level with the in-core
// builder's own reduction (esvo/reduce.hpp), so that the file equals
// write_slices(build_octree(voxelize(mesh))) byte for byte. The same pass
// yields the exact sizes of the next level, from which the slice plans its
// children (slice_plan.hpp) before they are built.
//
// Contours and the geometric variable depth (§7.1-7.2): an unbuilt slice
// also carries the build data the paper lists -- the triangles overlapping
// its region and the ancestor contours (the planner's SubtreeSeed of the
// region's voxel). Building it plans the region top-down from that seed
// (contours.cpp, the in-core planner itself, so a voxel gets exactly the
// contour and refine decision it gets in core: both depend only on the
// voxel's ancestors), two levels deep: the contours of the slice's children
// (level n + 1) and, for the sizes of the next level's records, of theirs
// (n + 2). Voxels below a voxel planned as a leaf are left out. A second
// pass down to the child slices' region depth hands each child its seed.
//
// Displacement (§7.4): a region is voxelized from the displacement
// primitives (voxelize/displacement_cells.hpp) whose displaced bound
// overlaps its cells, restricted exactly to the cell, so that the file
// equals slicing the in-core displaced build.
//
// Cost: every level streams the voxels of the regions it covers, i.e. the
// scene is voxelized once per level (the paper passes triangle lists down
// instead; see README "Slices"); with contours every voxel is also planned
// about twice (as a child and as a grandchild). Memory: the mesh, its
// triangle bins, the directory, the seeds of the unbuilt slices of one
// level and per worker one cell's voxels plus one slice.
#include <fcntl.h>
#include <tbb/parallel_for.h>
#include <unistd.h>
#include <xxhash.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <fstream>
#include <thread>

#include "esvo/contours.hpp"
#include "esvo/reduce.hpp"
#include "esvo/slice_plan.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo_slices.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/system.hpp"
#include "voxelize/cell.hpp"
#include "voxelize/displacement_cells.hpp"

namespace voxcast::esvo {
namespace sl = slice_layout;

namespace {

/// A node of the slice's child level (n + 1) as the reduction emits it.
struct OutNode {
  uint64_t code;
  Color color;
  Vec3 normal;
  uint8_t mask;  // its children (0 at the finest level)
};

/// Streaming bottom-up reduction of Morton-ordered voxels: one open sibling
/// group per level; a group is reduced when the next node has another
/// parent, which in Morton order means it is complete. Every node is
/// reduced from exactly its children's floats, as build_octree does. The
/// nodes of level `emit` go to `out`; the reduction goes on up to `top`
/// (<= emit). With `record`, the raw values of the nodes of levels
/// [record_lo, record_lo + record->size()) are appended to it per level, in
/// Morton order.
class Reducer {
 public:
  Reducer(int levels, int emit, int top = -1)
      : levels_(levels), emit_(emit), top_(top < 0 ? emit : top), open_(size_t(levels) + 1) {}

  void record_values(std::vector<std::vector<uint64_t>>* record, int lo) {
    record_ = record;
    record_lo_ = lo;
  }

  void push(int d, uint64_t code, const Color& c, Vec3 n, float w, uint8_t mask) {
    if (record_ != nullptr && d >= record_lo_ && size_t(d - record_lo_) < record_->size())
      (*record_)[size_t(d - record_lo_)].push_back(detail::encode_value(c, n));
    if (d == emit_) out.push_back({code, c, n, mask});
    if (d == top_) return;
    Open& o = open_[size_t(d)];
    if (o.k > 0 && o.parent != code >> 3) flush(d);
    o.parent = code >> 3;
    o.color[o.k] = c, o.normal[o.k] = n, o.weight[o.k] = w;
    o.mask |= uint8_t(1u << (code & 7));
    ++o.k;
  }
  void finish() {
    for (int d = levels_; d > top_; --d)
      if (open_[size_t(d)].k > 0) flush(d);
  }

  std::vector<OutNode> out;

 private:
  struct Open {
    uint64_t parent = 0;
    int k = 0;
    uint8_t mask = 0;
    Color color[8];
    Vec3 normal[8];
    float weight[8];
  };
  void flush(int d) {
    Open& o = open_[size_t(d)];
    Color c;
    Vec3 n;
    float w;
    detail::reduce_node(o.color, o.normal, o.weight, o.k, &c, &n, &w);
    const uint64_t parent = o.parent;
    const uint8_t mask = o.mask;
    o.k = 0, o.mask = 0;
    push(d - 1, parent, c, n, w, mask);
  }
  int levels_, emit_, top_;
  std::vector<Open> open_;
  std::vector<std::vector<uint64_t>>* record_ = nullptr;
  int record_lo_ = 0;
};

struct Builder {
  const Mesh& mesh;
  const GridTransform& grid;
  const VoxelizeOptions& vo;
  std::vector<std::array<double, 3>> gv;
  std::vector<voxcast::detail::CellBin> bins;
  int cell_bits = 0;
  int cell_level = 0;  // depth of a cell cube
  int fd = -1;         // the data file
  std::filesystem::path data_path;
  std::atomic<uint64_t> cells{0}, voxels{0}, max_cell_voxels{0};
  // Displaced (§7.4): the regions are voxelized from the displacement
  // primitives (bins hold task indices, not triangles).
  std::unique_ptr<const voxcast::detail::DisplacedVoxelizer> displaced;
  // With contours: what the in-core planner gets, and its mesh.
  BuildOptions plan_options;
  std::shared_ptr<const detail::PlannerMesh> pmesh;  // null: no contours
  bool compressed = false;                           // §5.5 compression blocks per slice
  using Seed = std::shared_ptr<const detail::SubtreeSeed>;

  /// Voxelizes the aligned cube (depth `depth`, code `code`) with the
  /// triangles of the bins [b0, b1).
  VoxelSet voxelize_cube(int depth, uint64_t code, size_t b0, size_t b1) {
    std::vector<uint32_t> tris;
    tris.reserve(b1 - b0);
    for (size_t b = b0; b < b1; ++b) tris.push_back(bins[b].tri);
    std::sort(tris.begin(), tris.end());
    tris.erase(std::unique(tris.begin(), tris.end()), tris.end());
    const MortonCoord m = morton_decode(code);
    const uint32_t side = 1u << (grid.levels - depth);
    const uint32_t lo[3] = {uint32_t(m.x) * side, uint32_t(m.y) * side, uint32_t(m.z) * side};
    VoxelSet v = displaced != nullptr ? displaced->voxelize(tris.data(), tris.size(), lo, side, vo)
                                      : voxcast::detail::voxelize_cell(mesh, grid, gv, tris.data(),
                                                                       tris.size(), lo, side, vo);
    ++cells;
    voxels += v.size();
    uint64_t seen = max_cell_voxels.load();
    while (v.size() > seen && !max_cell_voxels.compare_exchange_weak(seen, v.size())) {
    }
    if (v.colors.empty()) {
      v.colors.assign(v.size(), detail::kDefaultColor);
      v.normals.assign(v.size(), detail::kDefaultNormal);
    }
    return v;
  }

  /// Calls f(voxels) for the voxels of the region (depth r, code), cube by
  /// cube in Morton order.
  template <class F>
  void for_each_region_cube(int r, uint64_t region_code, F&& f) {
    if (r >= cell_level) {
      // The region lies in one cell: its triangles are a superset of the region's.
      const uint64_t cell = region_code >> (3 * (r - cell_level));
      const auto [b0, b1] = bin_range(cell, cell + 1);
      if (b0 != b1) f(voxelize_cube(r, region_code, b0, b1));
      return;
    }
    const int s = 3 * (cell_level - r);
    const auto [b0, b1] = bin_range(region_code << s, (region_code + 1) << s);
    for (size_t a = b0; a < b1;) {
      size_t b = a;
      while (b < b1 && bins[b].cell == bins[a].cell) ++b;
      f(voxelize_cube(cell_level, bins[a].cell, a, b));
      a = b;
    }
  }

  /// The bins of the cells with codes in [lo, hi) (cell level).
  std::pair<size_t, size_t> bin_range(uint64_t lo, uint64_t hi) const {
    auto cmp = [](const voxcast::detail::CellBin& b, uint64_t v) { return b.cell < v; };
    return {size_t(std::lower_bound(bins.begin(), bins.end(), lo, cmp) - bins.begin()),
            size_t(std::lower_bound(bins.begin(), bins.end(), hi, cmp) - bins.begin())};
  }

  /// Slice i's data -- descriptor words, then the children's attributes and
  /// contours -- written as soon as it is done at the offset its parent's
  /// plan gave it (relative to the data until the file is assembled); sets
  /// its counts, size and hash.
  void write_slice(uint32_t i, sl::SliceEntry& e, std::vector<uint32_t>& words,
                   const std::vector<uint32_t>& attrs, const std::vector<uint32_t>& contours,
                   const std::vector<uint32_t>* blocks_made = nullptr) {
    if (words.size() != e.node_count && i != 0)
      throw Error("slice builder: slice " + std::to_string(i) + " holds " +
                  std::to_string(words.size()) + " descriptors, its parent planned " +
                  std::to_string(e.node_count));
    e.node_count = uint32_t(words.size());
    e.voxel_count = uint32_t(attrs.size() / 2);
    e.contour_count = uint32_t(contours.size());
    const uint64_t planned = e.data_bytes;
    if (compressed) {
      // The blocks of these descriptors and attributes (made already by the
      // §7.3 test, else now).
      const std::vector<uint32_t> blocks =
          blocks_made != nullptr ? *blocks_made : detail::compress_slice_attributes(words, attrs);
      words.insert(words.end(), blocks.begin(), blocks.end());
    } else {
      words.insert(words.end(), attrs.begin(), attrs.end());
    }
    words.insert(words.end(), contours.begin(), contours.end());
    e.data_bytes = uint32_t(words.size() * 4);
    // The data of the slices after it was placed by the parent's plan.
    if (i != 0 && e.data_bytes != planned)
      throw Error("slice builder: slice " + std::to_string(i) + " holds " +
                  std::to_string(e.data_bytes) + " bytes, its parent planned " +
                  std::to_string(planned));
    e.hash = XXH64(words.data(), words.size() * 4, 0);
    const char* p = reinterpret_cast<const char*>(words.data());
    for (size_t done = 0; done < e.data_bytes;) {
      const ssize_t w = ::pwrite(fd, p + done, e.data_bytes - done, off_t(e.data_offset + done));
      if (w < 0 && errno == EINTR) continue;
      if (w <= 0) throw Error("slice builder: cannot write '" + data_path.string() + "'");
      done += size_t(w);
    }
  }

  /// The child slices planned from the next level's records `next`, with the
  /// node counts and sizes the next level will have.
  std::vector<sl::SliceEntry> plan_children(const std::vector<detail::PlanNode>& next, int n, int r,
                                            uint32_t i, uint64_t slice_bytes) const {
    std::vector<sl::SliceEntry> children;
    detail::plan_child_slices(next, n, r, i, slice_bytes, &children);
    for (sl::SliceEntry& c : children) {
      const int shift = 3 * (n + 1 - c.region_depth);
      for (const detail::PlanNode& q : next)
        if ((q.code >> shift) == c.region_code) {
          ++c.node_count;
          c.data_bytes += q.bytes;
        }
      c.data_bytes =
          uint32_t(detail::slice_data_bytes_from_records(c.data_bytes, c.node_count, compressed));
    }
    return children;
  }

  /// Builds slice `e` (index i): its data written at its planned offset in
  /// the data file, its counts and hash set, its children (planned from the
  /// exact next level) returned with their counts and sizes. With contours
  /// `seed` is the region's build data and the children's go to `child_seeds`.
  /// With compressed attributes and the attribute tolerances, `desc` marks
  /// which of the region's voxels of the node level are the slice's
  /// descriptors (its parent's decisions, 1 byte per voxel in Morton order;
  /// null for the root) and the children's go to `child_descs`.
  std::vector<sl::SliceEntry> build(uint32_t i, sl::SliceEntry& e, uint64_t slice_bytes,
                                    const Seed& seed = nullptr,
                                    std::vector<Seed>* child_seeds = nullptr,
                                    const std::vector<uint8_t>* desc = nullptr,
                                    std::vector<std::vector<uint8_t>>* child_descs = nullptr) {
    const int L = grid.levels, n = e.node_level, r = e.region_depth;
    // With the attribute tolerances (§7.3) the reduction goes on up to the
    // region's depth and keeps the raw values of depths r..n + 2.
    const bool attr_tolerance =
        pmesh != nullptr && (plan_options.color_error >= 0 || plan_options.normal_error >= 0);
    Reducer red(L, n + 1, attr_tolerance ? r : n + 1);
    std::vector<std::vector<uint64_t>> values;  // [d - r][node]
    if (attr_tolerance) {
      values.resize(size_t(std::min(n + 2, L) - r + 1));
      red.record_values(&values, r);
    }
    for_each_region_cube(r, e.region_code, [&](const VoxelSet& v) {
      for (size_t k = 0; k < v.size(); ++k)
        red.push(L, v.codes[k], v.colors[k], v.normals[k], v.weights.empty() ? 1.f : v.weights[k],
                 0);
    });
    red.finish();
    if (pmesh != nullptr)
      return build_contoured(i, e, slice_bytes, red.out, values, seed, child_seeds, desc,
                             child_descs);
    // The slice: level-n descriptors (the parents of the emitted nodes) and
    // the emitted nodes' attributes.
    const bool finest = n + 1 == L;
    std::vector<uint32_t> words, attrs;
    std::vector<detail::PlanNode> next;
    for (size_t a = 0; a < red.out.size();) {
      uint32_t valid = 0;
      size_t b = a;
      for (; b < red.out.size() && (red.out[b].code >> 3) == (red.out[a].code >> 3); ++b) {
        valid |= 1u << (red.out[b].code & 7);
        attrs.push_back(encode_color_abgr(red.out[b].color));
        attrs.push_back(encode_normal_cube(red.out[b].normal));
        if (!finest)
          next.push_back({red.out[b].code, detail::slice_record_bytes(
                                               std::popcount(red.out[b].mask), 0, compressed)});
      }
      words.push_back(sl::SliceValid::put(valid) | sl::SliceLeaf::put(finest ? valid : 0u));
      a = b;
    }
    e.link_count = finest ? 0u : uint32_t(attrs.size() / 2);
    write_slice(i, e, words, attrs, {});
    return plan_children(next, n, r, i, slice_bytes);
  }

  /// REFINE-ATTRIBUTES (§7.3) of the region's voxels of depths r..n + 2
  /// (`values`, their raw values per depth in Morton order) into
  /// flags[d][node]: a second pass over the region's full-depth voxels, each
  /// compared with its ancestors, as the in-core planner compares a voxel
  /// with every full-depth voxel below it (attributes_exceed()).
  ///
  /// With compressed attributes (`decoded` given) the test is of what the
  /// file will hold (§7.3 "attribute quantization and compression is
  /// performed before the test"), as in core: a voxel of depth n + 1 is
  /// flagged if its raw value or its value decoded from the slice's block
  /// is out of tolerance (the in-core builder refines a leaf whose decoded
  /// value is; refining never changes a block of the slice that holds the
  /// voxel, so one pass decides). Depths r..n are the parent's decisions,
  /// given in `decoded->fixed` and not compared again.
  struct Decoded {
    int depth = 0;                                   // n + 1
    const std::vector<uint32_t>* color;              // [node at depth n + 1]: sRGB ABGR code
    const std::vector<Vec3>* normal;                 // as the file renders it
    const std::vector<std::vector<uint8_t>>* fixed;  // [d][node] for d = r..n: flags
  };
  const std::vector<std::vector<uint8_t>>& attribute_flags(
      const sl::SliceEntry& e, const std::vector<std::vector<uint64_t>>& values,
      std::vector<std::vector<uint8_t>>& flags, const Decoded* decoded = nullptr) {
    const int L = grid.levels, r = e.region_depth;
    const int top = r + int(values.size()) - 1;  // deepest flagged depth
    flags.assign(size_t(top) + 1, {});
    for (int d = r; d <= top; ++d) flags[size_t(d)].assign(values[size_t(d - r)].size(), 0);
    const int first_compared = decoded != nullptr ? decoded->depth : r;
    if (decoded != nullptr)
      for (int d = r; d < first_compared; ++d) {
        if ((*decoded->fixed)[size_t(d - r)].size() != flags[size_t(d)].size())
          throw std::logic_error("slice builder: the parent's decisions do not match the region");
        flags[size_t(d)] = (*decoded->fixed)[size_t(d - r)];
      }
    // Per depth, the index of the node the current voxel lies below (voxels
    // come in Morton order, so it only moves forward) and its code.
    std::vector<size_t> at(values.size(), 0);
    std::vector<uint64_t> at_code(values.size(), ~uint64_t(0));
    std::vector<uint64_t> raw;
    for_each_region_cube(r, e.region_code, [&](const VoxelSet& v) {
      raw.resize(v.size());
      for (size_t k = 0; k < v.size(); ++k)
        raw[k] = detail::encode_value(v.colors[k], v.normals[k]);
      for (int d = first_compared; d <= top; ++d) {
        const size_t j = size_t(d - r);
        const int shift = 3 * (L - d);
        std::vector<uint8_t>& f = flags[size_t(d)];
        const bool with_decoded = decoded != nullptr && d == decoded->depth;
        // Runs of voxels below one node of depth d.
        for (size_t a = 0; a < v.size();) {
          const uint64_t c = v.codes[a] >> shift;
          size_t b = a + 1;
          while (b < v.size() && (v.codes[b] >> shift) == c) ++b;
          if (c != at_code[j]) {
            if (at_code[j] != ~uint64_t(0)) ++at[j];
            at_code[j] = c;
          }
          if (at[j] >= f.size())
            throw std::logic_error("slice builder: a voxel outside its region");
          if (!f[at[j]]) {
            const uint64_t nv = values[j][at[j]];
            f[at[j]] = detail::values_exceed(raw.data(), a, b, uint32_t(nv),
                                             decode_normal_cube(uint32_t(nv >> 32)), plan_options);
            if (with_decoded && !f[at[j]])
              f[at[j]] = detail::values_exceed(raw.data(), a, b, (*decoded->color)[at[j]],
                                               (*decoded->normal)[at[j]], plan_options);
          }
          a = b;
        }
      }
    });
    return flags;
  }

  /// build() with contours: `out` are the region's voxels of level n + 1.
  std::vector<sl::SliceEntry> build_contoured(uint32_t i, sl::SliceEntry& e, uint64_t slice_bytes,
                                              const std::vector<OutNode>& out,
                                              const std::vector<std::vector<uint64_t>>& values,
                                              const Seed& seed, std::vector<Seed>* child_seeds,
                                              const std::vector<uint8_t>* desc,
                                              std::vector<std::vector<uint8_t>>* child_descs) {
    const int L = grid.levels, n = e.node_level, r = e.region_depth;
    if (seed == nullptr || child_seeds == nullptr)
      throw std::logic_error("slice builder: a contoured slice without its build data");
    // The region's tree, depths r..n + 1 (index d - r): codes, masks and
    // first children, rebuilt from the level n + 1 voxels in Morton order.
    const int D = n + 2 - r;
    std::vector<std::vector<uint64_t>> code(static_cast<size_t>(D));
    std::vector<std::vector<uint8_t>> mask(static_cast<size_t>(D));
    std::vector<std::vector<uint32_t>> first(static_cast<size_t>(D));
    {
      auto& c = code[size_t(D) - 1];
      auto& m = mask[size_t(D) - 1];
      auto& f = first[size_t(D) - 1];
      uint64_t below = 0;  // voxels at n + 2
      for (const OutNode& o : out) {
        c.push_back(o.code);
        m.push_back(o.mask);
        f.push_back(uint32_t(below));
        below += uint64_t(std::popcount(unsigned(o.mask)));
      }
      if (below >= (uint64_t(1) << 32))
        throw Error("slice builder: more than 2^32 voxels in a slice");
    }
    for (int k = D - 2; k >= 0; --k) {
      const auto& cc = code[size_t(k) + 1];
      for (size_t a = 0; a < cc.size(); ++a) {
        const uint64_t p = cc[a] >> 3;
        if (code[size_t(k)].empty() || code[size_t(k)].back() != p) {
          code[size_t(k)].push_back(p);
          mask[size_t(k)].push_back(0);
          first[size_t(k)].push_back(uint32_t(a));
        }
        mask[size_t(k)].back() |= uint8_t(1u << (cc[a] & 7));
      }
    }
    if (code[0].size() != 1 || code[0][0] != e.region_code)
      throw std::logic_error("slice builder: the region's voxels are not below its cube");
    detail::TreeView t;
    t.levels = L;
    t.mask.assign(size_t(L), nullptr);
    t.first_child.assign(size_t(L), nullptr);
    t.count.assign(size_t(L) + 1, 0);
    t.value.assign(size_t(L) + 1, nullptr);
    for (int d = r; d <= n + 1; ++d) {
      const size_t k = size_t(d - r);
      if (d < L) {
        t.mask[size_t(d)] = mask[k].data();
        t.first_child[size_t(d)] = first[k].data();
      }
      t.count[size_t(d)] = code[k].size();
    }
    if (n + 2 <= L) {
      uint64_t below = 0;
      for (const OutNode& o : out) below += uint64_t(std::popcount(unsigned(o.mask)));
      t.count[size_t(n) + 2] = size_t(below);
    }
    for (int d = r; d <= std::min(n + 2, L) && !values.empty(); ++d)
      if (values[size_t(d - r)].size() != t.count[size_t(d)])
        throw std::logic_error("slice builder: the region's values do not match its tree");
    // Compressed with the tolerances: the slice's descriptors are its
    // parent's decisions (`desc`), so its §5.5 blocks -- and what each child
    // decodes to -- are known before planning.
    const bool decoded_test = compressed && !values.empty();
    const size_t kn = size_t(n - r);
    std::vector<std::vector<uint8_t>> fixed;
    std::vector<uint32_t> dcolor, blocks, raw_expected;
    std::vector<Vec3> dnormal;
    if (decoded_test) {
      const std::vector<uint8_t> root{1};
      const std::vector<uint8_t>& is_desc = desc != nullptr ? *desc : root;
      if (is_desc.size() != code[kn].size())
        throw std::logic_error("slice builder: the parent's decisions do not match the region");
      // Depths r..n: refined exactly where a descriptor lies below (the
      // parent's decisions; elsewhere what the planner decides changes
      // nothing this slice holds).
      fixed.resize(kn + 1);
      fixed[kn] = is_desc;
      for (size_t k = kn; k-- > 0;) {
        fixed[k].assign(code[k].size(), 0);
        for (size_t p = 0; p < code[k].size(); ++p)
          for (int c = 0; c < std::popcount(unsigned(mask[k][p])); ++c)
            fixed[k][p] |= fixed[k + 1][first[k][p] + size_t(c)];
      }
      // The slice's descriptor words (valid masks) and children's raw
      // attributes, as the slice will hold them; its blocks, made once
      // (write_slice stores them), and what each child decodes to.
      std::vector<uint32_t> dwords;
      std::vector<size_t> child_of;  // [k]: the index in `out` of the k-th child
      for (size_t j = 0; j < is_desc.size(); ++j) {
        if (!is_desc[j]) continue;
        dwords.push_back(sl::SliceValid::put(mask[kn][j]));
        for (int c = 0; c < std::popcount(unsigned(mask[kn][j])); ++c) {
          const OutNode& o = out[first[kn][j] + size_t(c)];
          raw_expected.push_back(encode_color_abgr(o.color));
          raw_expected.push_back(encode_normal_cube(o.normal));
          child_of.push_back(first[kn][j] + size_t(c));
        }
      }
      blocks = detail::compress_slice_attributes(dwords, raw_expected);
      const std::vector<uint32_t> decoded_attrs =
          detail::decode_slice_attributes(dwords, blocks.data());
      dcolor.assign(out.size(), 0);
      dnormal.assign(out.size(), Vec3{});
      for (size_t k = 0; k < child_of.size(); ++k) {
        dcolor[child_of[k]] = decoded_attrs[2 * k];
        dnormal[child_of[k]] = decode_normal_cube(decoded_attrs[2 * k + 1]);
      }
    }
    std::vector<std::vector<uint8_t>> attr_flags;
    const Decoded dec{n + 1, &dcolor, &dnormal, &fixed};
    const std::vector<std::vector<uint8_t>>* flags =
        values.empty() ? nullptr
                       : &attribute_flags(e, values, attr_flags, decoded_test ? &dec : nullptr);
    // Contours of levels n + 1 and n + 2 and the leaf decisions, as in core.
    detail::ContourPlanner planner(t, pmesh, plan_options, *seed, n + 2 <= L ? n + 2 : L + 1, false,
                                   flags);
    const detail::ContourPlan& plan = planner.plan();
    auto refined = [&](int d, size_t j) {  // a subdivided voxel (the region's is)
      return d == r || (d < L && plan.leaf[size_t(d)][j] == 0);
    };
    // The voxels the octree keeps: below no leaf.
    std::vector<std::vector<uint8_t>> kept(static_cast<size_t>(D));
    kept[0].assign(1, 1);
    for (int d = r + 1; d <= n + 1; ++d) {
      const size_t k = size_t(d - r);
      kept[k].assign(code[k].size(), 0);
      for (size_t p = 0; p < code[k - 1].size(); ++p) {
        if (!kept[k - 1][p] || !refined(d - 1, p)) continue;
        const uint32_t f = first[k - 1][p];
        for (int c = 0; c < std::popcount(unsigned(mask[k - 1][p])); ++c)
          kept[k][f + size_t(c)] = 1;
      }
    }
    // The slice: level-n descriptors kept and subdivided, their children's
    // attributes and contours.
    std::vector<uint32_t> words, attrs, contours;
    std::vector<detail::PlanNode> next;
    std::vector<uint8_t> child_desc(decoded_test ? out.size() : 0, 0);
    for (size_t j = 0; j < code[kn].size(); ++j) {
      const bool is_descriptor = kept[kn][j] && refined(n, j);
      if (decoded_test && uint8_t(is_descriptor) != fixed[kn][j])
        throw std::logic_error("slice builder: a slice's descriptors are not its parent's");
      if (!is_descriptor) continue;
      const uint32_t valid = mask[kn][j];
      uint32_t leaf = 0, cmask = 0;
      const uint32_t f = first[kn][j];
      for (int s = 0, q = 0; s < 8; ++s) {
        if (!(valid >> s & 1)) continue;
        const size_t c = f + size_t(q++);
        const bool child_leaf = !refined(n + 1, c);
        if (child_leaf) leaf |= 1u << s;
        attrs.push_back(encode_color_abgr(out[c].color));
        attrs.push_back(encode_normal_cube(out[c].normal));
        if (const uint32_t v = plan.contour[size_t(n) + 1][c]; v != 0)
          cmask |= 1u << s, contours.push_back(v);
        if (!child_leaf) {
          if (decoded_test) child_desc[c] = 1;
          uint32_t with_contour = 0;
          const uint32_t g = first[size_t(D) - 1][c];
          for (int u = 0; u < std::popcount(unsigned(out[c].mask)); ++u)
            with_contour += plan.contour[size_t(n) + 2][g + size_t(u)] != 0;
          next.push_back(
              {out[c].code, detail::slice_record_bytes(std::popcount(unsigned(out[c].mask)),
                                                       int(with_contour), compressed)});
        }
      }
      words.push_back(sl::SliceValid::put(valid) | sl::SliceLeaf::put(leaf) |
                      sl::SliceContourMask::put(cmask));
      e.link_count += uint32_t(std::popcount(valid & ~leaf));
    }
    // (The descriptors were checked against the parent's above, so the
    // attributes are the ones the blocks were made of.)
    if (decoded_test && attrs != raw_expected)
      throw std::logic_error("slice builder: a slice's attributes are not its blocks'");
    write_slice(i, e, words, attrs, contours, decoded_test ? &blocks : nullptr);
    std::vector<sl::SliceEntry> children = plan_children(next, n, r, i, slice_bytes);
    // The children's build data: the seeds of their region voxels (all at
    // one depth k), from a second pass that stops there.
    child_seeds->clear();
    if (child_descs != nullptr) child_descs->clear();
    if (children.empty()) return children;
    if (decoded_test) {
      if (child_descs == nullptr) throw std::logic_error("slice builder: no room for decisions");
      const std::vector<uint64_t>& at_n1 = code[size_t(D) - 1];
      for (const sl::SliceEntry& c : children) {
        const int shift = 3 * (n + 1 - c.region_depth);
        const auto lo = std::lower_bound(at_n1.begin(), at_n1.end(), c.region_code << shift);
        const auto hi = std::lower_bound(at_n1.begin(), at_n1.end(), (c.region_code + 1) << shift);
        child_descs->emplace_back(child_desc.begin() + (lo - at_n1.begin()),
                                  child_desc.begin() + (hi - at_n1.begin()));
      }
    }
    const int k = children[0].region_depth;
    if (k == r) {  // the region is kept: one child, this seed
      child_seeds->assign(children.size(), seed);
      return children;
    }
    detail::ContourPlanner seeder(t, pmesh, plan_options, *seed, k, true, flags);
    (void)seeder.plan();
    const std::vector<uint64_t>& at_k = code[size_t(k - r)];
    for (const sl::SliceEntry& c : children) {
      const auto it = std::lower_bound(at_k.begin(), at_k.end(), c.region_code);
      Seed s = it != at_k.end() && *it == c.region_code
                   ? seeder.take_seed(uint32_t(it - at_k.begin()))
                   : nullptr;
      if (s == nullptr) throw std::logic_error("slice builder: a child region without its seed");
      child_seeds->push_back(std::move(s));
    }
    return children;
  }
};

}  // namespace

void build_slices(const Mesh& mesh, const GridTransform& grid, const VoxelizeOptions& voxelize,
                  const std::filesystem::path& path, const SliceBuildOptions& options,
                  SliceBuildStats* stats) {
  if (options.slice_bytes < 64) throw Error("slices: the slice size must be at least 64 bytes");
  if (grid.levels < 1 || grid.levels > 20 || grid.resolution != (1u << grid.levels))
    throw Error("slice builder: grid levels outside 1..20");
  if (options.max_level < 0 || options.max_level > grid.levels)
    throw Error("slice builder: max level " + std::to_string(options.max_level) + " outside 0.." +
                std::to_string(grid.levels));
  if (!std::isfinite(options.geometry_error) || options.geometry_error < 0)
    throw Error("slice builder: the geometry error must be finite and non-negative");
  if (!std::isfinite(options.color_error) || options.color_error > 255 ||
      !std::isfinite(options.normal_error) || options.normal_error > 180)
    throw Error(
        "slice builder: the color error must be at most 255 and the normal error at most "
        "180 degrees");
  if (!options.contours && (options.max_level != 0 || options.geometry_error > 0 ||
                            options.color_error >= 0 || options.normal_error >= 0))
    throw Error("slice builder: max level, geometry, color and normal error need contours");
  if (options.displacement != nullptr &&
      (options.contours || !std::isfinite(options.displacement_scale)))
    throw Error("slice builder: displacement needs a finite scale and no contours");
  Builder b{mesh, grid, voxelize, {}, {}, 0, 0, -1, {}, {}, {}, {}, {}, {}, {}};
  b.compressed = options.compressed;
  if (options.contours) {
    if (mesh.triangle_count() > size_t(UINT32_MAX))
      throw Error("slice builder: more than 2^32-1 triangles");
    b.plan_options.contours = true;
    b.plan_options.max_level = options.max_level;
    b.plan_options.geometry_error = options.geometry_error;
    b.plan_options.color_error = options.color_error;
    b.plan_options.normal_error = options.normal_error;
    b.pmesh = detail::make_planner_mesh(grid, mesh);
  }
  if (options.displacement != nullptr) {
    b.displaced = std::make_unique<const voxcast::detail::DisplacedVoxelizer>(
        mesh, *options.displacement, options.displacement_scale, grid);
  } else {
    b.gv = voxcast::detail::grid_vertices(mesh, grid);
  }
  // Cells: the largest whose working set, once per worker, fits half the
  // budget next to the mesh and the bins (or options.cell_size).
  const uint64_t budget = options.memory_budget ? options.memory_budget
                                                : uint64_t(double(available_memory_bytes()) * 0.9);
  const int workers = std::max(1, int(std::thread::hardware_concurrency()));
  if (options.cell_size != 0) {
    if (!std::has_single_bit(options.cell_size) || options.cell_size > grid.resolution)
      throw Error("slice builder: the cell size must be a power of two up to the resolution");
    b.cell_bits = std::countr_zero(options.cell_size);
  } else if (b.displaced != nullptr) {
    // A displaced cell holds its surface's marks (a few per voxel of it):
    // 128^3 cells keep that to megabytes.
    b.cell_bits = std::min(grid.levels, 7);
  } else {
    b.cell_bits = std::min(grid.levels, 4);
    for (int bits = b.cell_bits + 1; bits <= grid.levels; ++bits) {
      constexpr double kBytesPerPair = 64.0;  // voxel codes, attributes and sort scratch
      const auto plan = voxcast::detail::plan_cells(mesh, b.gv, grid, bits, kBytesPerPair);
      if (double(plan.fixed_bytes) + double(workers) * double(plan.cell_bytes) >
          0.5 * double(budget))
        break;
      b.cell_bits = bits;
    }
  }
  b.cell_level = grid.levels - b.cell_bits;
  b.bins = b.displaced != nullptr ? b.displaced->bin(b.cell_bits)
                                  : voxcast::detail::bin_triangles(mesh, b.gv, grid, b.cell_bits);

  b.data_path = path.string() + ".data.tmp";
  b.fd = ::open(b.data_path.c_str(), O_RDWR | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (b.fd < 0)
    throw Error("slice builder: cannot create '" + b.data_path.string() +
                "': " + std::strerror(errno));
  struct Cleanup {
    Builder& b;
    ~Cleanup() {
      ::close(b.fd);
      std::error_code ec;
      std::filesystem::remove(b.data_path, ec);
    }
  } cleanup{b};

  // Level by level (breadth-first, the directory order of write_slices):
  // the slices of one level in parallel, then their children appended in
  // order, with data offsets from the sizes their parents computed.
  std::vector<sl::SliceEntry> slices(1);
  slices[0].parent = sl::kNoParent;
  // With contours, the build data of the unbuilt slices (released when built).
  std::vector<Builder::Seed> seeds;
  if (b.pmesh != nullptr) seeds.push_back(detail::root_seed(*b.pmesh));
  // Compressed with the tolerances: each unbuilt slice's descriptors as its
  // parent decided them (released when built).
  std::vector<std::vector<uint8_t>> descs;
  uint64_t data_end = 0;
  size_t level_begin = 0;
  while (level_begin < slices.size()) {
    const size_t level_end = slices.size();
    std::vector<std::vector<sl::SliceEntry>> children(level_end - level_begin);
    std::vector<std::vector<Builder::Seed>> child_seeds(level_end - level_begin);
    std::vector<std::vector<std::vector<uint8_t>>> child_descs(level_end - level_begin);
    auto build_one = [&](size_t i) {
      Builder::Seed seed = b.pmesh != nullptr ? std::move(seeds[i]) : nullptr;
      std::vector<uint8_t> desc;
      if (i < descs.size()) desc = std::move(descs[i]);
      children[i - level_begin] =
          b.build(uint32_t(i), slices[i], options.slice_bytes, seed, &child_seeds[i - level_begin],
                  i == 0 ? nullptr : &desc, &child_descs[i - level_begin]);
    };
    if (level_begin == 0) {
      build_one(0);  // sizes only known after it
      data_end = slices[0].data_bytes;
    } else {
      tbb::parallel_for(level_begin, level_end, build_one);
    }
    for (size_t i = level_begin; i < level_end; ++i) {
      std::vector<sl::SliceEntry>& c = children[i - level_begin];
      slices[i].first_child = c.empty() ? 0u : uint32_t(slices.size());
      slices[i].child_count = uint32_t(c.size());
      for (sl::SliceEntry& e : c) {
        e.data_offset = data_end;
        data_end += e.data_bytes;
        slices.push_back(e);
      }
      if (b.pmesh != nullptr)
        for (Builder::Seed& s : child_seeds[i - level_begin]) seeds.push_back(std::move(s));
      if (!child_descs[i - level_begin].empty()) {
        descs.resize(slices.size() - c.size());
        for (std::vector<uint8_t>& d : child_descs[i - level_begin]) descs.push_back(std::move(d));
      }
    }
    level_begin = level_end;
  }

  // Assemble: header, directory, then the data file's bytes.
  const bool contours = b.pmesh != nullptr;
  sl::FileHeader h =
      detail::slice_file_header(grid, contours, b.compressed, options.slice_bytes, slices);
  for (sl::SliceEntry& e : slices) e.data_offset += h.data_offset;
  h = detail::slice_file_header(grid, contours, b.compressed, options.slice_bytes, slices);
  const std::filesystem::path tmp = path.string() + ".tmp";
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    if (!out) throw Error("slice builder: cannot create '" + tmp.string() + "'");
    out.write(reinterpret_cast<const char*>(&h), sizeof h);
    out.write(reinterpret_cast<const char*>(slices.data()),
              std::streamsize(slices.size() * sizeof(sl::SliceEntry)));
    std::vector<char> buf(size_t(1) << 20);
    for (uint64_t at = 0; at < data_end;) {
      const ssize_t got =
          ::pread(b.fd, buf.data(), std::min<uint64_t>(buf.size(), data_end - at), off_t(at));
      if (got < 0 && errno == EINTR) continue;
      if (got <= 0) throw Error("slice builder: cannot read back '" + b.data_path.string() + "'");
      out.write(buf.data(), got);
      at += uint64_t(got);
    }
    out.close();
    if (!out) throw Error("slice builder: write failed: '" + tmp.string() + "'");
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) throw Error("slice builder: cannot rename into place: " + ec.message());
  if (stats) {
    stats->slices = slices.size();
    stats->cell_size = 1u << b.cell_bits;
    stats->cells = b.cells;
    stats->voxels_streamed = b.voxels;
    stats->max_cell_voxels = b.max_cell_voxels;
    stats->file_bytes = h.file_bytes;
  }
}

}  // namespace voxcast::esvo
