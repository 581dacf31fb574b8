#pragma once
// The body of shade_blinn_phong (render/shade_kernel.hpp), included only by
// the per-ISA translation units. `static`: each of them keeps its own copy,
// so the linker can never hand the baseline code an AVX-512 instance.
#include "render/shade_kernel.hpp"

namespace voxcast::detail {

/// The surface integrator's Blinn-Phong (surface_integrator.cpp, shade()):
/// ambient 0.18 * ao, diffuse 0.82 * max(0, n.l) * visibility, specular
/// 0.12 * max(0, n.h)^32 * visibility with h = normalize(l - d). Written
/// with plain float arithmetic on each lane so that GCC vectorizes the loop:
/// x > 0 ? x : 0 is fmax(0, x) for every x (NaN and -0 give +0 both ways),
/// and normalize's zero-length select becomes a blend.
static inline void shade_blinn_phong_body(ShadeBatch* s) {
  for (int i = 0; i < kShadeLanes; ++i) {
    const float nx = s->nx[i], ny = s->ny[i], nz = s->nz[i];
    const float lx = s->lx[i], ly = s->ly[i], lz = s->lz[i];
    const float vis = s->visibility[i];
    const float nl = nx * lx + ny * ly + nz * lz;
    const float diffuse = (nl > 0.f ? nl : 0.f) * vis;
    // normalize(light - dir): v / |v|, or 0 for a zero length (math.hpp).
    const float hx = lx - s->dx[i], hy = ly - s->dy[i], hz = lz - s->dz[i];
    const float len = __builtin_sqrtf(hx * hx + hy * hy + hz * hz);
    // The divisor is 1 where the result is dropped, so that the divisions
    // can run unconditionally (no masked division in AVX2) without raising
    // a division by zero; the select then gives normalize's answer.
    const bool pos = len > 0.f;
    const float div = pos ? len : 1.f;
    const float qx = hx / div, qy = hy / div, qz = hz / div;
    const float ux = pos ? qx : 0.f, uy = pos ? qy : 0.f, uz = pos ? qz : 0.f;
    const float nh = nx * ux + ny * uy + nz * uz;
    float spec = nh > 0.f ? nh : 0.f;
    spec *= spec, spec *= spec, spec *= spec, spec *= spec, spec *= spec;  // ^32
    spec *= vis;
    const float k = 0.18f * s->ao[i] + 0.82f * diffuse;
    s->r[i] = s->cr[i] * k + 0.12f * spec;
    s->g[i] = s->cg[i] * k + 0.12f * spec;
    s->b[i] = s->cb[i] * k + 0.12f * spec;
  }
}

}  // namespace voxcast::detail
