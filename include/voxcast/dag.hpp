#pragma once
// Sparse voxel DAG (Kämpe, Sintorn & Assarsson 2013, "High Resolution Sparse
// Voxel DAGs"): the sparse voxel octree of a VoxelSet with identical subtrees
// merged bottom-up (svdag §3), ray cast with the ESVO loop (svdag §4).
//
// Memory layout (`SparseVoxelDag::words`, little-endian u32, NanoVDB-style):
//
//   Let L = grid.levels (N = 2^L voxels per axis, L >= 2). Node levels run from
//   0 (the root, the whole grid) to L-2; a node at level l covers a cube of
//   2^(L-l) voxels per axis.
//
//   Interior node (levels 0 .. L-3), 8 to 36 bytes (svdag §3, Figure 3):
//     word 0      header: bits 7..0 child mask (bit i = child slot i, i = x |
//                 y<<1 | z<<2, the low three Morton bits of the child's code,
//                 as in esvo.hpp); bits 31..8 reserved, 0.
//     word 1..k   k = popcount(mask) child pointers, in child-slot order:
//                 absolute word index of the child node in `words`.
//   Leaf-mask node (level L-2), 8 bytes: the 4^3 voxels of its cube as one
//   64-bit mask (svdag §3 "Implementation details": the two lowest levels
//   without pointers), word 0 = bits 31..0, word 1 = bits 63..32. Bit b is the
//   voxel whose Morton code relative to the 4^3 block is b (b = code & 63), so
//   byte c (bits 8c..8c+7) is the 2^3 sub-block in child slot c of the node
//   and bit j of that byte is its child slot j. Node kind follows from the
//   level (a leaf-mask node has no header).
//
//   Order: level by level, root at word 0, then every level-1 node, ..., then
//   every level-(L-2) node; the nodes tile the array without gaps and every
//   node is reachable. Hence every child pointer points strictly forward
//   (to a greater word index), so no pointer chain can form a cycle. Within a
//   level, nodes are in order of their first occurrence in Morton order, so
//   the output depends only on the voxel set (not on the thread count).
//
// Enforced by validate(): the tiling and order above, masks non-empty,
// reserved bits zero, pointers in bounds, pointing forward at the start of a
// node of the next level, attribute arrays sized to the leaf count.
//
// Attributes (Hitchhiker's guide to voxels, "Dynamic voxel indexing",
// prefix-sum-in-parent variant): leaf voxels are numbered 0..V-1 in Morton
// order; `colors`/`normals` hold their attributes in that order (32-bit ABGR
// sRGB color and 32-bit cube-face normal, the esvo.hpp encodings).
// `voxel_prefix` (derived, never stored in files) parallels `words`: for the
// pointer word of child slot i of an interior node it holds the number of
// leaf voxels in the node's children before slot i; header words hold the
// node's own leaf count, leaf-mask words 0. A ray accumulates these while
// descending, so the hit voxel's index costs no extra memory reads beyond
// the pointer's neighbour. A coarser (LOD) hit cube holds the consecutive
// ranks [first, first + count) (Morton order keeps a cube's voxels together);
// it shows their mean linear color and normalized mean normal, like the
// parent averages of an ESVO (esvo §5.4), via `attribute_prefix` below.
// Without attributes, voxels are gray (0.5, 0.5, 0.5) with the normal of the
// cube face the ray entered.
//
// Compressed attributes (esvo §5.5 applied to the Morton-order array, cf.
// Hitchhiker's guide: attributes in a separate array found by voxel index):
// instead of `colors`/`normals`, `attribute_blocks` holds ceil(V / 16) blocks
// of 6 words, block k = voxels [16k, 16k + 16) (slot = index & 15), encoded
// by the ESVO block codec (esvo.hpp "Compressed attribute attachment", the
// same bit fields and encoder; the last block's unused slots get index 0).
// Morton-adjacent voxels are mostly spatially close, the coherence §5.5
// relies on when it packs sibling voxels (but a run of 16 spans more surface
// than an ESVO block of two siblings' children, and may straddle a Morton
// jump: larger errors, docs/notes-dagattr.md). 24 B per 16 voxels = 1.5 B per
// voxel instead of 8; a hit decodes one slot of one 24-byte block (at most
// two cache lines, one miss where raw reads two arrays). `attribute_prefix`
// is derived from the decoded values, so a LOD mean is the mean of what the
// leaves show. Built by compress_attributes() from the raw arrays.
//
// 64-bit voxel indices: a scene may hold 2^32 or more leaf voxels (the bunny
// at 65536^3 has ~1.5e10), but only nodes near the root can count that many.
// Counts are monotone up the tree (a parent holds at least what any child
// holds), so the levels with some node of >= 2^32 voxels are a prefix 0..T-1
// of the levels. Their words [0, wide_words) take their prefix entries from
// `voxel_prefix_wide` (u64); every other word from `voxel_prefix` (u32, whose
// first wide_words entries are 0). Index memory is 4 bytes per DAG word plus
// 8 per top-level word: T = 0 (no wide table) below 2^32 voxels; for the bunny
// at 65536^3 (1.47e10 voxels, 3.9e8 words) only the root's 9 words are wide,
// 1.47 GiB + 72 B of index where u64 entries throughout would take 2.9 GiB.
//
// The DAG occupies [1,2]^3 in octree space exactly as the ESVO does
// (esvo §6.1); cube side 2^(s - esvo::kMaxScale) at scale s.
#include <array>
#include <bit>
#include <cstdint>
#include <memory>
#include <vector>

