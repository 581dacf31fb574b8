// The volume integrator (volume_integrator.hpp) against the dense-grid
// emission-absorption oracle (tests/support/volume_oracle.hpp), through a
// minimal dense-grid VolumeQuery: constant spans (one per cell) must match the
// oracle's exact per-cell integration; one brick span marched with step dt
// must match the oracle's fixed-step integration with the same dt; early
// termination, the depth AOV, transfer functions, Blinn-Phong shading and the
// frame loop's film are checked against closed forms.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "support/dense_grid.hpp"
#include "support/volume_oracle.hpp"
#include "voxcast/error.hpp"
#include "voxcast/volume_integrator.hpp"

namespace voxcast {
namespace {

using DenseGrid = testing::DenseGridQuery;
using testing::DenseVolume;
using testing::DVec3;
using testing::random_volume;

struct TestRay {
  Ray ray;
  DVec3 o, d;
};

TestRay random_ray(std::mt19937_64& rng) {
  std::uniform_real_distribution<float> U(0, 1);
  const Vec3 o{-3.f, 8.f * U(rng), 8.f * U(rng)};
  const Vec3 target{11.f, 8.f * U(rng), 8.f * U(rng)};
  const Vec3 d = normalize(target - o);
  return {Ray{o, d, INFINITY}, {o.x, o.y, o.z}, {d.x, d.y, d.z}};
}

double max_error(const VolumeRayResult& r, const testing::VolumeSample& s) {
  double e = std::fabs(r.transmittance - s.transmittance);
  const float c[3] = {r.color.r, r.color.g, r.color.b};
  for (size_t k = 0; k < 3; ++k) e = std::max(e, std::fabs(c[k] - s.color[k]));
  return e;
}

VolumeIntegratorOptions no_cutoff() {
  VolumeIntegratorOptions o;
  o.opacity_cutoff = 1.f;
  return o;
}

TEST(VolumeIntegrator, ConstantSpansMatchExactOracle) {
  const DenseVolume v = random_volume(11);
  const DenseGrid grid(v, false);
  const VolumeIntegrator integrator(no_cutoff());
  std::mt19937_64 rng(12);
  TraceContext ctx;
  double worst = 0;
  int dense = 0;
  for (int i = 0; i < 300; ++i) {
    const TestRay r = random_ray(rng);
    const VolumeRayResult got = integrator.integrate(grid, r.ray, {}, ctx);
    const testing::VolumeSample want = v.integrate_exact(r.o, r.d, 0, 100);
    worst = std::max(worst, max_error(got, want));
    dense += want.transmittance < 0.3;
  }
  EXPECT_GT(dense, 30) << "the rays must cross dense media";
  EXPECT_LT(worst, 2e-5);  // float vs double on the same closed form
}

TEST(VolumeIntegrator, BrickSpansMatchFixedStepOracle) {
  const DenseVolume v = random_volume(21);
  std::mt19937_64 rng(22);
  TraceContext ctx;
  for (float voxel : {0.5f, 0.125f}) {
    const DenseGrid grid(v, true, voxel);
    VolumeIntegratorOptions o = no_cutoff();
    o.step_scale = 0.5f;
    const VolumeIntegrator integrator(o);
    const double dt = double(o.step_scale) * voxel;
    double worst_step = 0, worst_exact = 0;
    for (int i = 0; i < 100; ++i) {
      const TestRay r = random_ray(rng);
      // The chord's entry and exit, computed here in double: the oracle's
      // fixed steps start where the integrator's brick span starts.
      double t0 = 0, t1 = 1e30;
      for (int a = 0; a < 3; ++a) {
        if (r.d[a] == 0) continue;
        double ta = (0 - r.o[a]) / r.d[a], tb = (8 - r.o[a]) / r.d[a];
        if (ta > tb) std::swap(ta, tb);
        t0 = std::max(t0, ta), t1 = std::min(t1, tb);
      }
      if (!(t1 > t0)) continue;
      const VolumeRayResult got = integrator.integrate(grid, r.ray, {}, ctx);
      worst_step =
          std::max(worst_step, max_error(got, v.integrate_fixed_step(r.o, r.d, t0, t1, dt)));
      worst_exact = std::max(worst_exact, max_error(got, v.integrate_exact(r.o, r.d, 0, 100)));
    }
    // Same steps as the oracle: only float rounding (of t0 and the step
    // midpoints near cell faces) separates them.
    EXPECT_LT(worst_step, 2e-3) << "voxel " << voxel;
    // ...and marching converges to the exact integral as steps shrink.
    EXPECT_LT(worst_exact, voxel == 0.5f ? 0.2 : 0.05) << "voxel " << voxel;
  }
}

TEST(VolumeIntegrator, EarlyTerminationStopsNearOpaque) {
  const DenseVolume v = random_volume(31, 8, 1.0, 4.0);  // every cell dense
  const DenseGrid grid(v, false);
  VolumeIntegratorOptions o;
  o.opacity_cutoff = 0.99f;
  const VolumeIntegrator cut(o), full(no_cutoff());
  std::mt19937_64 rng(32);
  TraceContext ctx;
  VolumeIntegratorStats s_cut, s_full;
  for (int i = 0; i < 100; ++i) {
    const TestRay r = random_ray(rng);
    const VolumeRayResult a = cut.integrate(grid, r.ray, {}, ctx, &s_cut);
    const VolumeRayResult b = full.integrate(grid, r.ray, {}, ctx, &s_full);
    const testing::VolumeSample want = v.integrate_exact(r.o, r.d, 0, 100);
    EXPECT_LT(max_error(b, want), 2e-5);
    // What a stopped ray misses is at most its remaining transmittance.
    EXPECT_LE(max_error(a, want), std::max(1e-5, double(a.transmittance)) + 1e-5);
    if (a.transmittance <= 0.01f) {
      EXPECT_LE(b.transmittance, a.transmittance);
    }
  }
  EXPECT_GT(s_cut.early_terminations, 50u);
  // Without a cutoff a ray stops only where T underflows to exactly 0.
  EXPECT_LT(s_full.early_terminations, s_cut.early_terminations);
  EXPECT_LT(s_cut.spans, s_full.spans / 2);
}

TEST(VolumeIntegrator, DepthIsWhereOpacityReachesThreshold) {
  // A slab sigma 0.5 over x in [2, 6): opacity 0.5 is reached ln 2 / 0.5 in.
  DenseVolume v(8, 3, 3);
  for (int z = 0; z < 3; ++z)
    for (int y = 0; y < 3; ++y)
      for (int x = 2; x < 6; ++x) v.at(x, y, z) = {0.5, {1, 1, 1}};
  TraceContext ctx;
  const Ray ray{{-1.f, 1.5f, 1.5f}, {1.f, 0.f, 0.f}, INFINITY};
  for (bool brick : {false, true}) {
    const DenseGrid grid(v, brick, 0.25f);
    const VolumeIntegrator integrator;
    const VolumeRayResult r = integrator.integrate(grid, ray, {}, ctx);
    EXPECT_NEAR(r.depth, 3.0 + std::log(2.0) / 0.5, 1e-4) << "brick " << brick;
    EXPECT_NEAR(r.transmittance, std::exp(-0.5 * 4), 1e-5);
  }
  // A ray that never reaches the threshold has no depth.
  const DenseGrid grid(v, false);
  VolumeIntegratorOptions o;
  o.depth_opacity = 0.99f;
  EXPECT_TRUE(std::isinf(VolumeIntegrator(o).integrate(grid, ray, {}, ctx).depth));
}

TEST(VolumeIntegrator, TransferFunctionClassifiesScalars) {
  // Scalars s in [0, 1] stored as density; the transfer maps them to
  // sigma = 2 s and a color ramp; the oracle sees the classified cells.
  const TransferFunction tf = TransferFunction::parse("0:0:0,0,1;1:2:1,0.5,0");
  std::mt19937_64 rng(41);
  std::uniform_real_distribution<double> U(0, 1);
  DenseVolume scalars(8, 8, 8), classified(8, 8, 8);
  for (int z = 0; z < 8; ++z)
    for (int y = 0; y < 8; ++y)
      for (int x = 0; x < 8; ++x) {
        const double s = double(float(U(rng)));
        scalars.at(x, y, z) = {s, {1, 1, 1}};
        classified.at(x, y, z) = {2 * s, {s, 0.5 * s, 1 - s}};
      }
  VolumeIntegratorOptions o = no_cutoff();
  o.transfer = tf;
  const VolumeIntegrator integrator(o);
  const DenseGrid grid(scalars, false);
  TraceContext ctx;
  for (int i = 0; i < 100; ++i) {
    const TestRay r = random_ray(rng);
    EXPECT_LT(max_error(integrator.integrate(grid, r.ray, {}, ctx),
                        classified.integrate_exact(r.o, r.d, 0, 100)),
              2e-5);
  }
  EXPECT_NEAR(tf(0.25f).density, 0.5f, 1e-6);
  EXPECT_NEAR(tf(-1.f).density, 0.f, 1e-6);  // clamped to the end points
  EXPECT_NEAR(tf(7.f).color.g, 0.5f, 1e-6);
  for (const char* bad : {"", "0:1", "0:1:1,1", "x:1:1,1,1", "0:-1:1,1,1", "1:0:0,0,0;0:1:1,1,1",
                          "0:1:nan,1,1", "0:1:1,inf,1", "0:1:1,1,-0.5"})
    EXPECT_THROW(TransferFunction::parse(bad), Error) << bad;
}

TEST(VolumeIntegrator, BlinnPhongFromDensityGradient) {
  // Density grows with x: the gradient normal is -x everywhere inside. A ray
  // along +x from inside (so every sample's neighbours are in the grid):
  // light towards -x faces the normal (ambient + diffuse + specular, as the
  // half vector is -x too); light towards +x leaves only the ambient term.
  DenseVolume v(8, 8, 8);
  for (int z = 0; z < 8; ++z)
    for (int y = 0; y < 8; ++y)
      for (int x = 0; x < 8; ++x) v.at(x, y, z) = {0.05 * (x + 1), {0.8, 0.6, 0.4}};
  const DenseGrid grid(v, true, 1.f);
  const Ray ray{{1.5f, 4.5f, 4.5f}, {1.f, 0.f, 0.f}, 5.f};
  TraceContext ctx;
  VolumeIntegratorOptions o = no_cutoff();
  o.shading = true;
  o.light_dir = {-1, 0, 0};
  const VolumeRayResult lit = VolumeIntegrator(o).integrate(grid, ray, {}, ctx);
  o.light_dir = {1, 0, 0};
  const VolumeRayResult back = VolumeIntegrator(o).integrate(grid, ray, {}, ctx);
  o.shading = false;
  const VolumeRayResult flat = VolumeIntegrator(o).integrate(grid, ray, {}, ctx);
  ASSERT_GT(flat.color.r, 0.1f);
  EXPECT_NEAR(lit.color.r / flat.color.r, o.ambient + o.diffuse + o.specular, 1e-4);
  EXPECT_NEAR(back.color.r / flat.color.r, o.ambient, 1e-4);
  EXPECT_EQ(lit.transmittance, flat.transmittance);  // shading changes color only
}

TEST(VolumeIntegrator, ShadowsMatchClosedFormTransmittance) {
  // A 4^3 grid: an emitting layer (y = 0, sigma 0.5, white) under an empty
  // layer and two absorbing black layers (y = 2, 3, sigma 0.8). A ray along
  // x through the emitting layer sees it lit through the absorbers: the
  // light's transmittance from any of its points straight up is
  // exp(-0.8 x 2) (and what lies of the emitting layer above the light
  // cone's start), so every cell's color is ambient + (1 - ambient) T and
  // the composited color that times 1 - e^(-0.5 x 4).
  DenseVolume v(4, 4, 4);
  for (int z = 0; z < 4; ++z)
    for (int x = 0; x < 4; ++x) {
      v.at(x, 0, z) = {0.5, {1, 1, 1}};
      v.at(x, 2, z) = v.at(x, 3, z) = {0.8, {0, 0, 0}};
    }
  VolumeIntegratorOptions o = no_cutoff();
  o.shadows = true;
  o.light_dir = {0, 1, 0};
  const double emitted = 1 - std::exp(-2.0);
  const Ray ray{{-1.f, 0.5f, 0.5f}, {1.f, 0.f, 0.f}, INFINITY};
  TraceContext ctx;
  for (bool brick : {false, true}) {
    // Constant spans integrate the light exactly; brick steps of a quarter
    // cell fall on the cell faces along the light ray here. The light cone
    // starts one voxel above the sample (no self-shadowing at the sample):
    // a whole cell for constant spans (y = 1.5, above the emitting layer), a
    // quarter cell for the brick (y = 0.75: the emitting layer's last
    // quarter, sigma 0.5, shadows too).
    const DenseGrid grid(v, brick, 0.25f);
    const double depth = 1.6 + (brick ? 0.25 * 0.5 : 0.0);
    const double lit = o.ambient + (1 - o.ambient) * std::exp(-depth);
    const VolumeIntegrator integrator(o);
    VolumeIntegratorStats st;
    const VolumeRayResult r = integrator.integrate(grid, ray, {}, ctx, &st);
    EXPECT_NEAR(r.color.r, lit * emitted, 1e-4) << (brick ? "brick" : "constant");
    EXPECT_NEAR(r.transmittance, std::exp(-2.0), 1e-5);
    EXPECT_GT(st.shadow_rays, 0u);
    VolumeIntegratorOptions no = o;
    no.shadows = false;
    EXPECT_NEAR(VolumeIntegrator(no).integrate(grid, ray, {}, ctx).color.r, emitted, 1e-4);
  }
}

TEST(VolumeIntegrator, RenderFrameWritesColorAlphaDepth) {
  const DenseVolume v = random_volume(51);
  DenseGrid grid(v, false);
  VolumeIntegratorOptions o;
  o.background = {0.1f, 0.2f, 0.3f, 1.f};
  VolumeIntegrator integrator(o);
  FrameView view;
  view.width = 24, view.height = 16;
  view.camera = Camera::frame(grid.bounds(), view.width, view.height);
  Film film;
  const FrameStats fs = render_frame(grid, integrator, view, FrameOptions{}, &film);
  EXPECT_EQ(fs.passes.size(), 1u);
  ASSERT_TRUE(film.has(kAovColor | kAovAlpha | kAovDepth));
  const CameraRays cam = view.rays();
  TraceContext ctx;
  int covered = 0;
  for (int y = 0; y < view.height; ++y)
    for (int x = 0; x < view.width; ++x) {
      const VolumeRayResult r = integrator.integrate(grid, cam.ray(x, y), view.lod(), ctx);
      EXPECT_EQ(film.color.at(x, y)[2], r.color.b);
      EXPECT_EQ(*film.alpha.at(x, y), r.color.a);
      EXPECT_EQ(*film.depth.at(x, y), r.depth);
      covered += r.color.a > 0.5f;
    }
  EXPECT_GT(covered, view.width * view.height / 5);
  EXPECT_EQ(integrator.stats().rays, uint64_t(view.width * view.height));
  // A miss shows the background.
  Ray away{{-5.f, -5.f, -5.f}, normalize(Vec3{-1.f, -1.f, -1.f}), INFINITY};
  const VolumeRayResult miss = integrator.integrate(grid, away, {}, ctx);
  EXPECT_EQ(miss.color.g, 0.2f);
  EXPECT_EQ(miss.color.a, 0.f);
}

TEST(VolumeIntegrator, RejectsStructureWithoutVolumeQuery) {
  class Empty final : public Structure {
   public:
    std::string name() const override { return "empty"; }
    Aabb bounds() const override { return {{0, 0, 0}, {1, 1, 1}}; }
  } empty;
  VolumeIntegrator integrator;
  FrameView view;
  view.width = view.height = 4;
  view.camera.eye = {0.5f, 0.5f, 3.f}, view.camera.target = {0.5f, 0.5f, 0.f};
  Film film;
  EXPECT_THROW(render_frame(empty, integrator, view, FrameOptions{}, &film), Error);
  VolumeIntegratorOptions bad;
  bad.step_scale = 0.f;
  EXPECT_THROW(VolumeIntegrator{bad}, Error);
}

}  // namespace
}  // namespace voxcast
