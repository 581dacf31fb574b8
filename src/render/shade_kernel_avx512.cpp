// shade_blinn_phong (render/shade_kernel.hpp), AVX-512 variant: CMakeLists.txt
// compiles *_avx512.cpp with -march=x86-64-v4. Only called when the CPU has
// AVX-512 (SurfaceIntegrator checks the ISA at begin_frame).
#include "render/shade_kernel.hpp"
#include "render/shade_kernel_body.hpp"

namespace voxcast::detail {

void avx512::shade_blinn_phong(ShadeBatch* batch) {
  shade_blinn_phong_body(batch);
}

}  // namespace voxcast::detail
