#pragma once
// Any-hit packets (issue 10 item 5): occlusion rays of the octree family on
// 16 AVX-512 lanes (8 with AVX2), every lane ending at its first occupied
// cube, and, as an option, the AO deep start: rays that share an origin (the
// AO rays of one shading point) start at the deepest node whose cube holds
// all their segments, optionally after a cull of its subtree by the rays'
// ball, hemisphere and box (src/core/octree_anyhit_caster.hpp has the
// argument). The answers are
// those of occluded() bit for bit (tests/test_occlusion_packets.cpp), so the
// scalar caster stays the reference and either may answer any ray.
#include <cstddef>
#include <cstdint>

#include "voxcast/isa.hpp"
#include "voxcast/math.hpp"
#include "voxcast/structure.hpp"

namespace voxcast {
namespace esvo {
class EsvoStructure;
}
namespace dag {
class DagStructure;
}

struct AnyHitOptions {
  /// > 0: rays [k group, (k + 1) group) share their origin (checked): they
  /// may start deep (at LOD 0). 0: independent rays, all from the root.
  int group = 0;
  /// group > 0, may be null: one normal per group with dot(dir, normal) >= 0
  /// for its rays (checked): the cull also uses the half-space above it.
  const Vec3* normals = nullptr;
  /// Start groups at their deepest common node. Off by default: it measured
  /// slower than starting the same point-major packets at the root
  /// (docs/BENCHMARKS.md "Occlusion packets"); kept to measure it.
  bool deep_start = false;
  /// Nodes the cull of a deep group's subtree may fetch before it gives up
  /// and the rays are traced (0: no cull; docs/BENCHMARKS.md "Occlusion
  /// packets" measures it).
  int cull_budget = 0;
  Isa isa = active_isa();  // throws voxcast::Error if the CPU lacks it
};

/// What the deep start did, summed over calls.
struct AnyHitStats {
  uint64_t points = 0;       // ray groups offered a deep start
  uint64_t deep_points = 0;  // groups started below the root
  uint64_t depth_sum = 0;    // levels skipped, summed over the deep groups not culled
  uint64_t culled = 0;       // groups answered by the cull alone (no ray traced)
  uint64_t root_rays = 0;    // rays of deep groups that failed the per-ray check
};

/// occluded[i] = occluded(rays[i], lod) for i < n (0/1), bit-identical.
/// Octrees of 2^31 words or more take the scalar caster.
void occluded_anyhit(const esvo::EsvoStructure& s, const Ray* rays, size_t n,
                     const LodFootprint& lod, uint8_t* occluded, const AnyHitOptions& o = {},
                     AnyHitStats* stats = nullptr);
void occluded_anyhit(const dag::DagStructure& s, const Ray* rays, size_t n, const LodFootprint& lod,
                     uint8_t* occluded, const AnyHitOptions& o = {}, AnyHitStats* stats = nullptr);

}  // namespace voxcast
