// Procedural producers (gigavoxels.hpp make_procedural): a noise cloud and
// two fractal solids, evaluated per voxel at each level's resolution.
#include <array>
#include <cmath>
#include <cstdint>

#include "voxcast/error.hpp"
#include "voxcast/gigavoxels.hpp"

namespace voxcast::giga {
namespace {

struct P3 {
  double x, y, z;
};

double voxel_size(int level) {
  return 1.0 / double(int64_t(kBrickSide) << level);
}
P3 voxel_center(int level, int64_t x, int64_t y, int64_t z) {
  const double s = voxel_size(level);
  return {(double(x) + 0.5) * s, (double(y) + 0.5) * s, (double(z) + 0.5) * s};
}
bool outside_cube(int level, int64_t x, int64_t y, int64_t z) {
  const int64_t n = int64_t(kBrickSide) << level;
  return x < 0 || y < 0 || z < 0 || x >= n || y >= n || z >= n;
}
/// The node's region with a one-voxel margin: center and half diagonal.
void region_sphere(const NodeRegion& r, P3* center, double* radius) {
  const double side = std::ldexp(1.0, -r.level), margin = voxel_size(r.level);
  *center = {(r.x + 0.5) * side, (r.y + 0.5) * side, (r.z + 0.5) * side};
  *radius = std::sqrt(3.0) * (0.5 * side + margin);
}

class ProceduralBase : public Producer {
 public:
  explicit ProceduralBase(int max_level) : max_level_(max_level) {}
  int max_level() const override { return max_level_; }

 private:
  int max_level_;
};

// ---- Cloud: band-limited value-noise fBm in a soft sphere ----

uint32_t hash3(int64_t x, int64_t y, int64_t z, uint32_t seed) {
  uint64_t h = uint64_t(x) * 0x9E3779B97F4A7C15ull ^ uint64_t(y) * 0xC2B2AE3D27D4EB4Full ^
               uint64_t(z) * 0x165667B19E3779F9ull ^ uint64_t(seed) * 0x27D4EB2F165667C5ull;
  h ^= h >> 31, h *= 0xBF58476D1CE4E5B9ull, h ^= h >> 29;
  return uint32_t(h >> 32);
}

// Value noise's pieces, shared by the noise and by the cloud's bound on it
// (Cloud::octave_max), which must follow the same formulas.
double lattice_value(int64_t x, int64_t y, int64_t z, uint32_t seed) {
  return double(hash3(x, y, z, seed)) / 4294967296.0 - 0.5;
}
double fade(double t) {
  return t * t * (3 - 2 * t);
}
// The corner values h[n] (n = i + 2 j + 4 k) blended at faded (u, v, w).
double multilinear(const double h[8], double u, double v, double w) {
  double acc = 0;
  for (int n = 0; n < 8; ++n)
    acc += ((n & 1) ? u : 1 - u) * ((n >> 1 & 1) ? v : 1 - v) * ((n >> 2) ? w : 1 - w) * h[n];
  return acc;
}

/// Zero-mean value noise in [-0.5, 0.5) with a smooth (C1) fade.
double value_noise(P3 p, uint32_t seed) {
  const double fx = std::floor(p.x), fy = std::floor(p.y), fz = std::floor(p.z);
  const int64_t ix = int64_t(fx), iy = int64_t(fy), iz = int64_t(fz);
  double h[8];
  for (int n = 0; n < 8; ++n)
    h[n] = lattice_value(ix + (n & 1), iy + (n >> 1 & 1), iz + (n >> 2), seed);
  return multilinear(h, fade(p.x - fx), fade(p.y - fy), fade(p.z - fz));
}

class Cloud final : public ProceduralBase {
 public:
  using ProceduralBase::ProceduralBase;
  std::string name() const override { return "cloud"; }
  static constexpr int kOctaves = 9;
  static constexpr double kBaseFrequency = 3, kSigma = 30, kGain = 0.7;
  // Largest |fbm| (the octave amplitudes kGain, kGain / 2, ... times 0.5) and the sphere.
  static constexpr double kFbmMax = kGain, kRadius = 0.4, kShape = 1.0, kBias = 0.1;

