#pragma once
// The scenes the packet, occlusion and tile caster tests compare against the
// scalar caster (tests/test_packet_caster.cpp, test_occlusion_packets.cpp,
// test_tile_caster.cpp): spot.obj voxelized at 256^3 as every octree variant
// whose layout changes what the casters read, and the brickmap world of the
// same voxels.
#include <memory>

#include "voxcast/brickmap.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast::testing {

struct OctreeScenes {
  Mesh mesh;
  GridTransform grid;
  // ESVO: raw attributes; compressed attributes; 64-slot blocks (far
  // pointers between them); contours (esvo §5.2, built from the mesh).
  std::unique_ptr<esvo::EsvoStructure> esvo, esvo_compressed, esvo_far, esvo_contours;
  std::unique_ptr<dag::DagStructure> dag;
  std::unique_ptr<brickmap::BrickmapStructure> brickmap;
};

/// Built once per test executable.
const OctreeScenes& spot_octree_scenes();

}  // namespace voxcast::testing
