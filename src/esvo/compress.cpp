// Compressed shading attributes (esvo §5.5, Figures 9-10): one 6-word block
// encodes the colors and normals of the 16 child slots of two consecutive
// child descriptors (slot i = (descriptor parity) * 8 + child index).
//
// Block layout (32-bit words, bit 0 = least significant):
//
//   word 0, color endpoints (RGB-565 each, sRGB-encoded like the raw format):
//     | 31..16 c1 | 15..0 c0 |      c = | 15..11 R | 10..5 G | 4..0 B |
//   word 1, color indices: bits 2i+1..2i = index k_i of slot i:
//     0 -> c0, 1 -> c1, 2 -> (2 c0 + c1) / 3, 3 -> (c0 + 2 c1) / 3
//     (DXT1 without the transparency mode, §5.5 "Colors"). Decoding expands
//     5/6-bit channels to 8 bits by bit replication, interpolates in integers
//     with rounding ((2a + b + 1) / 3) and maps the 8-bit sRGB code to linear
//     with the raw format's table. Alpha is not stored (decodes as 1).
//   word 2, base normal n_b: a point on the unit cube, encoded exactly like the
//     raw normal (| 31..29 face | 28..15 u | 14..0 v |) but *not* normalized:
//     the major component is +-1 (§5.5 "Normals", Figure 10).
//   word 3, axis vectors n_u, n_v (signed 4-bit mantissas, shared exponent):
//     | 31..28 e_u | 27..24 u.z | 23..20 u.y | 19..16 u.x |
//     | 15..12 e_v | 11..8  v.z |  7..4  v.y |  3..0  v.x |
//     component = m * 2^(e - 15), m two's complement in -8..7, e in 0..15.
//   words 4, 5, normal indices: slot i uses the 4 bits at word 4 + (i >> 3),
//     bits 4(i&7)+3 .. 4(i&7): | 3..2 k_v | 1..0 k_u |, c(k) = (2k - 3) / 3,
//     i.e. c in {-1, -1/3, 1/3, 1}; normal = normalize(n_b + c(k_u) n_u + c(k_v) n_v)
//     (falls back to n_b if that sum is ~zero, so decoding is total).
//
// Decoding reads one slot only (a few shifts, one table lookup per channel and
// one normalization), which keeps EsvoOctree::attributes() cheap per hit.
//
// Encoding (not specified by the paper; our own search):
//   colors: principal axis of the used slots' colors (power iteration on the
//     covariance) seeds the endpoints at the extreme projections (also the
//     bounding-box corners); then a few rounds of least-squares endpoint refit
//     for the chosen indices, 565 quantization and optimal index selection
//     against the *decoded* palette; a +-1 local search on the quantized
//     channels (one endpoint or both) finishes. A constant block uses a
//     precomputed optimal endpoint pair per channel (index 2). Candidates are
//     compared by the summed squared error in sRGB 8-bit units.
//   normals: for each candidate base direction (mean normal, the used normal
//     farthest from it), targets are the used normals centrally projected onto
//     the plane through the cube point of the base, perpendicular to it; the
//     residuals' principal axes (2-D PCA) give n_u, n_v spanning their extent
//     (also a 1-D variant with n_u, n_v parallel, 4:1 lengths, giving 16
//     evenly spaced levels). Each configuration is quantized (exponent =
//     smallest covering the extent), indices are chosen by maximum cosine
//     among the 16 decoded candidates, then refit (3 rounds): least squares
//     for n_b, n_u, n_v, quantize n_u, refit n_b, n_v for it, quantize n_v,
//     n_b = mean residual (so the base absorbs the 4-bit rounding of the axes).
//     A constant configuration (n_b = mean, zero axes) is always a candidate;
//     widely spread sets also try two clusters (along the normals' principal
//     axis) at c_u = -1 / +1 (sharp edges, thin walls) and three clusters at
//     three grid corners (surface corners), §5.5's "entirely different
//     directions" case. The least (max + mean) angular error of the decoded
//     normals wins.
#include "esvo/compress.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>

#include "voxcast/esvo.hpp"
#include "voxcast/math.hpp"