  VolumeSample voxel(int level, int64_t x, int64_t y, int64_t z) const override {
    if (outside_cube(level, x, y, z)) return {};
    const P3 p = voxel_center(level, x, y, z);
    // Octaves whose lattice is finer than two voxels of this level would
    // alias: the level drops them (its prefilter; they average to ~0).
    const double vs = voxel_size(level);
    double f = kBaseFrequency, amp = kGain, fbm = 0;
    for (int o = 0; o < kOctaves && 1.0 / f >= 2 * vs; ++o, f *= 2, amp *= 0.5)
      fbm += amp * value_noise({p.x * f, p.y * f, p.z * f}, uint32_t(o));
    const double v = shape(p) + fbm;
    if (!(v > 0)) return {};
    const double c = std::min(1.0, 2 * v);
    VolumeSample s;
    s.density = float(kSigma * std::min(v, 1.0));
    s.color = {float(0.55 + 0.45 * c), float(0.6 + 0.4 * c), float(0.7 + 0.3 * c), 1.f};
    return s;
  }
  bool constant_below(const NodeRegion& r, VolumeSample* value) const override {
    P3 c;
    double radius;
    region_sphere(r, &c, &radius);
    const double d = std::sqrt((c.x - 0.5) * (c.x - 0.5) + (c.y - 0.5) * (c.y - 0.5) +
                               (c.z - 0.5) * (c.z - 0.5)) -
                     radius;
    // shape() + fbm <= 0 wherever the distance to the center exceeds
    // kRadius (1 + (kFbmMax - kBias) / kShape): empty at every level.
    if (d > kRadius * (1 + (kFbmMax - kBias) / kShape) || empty_box(r)) {
      *value = {};
      return true;
    }
    return false;
  }

 private:
  /// True when shape() + fbm <= 0 at every voxel center the node or any
  /// descendant stores (the region with its one-voxel margin), for every
  /// level from the node's to max_level: an interval bound, octave by
  /// octave. Without it the shell around the sphere (empty in fact, but
  /// beyond the radius test's reach) is only found empty brick by brick,
  /// non-terminal at every level, and rays descend through empty nodes down
  /// to their cone's level (docs/BENCHMARKS.md, "GigaVoxels: the empty
  /// shell proven empty").
  bool empty_box(const NodeRegion& r) const {
    const double side = std::ldexp(1.0, -r.level), margin = voxel_size(r.level);
    // A hair wider than the region: the centers' rounding stays inside.
    const double slack = 1e-12;
    const uint32_t cell[3] = {r.x, r.y, r.z};
    double lo[3], hi[3], dist2 = 0;
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::max(0.0, cell[a] * side - margin - slack);
      hi[a] = std::min(1.0, (cell[a] + 1) * side + margin + slack);
      const double q = std::max({lo[a] - 0.5, 0.0, 0.5 - hi[a]});
      dist2 += q * q;
    }
    const double shape_max = kShape * (1 - std::sqrt(dist2) / kRadius) - kBias;
    // Octaves of the node's level and of max_level (the finest keeps the most).
    auto octaves = [](int level) {
      int k = 0;
      for (double f = kBaseFrequency; k < kOctaves && 1.0 / f >= 2 * voxel_size(level); f *= 2) ++k;
      return k;
    };
    const int k_first = octaves(r.level), k_last = octaves(max_level());
    // bound(K) = shape_max + the sum over octaves o < K of the octave's
    // largest value over the box; each level from the node's down keeps a
    // prefix K in [k_first, k_last]: all of them must stay <= 0. The
    // octaves not yet bounded add at least -amp / 2 each: once a prefix
    // exceeds 0 by more than they can take away, stop (inside the cloud).
    double sum = shape_max, rest = 0;
    for (int o = 0; o < k_last; ++o) rest += kGain * std::ldexp(0.5, -o);
    if (k_first == 0 && sum > -1e-9) return false;
    double f = kBaseFrequency, amp = kGain;
    for (int o = 0; o < k_last; ++o, f *= 2, amp *= 0.5) {
      sum += amp * octave_max(lo, hi, f, uint32_t(o));
      rest -= amp * 0.5;
      if (o + 1 >= k_first && sum > -1e-9) return false;
      if (sum - rest > 0) return false;
    }
    return true;
  }