#include "voxcast/bitfield.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/math.hpp"
#include "voxcast/octree_structure.hpp"
#include "voxcast/structure.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast::detail {
struct DagNodes;  // its node-access policy, src/dag/octree_nodes.hpp
}  // namespace voxcast::detail

namespace voxcast::dag {

/// Bit fields of the layout above (pinned to the documented masks).
namespace layout {
// Interior node header: | 31..8 reserved (0) | 7..0 child mask |
using ChildMask = BitField<0, 8>;
using HeaderReserved = BitField<8, 24>;
static_assert(ChildMask::mask == 0xFFu && HeaderReserved::mask == 0xFFFFFF00u);
static_assert(fields_tile<ChildMask, HeaderReserved>());
// Leaf-mask node (64 bits): byte c = the 2^3 sub-block in child slot c.
using LeafMaskBytes = PackedFields<8, uint64_t>;
static_assert(LeafMaskBytes::get(0x0100000000000000ull, 7) == 1);
// A voxel's bit in its leaf-mask node is the low 6 bits of its Morton code;
// the remaining bits are the code of the node's 4^3 block.
using LeafMaskBit = BitField<0, 6, uint64_t>;
using LeafBlockCode = BitField<6, 58, uint64_t>;
static_assert(fields_tile<LeafMaskBit, LeafBlockCode>());
}  // namespace layout
inline constexpr uint32_t kReservedHeaderBits = layout::HeaderReserved::mask;

/// Per level l = 0 .. L: node counts of the DAG and of the plain SVO it was
/// reduced from (svdag Table 2). Level L holds the leaf voxels (no nodes).
struct LevelStats {
  uint64_t dag_nodes = 0;  // unique nodes (levels 0..L-2; L-1 and L live in the 64-bit masks)
  uint64_t svo_nodes = 0;  // nodes of the un-merged octree (levels 0..L-1), voxels at level L
  uint64_t dag_bytes = 0;  // words * 4 of this level's DAG nodes
};

struct DagStats {
  std::vector<LevelStats> levels;  // size L + 1
  uint64_t leaf_voxels = 0;
  uint64_t dag_nodes = 0;        // all levels
  uint64_t dag_bytes = 0;        // words.size() * 4 (geometry only)
  uint64_t svo_nodes = 0;        // levels 0..L-1
  uint64_t svo_bytes = 0;        // pointer-less SVO, 1 byte per node (Schnabel & Klein)
  uint64_t esvo_bytes = 0;       // 8 bytes per node (ESVO descriptor + contour word)
  uint64_t index_bytes = 0;      // voxel_prefix (+ _wide) + attribute_prefix (derived at load)
  uint64_t lod_mean_bytes = 0;   // of index_bytes: the LOD mean tables (cube_mean_bytes)
  uint64_t attribute_bytes = 0;  // colors + normals, or the compressed blocks
  bool compressed_attributes = false;  // attribute_bytes are esvo §5.5 blocks (24 B / 16 voxels)
  double bits_per_voxel = 0;           // dag_bytes * 8 / leaf_voxels
};

/// Leaf voxels [first, first + count) in Morton order.
struct VoxelRange {
  uint64_t first = 0;
  uint64_t count = 0;
};

class SparseVoxelDag {
 public:
  GridTransform grid;
  std::vector<uint32_t> words;    // layout above
  std::vector<uint32_t> colors;   // per leaf voxel in Morton order, ABGR; empty = no attributes
  std::vector<uint32_t> normals;  // per leaf voxel, cube-face encoding; empty iff colors is
  // Compressed alternative to colors + normals (see above): 6 words per 16
  // voxels; non-empty only when colors and normals are empty.
  std::vector<uint32_t> attribute_blocks;
  static constexpr uint32_t kCompressedSlots = 16;
  static constexpr uint32_t kCompressedBlockWords = 6;
  // Derived by finalize():
  std::vector<uint32_t> voxel_prefix;       // parallels words, see above
  std::vector<uint64_t> voxel_prefix_wide;  // words [0, wide_words): their u64 entries
  uint32_t wide_words = 0;                  // = level_start[T], see above
  std::vector<uint32_t>
      level_start;  // word index of the first node of level l, l = 0..L-1 (L-1: end)
  uint64_t leaf_voxels = 0;

