// The DAG any-hit kernel (core/octree_anyhit_kernel.hpp), 16 lanes: compiled
// with -march=x86-64-v4 (CMakeLists.txt, *_avx512.cpp); only called when the
// caller's Isa says the CPU has AVX-512.
#include "core/anyhit_kernels.hpp"
#include "core/octree_anyhit_kernel.hpp"
#include "dag/packet_nodes.hpp"

namespace voxcast::detail {

void dag_anyhit_kernel_avx512(const DagNodes& nodes, const AnyHitQueue& q, float size_coef,
                              float size_bias, uint8_t* hit) {
  anyhit_kernel<DagPacketNodes<16>>(nodes, q, size_coef, size_bias, hit);
}

}  // namespace voxcast::detail