  /// An upper bound of value_noise(p f, seed) over the box [lo, hi]. Value
  /// noise in one lattice cell is multilinear in the faded coordinates
  /// (fade is monotone), so its largest value over the part of the box in
  /// that cell is at one of that part's 8 corners: exact up to rounding
  /// (far below the caller's 1e-9 margin). A box over more than 64 cells
  /// takes the largest lattice value of the cells it touches (the noise is
  /// a convex combination of its cell's), over more than 1000 of those 0.5.
  static double octave_max(const double lo[3], const double hi[3], double f, uint32_t seed) {
    int64_t i0[3], i1[3];
    int64_t cells = 1, points = 1;
    for (int a = 0; a < 3; ++a) {
      i0[a] = int64_t(std::floor(lo[a] * f)), i1[a] = int64_t(std::floor(hi[a] * f));
      cells *= i1[a] - i0[a] + 1, points *= i1[a] - i0[a] + 2;
    }
    double m = -0.5;
    if (cells <= 64) {
      for (int64_t z = i0[2]; z <= i1[2]; ++z)
        for (int64_t y = i0[1]; y <= i1[1]; ++y)
          for (int64_t x = i0[0]; x <= i1[0]; ++x) {
            const int64_t c[3] = {x, y, z};
            double u[3][2];  // the faded sub-box of this cell
            for (int a = 0; a < 3; ++a) {
              u[a][0] = fade(std::clamp(lo[a] * f - double(c[a]), 0.0, 1.0));
              u[a][1] = fade(std::clamp(hi[a] * f - double(c[a]), 0.0, 1.0));
            }
            double h[8];
            for (int n = 0; n < 8; ++n)
              h[n] = lattice_value(x + (n & 1), y + (n >> 1 & 1), z + (n >> 2), seed);
            for (int corner = 0; corner < 8; ++corner)
              m = std::max(
                  m, multilinear(h, u[0][corner & 1], u[1][corner >> 1 & 1], u[2][corner >> 2]));
          }
      return m;
    }
    if (points > 1000) return 0.5;
    for (int64_t z = i0[2]; z <= i1[2] + 1; ++z)
      for (int64_t y = i0[1]; y <= i1[1] + 1; ++y)
        for (int64_t x = i0[0]; x <= i1[0] + 1; ++x) m = std::max(m, lattice_value(x, y, z, seed));
    return m;
  }

  static double shape(P3 p) {
    const double r = std::sqrt((p.x - 0.5) * (p.x - 0.5) + (p.y - 0.5) * (p.y - 0.5) +
                               (p.z - 0.5) * (p.z - 0.5)) /
                     kRadius;
    return kShape * (1 - r) - kBias;
  }
};

// ---- Solids from a distance: voxel density = coverage of the voxel ----

class DistanceSolid : public ProceduralBase {
 public:
  using ProceduralBase::ProceduralBase;
  static constexpr double kSigma = 400;
  /// Signed distance (unit-cube units, negative inside) and color at p.
  virtual double distance(P3 p, Color* color) const = 0;
  /// A radius around (0.5, 0.5, 0.5) outside which the solid is empty.
  virtual double extent() const = 0;

  VolumeSample voxel(int level, int64_t x, int64_t y, int64_t z) const override {
    if (outside_cube(level, x, y, z)) return {};
    Color color;
    const double d = distance(voxel_center(level, x, y, z), &color);
    const double coverage = std::clamp(0.5 - d / voxel_size(level), 0.0, 1.0);
    if (!(coverage > 0)) return {};
    return {float(kSigma * coverage), color};
  }
  bool constant_below(const NodeRegion& r, VolumeSample* value) const override {
    P3 c;
    double radius;
    region_sphere(r, &c, &radius);
    const double d = std::sqrt((c.x - 0.5) * (c.x - 0.5) + (c.y - 0.5) * (c.y - 0.5) +
                               (c.z - 0.5) * (c.z - 0.5));
    if (d - radius > extent()) {
      *value = {};
      return true;
    }
    return false;
  }
};

constexpr Color kMengerColor{0.85f, 0.72f, 0.55f, 1.f};

/// Iterations of the sponge at `resolution` voxels per side: until the
/// finest bars are about one voxel wide.
int menger_iterations(int resolution) {
  int iterations = 1;
  while (iterations < 7 && std::pow(3.0, iterations) < resolution / 3.0) ++iterations;
  return iterations;
}

/// The Menger sponge in [0.1, 0.9]^3: the cube minus, at every iteration
/// k, the three square bars through the middle third of each of its 3^k
/// cells (distance: the cube's, max the negated distance to each
/// iteration's bars within the point's cell).
class Menger final : public DistanceSolid {
 public:
  Menger(int max_level, int iterations) : DistanceSolid(max_level), iterations_(iterations) {}
  std::string name() const override { return "menger"; }
  double extent() const override { return 0.4 * std::sqrt(3.0) + 1e-9; }
  double distance(P3 p, Color* color) const override {
    *color = kMengerColor;
    const double s[3] = {(p.x - 0.1) / 0.8, (p.y - 0.1) / 0.8, (p.z - 0.1) / 0.8};
    // The cube [0, 1]^3.
    double q[3], outside = 0, inside = -1e9;
    for (int a = 0; a < 3; ++a) {
      q[a] = std::fabs(s[a] - 0.5) - 0.5;
      outside += std::max(q[a], 0.0) * std::max(q[a], 0.0);
      inside = std::max(inside, q[a]);
    }
    double d = std::sqrt(outside) + std::min(inside, 0.0);
    double h = 1;
    for (int k = 0; k < iterations_; ++k, h /= 3) {
      double m[3];
      for (int a = 0; a < 3; ++a) {
        const double u = s[a] / h - std::floor(s[a] / h);
        m[a] = std::fabs(u - 0.5) - 1.0 / 6;  // > 0 outside the middle third
      }
      double bars = 1e9;
      for (int a = 0; a < 3; ++a) {
        const double qa = m[a], qb = m[(a + 1) % 3];
        const double ext = std::sqrt(std::max(qa, 0.0) * std::max(qa, 0.0) +
                                     std::max(qb, 0.0) * std::max(qb, 0.0));
        bars = std::min(bars, (ext + std::min(std::max(qa, qb), 0.0)) * h);
      }
      d = std::max(d, -bars);
    }
    return d * 0.8;
  }

