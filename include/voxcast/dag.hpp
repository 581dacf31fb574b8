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
// node of the next level, leaf voxel count < 2^32, attribute arrays sized to
// the leaf count.
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
// the pointer's neighbour. A coarser (LOD) hit voxel shows the attributes of
// its first leaf voxel in Morton order. Without attributes, voxels are gray
// (0.5, 0.5, 0.5) with the normal of the cube face the ray entered.
//
// The DAG occupies [1,2]^3 in octree space exactly as the ESVO does
// (esvo §6.1); cube side 2^(s - esvo::kMaxScale) at scale s.
#include <cstdint>
#include <memory>
#include <vector>

#include "voxcast/esvo.hpp"
#include "voxcast/math.hpp"
#include "voxcast/structure.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast::dag {

inline constexpr uint32_t kReservedHeaderBits = 0xFFFFFF00u;

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
  uint64_t index_bytes = 0;      // voxel_prefix (attribute indexing, derived at load)
  uint64_t attribute_bytes = 0;  // colors + normals
  double bits_per_voxel = 0;     // dag_bytes * 8 / leaf_voxels
};

class SparseVoxelDag {
 public:
  GridTransform grid;
  std::vector<uint32_t> words;    // layout above
  std::vector<uint32_t> colors;   // per leaf voxel in Morton order, ABGR; empty = no attributes
  std::vector<uint32_t> normals;  // per leaf voxel, cube-face encoding; empty iff colors is
  // Derived by finalize():
  std::vector<uint32_t> voxel_prefix;  // parallels words, see above
  std::vector<uint32_t>
      level_start;  // word index of the first node of level l, l = 0..L-1 (L-1: end)
  uint64_t leaf_voxels = 0;

  int levels() const { return grid.levels; }
  bool has_attributes() const { return !colors.empty(); }

  /// Validates `words` and the attribute arrays (throws voxcast::Error naming
  /// the first problem) and computes the derived fields. After it succeeds,
  /// traversal and attribute lookup cannot read out of bounds or loop.
  void finalize();

  DagStats stats() const;
  /// The leaf voxels as sorted Morton codes (inverse of build_dag).
  std::vector<uint64_t> decode_leaves() const;
  /// Linear color and unit normal of leaf voxel `index` (Morton rank).
  void voxel_attributes(uint64_t index, Color* color, Vec3* normal) const;
};

/// Builds the DAG of `voxels` (L >= 2; throws voxcast::Error otherwise):
/// 4^3 leaf masks, then one level at a time upward, identical nodes merged
/// (svdag §3: parallel sort of the node keys, then compaction). Attributes are
/// copied when the set has them. Deterministic for any thread count.
SparseVoxelDag build_dag(const VoxelSet& voxels);

/// Out-of-core construction (svdag §3 "Implementation details"; src/dag/build_ooc.cpp).
struct OutOfCoreOptions {
  VoxelizationMode mode = VoxelizationMode::Conservative;
  bool attributes = false;     // store colors + normals (8 B per voxel in memory)
  uint64_t memory_budget = 0;  // bytes; 0 = 90% of available memory
  uint32_t cell_size = 0;      // sub-volume side, power of two >= 4; 0 = from the budget
  bool progress = true;        // progress bar with ETA on a TTY
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
/// when the DAG outgrows it, or past 2^32 - 1 voxels.
SparseVoxelDag build_dag_out_of_core(const Mesh& mesh, const GridTransform& grid,
                                     const OutOfCoreOptions& options,
                                     OutOfCoreReport* report = nullptr);

/// World-space bounds of the occupied voxels resolved to `max_level`.
Aabb occupied_bounds(const SparseVoxelDag& dag, int max_level = 7);

/// Result of a cast in octree space (root cube [1,2]^3).
struct CastResult {
  float t;               // entry t of the hit cube (input ray parameterization)
  Vec3 pos;              // min corner of the hit cube, octree space
  uint32_t voxel_index;  // Morton rank of the hit cube's first leaf voxel
  int scale;             // hit cube side = 2^(scale - esvo::kMaxScale)
  int face;              // entered cube face: axis*2 + (outward normal negative ? 1 : 0)
  bool hit;
};

/// The ESVO loop (esvo Appendix A, as in esvo::cast_ray, same arithmetic so
/// the hits are bit-identical) over the DAG (svdag §4): octant mirroring,
/// float-bit POP, a stack per scale holding node, t_max and voxel-index base.
/// LOD terminates like esvo::cast_ray. cast_occluded (any hit): stop at the
/// first leaf without accumulating the voxel index (shadow rays). `dag` must be
/// finalized (build_dag and the scene loaders do it).
CastResult cast_ray(const SparseVoxelDag& dag, Vec3 origin, Vec3 dir, float tmax, float size_coef,
                    float size_bias);
bool cast_occluded(const SparseVoxelDag& dag, Vec3 origin, Vec3 dir, float tmax, float size_coef,
                   float size_bias);

class DagStructure final : public VoxelStructure {
 public:
  explicit DagStructure(std::shared_ptr<const SparseVoxelDag> dag);
  Aabb bounds() const override;
  /// voxel_ref = Morton rank of the hit voxel (its first leaf for LOD hits),
  /// child = entered face (see CastResult::face).
  bool trace(const Ray& ray, const LodFootprint& lod, SurfaceHit* hit) const override;
  /// Any hit within [0, ray.tmax] (stops at the first leaf; for shadow rays).
  bool occluded(const Ray& ray, const LodFootprint& lod = {}) const override;
  void attributes(const SurfaceHit& hit, Color* color, Vec3* normal) const override;
  std::string name() const override { return "dag"; }
  const SparseVoxelDag& dag() const { return *dag_; }

 private:
  std::shared_ptr<const SparseVoxelDag> dag_;
};

}  // namespace voxcast::dag
