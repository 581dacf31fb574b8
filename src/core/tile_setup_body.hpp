#pragma once
// The tile caster's ray set-up (core/octree_tile_caster.hpp), a pixel row at
// a time in N lanes: included only by src/core/tile_setup_avx2.cpp and
// _avx512.cpp. Every lane computes what cast_octree's callers compute for
// its pixel, in the same order of float operations (CameraRays::ray,
// OctreeFrame::point/direction, avoid_tiny_components, MirroredRay,
// enter_root; -ffp-contract=off everywhere), so the floats are the scalar
// ones bit for bit (tests/test_tile_caster.cpp compares every hit).
#include <cmath>
#include <cstdint>
#include <cstring>

#include "core/octree_packet_kernel.hpp"
#include "core/octree_tile_caster.hpp"

namespace voxcast::detail {
namespace {

template <int N>
void tile_rays_lanes(const CameraRays& cam, const OctreeFrame& frame, int x0, int y0, int x1,
                     int y1, TileRays* r) {
  using L = Lanes<N>;
  using F = typename L::F;
  using I = typename L::I;
  auto splat = [](float v) { return L::template splat<F>(v); };
  auto finite = [](F v) { return (v - v) == 0.f; };  // false for NaN and +-Inf
  auto store = [](float(&row)[kTileCols], int at, F v) { std::memcpy(row + at, &v, sizeof v); };
  const F sign_bit = (F)(L::template splat<I>(int32_t(0x80000000u)));
  r->rows = y1 - y0, r->cols = x1 - x0;
  tile_camera(cam, frame, x0, y0, r);
  const float W = float(cam.width), H = float(cam.height);
  for (int j = 0; j < r->rows; ++j) {
    uint32_t mx = 0, my = 0, mz = 0, live = 0;
    // CameraRays::screen_y(float(y) + sample.y): one value per row.
    const float sy = 1.f - 2.f * (float(y0 + j) + cam.sample.y) / H;
    for (int col = 0; col < kTileCols; col += N) {
      const F X = __builtin_convertvector(L::iota() + (x0 + col), F) + splat(cam.sample.x);
      const F sx = splat(2.f) * X / splat(W) - splat(1.f);
      F ox, oy, oz, vx, vy, vz;
      if (cam.ortho) {
        // CameraRays::ortho_origin; the direction is forward.
        const F a = sx * splat(cam.half_width);
        const float b = sy * cam.half_height;
        ox = splat(cam.eye.x) + splat(cam.right.x) * a + splat(cam.true_up.x * b);
        oy = splat(cam.eye.y) + splat(cam.right.y) * a + splat(cam.true_up.y * b);
        oz = splat(cam.eye.z) + splat(cam.right.z) * a + splat(cam.true_up.z * b);
        vx = splat(cam.forward.x), vy = splat(cam.forward.y), vz = splat(cam.forward.z);
      } else {
        // perspective_direction: normalize(forward + right (sx tan aspect) + up (sy tan)).
        const F a = sx * splat(cam.tan_half) * splat(cam.aspect);
        const float b = sy * cam.tan_half;
        const F ux = splat(cam.forward.x) + splat(cam.right.x) * a + splat(cam.true_up.x * b);
        const F uy = splat(cam.forward.y) + splat(cam.right.y) * a + splat(cam.true_up.y * b);
        const F uz = splat(cam.forward.z) + splat(cam.right.z) * a + splat(cam.true_up.z * b);
        F len = ux * ux + uy * uy + uz * uz;  // dot(u, u)
        if constexpr (N == 16)
          len = (F)_mm512_maskz_sqrt_ps(__mmask16(0xFFFF), (__m512)len);
        else
          len = (F)_mm256_sqrt_ps((__m256)len);
        const I pos = len > 0.f;
        vx = pos ? ux / len : splat(0.f);
        vy = pos ? uy / len : splat(0.f);
        vz = pos ? uz / len : splat(0.f);
        ox = splat(cam.eye.x), oy = splat(cam.eye.y), oz = splat(cam.eye.z);
      }
      // OctreeFrame::point and ::direction.
      const F px = (ox - splat(frame.origin.x)) * splat(frame.inv_side) + splat(1.f);
      const F py = (oy - splat(frame.origin.y)) * splat(frame.inv_side) + splat(1.f);
      const F pz = (oz - splat(frame.origin.z)) * splat(frame.inv_side) + splat(1.f);
      const F dx0 = vx * splat(frame.inv_side), dy0 = vy * splat(frame.inv_side),
              dz0 = vz * splat(frame.inv_side);
      const I ok_in =
          finite(px) & finite(py) & finite(pz) & finite(dx0) & finite(dy0) & finite(dz0);
      // avoid_tiny_components (fmax of finite magnitudes is max).
      const F ax = (F)((I)dx0 & ~(I)sign_bit), ay = (F)((I)dy0 & ~(I)sign_bit),
              az = (F)((I)dz0 & ~(I)sign_bit);
      const F largest = L::max(ax, L::max(ay, az));
      F eps = splat(0x1p-23f) * largest;
      eps = eps >= splat(0x1p-126f) ? eps : splat(0x1p-23f);
      auto tiny = [&](F d, F a) { return a < eps ? (F)((I)eps | ((I)d & (I)sign_bit)) : d; };
      const F dx = tiny(dx0, ax), dy = tiny(dy0, ay), dz = tiny(dz0, az);
      // MirroredRay.
      const F absx = (F)((I)dx & ~(I)sign_bit), absy = (F)((I)dy & ~(I)sign_bit),
              absz = (F)((I)dz & ~(I)sign_bit);
      const F cx = splat(1.f) / -absx, cy = splat(1.f) / -absy, cz = splat(1.f) / -absz;
      F bx = cx * px, by = cy * py, bz = cz * pz;
      const I fx = dx > 0.f, fy = dy > 0.f, fz = dz > 0.f;
      bx = fx ? splat(3.f) * cx - bx : bx;
      by = fy ? splat(3.f) * cy - by : by;
      bz = fz ? splat(3.f) * cz - bz : bz;
      // enter_root (tmax = INFINITY, no region).
      const F nbx = -bx, nby = -by, nbz = -bz;
      F t_min = L::max(L::max(L::fma(splat(2.f), cx, nbx), L::fma(splat(2.f), cy, nby)),
                       L::fma(splat(2.f), cz, nbz));
      F t_max = L::min(L::min(L::fma(splat(1.f), cx, nbx), L::fma(splat(1.f), cy, nby)),
                       L::fma(splat(1.f), cz, nbz));
      t_min = L::max(t_min, splat(0.f));
      t_max = L::min(t_max, splat(INFINITY));
      const int left = r->cols - col;  // pixels of this row from lane 0 on
      const uint32_t in_tile = left >= N ? L::kAll : left > 0 ? (1u << left) - 1 : 0u;
      const uint32_t ok = L::bits(ok_in & (t_min <= t_max)) & in_tile;
      store(r->cx[j], col, cx), store(r->cy[j], col, cy), store(r->cz[j], col, cz);
      store(r->nbx[j], col, nbx), store(r->nby[j], col, nby), store(r->nbz[j], col, nbz);
      store(r->dx[j], col, dx), store(r->dy[j], col, dy), store(r->dz[j], col, dz);
      store(r->px[j], col, px), store(r->py[j], col, py), store(r->pz[j], col, pz);
      store(r->ux[j], col, dx0), store(r->uy[j], col, dy0), store(r->uz[j], col, dz0);
      store(r->t_min[j], col, t_min), store(r->t_max[j], col, t_max);
      mx |= L::bits(fx) << col, my |= L::bits(fy) << col, mz |= L::bits(fz) << col;
      live |= ok << col;
    }
    r->mirror_x[j] = mx, r->mirror_y[j] = my, r->mirror_z[j] = mz, r->live[j] = live;
  }
}

}  // namespace
}  // namespace voxcast::detail
