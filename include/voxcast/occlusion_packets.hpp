#pragma once
// Any-hit packets (issue 10 item 5): occlusion rays of the octree family on
// 16 AVX-512 lanes (8 with AVX2), every lane ending at its first occupied
// cube. As an option (AnyHitOptions::deep_start) every ray starts deep: at
// the deepest cube around its origin that the scalar loop reaches by
// descending alone, replaying that descent with the loop's own floats and
// filling its stack on the way, so that rays leaving that cube go on as from
// the root (the walk to the cube is shared by neighbouring origins: the
// shadow rays of a pixel block, the AO rays of a point). Rays that share an origin (the AO rays of
// one shading point) may also be culled by their ball, hemisphere and box
// (src/core/octree_anyhit_caster.hpp has the argument). Runs of rays with
// one direction (shadow rays under a directional light) are traced together,
// by one walk of the tree per up to 256 rays (AnyHitOptions::parallel). The answers are
// those of occluded() bit for bit (tests/test_occlusion_packets.cpp), so the
// scalar caster stays the reference and either may answer any ray.
#include <cstddef>
#include <cstdint>

#include "voxcast/isa.hpp"
#include "voxcast/math.hpp"
#include "voxcast/structure.hpp"

namespace voxcast {

/// Where occlusion rays start (AnyHitOptions::deep_start).
enum class DeepStart {
  /// Every ray from the root.
  Off,
  /// Each ray at the deepest cube around its origin that the loop reaches
  /// by descending alone: a walk of the origin's path and a replay of the
  /// loop's PUSHes along it per ray, before the kernel (measured slower than
  /// the root start: docs/BENCHMARKS.md "Occlusion packets: the fold and
  /// the per-ray deep start").
  PerRay,
  /// Each packet (16 or 8 consecutive rays) shares one path, to the deepest
  /// cube holding its lanes' origins; the kernel replays the loop's PUSHes
  /// along it in its lanes at the refill, without fetching.
  Packet,
};

struct AnyHitOptions {
  /// > 0: rays [k group, (k + 1) group) share their origin (checked): the
  /// cull may answer them (at LOD 0). 0: independent rays.
  int group = 0;
  /// group > 0, may be null: one normal per group with dot(dir, normal) >= 0
  /// for its rays (checked): the cull also uses the half-space above it.
  const Vec3* normals = nullptr;
  /// Where rays start (DeepStart): from the root by default.
  DeepStart deep_start = DeepStart::Off;
  /// DeepStart::Packet: a packet's path goes one level deeper while at least
  /// this share of its lanes (those with an origin inside the root) has its
  /// origin in the same child; the others stop replaying there. 1: the
  /// deepest cube holding every origin.
  float path_share = 1.f;
  /// Nodes the cull of a group may fetch before it gives up and the rays are
  /// traced (0: no cull; it costs more than it saves, docs/BENCHMARKS.md
  /// "Occlusion packets").
  int cull_budget = 0;
  /// group == 0: every run of at least kParallelRun consecutive rays with
  /// one direction (bitwise; the shadow rays of a directional light) is
  /// traced by shared walks of the tree, up to 256 rays a walk, children in
  /// the direction's octant order (core/octree_tile_caster.hpp "Parallel
  /// rays"); the other rays take the lane kernel (and deep_start).
  bool parallel = true;
  Isa isa = active_isa();  // throws voxcast::Error if the CPU lacks it
};

/// The shortest run of parallel rays AnyHitOptions::parallel walks together.
/// Shorter runs take the lane kernel: a walk of 16 rays measured 0.83x the
/// lanes (docs/BENCHMARKS.md "Parallel walks for shadow rays").
inline constexpr size_t kParallelRun = 64;

/// What the deep start and the cull did, summed over calls.
struct AnyHitStats {
  uint64_t points = 0;         // ray groups offered the cull
  uint64_t culled = 0;         // groups answered by the cull alone (no ray traced)
  uint64_t rays = 0;           // rays traced by the kernel
  uint64_t deep_rays = 0;      // of those, rays started below the root
  uint64_t depth_sum = 0;      // PerRay: levels of descent skipped, summed over the rays
  uint64_t path_levels = 0;    // Packet: levels of the packets' paths, summed over the packets
  uint64_t parallel_rays = 0;  // rays answered by parallel walks (not in `rays`)
};

/// occluded[i] = occluded(rays[i], lod) for i < n (0/1), bit-identical.
/// `s`: an octree structure (esvo::EsvoStructure, dag::DagStructure).
/// Octrees of 2^31 words or more take the scalar caster.
template <class S>
void occluded_anyhit(const S& s, const Ray* rays, size_t n, const LodFootprint& lod,
                     uint8_t* occluded, const AnyHitOptions& o = {}, AnyHitStats* stats = nullptr) {
  s.cast_anyhit(rays, n, lod, occluded, o, stats);
}

}  // namespace voxcast