  int levels() const { return grid.levels; }
  bool has_attributes() const { return !colors.empty() || !attribute_blocks.empty(); }
  bool compressed_attributes() const { return !attribute_blocks.empty(); }
  /// Replaces colors + normals by `attribute_blocks` (esvo §5.5 encoder, one
  /// block per 16 voxels in parallel; deterministic for any thread count)
  /// and re-derives the LOD prefix sums from the decoded values. No-op
  /// without attributes or when already compressed.
  void compress_attributes();
  /// The blocks of compress_attributes() for `count` Morton-consecutive voxels
  /// starting at a multiple of kCompressedSlots: ceil(count / 16) blocks of
  /// kCompressedBlockWords words to `out` (the last one partial when count is
  /// not a multiple of 16). Encoding an array piece by piece at block
  /// boundaries gives the bytes of encoding it whole.
  static void encode_compressed_blocks(const uint32_t* colors, const uint32_t* normals,
                                       size_t count, uint32_t* out);
  /// Prefix entry of word `w` (see above): the node's leaf count for a header
  /// word, the leaf count of the children before the slot for a pointer word.
  uint64_t prefix_entry(uint32_t w) const {
    return w < wide_words ? voxel_prefix_wide[w] : voxel_prefix[w];
  }

  /// Validates `words` and the attribute arrays (throws voxcast::Error naming
  /// the first problem) and computes the derived fields. After it succeeds,
  /// traversal and attribute lookup cannot read out of bounds or loop.
  void finalize();

  DagStats stats() const;
  /// The leaf voxels as sorted Morton codes (inverse of build_dag).
  std::vector<uint64_t> decode_leaves() const;
  /// The leaf voxels (sorted global Morton codes) inside the cube at `level`
  /// (0 = root .. L = one voxel) whose Morton code at that level is `cube`.
  std::vector<uint64_t> decode_cube(int level, uint64_t cube) const;
  /// Morton rank of `code`: the number of leaf voxels with a smaller code.
  uint64_t voxel_rank(uint64_t code) const;
  /// The leaf voxels [first, first + count) of the cube at `level` that holds
  /// leaf voxel `voxel` (< leaf_voxels): one descent by rank, O(L).
  VoxelRange cube_range(uint64_t voxel, int level) const;
  /// Linear color and unit normal of leaf voxel `index` (Morton rank).
  void voxel_attributes(uint64_t index, Color* color, Vec3* normal) const;
  /// Mean linear color and normalized mean normal of the leaf voxels in
  /// `range` (what a coarse LOD hit shows), from the blocked prefix sums below.
  void mean_attributes(VoxelRange range, Color* color, Vec3* normal) const;
  /// mean_attributes(ranges[i], &colors[i], &normals[i]) for i < n, the same
  /// floats: with raw attributes, the ranges of at most kBatchMeanVoxels
  /// voxels (a LOD hit's small cube) are read together (every line of a
  /// chunk's ranges prefetched before any is summed) and their normals
  /// decoded in vector lanes (esvo::decode_normal_cubes); the same integer
  /// sums, so the same means.
  void mean_attributes(const VoxelRange* ranges, size_t n, Color* colors, Vec3* normals) const;
  static constexpr uint64_t kBatchMeanVoxels = 64;

