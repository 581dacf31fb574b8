// The ESVO packet kernels, first-hit and any-hit (core/octree_packet_kernel.hpp),
// 16 lanes: compiled with -march=x86-64-v4 (CMakeLists.txt, *_avx512.cpp);
// only called when the caller's Isa says the CPU has AVX-512.
#include "core/octree_tile_kernel.hpp"
#include "core/packet_kernels.hpp"
#include "esvo/packet_nodes.hpp"

namespace voxcast::detail {

VOXCAST_DEFINE_PACKET_KERNELS(esvo, avx512, EsvoNodes, EsvoPacketNodes<16>)
VOXCAST_DEFINE_TILE_KERNEL(esvo, avx512, EsvoNodes, 16)

}  // namespace voxcast::detail
