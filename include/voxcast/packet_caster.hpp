#pragma once
// Packet ray casting of the octree family (issue 10 item 3): the ESVO's and
// the DAG's one caster (Appendix A, src/core/octree_caster.hpp) run on 16 rays
// at once in AVX-512 lanes, 8 with AVX2, over the structures' own node
// policies. The answers are those of trace() / occluded() bit for bit (every
// SurfaceHit field; tests/test_packet_caster.cpp), so the scalar caster stays
// the reference and either may be used for any ray.
//
// Rays are traced in the order given, up to 256 at a time as a queue: the
// first 16 (8) fill a packet, and each lane whose ray ends takes the next ray
// of the queue. Coherent neighbours make fast packets: give camera rays as
// 4x4 pixel blocks (block_order below), shadow rays of neighbouring pixels
// together.
#include <cstddef>
#include <cstdint>
#include <vector>

#include "voxcast/isa.hpp"
#include "voxcast/math.hpp"
#include "voxcast/occlusion_packets.hpp"
#include "voxcast/structure.hpp"

namespace voxcast {

/// Rays per packet of `isa`'s kernel.
inline int packet_width(Isa isa) {
  return isa == Isa::Avx512 ? 16 : 8;
}

/// trace(rays[i], lod, ctx, &hits[i], beams[i]) for i < n: found[i] =
/// the return value, hits[i] written where found[i] (bit-identical).
/// `s`: an octree structure (esvo::EsvoStructure, dag::DagStructure).
/// `beams` (may be null, entries may be null): the coarse pass of each ray's
/// pixel block (beam_start, esvo §6.2): rays of an empty beam cost nothing,
/// the others start at the region. `isa`: the kernel variant (throws
/// voxcast::Error if the CPU lacks it). Octrees of 2^31 words or more
/// (beyond the gathers' 32-bit indices) are traced by the scalar caster.
template <class S>
void trace_packets(const S& s, const Ray* rays, size_t n, const LodFootprint& lod, SurfaceHit* hits,
                   uint8_t* found, Isa isa = active_isa(),
                   const BeamStart* const* beams = nullptr) {
  s.cast_packets(rays, n, lod, hits, found, isa, beams);
}
/// occluded[i] = occluded(rays[i], lod) for i < n, bit-identical answers:
/// any-hit packets (occluded_anyhit with its default options,
/// voxcast/occlusion_packets.hpp); give shadow rays of neighbouring pixels
/// and AO rays of one point together.
template <class S>
void occluded_packets(const S& s, const Ray* rays, size_t n, const LodFootprint& lod,
                      uint8_t* occluded, Isa isa = active_isa()) {
  AnyHitOptions o;
  o.isa = isa;
  s.cast_anyhit(rays, n, lod, occluded, o, nullptr);
}

/// Pixel (x, y) of the w x h rectangle at (x0, y0), in packet order: 4x4
/// blocks row by row, pixels row-major inside a block; edge blocks are cut.
/// Appends to *out as x | y << 16 (w, h, x0 + w, y0 + h <= 65536).
void block_order(int x0, int y0, int w, int h, std::vector<uint32_t>* out);

}  // namespace voxcast
