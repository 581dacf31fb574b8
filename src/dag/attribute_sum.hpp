#pragma once
// Fixed-point sums of decoded raw DAG attributes (dag.hpp): the kernel behind
// SparseVoxelDag::attribute_prefix (every voxel, at build and load) and LOD
// means (up to ~126 voxels per hit). Runtime-dispatched (voxcast/isa.hpp):
// attribute_sum_avx2.cpp is compiled with the baseline flags, where GCC keeps
// the loop scalar (AVX2 has no packed double -> int64 conversion);
// attribute_sum_avx512.cpp with -march=x86-64-v4, where it runs 8 voxels per
// vector. Integer sums of the same per-voxel values, so both variants return
// the same bits.
#include <array>
#include <cstddef>
#include <cstdint>

#include "voxcast/dag.hpp"

namespace voxcast::dag::detail {

/// Per voxel: linear r, g, b, a of the ABGR color and x, y, z of the
/// cube-face normal (esvo::decode_color_abgr / decode_normal_cube), each
/// rounded to fixed point (2^24 = 1, half away from zero), summed over
/// voxels [first, first + count).
using AttributeSum = std::array<int64_t, 7>;
using AttributeSumKernel = AttributeSum (*)(const uint32_t* colors, const uint32_t* normals,
                                            size_t first, size_t count);

namespace avx2 {
AttributeSum attribute_sum(const uint32_t* colors, const uint32_t* normals, size_t first,
                           size_t count);
}
namespace avx512 {
AttributeSum attribute_sum(const uint32_t* colors, const uint32_t* normals, size_t first,
                           size_t count);
}
/// The variant of active_isa(), chosen at the first call.
AttributeSumKernel attribute_sum_kernel();

/// Fixed point, 2^24 = 1.0, rounded half away from zero (no libm call: this
/// runs for up to 126 voxels per LOD hit). `static`: each translation unit,
/// the AVX-512 one included, keeps its own copy, so the linker can never hand
/// the baseline code an AVX-512 instance.
static inline int64_t to_fixed(float v) {
  const double x = double(v) * SparseVoxelDag::kAttributeSumOne;
  return int64_t(x + (x >= 0 ? 0.5 : -0.5));
}

/// to_fixed of the decoded channels of a color byte: index c = linear value
/// of sRGB byte c, 256 + c = alpha byte c (shared by both variants).
const int64_t* fixed_channel_table();

}  // namespace voxcast::dag::detail
