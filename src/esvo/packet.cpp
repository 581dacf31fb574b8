// ESVO packet casting (voxcast/packet_caster.hpp): the octree family's
// packet driver (core/octree_packet_caster.hpp) with the ESVO's kernels.
#include <cstdint>
#include <vector>

#include "core/frustum_packets.hpp"
#include "core/octree_packet_caster.hpp"
#include "core/packet_kernels.hpp"
#include "esvo/octree_nodes.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/packet_caster.hpp"

namespace voxcast {

const char* caster_name(Caster c) {
  return c == Caster::Packet ? "packet" : "scalar";
}

void block_order(int x0, int y0, int w, int h, std::vector<uint32_t>* out) {
  for (int by = 0; by < h; by += 4)
    for (int bx = 0; bx < w; bx += 4)
      for (int y = by; y < by + 4 && y < h; ++y)
        for (int x = bx; x < bx + 4 && x < w; ++x)
          out->push_back(uint32_t(x0 + x) | uint32_t(y0 + y) << 16);
}

void trace_packets(const esvo::EsvoStructure& s, const Ray* rays, size_t n, const LodFootprint& lod,
                   SurfaceHit* hits, uint8_t* found, Isa isa, const BeamStart* const* beams) {
  detail::structure_trace_packets<detail::EsvoNodes>(
      s, s.octree(), isa, &detail::esvo_packet_kernel_avx2, &detail::esvo_packet_kernel_avx512,
      rays, n, lod, beams, hits, found);
}

void occluded_packets(const esvo::EsvoStructure& s, const Ray* rays, size_t n,
                      const LodFootprint& lod, uint8_t* occluded, Isa isa) {
  detail::structure_packets<detail::EsvoNodes>(s, s.octree(), isa, &detail::esvo_packet_kernel_avx2,
                                               &detail::esvo_packet_kernel_avx512, rays, n, lod,
                                               nullptr, true, nullptr, occluded);
}

}  // namespace voxcast