namespace voxcast::esvo {
namespace {

// ---------------------------------------------------------------- common ----

// Double-precision vectors: voxcast::Vec3d (include/voxcast/math.hpp).
// unit() multiplies by the reciprocal length and maps zero to +z; the encoded
// normals' bytes depend on both, so it is not voxcast::normalize.
Vec3d unit(Vec3d a) {
  const double l = length(a);
  return l > 0 ? a * (1.0 / l) : Vec3d{0, 0, 1};
}

/// Principal eigenvector of a symmetric 3x3 matrix by power iteration, started
/// from its largest column (which lies in its range). Zero matrix -> zero.
Vec3d principal_axis(const double m[3][3]) {
  Vec3d v{};
  double best = 0;
  for (int c = 0; c < 3; ++c) {
    const Vec3d col{m[0][c], m[1][c], m[2][c]};
    if (dot(col, col) > best) best = dot(col, col), v = col;
  }
  if (!(best > 1e-24)) return {};
  v = unit(v);
  for (int it = 0; it < 8; ++it) {
    const Vec3d w{m[0][0] * v.x + m[0][1] * v.y + m[0][2] * v.z,
                  m[1][0] * v.x + m[1][1] * v.y + m[1][2] * v.z,
                  m[2][0] * v.x + m[2][1] * v.y + m[2][2] * v.z};
    if (!(dot(w, w) > 1e-30)) break;
    v = unit(w);
  }
  return v;
}

// ---------------------------------------------------------------- colors ----

uint32_t expand5(uint32_t x) {
  return x << 3 | x >> 2;
}
uint32_t expand6(uint32_t x) {
  return x << 2 | x >> 4;
}

/// The four decoded palette entries (8-bit sRGB) of endpoints c0, c1 (565).
struct Palette {
  int c[4][3];
};
Palette make_palette(uint32_t c0, uint32_t c1) {
  using layout::Rgb565B, layout::Rgb565G, layout::Rgb565R;
  const int e0[3] = {int(expand5(Rgb565R::get(c0))), int(expand6(Rgb565G::get(c0))),
                     int(expand5(Rgb565B::get(c0)))};
  const int e1[3] = {int(expand5(Rgb565R::get(c1))), int(expand6(Rgb565G::get(c1))),
                     int(expand5(Rgb565B::get(c1)))};
  Palette p;
  for (int ch = 0; ch < 3; ++ch) {
    p.c[0][ch] = e0[ch];
    p.c[1][ch] = e1[ch];
    p.c[2][ch] = (2 * e0[ch] + e1[ch] + 1) / 3;
    p.c[3][ch] = (e0[ch] + 2 * e1[ch] + 1) / 3;
  }
  return p;
}

uint32_t pack565(int r, int g, int b) {
  return layout::Rgb565R::put(uint32_t(r)) | layout::Rgb565G::put(uint32_t(g)) |
         layout::Rgb565B::put(uint32_t(b));
}

/// Optimal endpoints for a single 8-bit value with index 2 ((2a + b + 1) / 3):
/// per channel width (5 or 6 bits) and target, the (a, b) pair with the least
/// error. Makes constant blocks exact or within 1/255 (see the tests).
struct SingleColorTables {
  std::array<std::array<uint8_t, 2>, 256> t5{}, t6{};
  SingleColorTables() {
    fill(t5, 5);
    fill(t6, 6);
  }
  static void fill(std::array<std::array<uint8_t, 2>, 256>& t, int bits) {
    const int n = 1 << bits;
    for (int target = 0; target < 256; ++target) {
      int best = 1 << 30;
      for (int a = 0; a < n; ++a)
        for (int b = 0; b < n; ++b) {
          const int ea = int(bits == 5 ? expand5(uint32_t(a)) : expand6(uint32_t(a)));
          const int eb = int(bits == 5 ? expand5(uint32_t(b)) : expand6(uint32_t(b)));
          // Prefer close endpoints (smaller spread) among equal errors.
          const int err = std::abs((2 * ea + eb + 1) / 3 - target) * 1024 + std::abs(ea - eb);
          if (err < best) best = err, t[size_t(target)] = {uint8_t(a), uint8_t(b)};
        }
    }
  }
};
const SingleColorTables& single_color_tables() {
  static const SingleColorTables t;
  return t;
}

struct ColorFit {
  uint32_t c0 = 0, c1 = 0;
  double sse = INFINITY;
  uint8_t idx[16] = {};
};

class ColorEncoder {
 public:
  ColorEncoder(const float (*x)[3], int n) : x_(x), n_(n) {}

  /// Sum of squared errors (8-bit units) with the optimal index per slot.
  double evaluate(uint32_t c0, uint32_t c1, uint8_t* idx) const {
    const Palette p = make_palette(c0, c1);
    double sse = 0;
    for (int i = 0; i < n_; ++i) {
      double best = INFINITY;
      int bk = 0;
      for (int k = 0; k < 4; ++k) {
        const double dr = x_[i][0] - p.c[k][0], dg = x_[i][1] - p.c[k][1],
                     db = x_[i][2] - p.c[k][2];
        const double e = dr * dr + dg * dg + db * db;
        if (e < best) best = e, bk = k;
      }
      sse += best;
      if (idx) idx[i] = uint8_t(bk);
    }
    return sse;
  }