  // Derived by finalize() when there are attributes (never stored in files):
  // fixed-point sums (kAttributeSumOne = 1.0) of the linear r, g, b, a and the
  // normal x, y, z of leaf voxels [0, 64 b), b = 0 .. leaf_voxels / 64. A
  // range's mean is two table lookups plus at most 2 x 32 voxels summed
  // directly at its ends (from the nearer block boundary; 2 x 16 on average,
  // ranges of <= 64 voxels summed directly); integer sums make it exact and
  // independent of the summation order (and so of the thread count). 56 B per
  // 64 voxels = 0.875 B per leaf voxel on top of the 8 B of colors + normals.
  static constexpr int kAttributeBlock = 64;
  static constexpr double kAttributeSumOne = 16777216.0;  // 2^24
  std::vector<std::array<int64_t, 7>> attribute_prefix;

  // Derived by finalize() when there are attributes (never stored in files):
  // the LOD means of every cube of more than kCubeMeanMin leaf voxels at
  // levels 0 .. L - 4, so that a coarse hit on one of them costs one short
  // lookup instead of cube_range's descent and mean_attributes' sums. Level
  // L - 3 is in `fine_means` below (every cube); finer cubes (levels L - 2
  // and L - 1, at most 64 voxels) keep that path, as do cubes of <=
  // kCubeMeanMin voxels. Per level, the entries in Morton order
  // (ascending first voxel) and a bucket index over the first voxel's high
  // bits: bucket[b] = the first entry whose first voxel is >= b << shift,
  // about one bucket per entry. Neighbouring pixels hit cubes of nearby
  // Morton ranks, so their lookups share cache lines and pages (a hashed
  // table scattered them: at 16384³ one cache and TLB miss per hit). Each
  // entry's mean comes from the cube's exact fixed-point sum through
  // mean_attributes' own sum-to-mean step, so the answer is the same floats
  // either way; the table is the same for every thread count.
  struct CubeMean {
    uint64_t first = 0;
    int32_t level = -1;
    Color color;
    Vec3 normal;
  };
  struct CubeMeanLevel {
    std::vector<CubeMean> entries;  // ascending first
    std::vector<uint32_t> bucket;   // (leaf_voxels >> shift) + 2 entries
    int shift = 0;
  };
  static constexpr uint64_t kCubeMeanMin = 32;
  std::vector<CubeMeanLevel> cube_means;  // levels 0 .. L - 4, or none

  // Derived by finalize() with the table above (never stored in files): the
  // LOD means of every cube at level L - 3 (the 8^3 cubes, 1 .. 512 voxels;
  // where the LOD-1 hits of a 16384^3 scene land at 2048x1536, 39 % of them
  // on cubes of <= kCubeMeanMin voxels, which the table above leaves out). No
  // keys: `fine_starts` marks each cube's first voxel, one bit per leaf voxel
  // in cache lines of 512, and `fine_before` holds the number of cubes before
  // each line (4 B per 512 voxels, small enough to stay cached), so a lookup
  // is one line of bits (the voxel's bit and up to 8 popcounts) and one
  // 28-byte entry, both in Morton order (neighbouring pixels share lines).
  // The means are mean_of_sum of each cube's exact fixed-point sum: the
  // floats of mean_attributes. 1 bit per leaf voxel + 28 B per cube.
  struct FineMean {
    Color color;
    Vec3 normal;
  };
  struct alignas(64) FineStarts {
    uint64_t bits[8] = {};  // bit i of word k: voxel 512 line + 64 k + i starts a cube
  };
  std::vector<FineStarts> fine_starts;  // ceil(leaf_voxels / 512) lines, or none
  std::vector<uint32_t> fine_before;    // per line: the cubes that start before it
  std::vector<FineMean> fine_means;     // one per L - 3 cube, ascending first voxel
  /// The L - 3 cube whose first leaf voxel is `first`, or null.
  const FineMean* fine_mean(uint64_t first) const {
    const uint64_t line = first >> 9;
    if (line >= fine_starts.size()) return nullptr;
    const uint64_t* w = fine_starts[size_t(line)].bits;
    const int k = int(first >> 6) & 7;
    const uint64_t bit = 1ull << (first & 63);
    if (!(w[k] & bit)) return nullptr;
    uint64_t n = fine_before[size_t(line)] + uint64_t(std::popcount(w[k] & (bit - 1)));
    for (int j = 0; j < 8; ++j) n += j < k ? uint64_t(std::popcount(w[j])) : 0;
    return &fine_means[size_t(n)];
  }

