// The ESVO packet kernel (core/octree_packet_kernel.hpp), 8 lanes: compiled
// with the library's baseline flags (x86-64-v3).
#include "core/packet_kernels.hpp"
#include "esvo/packet_nodes.hpp"

namespace voxcast::detail {

void esvo_packet_kernel_avx2(const EsvoNodes& nodes, const PacketQueue& q, float size_coef,
                             float size_bias, PacketOut* out) {
  packet_kernel<EsvoPacketNodes<8>>(nodes, q, size_coef, size_bias, out);
}

}  // namespace voxcast::detail
