// The ESVO packet kernel (core/octree_packet_kernel.hpp), 16 lanes: compiled
// with -march=x86-64-v4 (CMakeLists.txt, *_avx512.cpp); only called when
// active_isa() or the caller's Isa says the CPU has AVX-512.
#include "core/packet_kernels.hpp"
#include "esvo/packet_nodes.hpp"

namespace voxcast::detail {

void esvo_packet_kernel_avx512(const EsvoNodes& nodes, const PacketQueue& q, float size_coef,
                               float size_bias, PacketOut* out) {
  packet_kernel<EsvoPacketNodes<16>>(nodes, q, size_coef, size_bias, out);
}

}  // namespace voxcast::detail