  void consider(uint32_t c0, uint32_t c1) {
    uint8_t idx[16] = {};
    const double e = evaluate(c0, c1, idx);
    if (e < fit_.sse) {
      fit_.c0 = c0, fit_.c1 = c1, fit_.sse = e;
      std::copy(idx, idx + 16, fit_.idx);
    }
  }

  static uint32_t quantize(const double e[3]) {
    const auto q = [](double v, int max) {
      const double s = std::clamp(v, 0.0, 255.0) * max / 255.0;
      return int(s + 0.5);
    };
    return pack565(q(e[0], 31), q(e[1], 63), q(e[2], 31));
  }

  ColorFit run() {
    // Mean and covariance of the used colors.
    double mean[3] = {0, 0, 0};
    for (int i = 0; i < n_; ++i)
      for (int c = 0; c < 3; ++c) mean[c] += x_[i][c];
    for (double& m : mean) m /= n_;
    double cov[3][3] = {};
    for (int i = 0; i < n_; ++i)
      for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b) cov[a][b] += (x_[i][a] - mean[a]) * (x_[i][b] - mean[b]);

    // Constant (or near-constant) block: optimal single-color endpoints.
    {
      const auto& t = single_color_tables();
      int m8[3];
      for (int c = 0; c < 3; ++c) m8[c] = std::clamp(int(mean[c] + 0.5), 0, 255);
      consider(pack565(t.t5[size_t(m8[0])][0], t.t6[size_t(m8[1])][0], t.t5[size_t(m8[2])][0]),
               pack565(t.t5[size_t(m8[0])][1], t.t6[size_t(m8[1])][1], t.t5[size_t(m8[2])][1]));
    }
    if (fit_.sse == 0) return fit_;

    // Principal axis seed: endpoints at the extreme projections.
    const Vec3d axis = principal_axis(cov);
    double tmin = 0, tmax = 0;
    for (int i = 0; i < n_; ++i) {
      const double t = (x_[i][0] - mean[0]) * axis.x + (x_[i][1] - mean[1]) * axis.y +
                       (x_[i][2] - mean[2]) * axis.z;
      tmin = std::min(tmin, t), tmax = std::max(tmax, t);
    }
    double e0[3], e1[3];
    for (int c = 0; c < 3; ++c) e0[c] = mean[c] + tmin * axis[c], e1[c] = mean[c] + tmax * axis[c];
    consider(quantize(e0), quantize(e1));
    // Bounding box corners (helps when the axis is poorly defined).
    {
      double lo[3] = {255, 255, 255}, hi[3] = {0, 0, 0};
      for (int i = 0; i < n_; ++i)
        for (int c = 0; c < 3; ++c)
          lo[c] = std::min(lo[c], double(x_[i][c])), hi[c] = std::max(hi[c], double(x_[i][c]));
      consider(quantize(lo), quantize(hi));
    }

    // Least-squares refit of the continuous endpoints for the current indices.
    static constexpr double kAlpha[4] = {1.0, 0.0, 2.0 / 3.0, 1.0 / 3.0};  // weight of c0
    for (int round = 0; round < 3; ++round) {
      double aa = 0, ab = 0, bb = 0, ax[3] = {0, 0, 0}, bx[3] = {0, 0, 0};
      for (int i = 0; i < n_; ++i) {
        const double a = kAlpha[fit_.idx[i]], b = 1.0 - a;
        aa += a * a, ab += a * b, bb += b * b;
        for (int c = 0; c < 3; ++c) ax[c] += a * x_[i][c], bx[c] += b * x_[i][c];
      }
      const double det = aa * bb - ab * ab;
      if (!(std::fabs(det) > 1e-9)) break;
      for (int c = 0; c < 3; ++c) {
        e0[c] = (bb * ax[c] - ab * bx[c]) / det;
        e1[c] = (aa * bx[c] - ab * ax[c]) / det;
      }
      const double before = fit_.sse;
      consider(quantize(e0), quantize(e1));
      if (!(fit_.sse < before)) break;
    }

