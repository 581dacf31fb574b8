#include "support/octree_scenes.hpp"

#include "support/test_data.hpp"
#include "voxcast/esvo.hpp"

namespace voxcast::testing {

const OctreeScenes& spot_octree_scenes() {
  static const OctreeScenes s = [] {
    OctreeScenes s;
    s.mesh = load_mesh(test_mesh("spot.obj"));
    s.grid = GridTransform::fit(s.mesh.bounds(), 256);
    const VoxelSet v = voxelize(s.mesh, s.grid, {});
    auto esvo = [&](const esvo::BuildOptions& o, bool with_mesh) {
      return std::make_unique<esvo::EsvoStructure>(std::make_shared<const esvo::EsvoOctree>(
          with_mesh ? esvo::build_octree(v, s.mesh, o) : esvo::build_octree(v, o)));
    };
    s.esvo = esvo({}, false);
    esvo::BuildOptions compressed;
    compressed.attributes = esvo::AttributeFormat::Compressed;
    s.esvo_compressed = esvo(compressed, false);
    esvo::BuildOptions small;
    small.max_block_slots = 64;
    s.esvo_far = esvo(small, false);
    esvo::BuildOptions contours;
    contours.contours = true;
    s.esvo_contours = esvo(contours, true);
    s.dag = std::make_unique<dag::DagStructure>(
        std::make_shared<const dag::SparseVoxelDag>(dag::build_dag(v)));
    s.brickmap = std::make_unique<brickmap::BrickmapStructure>(
        std::make_shared<const brickmap::World>(brickmap::build_world(v)));
    return s;
  }();
  return s;
}

}  // namespace voxcast::testing
