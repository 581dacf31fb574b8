#pragma once
// The any-hit kernels of the octree family (core/octree_anyhit_caster.hpp),
// one per structure and ISA: *_avx2 compiled with the baseline flags (8
// lanes), *_avx512 with -march=x86-64-v4 (16 lanes), in
// src/esvo/anyhit_kernel_*.cpp and src/dag/anyhit_kernel_*.cpp.
#include "core/octree_anyhit_caster.hpp"

namespace voxcast::detail {

struct EsvoNodes;
struct DagNodes;

void esvo_anyhit_kernel_avx2(const EsvoNodes& nodes, const AnyHitQueue& q, float size_coef,
                             float size_bias, uint8_t* hit);
void esvo_anyhit_kernel_avx512(const EsvoNodes& nodes, const AnyHitQueue& q, float size_coef,
                               float size_bias, uint8_t* hit);
void dag_anyhit_kernel_avx2(const DagNodes& nodes, const AnyHitQueue& q, float size_coef,
                            float size_bias, uint8_t* hit);
void dag_anyhit_kernel_avx512(const DagNodes& nodes, const AnyHitQueue& q, float size_coef,
                              float size_bias, uint8_t* hit);

}  // namespace voxcast::detail