    // Local search on the quantized endpoints: +-1 on one channel of c0, of
    // c1, or of both (a shift of the whole segment).
    static constexpr int kShift[3] = {layout::Rgb565R::lo, layout::Rgb565G::lo,
                                      layout::Rgb565B::lo};
    static constexpr int kMax[3] = {layout::Rgb565R::max, layout::Rgb565G::max,
                                    layout::Rgb565B::max};
    for (int pass = 0; pass < 8 && fit_.sse > 0; ++pass) {
      bool improved = false;
      for (int which = 1; which <= 3; ++which)  // bit 0: c0, bit 1: c1
        for (int c = 0; c < 3; ++c)
          for (int d = -1; d <= 1; d += 2) {
            uint32_t ep[2] = {fit_.c0, fit_.c1};
            bool ok = true;
            for (int end = 0; end < 2; ++end) {
              if (!(which >> end & 1)) continue;
              const int v = int(ep[end] >> kShift[c]) & kMax[c];
              if (v + d < 0 || v + d > kMax[c]) ok = false;
              ep[end] = (ep[end] & ~(uint32_t(kMax[c]) << kShift[c])) |
                        uint32_t(std::clamp(v + d, 0, kMax[c])) << kShift[c];
            }
            if (!ok) continue;
            const double before = fit_.sse;
            consider(ep[0], ep[1]);
            improved |= fit_.sse < before;
          }
      if (!improved) break;
    }
    return fit_;
  }

 private:
  const float (*x_)[3];
  int n_;
  ColorFit fit_;
};

// --------------------------------------------------------------- normals ----

constexpr double kCoef[4] = {-1.0, -1.0 / 3.0, 1.0 / 3.0, 1.0};
constexpr int kAxisExpBias = 15;

/// Cube point (major component +-1) of a cube normal code; face > 5 -> +z.
Vec3d cube_point(uint32_t code) {
  const Vec3 n = decode_normal_cube(code);  // normalized; rescale to the cube
  const double m =
      std::max({std::fabs(double(n.x)), std::fabs(double(n.y)), std::fabs(double(n.z))});
  return Vec3d{n.x / m, n.y / m, n.z / m};
}

/// Quantized axis: 4-bit exponent + three signed 4-bit mantissas (16 bits).
struct QAxis {
  uint32_t bits = 0;
  Vec3d value;
};
QAxis quantize_axis(Vec3d a) {
  const double amax = std::max({std::fabs(a.x), std::fabs(a.y), std::fabs(a.z)});
  int e = 0;
  // Smallest exponent whose mantissa range covers the extent.
  while (e < 15 && amax > 7.5 * std::ldexp(1.0, e - kAxisExpBias)) ++e;
  const double step = std::ldexp(1.0, e - kAxisExpBias);
  QAxis q;
  q.bits = layout::AxisExponent::put(uint32_t(e));
  for (int c = 0; c < 3; ++c) {
    const int m = std::clamp(int(std::lround(a[c] / step)), -8, 7);
    q.bits |= layout::AxisMantissas::put(uint32_t(m), unsigned(c));
    q.value[c] = m * step;
  }
  return q;
}

struct NormalFit {
  uint32_t base = 0, axes = 0;
  uint8_t ku[16] = {}, kv[16] = {};
  double score = INFINITY;  // max + mean angle (radians)
  Vec3d b, u, v;            // dequantized
};

class NormalEncoder {
 public:
  NormalEncoder(const Vec3d* n, int count) : n_(n), count_(count) {}

  /// Quantizes (b, u, v) (b is rescaled onto the cube together with u, v,
  /// which leaves every decoded direction unchanged), picks the best index
  /// pair per normal and scores the result. Returns the candidate.
  NormalFit evaluate(Vec3d b, Vec3d u, Vec3d v) const {
    NormalFit f;
    const double m = std::max({std::fabs(b.x), std::fabs(b.y), std::fabs(b.z)});
    if (!(m > 1e-9) || !std::isfinite(m)) return f;
    b = b * (1.0 / m), u = u * (1.0 / m), v = v * (1.0 / m);
    f.base = encode_normal_cube(Vec3{float(b.x), float(b.y), float(b.z)});
    f.b = cube_point(f.base);
    const QAxis qu = quantize_axis(u), qv = quantize_axis(v);
    f.axes = layout::AxisU::put(qu.bits) | layout::AxisV::put(qv.bits);
    f.u = qu.value, f.v = qv.value;
    Vec3d cand[16];
    for (int k = 0; k < 16; ++k) {
      const Vec3d p = f.b + f.u * kCoef[k & 3] + f.v * kCoef[k >> 2];
      cand[k] = dot(p, p) > 1e-12 ? unit(p) : unit(f.b);
    }
    double sum = 0, worst = 0;
    for (int i = 0; i < count_; ++i) {
      double best = -2;
      int bk = 0;
      for (int k = 0; k < 16; ++k) {
        const double c = dot(cand[k], n_[i]);
        if (c > best) best = c, bk = k;
      }
      f.ku[i] = uint8_t(bk & 3), f.kv[i] = uint8_t(bk >> 2);
      const double ang = 2.0 * std::asin(std::min(1.0, 0.5 * length(cand[bk] - n_[i])));
      sum += ang, worst = std::max(worst, ang);
    }
    f.score = worst + sum / count_;
    return f;
  }

