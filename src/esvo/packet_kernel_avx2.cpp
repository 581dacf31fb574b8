// The ESVO packet kernels, first-hit and any-hit (core/octree_packet_kernel.hpp),
// 8 lanes: compiled with the baseline flags (x86-64-v3).
#include "core/octree_tile_kernel.hpp"
#include "core/packet_kernels.hpp"
#include "esvo/packet_nodes.hpp"

namespace voxcast::detail {

VOXCAST_DEFINE_PACKET_KERNELS(esvo, avx2, EsvoNodes, EsvoPacketNodes<8>)
VOXCAST_DEFINE_TILE_KERNEL(esvo, avx2, EsvoNodes, 8)

}  // namespace voxcast::detail
