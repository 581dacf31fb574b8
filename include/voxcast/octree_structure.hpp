#pragma once
// The octree family of voxel structures (ESVO octree, sparse voxel DAG; a
// streamed ESVO later): structures in the [1,2]^3 octree space of esvo §6.1
// that share one ray caster, the Appendix A loop of src/core/octree_caster.hpp
// over a node-access policy. Deriving from OctreeStructure<Self> gives a
// structure its VoxelStructure tracing methods from that caster; Self
// supplies `world()` (its policy and grid), declared private with
// OctreeStructure<Self> as a friend, and instantiates the template in its
// own source file (src/esvo/traverse.cpp, src/dag/traverse.cpp).
#include "voxcast/structure.hpp"

namespace voxcast {

namespace detail {
template <class Nodes>
struct OctreeWorld;  // what Self::world() returns: src/core/octree_caster.hpp
}  // namespace detail

template <class Self>
class OctreeStructure : public VoxelStructure {
 public:
  /// World-space bounds of the root cube.
  Aabb bounds() const override;
  /// First hit (esvo §6.1, Appendix A), LOD stop from the footprint.
  bool trace(const Ray& ray, const LodFootprint& lod, SurfaceHit* hit) const override;
  /// trace() started at the beam's region (esvo §6.2; bit-identical hits), with counters.
  bool trace_hinted(const Ray& ray, const LodFootprint& lod, const TraceHints& hints,
                    SurfaceHit* hit) const override;
  /// Any hit within [0, ray.tmax]: the same loop, stopped at the first hit
  /// without the hit's position or attribute handle (shadow and AO rays).
  bool occluded(const Ray& ray, const LodFootprint& lod = {}) const override;
  /// Coarse pass of the beam optimization (esvo §6.2, core/beam_frustum.hpp).
  void beam_start(const BeamFrustum& beam, BeamStart* start, RayCounters* counters) const override;
};

}  // namespace voxcast