  void consider(const NormalFit& f) {
    if (f.score < fit_.score) fit_ = f;
  }

  /// Central projection of unit `n` onto the plane {x : x . bh = bl} (the
  /// plane through the base point perpendicular to the base direction; the
  /// decoded grid n_b + c_u n_u + c_v n_v is an affine grid in such a plane).
  /// Normals (nearly) perpendicular to or behind the base go far out in their
  /// tangential direction instead.
  static Vec3d project(Vec3d n, Vec3d bh, double bl) {
    const double d = dot(n, bh);
    if (d > 0.05) return n * (bl / d);
    Vec3d t = n - bh * d;
    if (!(dot(t, t) > 1e-12))
      t = cross(bh, std::fabs(bh.x) < 0.9 ? Vec3d{1, 0, 0} : Vec3d{0, 1, 0});
    return bh * bl + unit(t) * (bl * 20.0);
  }

  /// Least-squares refit for the indices of `f`, quantizing one unknown at a
  /// time and refitting the rest for the quantized value (so the base absorbs
  /// the axes' 4-bit rounding): (b, u, v) -> quantize u -> (b, v | u) ->
  /// quantize v -> b = mean residual. Targets lie in the plane through f's
  /// base point perpendicular to it; evaluate() moves the base back onto the
  /// cube (rescaling the axes by ~1, which keeps their mantissas).
  NormalFit refit(const NormalFit& f) const {
    const Vec3d bh = unit(f.b);
    const double bl = length(f.b);
    Vec3d p[16];
    double cu[16], cv[16];
    for (int i = 0; i < count_; ++i) {
      p[i] = project(n_[i], bh, bl);
      cu[i] = kCoef[f.ku[i]], cv[i] = kCoef[f.kv[i]];
    }
    // Full 3x3 normal equations of rows [1, cu, cv] (shared by x, y, z). A
    // small ridge toward the current solution keeps degenerate systems (all
    // normals on one index) solvable.
    const double lambda = 1e-6;
    double m[3][3] = {};
    Vec3d rhs[3] = {f.b * lambda, f.u * lambda, f.v * lambda};
    for (int i = 0; i < count_; ++i) {
      const double w[3] = {1.0, cu[i], cv[i]};
      for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) m[r][c] += w[r] * w[c];
        rhs[r] = rhs[r] + p[i] * w[r];
      }
    }
    for (int r = 0; r < 3; ++r) m[r][r] += lambda;
    const double det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) -
                       m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
                       m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    if (!(std::fabs(det) > 1e-12)) return NormalFit{};
    // Row 1 of the inverse gives u (Cramer).
    const double i10 = (m[1][2] * m[2][0] - m[1][0] * m[2][2]) / det;
    const double i11 = (m[0][0] * m[2][2] - m[0][2] * m[2][0]) / det;
    const double i12 = (m[0][2] * m[1][0] - m[0][0] * m[1][2]) / det;
    const QAxis qu = quantize_axis(rhs[0] * i10 + rhs[1] * i11 + rhs[2] * i12);
    // (b, v) for the quantized u: 2x2 system of rows [1, cv].
    double a00 = lambda, a01 = 0, a11 = lambda;
    Vec3d r0 = f.b * lambda, r1 = f.v * lambda;
    for (int i = 0; i < count_; ++i) {
      const Vec3d q = p[i] - qu.value * cu[i];
      a00 += 1, a01 += cv[i], a11 += cv[i] * cv[i];
      r0 = r0 + q, r1 = r1 + q * cv[i];
    }
    const double d2 = a00 * a11 - a01 * a01;
    if (!(std::fabs(d2) > 1e-12)) return NormalFit{};
    const QAxis qv = quantize_axis((r1 * a00 - r0 * a01) * (1.0 / d2));
    // Base = mean residual for both quantized axes.
    Vec3d base{};
    for (int i = 0; i < count_; ++i) base = base + (p[i] - qu.value * cu[i] - qv.value * cv[i]);
    return evaluate(base * (1.0 / count_), qu.value, qv.value);
  }

  /// Principal-axis configuration around base direction `dir`.
  void try_base(Vec3d dir) {
    const double m = std::max({std::fabs(dir.x), std::fabs(dir.y), std::fabs(dir.z)});
    if (!(m > 0)) return;
    const Vec3d b = dir * (1.0 / m);  // cube point
    const Vec3d bh = unit(b);
    const double bl = length(b);
    Vec3d r[16];
    double cov[3][3] = {};
    for (int i = 0; i < count_; ++i) {
      r[i] = project(n_[i], bh, bl) - b;  // in the tangent plane
      for (int a = 0; a < 3; ++a)
        for (int c = 0; c < 3; ++c) cov[a][c] += r[i][a] * r[i][c];
    }
    Vec3d e1 = principal_axis(cov);
    e1 = e1 - bh * dot(e1, bh);  // numerically in the plane
    if (!(dot(e1, e1) > 1e-20))
      e1 = cross(bh, std::fabs(bh.x) < 0.9 ? Vec3d{1, 0, 0} : Vec3d{0, 1, 0});
    e1 = unit(e1);
    const Vec3d e2 = unit(cross(bh, e1));
    double lo1 = 0, hi1 = 0, lo2 = 0, hi2 = 0;
    for (int i = 0; i < count_; ++i) {
      const double t1 = dot(r[i], e1), t2 = dot(r[i], e2);
      lo1 = std::min(lo1, t1), hi1 = std::max(hi1, t1);
      lo2 = std::min(lo2, t2), hi2 = std::max(hi2, t2);
    }
    const Vec3d center = b + e1 * (0.5 * (lo1 + hi1)) + e2 * (0.5 * (lo2 + hi2));
    const double h1 = 0.5 * (hi1 - lo1), h2 = 0.5 * (hi2 - lo2);
    // 2-D grid and 1-D (parallel axes 4:1 -> 16 even levels along e1).
    NormalFit cand[2] = {evaluate(center, e1 * h1, e2 * h2),
                         evaluate(center, e1 * (0.8 * h1), e1 * (0.2 * h1))};
    for (NormalFit f : cand) {
      consider(f);
      for (int round = 0; round < 3 && std::isfinite(f.score); ++round) {
        const NormalFit g = refit(f);
        if (!(g.score < f.score)) break;
        f = g;
        consider(f);
      }
    }
  }

  /// Sharp features (e.g. both sides of a thin wall or an edge): split the
  /// normals in two clusters along their principal axis and put the cluster
  /// directions a, b at c_u = -1 and +1: n_b - n_u = a, n_b + n_u = k b
  /// (k = 1, 2; k = 2 keeps n_b off zero for opposite clusters), n_v = 0
  /// (§5.5: "one of the directions can be selected as n_b while using n_u
  /// and n_v to approximate two other directions"). No projection is needed,
  /// so normals behind the base are handled.
  void try_two_clusters() {
    Vec3d mean{};
    for (int i = 0; i < count_; ++i) mean = mean + n_[i];
    mean = mean * (1.0 / count_);
    double cov[3][3] = {};
    for (int i = 0; i < count_; ++i) {
      const Vec3d d = n_[i] - mean;
      for (int a = 0; a < 3; ++a)
        for (int c = 0; c < 3; ++c) cov[a][c] += d[a] * d[c];
    }
    const Vec3d e = principal_axis(cov);
    if (dot(e, e) == 0) return;
    Vec3d sa{}, sb{};
    for (int i = 0; i < count_; ++i) {
      Vec3d& side = dot(n_[i] - mean, e) < 0 ? sa : sb;
      side = side + n_[i];
    }
    if (!(length(sa) > 1e-9) || !(length(sb) > 1e-9)) return;
    const Vec3d a = unit(sa), b = unit(sb);
    for (int order = 0; order < 2; ++order) {
      const Vec3d x = order ? b : a, y = order ? a : b;
      for (double k : {1.0, 2.0}) {
        const Vec3d base = (x + y * k) * 0.5, u = (y * k - x) * 0.5;
        if (!(length(base) > 1e-3)) continue;
        NormalFit f = evaluate(base, u, Vec3d{});
        consider(f);
        // Refit only when every normal is in front of the base (projection).
        bool front = true;
        for (int i = 0; i < count_ && front; ++i) front = dot(n_[i], unit(f.b)) > 0.1;
        for (int round = 0; front && round < 2 && std::isfinite(f.score); ++round) {
          const NormalFit g = refit(f);
          if (!(g.score < f.score)) break;
          f = g;
          consider(f);
        }
      }
    }
  }

  /// Three distinct directions (e.g. a corner): farthest-point seeds, nearest
  /// assignment, cluster means a, b, c at three corners of the grid:
  /// n_b - n_u - n_v = a, n_b + n_u - n_v = k1 b, n_b - n_u + n_v = k2 c
  /// (scales k1, k2 in {1, 2} keep n_b off zero when b and c are opposite).
  void try_three_clusters() {
    Vec3d mean{};
    for (int i = 0; i < count_; ++i) mean = mean + n_[i];
    int s0 = 0;
    for (int i = 1; i < count_; ++i)
      if (dot(n_[i], mean) < dot(n_[s0], mean)) s0 = i;
    int s1 = s0;
    for (int i = 0; i < count_; ++i)
      if (dot(n_[i], n_[s0]) < dot(n_[s1], n_[s0])) s1 = i;
    int s2 = s0;
    double best = 2;
    for (int i = 0; i < count_; ++i) {
      const double c = std::max(dot(n_[i], n_[s0]), dot(n_[i], n_[s1]));
      if (c < best) best = c, s2 = i;
    }
    if (s1 == s0 || s2 == s0 || s2 == s1) return;
    Vec3d sum[3] = {};
    const Vec3d seed[3] = {n_[s0], n_[s1], n_[s2]};
    for (int i = 0; i < count_; ++i) {
      int k = 0;
      for (int j = 1; j < 3; ++j)
        if (dot(n_[i], seed[j]) > dot(n_[i], seed[k])) k = j;
      sum[k] = sum[k] + n_[i];
    }
    Vec3d c[3];
    for (int j = 0; j < 3; ++j) c[j] = length(sum[j]) > 1e-9 ? unit(sum[j]) : seed[j];
    for (int corner = 0; corner < 3; ++corner) {
      const Vec3d a = c[corner], b = c[(corner + 1) % 3], d = c[(corner + 2) % 3];
      for (const auto& [k1, k2] : {std::pair{1.0, 1.0}, std::pair{2.0, 1.0}, std::pair{1.0, 2.0}}) {
        const Vec3d u = (b * k1 - a) * 0.5, v = (d * k2 - a) * 0.5;
        const Vec3d base = a + u + v;
        if (length(base) > 1e-3) consider(evaluate(base, u, v));
      }
    }
  }

  NormalFit run() {
    Vec3d mean{};
    for (int i = 0; i < count_; ++i) mean = mean + n_[i];
    if (!(length(mean) > 1e-9)) mean = n_[0];
    mean = unit(mean);
    // Constant configuration (guarantees: never worse than the mean normal).
    consider(evaluate(mean, Vec3d{}, Vec3d{}));
    if (fit_.score < 1e-4) return fit_;
    try_base(mean);
    // Base at the normal farthest from the mean (handles widely spread sets).
    int far = 0;
    for (int i = 1; i < count_; ++i)
      if (dot(n_[i], mean) < dot(n_[far], mean)) far = i;
    if (dot(n_[far], mean) < 0.9) try_base(n_[far]);
    if (fit_.score > 0.05) try_two_clusters();
    if (fit_.score > 0.05) try_three_clusters();
    return fit_;
  }

 private:
  const Vec3d* n_;
  int count_;
  NormalFit fit_;
};

