// The dense-grid emission–absorption oracle (tests/support/volume_oracle.*)
// against closed forms: empty grid, a homogeneous slab, two slabs in both
// orders, an oblique chord; segment splitting composes; fine fixed steps
// converge to the exact per-cell integration. It is the reference the first
// volume structure's conformance tests will use (GigaVoxels, a later issue).
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "support/volume_oracle.hpp"

namespace voxcast::testing {
namespace {

constexpr std::array<double, 3> kRed{0.9, 0.2, 0.1}, kBlue{0.1, 0.3, 0.8};

// Cells with lo <= x < hi get (sigma, color).
void fill_x(DenseVolume& v, int lo, int hi, double sigma, std::array<double, 3> color) {
  for (int z = 0; z < v.nz(); ++z)
    for (int y = 0; y < v.ny(); ++y)
      for (int x = lo; x < hi; ++x) v.at(x, y, z) = {sigma, color};
}

void expect_sample(const VolumeSample& s, std::array<double, 3> color, double transmittance,
                   double tol = 1e-12) {
  EXPECT_NEAR(s.transmittance, transmittance, tol);
  for (size_t k = 0; k < 3; ++k) EXPECT_NEAR(s.color[k], color[k], tol) << "channel " << k;
}

TEST(VolumeOracle, EmptyGridIsTransparent) {
  const DenseVolume v(4, 4, 4);
  for (const VolumeSample& s : {v.integrate_exact({-1, 1.5, 2.5}, {1, 0.1, 0}, 0, 10),
                                v.integrate_fixed_step({-1, 1.5, 2.5}, {1, 0.1, 0}, 0, 10, 0.01)})
    expect_sample(s, {0, 0, 0}, 1);
  // A dense grid the ray never enters is transparent too.
  DenseVolume full(2, 2, 2);
  fill_x(full, 0, 2, 5.0, kRed);
  expect_sample(full.integrate_exact({-1, 3, 0.5}, {1, 0, 0}, 0, 10), {0, 0, 0}, 1);
}

TEST(VolumeOracle, HomogeneousSlab) {
  // sigma 0.7 over x in [1, 3): an axis ray crosses 2 units.
  DenseVolume v(4, 3, 3);
  fill_x(v, 1, 3, 0.7, kRed);
  const double T = std::exp(-0.7 * 2);
  const std::array<double, 3> C{(1 - T) * kRed[0], (1 - T) * kRed[1], (1 - T) * kRed[2]};
  expect_sample(v.integrate_exact({-1, 1.5, 1.5}, {1, 0, 0}, 0, 10), C, T);
  // A non-unit direction: distances are |d| dt, the result is the same.
  expect_sample(v.integrate_exact({-1, 1.5, 1.5}, {2, 0, 0}, 0, 5), C, T);
  // Stopping halfway through the slab (at x = 2): one unit.
  const double Th = std::exp(-0.7);
  expect_sample(v.integrate_exact({-1, 1.5, 1.5}, {1, 0, 0}, 0, 3),
                {(1 - Th) * kRed[0], (1 - Th) * kRed[1], (1 - Th) * kRed[2]}, Th);
  // Fixed steps aligned with the cells are exact too.
  expect_sample(v.integrate_fixed_step({-1, 1.5, 1.5}, {1, 0, 0}, 0, 10, 0.25), C, T);
}

TEST(VolumeOracle, TwoSlabsInBothOrders) {
  // x in [1, 2): sigma 1.3, red; x in [2, 4): sigma 0.4, blue.
  DenseVolume v(4, 2, 2);
  fill_x(v, 1, 2, 1.3, kRed);
  fill_x(v, 2, 4, 0.4, kBlue);
  const double T1 = std::exp(-1.3), T2 = std::exp(-0.4 * 2);
  std::array<double, 3> front_red, front_blue;
  for (size_t k = 0; k < 3; ++k) {
    front_red[k] = (1 - T1) * kRed[k] + T1 * (1 - T2) * kBlue[k];
    front_blue[k] = (1 - T2) * kBlue[k] + T2 * (1 - T1) * kRed[k];
  }
  expect_sample(v.integrate_exact({-0.5, 1, 1.25}, {1, 0, 0}, 0, 100), front_red, T1 * T2);
  expect_sample(v.integrate_exact({4.5, 1, 1.25}, {-1, 0, 0}, 0, 100), front_blue, T1 * T2);
  // Colors differ with the order, transmittance does not.
  EXPECT_GT(std::fabs(front_red[0] - front_blue[0]), 0.05);
}

TEST(VolumeOracle, ObliqueChordThroughHomogeneousGrid) {
  DenseVolume v(5, 3, 4);
  fill_x(v, 0, 5, 0.35, kBlue);
  // From (-1, 0.5, 0.2) toward (6, 2.5, 3.7): the chord inside [0,5]x[0,3]x[0,4].
  const DVec3 o{-1, 0.5, 0.2}, d{7, 2, 3.5};
  double t0 = 0, t1 = 1e9;
  const double hi[3] = {5, 3, 4};
  for (int a = 0; a < 3; ++a) {
    double ta = (0 - o[a]) / d[a], tb = (hi[a] - o[a]) / d[a];
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta), t1 = std::min(t1, tb);
  }
  ASSERT_LT(t0, t1);
  const double chord = (t1 - t0) * std::sqrt(d.x * d.x + d.y * d.y + d.z * d.z);
  const double T = std::exp(-0.35 * chord);
  expect_sample(v.integrate_exact(o, d, 0, 2),
                {(1 - T) * kBlue[0], (1 - T) * kBlue[1], (1 - T) * kBlue[2]}, T, 1e-10);
}

DenseVolume random_volume(uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> U(0, 1);
  DenseVolume v(8, 8, 8);
  for (int z = 0; z < 8; ++z)
    for (int y = 0; y < 8; ++y)
      for (int x = 0; x < 8; ++x)
        if (U(rng) < 0.6) v.at(x, y, z) = {3 * U(rng), {U(rng), U(rng), U(rng)}};
  return v;
}

TEST(VolumeOracle, SplitSegmentsCompose) {
  // Front-to-back compositing is associative: [t0, tm] then [tm, t1] gives
  // C = C_a + T_a C_b and T = T_a T_b.
  const DenseVolume v = random_volume(3);
  std::mt19937_64 rng(4);
  std::uniform_real_distribution<double> U(0, 1);
  for (int i = 0; i < 200; ++i) {
    const DVec3 o{-2 + 12 * U(rng), -2 + 12 * U(rng), -2 + 12 * U(rng)};
    const DVec3 d{U(rng) - 0.5, U(rng) - 0.5, U(rng) - 0.5};
    const double tm = 5 + 10 * U(rng), t1 = 40;
    const VolumeSample all = v.integrate_exact(o, d, 0, t1);
    const VolumeSample a = v.integrate_exact(o, d, 0, tm), b = v.integrate_exact(o, d, tm, t1);
    std::array<double, 3> c;
    for (size_t k = 0; k < 3; ++k) c[k] = a.color[k] + a.transmittance * b.color[k];
    expect_sample(all, c, a.transmittance * b.transmittance, 1e-12);
  }
}

TEST(VolumeOracle, FixedStepConvergesToExact) {
  const DenseVolume v = random_volume(5);
  std::mt19937_64 rng(6);
  std::uniform_real_distribution<double> U(0, 1);
  double worst_coarse = 0, worst_fine = 0, opaque = 0;
  for (int i = 0; i < 100; ++i) {
    const DVec3 o{-1, 8 * U(rng), 8 * U(rng)};
    const DVec3 d{1, U(rng) - 0.5, U(rng) - 0.5};
    const VolumeSample exact = v.integrate_exact(o, d, 0, 12);
    opaque += exact.transmittance < 0.5;
    const auto err = [&](double dt) {
      const VolumeSample s = v.integrate_fixed_step(o, d, 0, 12, dt);
      double e = std::fabs(s.transmittance - exact.transmittance);
      for (size_t k = 0; k < 3; ++k) e = std::max(e, std::fabs(s.color[k] - exact.color[k]));
      return e;
    };
    worst_coarse = std::max(worst_coarse, err(0.05));
    worst_fine = std::max(worst_fine, err(0.0005));
  }
  std::printf("fixed step vs exact: worst %.3g at dt 0.05, %.3g at dt 0.0005\n", worst_coarse,
              worst_fine);
  EXPECT_GT(opaque, 10) << "the rays must cross dense media for the test to mean anything";
  EXPECT_GT(worst_coarse, 1e-4);  // coarse steps straddle boundaries visibly...
  EXPECT_LT(worst_fine, 5e-3);    // ...fine ones converge (error O(dt) per boundary)
  EXPECT_LT(worst_fine, worst_coarse / 20);
}

}  // namespace
}  // namespace voxcast::testing
