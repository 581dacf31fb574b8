// DXT1 (BC1) color blocks of brickmap worlds (§3.1.3; layout in
// include/voxcast/brickmap.hpp): the render-side color pool.
#include <algorithm>
#include <cmath>
#include <cstdint>

#include "voxcast/brickmap.hpp"

namespace voxcast::brickmap {
namespace {

struct Rgb {
  int c[3];
};

Rgb rgb_of(uint32_t abgr) {
  return {{int(abgr & 255), int(abgr >> 8 & 255), int(abgr >> 16 & 255)}};
}

uint32_t to565(const Rgb& v) {
  // Rounded to the nearest 5/6/5-bit level of the 8-bit value.
  const uint32_t r = uint32_t((v.c[0] * 31 + 127) / 255), g = uint32_t((v.c[1] * 63 + 127) / 255),
                 b = uint32_t((v.c[2] * 31 + 127) / 255);
  return r << 11 | g << 5 | b;
}

Rgb from565(uint32_t q) {
  const int r = int(q >> 11 & 31), g = int(q >> 5 & 63), b = int(q & 31);
  return {{r << 3 | r >> 2, g << 2 | g >> 4, b << 3 | b >> 2}};
}

// The block's palette of 4 colors.
void palette(uint32_t q0, uint32_t q1, Rgb p[4]) {
  p[0] = from565(q0), p[1] = from565(q1);
  for (int a = 0; a < 3; ++a) {
    if (q0 > q1) {
      p[2].c[a] = (2 * p[0].c[a] + p[1].c[a]) / 3;
      p[3].c[a] = (p[0].c[a] + 2 * p[1].c[a]) / 3;
    } else {
      p[2].c[a] = (p[0].c[a] + p[1].c[a]) / 2;
      p[3].c[a] = 0;
    }
  }
}

int distance2(const Rgb& a, const Rgb& b) {
  int d = 0;
  for (int k = 0; k < 3; ++k) d += (a.c[k] - b.c[k]) * (a.c[k] - b.c[k]);
  return d;
}

}  // namespace

uint64_t dxt1_encode(const uint32_t* abgr, int count) {
  Rgb v[16];
  double mean[3] = {0, 0, 0};
  for (int i = 0; i < count; ++i) {
    v[i] = rgb_of(abgr[i]);
    for (int a = 0; a < 3; ++a) mean[a] += v[i].c[a];
  }
  for (double& m : mean) m /= count;
  // Principal axis of the colors (power iteration on their covariance).
  double cov[3][3] = {};
  for (int i = 0; i < count; ++i)
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b) cov[a][b] += (v[i].c[a] - mean[a]) * (v[i].c[b] - mean[b]);
  // Start from the covariance column of the channel with the largest
  // variance (never orthogonal to the principal axis unless all are 0).
  const int k0 =
      cov[0][0] >= cov[1][1] ? (cov[0][0] >= cov[2][2] ? 0 : 2) : (cov[1][1] >= cov[2][2] ? 1 : 2);
  double axis[3] = {cov[0][k0], cov[1][k0], cov[2][k0]};
  for (int it = 0; it < 8; ++it) {
    double n[3];
    for (int a = 0; a < 3; ++a)
      n[a] = cov[a][0] * axis[0] + cov[a][1] * axis[1] + cov[a][2] * axis[2];
    const double l = std::max({std::fabs(n[0]), std::fabs(n[1]), std::fabs(n[2])});
    if (!(l > 0)) break;
    for (int a = 0; a < 3; ++a) axis[a] = n[a] / l;
  }
  // Endpoints: the colors at both ends along the axis (first of equals).
  int lo = 0, hi = 0;
  double plo = 0, phi = 0;
  for (int i = 0; i < count; ++i) {
    const double p = v[i].c[0] * axis[0] + v[i].c[1] * axis[1] + v[i].c[2] * axis[2];
    if (i == 0 || p < plo) plo = p, lo = i;
    if (i == 0 || p > phi) phi = p, hi = i;
  }
  uint32_t q0 = to565(v[hi]), q1 = to565(v[lo]);
  if (q0 < q1) std::swap(q0, q1);
  uint64_t block = uint64_t(q0) | uint64_t(q1) << 16;
  if (q0 == q1) return block;  // one color: every index 0
  Rgb p[4];
  palette(q0, q1, p);
  for (int i = 0; i < count; ++i) {
    int best = 0, bd = distance2(v[i], p[0]);
    for (int k = 1; k < 4; ++k) {
      const int d = distance2(v[i], p[k]);
      if (d < bd) bd = d, best = k;
    }
    block |= uint64_t(best) << (32 + 2 * i);
  }
  return block;
}

uint32_t dxt1_decode(uint64_t block, int i) {
  Rgb p[4];
  palette(uint32_t(block & 0xFFFF), uint32_t(block >> 16 & 0xFFFF), p);
  const Rgb& c = p[(block >> (32 + 2 * i)) & 3];
  return uint32_t(c.c[0]) | uint32_t(c.c[1]) << 8 | uint32_t(c.c[2]) << 16 | 0xFF000000u;
}

}  // namespace voxcast::brickmap
