// The DAG any-hit kernel (core/octree_anyhit_kernel.hpp), 8 lanes: compiled
// with the library's baseline flags (x86-64-v3).
#include "core/anyhit_kernels.hpp"
#include "core/octree_anyhit_kernel.hpp"
#include "dag/packet_nodes.hpp"

namespace voxcast::detail {

void dag_anyhit_kernel_avx2(const DagNodes& nodes, const AnyHitQueue& q, float size_coef,
                            float size_bias, uint8_t* hit) {
  anyhit_kernel<DagPacketNodes<8>>(nodes, q, size_coef, size_bias, hit);
}

}  // namespace voxcast::detail
