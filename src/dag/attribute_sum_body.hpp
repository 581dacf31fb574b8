#pragma once
// Body of the attribute_sum kernel (attribute_sum.hpp), included by each
// ISA's translation unit. Internal linkage: each inclusion is its own
// function, compiled with that file's flags (no ODR merging across ISAs).
// What it calls from headers is constexpr/inline and inlined at -O3.
#include <cmath>
#include <cstddef>
#include <cstdint>

#include "dag/attribute_sum.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/esvo.hpp"

namespace voxcast::dag::detail {
namespace {

inline AttributeSum attribute_sum_body(const uint32_t* __restrict colors,
                                       const uint32_t* __restrict normals, size_t first,
                                       size_t count) {
  const int64_t* __restrict ch = fixed_channel_table();
  // Seven scalar accumulators and branch-free selects, so that the compiler
  // can vectorize the loop (integer sums: any order gives the same result).
  int64_t s0 = 0, s1 = 0, s2 = 0, s3 = 0, s4 = 0, s5 = 0, s6 = 0;
  for (size_t i = first; i < first + count; ++i) {
    const uint32_t abgr = colors[i];
    s0 += ch[esvo::layout::ColorR::get(abgr)];
    s1 += ch[esvo::layout::ColorG::get(abgr)];
    s2 += ch[esvo::layout::ColorB::get(abgr)];
    s3 += ch[256 + esvo::layout::ColorA::get(abgr)];
    // esvo::decode_normal_cube, inlined: the same float operations.
    const uint32_t code = normals[i];
    uint32_t face = esvo::layout::NormalFace::get(code);
    face = face > 5 ? 4 : face;  // not produced by the encoder (+z, as the decoder)
    const uint32_t axis = face >> 1;
    const float u = float(esvo::layout::NormalU::get(code)) * (2.f / 16383.f) - 1.f;
    const float v = float(esvo::layout::NormalV::get(code)) * (2.f / 32767.f) - 1.f;
    const float len = std::sqrt(1.f + u * u + v * v);
    const float major = ((face & 1) ? -1.f : 1.f) / len, nu = u / len, nv = v / len;
    // Component axis is the major one, (axis + 1) % 3 gets u, (axis + 2) % 3 v.
    const float nx = axis == 0 ? major : (axis == 1 ? nv : nu);
    const float ny = axis == 0 ? nu : (axis == 1 ? major : nv);
    const float nz = axis == 0 ? nv : (axis == 1 ? nu : major);
    s4 += to_fixed(nx);
    s5 += to_fixed(ny);
    s6 += to_fixed(nz);
  }
  return {s0, s1, s2, s3, s4, s5, s6};
}

}  // namespace
}  // namespace voxcast::dag::detail
