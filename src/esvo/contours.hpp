#pragma once
// Contour construction and the variable-depth decisions (esvo §7.1-7.3),
// private to src/esvo. The builder (builder.cpp) runs its bottom-up phase 1
// over the full-depth voxel set, hands the resulting tree to a
// ContourPlanner, and lays out only the part of the tree the plan keeps, with
// the planned contour values in descriptor word 1 / the contour attachments.
// With compressed attributes it then decodes the laid-out leaves and asks the
// planner to refine those whose decoded attributes are out of tolerance
// (§7.3 "attribute quantization and compression is performed before the
// test"), until none is. The cell-by-cell build (build_cells.hpp) instead
// plans the top levels first, stopping at the cells' roots, and then each
// refined cell's subtree from the seed its root left.
#include <cstdint>
#include <memory>
#include <utility>
#include <vector>

#include "voxcast/esvo.hpp"
#include "voxcast/mesh.hpp"

namespace voxcast::esvo::detail {

/// Phase 1's full-depth tree (all leaves at depth L).
struct TreeView {
  int levels = 0;                            // L
  std::vector<const uint8_t*> mask;          // depth 0..L-1: valid masks
  std::vector<const uint32_t*> first_child;  // depth 0..L-1: first child's index at depth + 1
  std::vector<size_t> count;                 // nodes at depth 0..L
  std::vector<const uint64_t*> value;  // depth 1..L (entry 0 unused): raw color | normal << 32
};

struct ContourPlan {
  /// [depth][node] for depth 1..L: the voxel's contour value, 0 = none (a
  /// valid contour has a non-zero normal, so 0 is free). Entry 0 is empty.
  std::vector<std::vector<uint32_t>> contour;
  /// [depth][node] for depth 1..L-1: 1 = the voxel is a leaf, its subtree is
  /// dropped (variable depth, max_level). Nodes below a leaf are undefined.
  std::vector<std::vector<uint8_t>> leaf;
};

struct PlannerState;

/// The mesh as the planner reads it (grid-unit triangles, normals, boxes,
/// boundary edges); built once and shared by every cell's planner.
struct PlannerMesh;
std::shared_ptr<const PlannerMesh> make_planner_mesh(const GridTransform& grid, const Mesh& mesh);

/// What the planner hands down to a refined voxel's subtree: its cube, the
/// triangles overlapping it and the ancestor slabs (its own included).
struct SubtreeSeed;

/// Top-down over the tree (§7.1): filters the mesh triangles into every
/// voxel, builds its contour (§7.2) and decides whether it is refined
/// (REFINE-GEOMETRY / REFINE-ATTRIBUTES, §7.1/§7.3). Parallel over subtrees.
/// The first plan() plans the whole tree; refine() then forces planned
/// leaves to be subdivided and re-plans only their subtrees (and the paths
/// to them, recomputed identically), so the result equals a fresh plan with
/// the same forced set, for any thread count.
class ContourPlanner {
 public:
  ContourPlanner(const TreeView& tree, const GridTransform& grid, const Mesh& mesh,
                 const BuildOptions& options);
  /// Cell-by-cell build, top levels: `tree` holds depths 0..stop_depth only
  /// (it may hold extra nodes: a voxel's plan depends on its ancestors, not
  /// on its siblings). Voxels at stop_depth that are refined are not
  /// descended into; their seeds are kept (take_seed). `attr_flags` [depth][node] (depth 1..
  /// stop_depth, or null without color/normal tolerance) replaces
  /// attributes_exceed(), whose full-depth voxels are not in `tree`.
  ContourPlanner(const TreeView& tree, std::shared_ptr<const PlannerMesh> mesh,
                 const BuildOptions& options, int stop_depth,
                 const std::vector<std::vector<uint8_t>>* attr_flags);
  /// Cell-by-cell build, one cell: `tree` is the cell's full-depth tree with
  /// the cell's voxel as node (seed depth, 0); plans exactly what the
  /// in-core planner plans below that voxel.
  ContourPlanner(const TreeView& tree, std::shared_ptr<const PlannerMesh> mesh,
                 const BuildOptions& options, const SubtreeSeed& seed);
  /// Top-down slice build (esvo §7.1, slice_build.cpp): as the cell
  /// constructor, but plans only down to `stop_depth` (> the seed's depth):
  /// `tree` holds the seed's subtree to stop_depth - 1 (masks, first
  /// children; counts to stop_depth). With `keep_seeds` the refined voxels at
  /// stop_depth keep their seeds (take_seed); without, they are dropped.
  /// `attr_flags` as above ([depth][node] of `tree`, depths seed..stop_depth;
  /// null without color/normal tolerance).
  ContourPlanner(const TreeView& tree, std::shared_ptr<const PlannerMesh> mesh,
                 const BuildOptions& options, const SubtreeSeed& seed, int stop_depth,
                 bool keep_seeds, const std::vector<std::vector<uint8_t>>* attr_flags = nullptr);
  /// The seed of refined voxel `index` at stop_depth after plan(), or null
  /// if it is not refined or not reached (below a leaf). Moves it out.
  std::shared_ptr<const SubtreeSeed> take_seed(uint32_t index);
  ~ContourPlanner();
  /// The current plan (planned on the first call).
  const ContourPlan& plan();
  /// Forces the planned leaves (depth, index) (depth < max level) to be
  /// subdivided and re-plans below them. Monotone: refinement only grows.
  void refine(const std::vector<std::pair<int, uint32_t>>& leaves);

 private:
  std::unique_ptr<PlannerState> p_;
  bool planned_ = false;
};

/// The root's seed: the root cube (depth 0) with every triangle and no
/// ancestor slabs, what the in-core planner starts from.
std::shared_ptr<const SubtreeSeed> root_seed(const PlannerMesh& mesh);

/// Index at depth L (the full-depth voxels) of the first voxel below node
/// (depth, index); index == count[depth] gives count[L]. The full-depth
/// voxels below node i are [first_leaf(d, i), first_leaf(d, i + 1)) (Morton order).
size_t first_leaf(const TreeView& tree, int depth, size_t index);

/// REFINE-ATTRIBUTES (§7.3) on decoded values: true if the attributes that a
/// leaf at (depth, index) decodes to -- 8-bit sRGB code `color_abgr` (alpha
/// ignored) and unit `normal` -- are farther than BuildOptions::color_error
/// (any channel, 0-255) or normal_error (degrees) from the original (raw
/// encoded) attributes of some full-depth voxel below it. Exact: every such
/// voxel is compared (stops at the first violation).
bool attributes_exceed(const TreeView& tree, int depth, size_t index, uint32_t color_abgr,
                       Vec3 normal, const BuildOptions& options);

/// The same test against the raw-encoded full-depth values v[b, e).
bool values_exceed(const uint64_t* v, size_t b, size_t e, uint32_t color_abgr, Vec3 normal,
                   const BuildOptions& options);

/// The slab of a contour value in the voxel [lo, lo + side]^3: n . x in
/// [lo_t, hi_t] with the integer normal n (esvo.hpp, ContourValue), in the
/// units of lo/side. Double precision; shared by the builder and validate-
/// free tools (tests use their own decode).
struct Slab {
  double n[3];
  double lo, hi;
};
Slab contour_slab(uint32_t value, const double lo[3], double side);

}  // namespace voxcast::esvo::detail
