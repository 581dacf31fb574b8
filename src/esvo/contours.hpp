#pragma once
// Contour construction and the variable-depth decisions (esvo §7.1-7.3),
// private to src/esvo. The builder (builder.cpp) runs its bottom-up phase 1
// over the full-depth voxel set, hands the resulting tree to plan_contours(),
// and lays out only the part of the tree the plan keeps, with the planned
// contour values in descriptor word 1 / the contour attachments.
#include <cstdint>
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

/// Top-down over the tree (§7.1): filters the mesh triangles into every
/// voxel, builds its contour (§7.2) and decides whether it is refined
/// (REFINE-GEOMETRY / REFINE-ATTRIBUTES, §7.1/§7.3). Parallel over subtrees.
ContourPlan plan_contours(const TreeView& tree, const GridTransform& grid, const Mesh& mesh,
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