  /// Bytes of the tables (entries and bucket indices, fine means and starts).
  uint64_t cube_mean_bytes() const {
    uint64_t b = 0;
    for (const CubeMeanLevel& t : cube_means)
      b += uint64_t(t.entries.size()) * sizeof(CubeMean) + uint64_t(t.bucket.size()) * 4;
    return b + uint64_t(fine_starts.size()) * sizeof(FineStarts) +
           uint64_t(fine_before.size()) * 4 + uint64_t(fine_means.size()) * sizeof(FineMean);
  }
  /// The table's entry for the cube at `level` whose first leaf voxel is
  /// `first`, or null (a cube of <= kCubeMeanMin voxels, or `first` is not
  /// the first voxel of a cube at that level).
  const CubeMean* cached_mean(uint64_t first, int level) const {
    if (level < 0 || size_t(level) >= cube_means.size()) return nullptr;
    const CubeMeanLevel& t = cube_means[size_t(level)];
    const uint64_t b = first >> t.shift;
    if (b + 1 >= t.bucket.size()) return nullptr;
    // Firsts of one level are > kCubeMeanMin apart: a bucket of 2^shift
    // ranks holds at most 2^shift / 33 + 1 entries.
    for (uint32_t i = t.bucket[size_t(b)], e = t.bucket[size_t(b) + 1]; i < e; ++i) {
      const CubeMean& m = t.entries[i];
      if (m.first >= first) return m.first == first ? &m : nullptr;
    }
    return nullptr;
  }
};

/// Builds the DAG of `voxels` (L >= 2; throws voxcast::Error otherwise):
/// 4^3 leaf masks, then one level at a time upward, identical nodes merged
/// (svdag §3: parallel sort of the node keys, then compaction). Attributes are
/// copied when the set has them. Deterministic for any thread count.
/// `progress` (optional): the bar of the build, its phases re-planned
/// (leaf masks, merged levels, layout and attributes).
SparseVoxelDag build_dag(const VoxelSet& voxels, Progress* progress = nullptr);

/// Out-of-core construction (svdag §3 "Implementation details"; src/dag/build_ooc.cpp).
struct OutOfCoreOptions {
  VoxelizationMode mode = VoxelizationMode::Conservative;
  bool attributes = false;     // store colors + normals (8 B per voxel in memory)
  uint64_t memory_budget = 0;  // bytes; 0 = 90% of available memory
  uint32_t cell_size = 0;      // sub-volume side, power of two >= 4; 0 = from the budget
  bool progress = true;        // progress bar with ETA on a TTY
  // With attributes: encode them into compressed blocks (dag.hpp) cell by
  // cell as the cells arrive, so that 1.5 B per voxel are held instead of
  // the 8 B of the raw arrays; the same bytes as compress_attributes().
  bool compress_attributes = false;
};
struct OutOfCoreReport {
  uint32_t cell_size = 0;
  uint64_t cells = 0;  // non-empty cells
  uint64_t max_cell_voxels = 0;
  uint64_t estimated_cell_bytes = 0;  // working set of the fullest cell (estimate)
  uint64_t fixed_bytes = 0;           // mesh + grid-unit vertices + triangle bins
  double voxelize_seconds = 0, reduce_seconds = 0, total_seconds = 0;
};
/// Voxelizes `mesh` into `grid` one sub-volume (aligned 2^c cube, Morton
/// order) at a time, reduces each to a sub-DAG merged into global per-level
/// tables of unique nodes, then builds the levels above the cells. The result
/// is byte-identical to build_dag(voxelize(mesh, grid, {mode, attributes})).
/// Throws voxcast::Error when even the smallest cells cannot fit the budget,
/// when the DAG outgrows it, or past 2^32 DAG words (pointers are 32-bit).
SparseVoxelDag build_dag_out_of_core(const Mesh& mesh, const GridTransform& grid,
                                     const OutOfCoreOptions& options,
                                     OutOfCoreReport* report = nullptr);

/// World-space bounds of the occupied voxels resolved to `max_level`.
Aabb occupied_bounds(const SparseVoxelDag& dag, int max_level = 7);

/// Result of a cast in octree space (root cube [1,2]^3).
struct CastResult {
  float t;               // entry t of the hit cube (input ray parameterization)
  Vec3 pos;              // min corner of the hit cube, octree space
  uint64_t voxel_index;  // Morton rank of the hit cube's first leaf voxel
  int scale;             // hit cube side = 2^(scale - esvo::kMaxScale)
  int face;              // entered cube face: axis*2 + (outward normal negative ? 1 : 0)
  bool hit;
};

/// The ESVO loop (esvo Appendix A: the one caster of the octree family,
/// src/core/octree_caster.hpp, that esvo::cast_ray also runs, so the hits are
/// bit-identical) over the DAG (svdag §4): octant mirroring, float-bit POP, a
/// stack per scale holding node, t_max and voxel-index base.
/// LOD terminates like esvo::cast_ray. cast_occluded (any hit): stop at the
/// first leaf without accumulating the voxel index (shadow rays). `dag` must be
/// finalized (build_dag and the scene loaders do it).
CastResult cast_ray(const SparseVoxelDag& dag, Vec3 origin, Vec3 dir, float tmax, float size_coef,
                    float size_bias);
bool cast_occluded(const SparseVoxelDag& dag, Vec3 origin, Vec3 dir, float tmax, float size_coef,
                   float size_bias);

class DagStructure final : public OctreeStructure<DagStructure> {
 public:
  explicit DagStructure(std::shared_ptr<const SparseVoxelDag> dag);
  // bounds, surface, trace, transmittance, beam_start: the octree family's
  // (octree_structure.hpp), the ESVO's caster and beam walk over the DAG's
  // nodes (svdag §4). SurfaceHit::voxel_ref = Morton rank of the hit voxel
  // (its first leaf for LOD hits), child = entered face | voxel count << 3 (name_hit).
  /// The hit voxel's attributes; while ctx.counting, adds the bytes read
  /// (raw: the 32-bit color and normal words; compressed: the 24-byte block).
  void attributes(const SurfaceHit& hit, TraceContext& ctx, Color* color,
                  Vec3* normal) const override;
  /// What attributes(hit) reads first: an L - 3 hit's fine_means entry (its
  /// line of start bits was prefetched when the hit was named,
  /// DagNodes::name_hit), a leaf voxel's value or a small cube's first
  /// voxel; a mean table lookup is not prefetched.
  void prefetch_attributes(const SurfaceHit& hit) const override;
  /// attributes() of each hit, the same answers and counts: the small cubes'
  /// means of a group (LOD hits below L - 3) by the batched
  /// SparseVoxelDag::mean_attributes, the others one at a time with their
  /// reads prefetched first.
  void attributes_batch(const SurfaceHit* const* hits, int n, TraceContext& ctx, Color* colors,
                        Vec3* normals) const override;
  std::string name() const override { return "dag"; }
  const SparseVoxelDag& dag() const { return *dag_; }

 private:
  friend class OctreeStructure<DagStructure>;
  ::voxcast::detail::OctreeWorld<::voxcast::detail::DagNodes> world() const;
  /// attributes() without the counters.
  void read_attributes(const SurfaceHit& hit, Color* color, Vec3* normal) const;

  std::shared_ptr<const SparseVoxelDag> dag_;
};

}  // namespace voxcast::dag