 private:
  int iterations_;
};

/// The power-8 Mandelbulb in [-1.2, 1.2]^3 mapped to the unit cube; its
/// distance is the usual estimate 0.5 log(r) r / dr of the escaping orbit,
/// colored by the orbit's closest approach to the origin.
class Mandelbulb final : public DistanceSolid {
 public:
  using DistanceSolid::DistanceSolid;
  std::string name() const override { return "mandelbulb"; }
  static constexpr double kHalf = 1.2;
  double extent() const override { return 1.2 / (2 * kHalf); }  // the bulb fits in r < 1.2
  double distance(P3 p, Color* color) const override {
    const P3 c{(p.x - 0.5) * 2 * kHalf, (p.y - 0.5) * 2 * kHalf, (p.z - 0.5) * 2 * kHalf};
    P3 z = c;
    double dr = 1, r = 0, trap = 1e9;
    for (int i = 0; i < 12; ++i) {
      r = std::sqrt(z.x * z.x + z.y * z.y + z.z * z.z);
      trap = std::min(trap, r);
      if (r > 2) break;
      if (r == 0) break;
      const double theta = std::acos(std::clamp(z.z / r, -1.0, 1.0)) * 8;
      const double phi = std::atan2(z.y, z.x) * 8;
      const double r7 = std::pow(r, 7);
      dr = 8 * r7 * dr + 1;
      const double r8 = r7 * r;
      z = {r8 * std::sin(theta) * std::cos(phi) + c.x, r8 * std::sin(theta) * std::sin(phi) + c.y,
           r8 * std::cos(theta) + c.z};
    }
    const double t = std::clamp(trap, 0.0, 1.0);
    *color = {float(0.9 - 0.5 * t), float(0.45 + 0.3 * t), float(0.25 + 0.6 * t), 1.f};
    if (r <= 2) return -1e-3;  // the orbit stayed bounded: inside
    return 0.5 * std::log(r) * r / dr / (2 * kHalf);
  }
};

}  // namespace

std::shared_ptr<Producer> make_procedural(const std::string& name, int resolution) {
  if (resolution < kBrickSide || resolution > (kBrickSide << kMaxLevel) ||
      (resolution & (resolution - 1)) != 0)
    throw Error("procedural volume: --resolution must be a power of two in " +
                std::to_string(kBrickSide) + ".." + std::to_string(kBrickSide << kMaxLevel));
  int level = 0;
  while ((kBrickSide << level) < resolution) ++level;
  if (name == "cloud") return std::make_shared<Cloud>(level);
  if (name == "mandelbulb") return std::make_shared<Mandelbulb>(level);
  if (name == "menger") return std::make_shared<Menger>(level, menger_iterations(resolution));
  throw Error("procedural volume '" + name +
              "': expected cloud, mandelbulb, menger or menger-recursive");
}

RecursiveVolume make_recursive_menger(int resolution) {
  make_procedural("menger", resolution);  // the same resolution rules
  return RecursiveVolume::menger(menger_iterations(resolution), float(DistanceSolid::kSigma),
                                 kMengerColor, {0.1f, 0.1f, 0.1f}, 0.8f);
}

}  // namespace voxcast::giga