double srgb_from_linear(double c) {
  if (!(c > 0)) return 0;
  if (c >= 1) return 1;
  return c <= 0.0031308 ? 12.92 * c : 1.055 * std::pow(c, 1.0 / 2.4) - 0.055;
}

/// Encodes one block from per-used-slot sRGB colors (0..255) and unit normals
/// (both compacted in ascending slot order).
void encode_core(const float (*srgb)[3], const Vec3d* normals, uint32_t used, uint32_t out[6]) {
  for (int i = 0; i < 6; ++i) out[i] = 0;
  used &= 0xFFFFu;
  const int n = std::popcount(used);
  if (n == 0) return;
  const ColorFit cf = ColorEncoder(srgb, n).run();
  const NormalFit nf = NormalEncoder(normals, n).run();
  out[0] = layout::Endpoint0::put(cf.c0) | layout::Endpoint1::put(cf.c1);
  out[2] = nf.base;
  out[3] = nf.axes;
  int j = 0;
  for (int slot = 0; slot < 16; ++slot) {
    if (!(used >> slot & 1)) continue;
    out[1] |= layout::ColorIndices::put(uint32_t(cf.idx[j]), unsigned(slot));
    out[layout::kNormalIndexWord + (slot >> 3)] |= layout::NormalIndices::put(
        layout::NormalIndexU::put(nf.ku[j]) | layout::NormalIndexV::put(nf.kv[j]),
        unsigned(slot & 7));
    ++j;
  }
}

}  // namespace

