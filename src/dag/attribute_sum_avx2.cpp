// attribute_sum kernel (attribute_sum.hpp), AVX2 variant: the library's
// baseline flags (-march=x86-64-v3). Also the shared table and the dispatch.
#include <array>

#include "dag/attribute_sum.hpp"
#include "dag/attribute_sum_body.hpp"
#include "voxcast/isa.hpp"

namespace voxcast::dag::detail {

const int64_t* fixed_channel_table() {
  static const std::array<int64_t, 512> table = [] {
    std::array<int64_t, 512> t{};
    for (uint32_t c = 0; c < 256; ++c) {
      t[c] = to_fixed(esvo::decode_color_abgr(c).r);
      t[256 + c] = to_fixed(esvo::decode_color_abgr(esvo::layout::ColorA::put(c)).a);
    }
    return t;
  }();
  return table.data();
}

AttributeSum avx2::attribute_sum(const uint32_t* colors, const uint32_t* normals, size_t first,
                                 size_t count) {
  return attribute_sum_body(colors, normals, first, count);
}

AttributeSumKernel attribute_sum_kernel() {
  static const AttributeSumKernel kernel =
      active_isa() == Isa::Avx512 ? &avx512::attribute_sum : &avx2::attribute_sum;
  return kernel;
}

}  // namespace voxcast::dag::detail
