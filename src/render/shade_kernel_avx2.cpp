// shade_blinn_phong (render/shade_kernel.hpp), AVX2 variant: the baseline
// flags (x86-64-v3), 8 lanes per vector.
#include "render/shade_kernel.hpp"
#include "render/shade_kernel_body.hpp"

namespace voxcast::detail {

void avx2::shade_blinn_phong(ShadeBatch* batch) {
  shade_blinn_phong_body(batch);
}

}  // namespace voxcast::detail