void encode_compressed_block(const Color* colors, const Vec3* normals, uint32_t used,
                             uint32_t out[6]) {
  float x[16][3];
  Vec3d n[16];
  int j = 0;
  for (int slot = 0; slot < 16; ++slot) {
    if (!(used >> slot & 1)) continue;
    x[j][0] = float(srgb_from_linear(colors[slot].r) * 255.0);
    x[j][1] = float(srgb_from_linear(colors[slot].g) * 255.0);
    x[j][2] = float(srgb_from_linear(colors[slot].b) * 255.0);
    const Vec3d v{normals[slot].x, normals[slot].y, normals[slot].z};
    n[j] = dot(v, v) > 0 && std::isfinite(dot(v, v)) ? unit(v) : Vec3d{0, 0, 1};
    ++j;
  }
  encode_core(x, n, used, out);
}

Color decode_compressed_color(const uint32_t* block, int entry) {
  const Palette p =
      make_palette(layout::Endpoint0::get(block[0]), layout::Endpoint1::get(block[0]));
  const int k = entry & 3;
  return decode_color_abgr(layout::ColorR::put(uint32_t(p.c[k][0])) |
                           layout::ColorG::put(uint32_t(p.c[k][1])) |
                           layout::ColorB::put(uint32_t(p.c[k][2])) | layout::ColorA::mask);
}

