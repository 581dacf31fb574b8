// attribute_sum kernel (attribute_sum.hpp), AVX-512 variant: CMakeLists.txt
// compiles *_avx512.cpp with -march=x86-64-v4 -mprefer-vector-width=512. Only
// called when active_isa() says the CPU has AVX-512.
#include "dag/attribute_sum.hpp"
#include "dag/attribute_sum_body.hpp"

namespace voxcast::dag::detail {

AttributeSum avx512::attribute_sum(const uint32_t* colors, const uint32_t* normals, size_t first,
                                   size_t count) {
  return attribute_sum_body(colors, normals, first, count);
}

}  // namespace voxcast::dag::detail
