// Bounds of the occupied part of an ESVO (for automatic cameras): a walk of
// the top levels of the hierarchy, cheap even for very large octrees.
#include <vector>

#include "esvo/layout_internal.hpp"
#include "voxcast/esvo.hpp"

namespace voxcast::esvo {

Aabb occupied_bounds(const EsvoOctree& octree, int max_level) {
  struct Item {
    uint32_t slot;  // descriptor slot of this (non-leaf) voxel
    uint32_t x, y, z;
    int level;
  };
  Aabb box;
  const double side = octree.grid.side();
  auto add_voxel = [&](uint32_t x, uint32_t y, uint32_t z, int level) {
    double size = side / double(1u << level);
    Vec3 lo{float(octree.grid.origin.x + x * size), float(octree.grid.origin.y + y * size),
            float(octree.grid.origin.z + z * size)};
    box.extend(lo);
    box.extend(lo + Vec3{float(size), float(size), float(size)});
  };
  std::vector<Item> stack{{octree.root_slot(), 0, 0, 0, 0}};
  while (!stack.empty()) {
    Item it = stack.back();
    stack.pop_back();
    const uint32_t* d = octree.slot_ptr(it.slot);
    uint32_t valid = layout::ValidMask::get(d[0]), leaf = layout::LeafMask::get(d[0]);
    // The child group is only looked up when a subdivided child is pushed
    // (validate() checks the pointer exactly then).
    const bool descend = (valid & ~leaf) != 0 && it.level + 1 < max_level;
    const int64_t first = descend ? int64_t(detail::child_group(octree.words.data(), it.slot)) : 0;
    int nonleaf_rank = 0;
    for (int c = 0; c < 8; ++c) {
      if (!(valid & (1u << c))) continue;
      uint32_t cx = it.x * 2 + (c & 1), cy = it.y * 2 + ((c >> 1) & 1),
               cz = it.z * 2 + ((c >> 2) & 1);
      bool is_leaf = leaf & (1u << c);
      if (is_leaf || it.level + 1 >= max_level)
        add_voxel(cx, cy, cz, it.level + 1);
      else
        stack.push_back({uint32_t(first + nonleaf_rank), cx, cy, cz, it.level + 1});
      if (!is_leaf) ++nonleaf_rank;
    }
  }
  return box;
}

}  // namespace voxcast::esvo