void decode_compressed_normals(const uint32_t* block, uint32_t entries, Vec3 out[16]) {
  const Vec3 bn = decode_normal_cube(block[2]);
  const float m = std::max({std::fabs(bn.x), std::fabs(bn.y), std::fabs(bn.z)});
  const Vec3 b = bn / m;  // back onto the cube (m >= 1/sqrt(3))
  const uint32_t axes = block[3];
  static constexpr float kC[4] = {-1.f, -1.f / 3.f, 1.f / 3.f, 1.f};
  const auto axis = [](uint32_t bits, float c) {
    // 2^(e - 15) * c, built from the exponent bits (e in 0..15).
    const float scale =
        std::bit_cast<float>(uint32_t(int(layout::AxisExponent::get(bits)) - kAxisExpBias + 127)
                             << 23) *
        c;
    const auto m4 = [bits](unsigned i) {
      return float(layout::AxisMantissas::get_signed(bits, i));
    };
    return Vec3{m4(0) * scale, m4(1) * scale, m4(2) * scale};
  };
  for (uint32_t e = entries & 0xFFFFu; e; e &= e - 1) {
    const uint32_t sel = uint32_t(std::countr_zero(e));
    const Vec3 p = b + axis(layout::AxisU::get(axes), kC[layout::NormalIndexU::get(sel)]) +
                   axis(layout::AxisV::get(axes), kC[layout::NormalIndexV::get(sel)]);
    const float l2 = dot(p, p);
    out[sel] = l2 > 1e-12f ? p / std::sqrt(l2) : bn;
  }
}

Vec3 decode_compressed_normal(const uint32_t* block, int entry) {
  Vec3 n[16];
  decode_compressed_normals(block, 1u << (entry & 15), n);
  return n[entry & 15];
}

void decode_compressed_slot(const uint32_t* block, int slot, Color* color, Vec3* normal) {
  if (color) *color = decode_compressed_color(block, compressed_color_index(block, slot));
  if (normal) *normal = decode_compressed_normal(block, compressed_normal_index(block, slot));
}

namespace detail {

void encode_block_from_raw(const uint64_t* values, uint32_t used, uint32_t out[6]) {
  float x[16][3];
  Vec3d n[16];
  const int count = std::popcount(used & 0xFFFFu);
  for (int j = 0; j < count; ++j) {
    const uint32_t c = uint32_t(values[j]);
    x[j][0] = float(layout::ColorR::get(c)), x[j][1] = float(layout::ColorG::get(c)),
    x[j][2] = float(layout::ColorB::get(c));
    const Vec3 v = decode_normal_cube(uint32_t(values[j] >> 32));
    n[j] = unit(Vec3d{v.x, v.y, v.z});
  }
  encode_core(x, n, used, out);
}

}  // namespace detail
}  // namespace voxcast::esvo
