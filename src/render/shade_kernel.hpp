#pragma once
// Blinn-Phong of 16 hits at once (issue 10 item 6): the surface integrator's
// shading of a packet's hits, lane i of every array one hit, structure of
// arrays so that the loop runs in vector registers. Runtime-dispatched
// (voxcast/isa.hpp): shade_kernel_avx2.cpp with the baseline flags (8 lanes
// per vector), shade_kernel_avx512.cpp with -march=x86-64-v4 (16). Every
// lane computes exactly the scalar formula's IEEE operations in the same
// order (sqrt and division are correctly rounded, -ffp-contract=off forbids
// fused multiply-adds), so the colors are the scalar path's bit for bit
// (SurfaceIntegratorPackets.*, SurfaceIntegratorVsReference.*).
#include "voxcast/isa.hpp"

namespace voxcast::detail {

inline constexpr int kShadeLanes = 16;

/// One batch: inputs per hit, the shaded color out. Lanes past `count` are
/// shaded too (whatever they hold) and ignored.
struct alignas(64) ShadeBatch {
  float cr[kShadeLanes], cg[kShadeLanes], cb[kShadeLanes];  // linear surface color
  float nx[kShadeLanes], ny[kShadeLanes], nz[kShadeLanes];  // unit normal, facing the ray
  float dx[kShadeLanes], dy[kShadeLanes], dz[kShadeLanes];  // unit ray direction
  float lx[kShadeLanes], ly[kShadeLanes], lz[kShadeLanes];  // unit direction to the light
  float visibility[kShadeLanes], ao[kShadeLanes];           // effects (1 without)
  float r[kShadeLanes], g[kShadeLanes], b[kShadeLanes];     // out: the shaded color
  int count = 0;
};

using ShadeKernel = void (*)(ShadeBatch* batch);
namespace avx2 {
void shade_blinn_phong(ShadeBatch* batch);
}
namespace avx512 {
void shade_blinn_phong(ShadeBatch* batch);
}
/// The variant of `isa` (the caller checked that the CPU runs it).
inline ShadeKernel shade_kernel(Isa isa) {
  return isa == Isa::Avx512 ? &avx512::shade_blinn_phong : &avx2::shade_blinn_phong;
}

}  // namespace voxcast::detail
