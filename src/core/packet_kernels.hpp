#pragma once
// The packet kernels of the octree family (core/octree_packet_caster.hpp),
// one per structure and ISA: *_avx2 compiled with the baseline flags (8
// lanes), *_avx512 with -march=x86-64-v4 (16 lanes), in
// src/esvo/packet_kernel_*.cpp and src/dag/packet_kernel_*.cpp.
#include "core/octree_packet_caster.hpp"

namespace voxcast::detail {

struct EsvoNodes;
struct DagNodes;

void esvo_packet_kernel_avx2(const EsvoNodes& nodes, const PacketQueue& q, float size_coef,
                             float size_bias, PacketOut* out);
void esvo_packet_kernel_avx512(const EsvoNodes& nodes, const PacketQueue& q, float size_coef,
                               float size_bias, PacketOut* out);
void dag_packet_kernel_avx2(const DagNodes& nodes, const PacketQueue& q, float size_coef,
                            float size_bias, PacketOut* out);
void dag_packet_kernel_avx512(const DagNodes& nodes, const PacketQueue& q, float size_coef,
                              float size_bias, PacketOut* out);

}  // namespace voxcast::detail
