// Volume scenes (gigavoxels_scene.hpp): several objects with their own
// transforms, composited front to back.
//  * two disjoint GigaVoxels objects placed by transforms render, wherever
//    the other one is absent, what each renders alone placed by its own
//    origin and size (an independent placement: no Affine involved);
//  * overlapping transformed grids (scaled, rotated) against the dense
//    emission-absorption oracle of their summed medium, for constant spans
//    and for sampled spans (tests/support/dense_grid.hpp: a piece between
//    two cut points lies in one cell of every part, so both are exact);
//  * Affine inverse and composition against hand-computed maps;
//  * the CLI: a scene file renders; bad JSON, unknown keys, a missing source
//    exit 1 with one line; --transfer with a scene exits 2.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "support/cli_runner.hpp"
#include "support/dense_grid.hpp"
#include "support/volume_oracle.hpp"
#include "voxcast/error.hpp"
#include "voxcast/gigavoxels.hpp"
#include "voxcast/gigavoxels_scene.hpp"
#include "voxcast/volume_integrator.hpp"

namespace voxcast::giga {
namespace {

using testing::DenseVolume;

TEST(GigaScene, AffineInverseAndComposition) {
  const Affine m =
      Affine::translate({1, 2, 3}) * Affine::rotate({0, 0, 1}, 90.f) * Affine::scale({2, 2, 2});
  // (1, 0, 0) -> scaled (2, 0, 0) -> turned (0, 2, 0) -> moved (1, 4, 3).
  const Vec3 p = m.point({1, 0, 0});
  EXPECT_NEAR(p.x, 1.f, 1e-6f);
  EXPECT_NEAR(p.y, 4.f, 1e-6f);
  EXPECT_NEAR(p.z, 3.f, 1e-6f);
  EXPECT_NEAR(m.determinant(), 8.f, 1e-5f);
  const Vec3 q = m.inverse().point(p);
  EXPECT_NEAR(q.x, 1.f, 1e-6f);
  EXPECT_NEAR(q.y, 0.f, 1e-6f);
  EXPECT_NEAR(q.z, 0.f, 1e-6f);
  EXPECT_THROW(Affine::scale({1, 0, 1}).inverse(), Error);
  EXPECT_THROW(Affine::rotate({0, 0, 0}, 10.f), Error);
}

// Two grids overlapping in part, one scaled, one scaled and turned: the scene
// integrates the sum of their media (extinctions add, colors mix by
// extinction) as the oracle does cell by cell.
TEST(GigaScene, OverlappingObjectsMatchTheDenseOracle) {
  const DenseVolume a = testing::random_volume(5, 4, 0.7), b = testing::random_volume(9, 4, 0.7);
  // A: [0, 4]^3 scaled by 1/2 -> world [0, 2]^3, cells of 0.5 (k = 2).
  // B: [0, 4]^3 scaled by 1/4, turned 90 degrees about z, moved by
  // (1.5, 0.5, 0.5) -> world [0.5, 1.5]^3, cells of 0.25 (k = 4).
  const Affine ma = Affine::scale({0.5f, 0.5f, 0.5f});
  const Affine mb = Affine::translate({1.5f, 0.5f, 0.5f}) * Affine::rotate({0, 0, 1}, 90.f) *
                    Affine::scale({0.25f, 0.25f, 0.25f});
  // The oracle: 8^3 cells of 0.25 over [0, 2]^3, each the sum of what A and
  // B hold at its center (world extinction: local x k), in grid units.
  DenseVolume sum(8, 8, 8);
  for (int z = 0; z < 8; ++z)
    for (int y = 0; y < 8; ++y)
      for (int x = 0; x < 8; ++x) {
        const double c[3] = {(x + 0.5) * 0.25, (y + 0.5) * 0.25, (z + 0.5) * 0.25};
        double sigma = 0, col[3] = {0, 0, 0};
        auto add = [&](const testing::VolumeCell& v, double k) {
          sigma += v.sigma * k;
          for (int i = 0; i < 3; ++i) col[i] += v.sigma * k * v.color[i];
        };
        add(a.at(int(c[0] * 2), int(c[1] * 2), int(c[2] * 2)), 2.0);
        // B's local point: 4 R^-1 (c - T), R^-1 (x, y, z) = (y, -x, z).
        const double d[3] = {c[0] - 1.5, c[1] - 0.5, c[2] - 0.5};
        const double lb[3] = {4 * d[1], -4 * d[0], 4 * d[2]};
        if (lb[0] > 0 && lb[0] < 4 && lb[1] > 0 && lb[1] < 4 && lb[2] > 0 && lb[2] < 4)
          add(b.at(int(lb[0]), int(lb[1]), int(lb[2])), 4.0);
        testing::VolumeCell& o = sum.at(x, y, z);
        o.sigma = sigma * 0.25;  // per grid unit (a cell is 0.25 world units)
        for (int i = 0; i < 3; ++i) o.color[i] = sigma > 0 ? col[i] / sigma : 0;
      }
  for (bool sampled : {false, true}) {
    SCOPED_TRACE(sampled ? "sampled spans" : "constant spans");
    std::vector<SceneObject> objects(2);
    objects[0].structure = std::make_shared<testing::DenseGridQuery>(a, false, 1.f, sampled),
    objects[0].transform = ma;
    objects[1].structure = std::make_shared<testing::DenseGridQuery>(b, false, 1.f, sampled),
    objects[1].transform = mb;
    VolumeScene scene(std::move(objects));
    EXPECT_NEAR(scene.bounds().lo.x, 0.f, 1e-6f);
    EXPECT_NEAR(scene.bounds().hi.x, 2.f, 1e-6f);
    VolumeIntegratorOptions io;
    io.opacity_cutoff = 1.f;
    VolumeIntegrator integrator(io);
    std::mt19937_64 rng(17);
    std::uniform_real_distribution<float> U(0.f, 1.f);
    TraceContext ctx;
    int crossing_both = 0;
    for (int r = 0; r < 200; ++r) {
      // From a point around the box through a point inside it.
      const Vec3 target{0.3f + 1.4f * U(rng), 0.3f + 1.4f * U(rng), 0.3f + 1.4f * U(rng)};
      const Vec3 dir = normalize(Vec3{U(rng) - 0.5f, U(rng) - 0.5f, U(rng) - 0.5f});
      const Ray ray{target - dir * 4.f, dir, INFINITY};
      const VolumeRayResult got = integrator.integrate(scene, ray, {}, ctx);
      const testing::VolumeSample want =
          sum.integrate_exact({4.0 * ray.origin.x, 4.0 * ray.origin.y, 4.0 * ray.origin.z},
                              {4.0 * dir.x, 4.0 * dir.y, 4.0 * dir.z}, 0, 100);
      EXPECT_NEAR(got.transmittance, want.transmittance, 2e-4) << r;
      EXPECT_NEAR(got.color.r, want.color[0], 2e-4) << r;
      EXPECT_NEAR(got.color.g, want.color[1], 2e-4) << r;
      EXPECT_NEAR(got.color.b, want.color[2], 2e-4) << r;
      float t0 = 0, t1 = INFINITY;
      const Vec3 lo{0.5f, 0.5f, 0.5f};
      bool hits_b = true;
      for (int ax = 0; ax < 3 && hits_b; ++ax) {
        float ta = (lo[ax] - ray.origin[ax]) / dir[ax],
              tb = (lo[ax] + 1 - ray.origin[ax]) / dir[ax];
        if (ta > tb) std::swap(ta, tb);
        t0 = std::max(t0, ta), t1 = std::min(t1, tb);
        hits_b = t1 > t0;
      }
      crossing_both += hits_b;
    }
    EXPECT_GT(crossing_both, 50);  // the overlap is exercised
  }
}

// A local volume that records the footprint it is asked for and answers
// one brick span over its unit cube, of a fixed local voxel size: what the
// scene hands an object and what it makes of the object's answer.
class FootprintProbe final : public Structure, public VolumeQuery {
 public:
  static constexpr float kVoxel = 1.f / 64.f;
  mutable LodFootprint asked;
  std::string name() const override { return "footprint probe"; }
  Aabb bounds() const override { return {{0, 0, 0}, {1, 1, 1}}; }
  const VolumeQuery* volume() const override { return this; }
  int march(const Ray& ray, float t_begin, const LodFootprint& lod, TraceContext&,
            std::span<VolumeSpan> out) const override {
    asked = lod;
    float t0 = std::max(0.f, t_begin), t1 = ray.tmax;
    for (int a = 0; a < 3; ++a) {
      float ta = (0.f - ray.origin[a]) / ray.dir[a], tb = (1.f - ray.origin[a]) / ray.dir[a];
      if (ta > tb) std::swap(ta, tb);
      t0 = std::max(t0, ta), t1 = std::min(t1, tb);
    }
    if (!(t1 > t0) || out.empty()) return 0;
    VolumeSpan s;
    s.t0 = t0, s.t1 = t1, s.level = 3, s.voxel_size = kVoxel;
    out[0] = s;
    return 1;
  }
  VolumeSample sample(Vec3, float, TraceContext&, const VolumeSpan*) const override {
    return {0.5f, {1.f, 1.f, 1.f, 1.f}};
  }
};

// The largest world length across the unit direction d of a local unit
// under the linear map A: max over unit w across d of |A^T w|, by brute
// force over the half circle of w.
double across_stretch_brute(const double A[3][3], Vec3 d) {
  const Vec3 n = normalize(d);
  const Vec3 helper = std::abs(n.x) < 0.6f ? Vec3{1, 0, 0} : Vec3{0, 1, 0};
  const Vec3 u = normalize(cross(n, helper)), v = cross(n, u);
  double best = 0;
  constexpr int kSteps = 20000;
  for (int i = 0; i < kSteps; ++i) {
    const double a = M_PI * i / kSteps, c = std::cos(a), s = std::sin(a);
    const double w[3] = {c * u.x + s * v.x, c * u.y + s * v.y, c * u.z + s * v.z};
    double len2 = 0;
    for (int j = 0; j < 3; ++j) {
      const double x = A[0][j] * w[0] + A[1][j] * w[1] + A[2][j] * w[2];
      len2 += x * x;
    }
    best = std::max(best, std::sqrt(len2));
  }
  return best;
}

// Level of detail under non-uniform maps (gigavoxels_scene.hpp): the local
// footprint is the world one over sigma, the largest world length across
// the ray of a local unit (brute force over the directions across it), the
// span's size across the ray is the local voxel times sigma, and its
// stretch makes the integrator step half a local voxel along the ray.
TEST(GigaScene, FootprintAcrossTheRayUnderNonUniformMaps) {
  std::mt19937_64 rng(23);
  std::uniform_real_distribution<float> U(0.f, 1.f);
  int checked = 0;
  for (int m = 0; m < 12; ++m) {
    // Rotation * non-uniform scale * rotation, scales over 1/4 .. 4.
    const Vec3 scale{std::exp2(4.f * U(rng) - 2.f), std::exp2(4.f * U(rng) - 2.f),
                     std::exp2(4.f * U(rng) - 2.f)};
    const Affine map =
        Affine::translate({U(rng), U(rng), U(rng)}) *
        Affine::rotate({U(rng) - 0.5f, U(rng) - 0.5f, U(rng) - 0.5f}, 360.f * U(rng)) *
        Affine::scale(scale) *
        Affine::rotate({U(rng) - 0.5f, U(rng) - 0.5f, U(rng) - 0.5f}, 360.f * U(rng));
    double A[3][3];
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) A[i][j] = map.m[i][j];
    auto probe = std::make_shared<FootprintProbe>();
    std::vector<SceneObject> objects(1);
    objects[0].structure = probe, objects[0].transform = map;
    VolumeScene scene(std::move(objects));
    const Aabb box = scene.bounds();
    const Affine inverse = map.inverse();
    for (int r = 0; r < 20; ++r) {
      const Vec3 target =
          map.point({0.25f + 0.5f * U(rng), 0.25f + 0.5f * U(rng), 0.25f + 0.5f * U(rng)});
      const Vec3 dir = normalize(Vec3{U(rng) - 0.5f, U(rng) - 0.5f, U(rng) - 0.5f});
      const Ray ray{target - dir * (2.f * length(box.extent())), dir, INFINITY};
      const LodFootprint lod{0.002f, 0.001f};
      TraceContext ctx;
      VolumeSpan spans[4];
      ASSERT_EQ(scene.march(ray, 0.f, lod, ctx, spans), 1);
      const double sigma = across_stretch_brute(A, dir);
      const double k = length(inverse.vector(dir));
      EXPECT_NEAR(probe->asked.size_at_origin, lod.size_at_origin / sigma,
                  1e-4 * lod.size_at_origin / sigma);
      EXPECT_NEAR(probe->asked.size_per_t, lod.size_per_t / sigma, 1e-4 * lod.size_per_t / sigma);
      EXPECT_NEAR(spans[0].voxel_size, FootprintProbe::kVoxel * sigma,
                  1e-4 * FootprintProbe::kVoxel * sigma);
      EXPECT_NEAR(spans[0].stretch, 1.0 / (k * sigma), 1e-4 / (k * sigma));
      // The integrator's steps at the finest footprint: half a local voxel
      // along the ray, so the sample count is the local length over it.
      VolumeIntegratorOptions io;
      io.opacity_cutoff = 1.f;
      VolumeIntegrator integrator(io);
      VolumeIntegratorStats stats;
      integrator.integrate(scene, ray, {}, ctx, &stats);
      const double local_length = (spans[0].t1 - spans[0].t0) * k;
      EXPECT_NEAR(double(stats.samples), std::ceil(local_length / (0.5 * FootprintProbe::kVoxel)),
                  1.0);
      ++checked;
    }
  }
  EXPECT_EQ(checked, 240);

  // A cloud stretched 8x along z against its cross-section: seen from the
  // side (across z) its local voxels project 8x taller than from above, so
  // the same footprint reads 3 levels finer there (it used to be the other
  // way around: the scale along the ray picked the level).
  const Affine tall = Affine::scale({0.125f, 0.125f, 1.f});
  std::vector<SceneObject> one(1);
  one[0].structure = std::make_shared<FootprintProbe>(), one[0].transform = tall;
  VolumeScene scene(std::move(one));
  const auto& probe = static_cast<const FootprintProbe&>(*scene.objects()[0].structure);
  TraceContext ctx;
  VolumeSpan span[1];
  const LodFootprint foot{1.f / 32.f, 0.f};
  ASSERT_EQ(scene.march({{-1.f, 0.06f, 0.5f}, {1, 0, 0}, INFINITY}, 0.f, foot, ctx, span), 1);
  EXPECT_FLOAT_EQ(probe.asked.size_at_origin, 1.f / 32.f);  // across x: y 1/8, z 1
  EXPECT_FLOAT_EQ(span[0].voxel_size, FootprintProbe::kVoxel);
  ASSERT_EQ(scene.march({{0.06f, 0.06f, -1.f}, {0, 0, 1}, INFINITY}, 0.f, foot, ctx, span), 1);
  EXPECT_FLOAT_EQ(probe.asked.size_at_origin, 1.f / 4.f);  // across z: x and y 1/8
  EXPECT_FLOAT_EQ(span[0].voxel_size, FootprintProbe::kVoxel / 8.f);
  EXPECT_FLOAT_EQ(span[0].stretch, 8.f);  // a local voxel is 8x longer along z
}

FrameView view_of(const Aabb& box, int w, int h) {
  FrameView v;
  v.width = w, v.height = h;
  v.camera = Camera::orbit(box, w, h, 10.f, 15.f);
  return v;
}

Film render(Structure& s, const FrameView& view) {
  VolumeIntegrator integrator;
  FrameOptions fo;
  fo.max_passes = 1000;
  fo.tile_size = 8;
  Film film;
  render_frame(s, integrator, view, fo, &film);
  return film;
}

// Two clouds side by side, each on its own small pools (tagged requests,
// exact mode): where the other is absent, the scene's pixels are the ones
// each renders alone, placed by GigaOptions origin and size instead.
TEST(GigaScene, DisjointObjectsRenderAsEachAlone) {
  const auto cloud = make_procedural("cloud", 32);
  const Vec3 ta{-1.2f, 0.f, 0.f}, tb{0.3f, 0.1f, 0.f};
  const float sa = 1.f, sb = 0.8f;
  auto pools = [](Vec3 origin, float size) {
    GigaOptions o;
    o.tiles = 400, o.bricks = 300;
    o.origin = origin, o.size = size;
    o.check_after_pass = true;
    return o;
  };
  std::vector<SceneObject> objects(2);
  objects[0].structure = std::make_shared<GigaVoxels>(cloud, pools({0, 0, 0}, 1.f));
  objects[0].transform = Affine::translate(ta) * Affine::scale({sa, sa, sa});
  objects[1].structure = std::make_shared<GigaVoxels>(cloud, pools({0, 0, 0}, 1.f));
  objects[1].transform = Affine::translate(tb) * Affine::scale({sb, sb, sb});
  VolumeScene scene(std::move(objects));
  GigaVoxels alone_a(cloud, pools(ta, sa)), alone_b(cloud, pools(tb, sb));
  const FrameView view = view_of(scene.bounds(), 64, 40);
  const Film both = render(scene, view), fa = render(alone_a, view), fb = render(alone_b, view);
  int compared[2] = {0, 0};
  double worst = 0;
  for (int y = 0; y < view.height; ++y)
    for (int x = 0; x < view.width; ++x) {
      const float alpha_a = *fa.alpha.at(x, y), alpha_b = *fb.alpha.at(x, y);
      if (alpha_a > 0.f && alpha_b > 0.f) continue;  // both along this ray
      const Film& one = alpha_a > 0.f ? fa : fb;
      if (alpha_a > 0.01f || alpha_b > 0.01f) ++compared[alpha_a > 0.f ? 0 : 1];
      for (int c = 0; c < 3; ++c)
        worst = std::max(worst, double(std::abs(both.color.at(x, y)[c] - one.color.at(x, y)[c])));
      worst = std::max(worst, double(std::abs(*both.alpha.at(x, y) - *one.alpha.at(x, y))));
    }
  EXPECT_GT(compared[0], 100);
  EXPECT_GT(compared[1], 100);
  EXPECT_LT(worst, 2e-3);
}

using testing::run_cli_split;

TEST(GigaScene, CliRendersSceneFilesAndRejectsBadOnes) {
  testing::TempDir dir;
  const std::string scene = dir.file("scene.json");
  testing::write_text(scene, R"({"objects": [
    {"source": "procedural:cloud", "resolution": 32,
     "transform": {"translate": [-1.1, 0, 0], "rotate": [0, 1, 0, 30], "scale": 0.9}},
    {"source": "procedural:menger-recursive", "resolution": 32,
     "transform": [[0.8, 0, 0, 0.2], [0, 0.8, 0, 0], [0, 0, 0.8, 0], [0, 0, 0, 1]]}]})");
  const std::string out = dir.file("scene.png");
  const testing::CliResult ok =
      run_cli_split("volume render " + scene + " --size 40x24 --budget 8M -o " + out);
  ASSERT_EQ(ok.exit_code, 0) << ok.output << ok.errors;
  EXPECT_TRUE(std::filesystem::exists(out));
  EXPECT_NE(ok.output.find("scene of 2 objects (1 streamed"), std::string::npos) << ok.output;

  const testing::CliResult info = run_cli_split("volume info " + scene);
  ASSERT_EQ(info.exit_code, 0) << info.errors;
  EXPECT_NE(info.output.find("volume scene, 2 objects, 1 streamed"), std::string::npos)
      << info.output;
  EXPECT_NE(
      info.output.find(
          "object 1    procedural:menger-recursive: world box 0.28,0.08,0.08 .. 0.92,0.72,0.72"),
      std::string::npos)
      << info.output;

  struct Case {
    std::string json;
    std::string says;
  };
  const Case cases[] = {
      {R"({"objects": [ {"source": )", "not valid JSON"},
      {R"({"objects": []})", "at least one object"},
      {R"({"objects": [{"resolution": 32}]})", "has no 'source'"},
      {R"({"objects": [{"source": "missing.inr"}]})", "cannot open"},
      {R"({"objects": [{"source": "procedural:cloud", "colour": 1}]})", "unknown key 'colour'"},
      {R"({"objects": [{"source": "procedural:nothing"}]})", "object 0"},
      {R"({"objects": [{"source": "procedural:cloud", "transform": {"scale": 0}}]})", "singular"},
      {R"({"objects": [{"source": "procedural:cloud", "transfer": "1:2"}]})", "transfer"},
      {R"({"objects": [{"source": "procedural:cloud", "transfer": "0.5:1:nan,1,1"}]})",
       "colors must be finite"},
      {R"({"objects": [{"source": "procedural:cloud", "transform": {"scale": 1e38}}]})",
       "object 0: 'transform' entries must be within +-1e18"},
  };
  for (const Case& c : cases) {
    const std::string bad = dir.file("bad.json"), img = dir.file("bad.png");
    testing::write_text(bad, c.json);
    const testing::CliResult r = run_cli_split("volume render " + bad + " --size 8x8 -o " + img);
    EXPECT_EQ(r.exit_code, 1) << c.json << "\n" << r.errors;
    EXPECT_NE(r.errors.find(c.says), std::string::npos) << c.json << "\n" << r.errors;
    EXPECT_EQ(std::count(r.errors.begin(), r.errors.end(), '\n'), 1) << r.errors;
    EXPECT_FALSE(std::filesystem::exists(img)) << c.json;
  }
  const testing::CliResult usage =
      run_cli_split("volume render " + scene + " --transfer 0:1:1,1,1 -o " + out);
  EXPECT_EQ(usage.exit_code, 2) << usage.errors;
}

// The row of `output` that starts with `name` and then `budget`: its
// numbers after the pools column, as printed (first s, frames/s, CPU
// s/frame, Mrays/s, passes/f, requests/f, uploads/f, ratio).
std::vector<double> bench_row(const std::string& output, const std::string& name,
                              const std::string& budget) {
  std::istringstream lines(output);
  std::string line;
  while (std::getline(lines, line)) {
    if (line.rfind("  " + name + " ", 0) != 0) continue;
    std::istringstream words(line.substr(name.size() + 2));
    std::vector<std::string> w;
    for (std::string x; words >> x;) w.push_back(x);
    if (w.empty() || w[0] != budget || w.size() < 9) continue;
    std::vector<double> numbers;
    for (size_t i = w.size() - 8; i < w.size(); ++i) numbers.push_back(std::stod(w[i]));
    return numbers;
  }
  return {};
}

// `volume bench` on a scene file: a row per budget (each its own pools), the
// effects rows, no peer. Two overlapping clouds at 256K (128K of pools each)
// need more than their pools hold for this view, so every warm frame asks
// again; at 64M the view fits and warm frames ask nothing.
TEST(GigaScene, BenchTimesSceneFilesPerBudgetAndEffect) {
  testing::TempDir dir;
  const std::string scene = dir.file("two.json");
  testing::write_text(scene, R"({"objects": [
    {"source": "procedural:cloud", "resolution": 64},
    {"source": "procedural:cloud", "resolution": 64,
     "transform": {"translate": [0.25, 0.1, 0.05], "scale": 0.9}}]})");
  const testing::CliResult r = run_cli_split(
      "volume bench " + scene +
      " --size 48x32 --frames 1 --threads 1 --budget 256K,64M --effects -o " + dir.file("b.png"));
  ASSERT_EQ(r.exit_code, 0) << r.output << r.errors;
  EXPECT_NE(r.output.find("scene of 2 objects (2 streamed)"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("pools       256K: node pool "), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("pools       64M: node pool "), std::string::npos) << r.output;
  const std::vector<double> tight = bench_row(r.output, "gigavoxels", "256K"),
                            roomy = bench_row(r.output, "gigavoxels", "64M");
  ASSERT_EQ(tight.size(), 8u) << r.output;
  ASSERT_EQ(roomy.size(), 8u) << r.output;
  EXPECT_GT(tight[5], 0.0) << r.output;  // requests per warm frame
  EXPECT_EQ(roomy[5], 0.0) << r.output;
  EXPECT_EQ(roomy[4], 1.0) << r.output;  // one pass per warm frame
  for (const char* effect : {"pinhole, hard shadows", "pinhole, no shadows",
                             "pinhole, soft shadows", "dof, hard shadows", "dof, soft shadows"})
    EXPECT_EQ(bench_row(r.output, effect, "64M").size(), 8u) << effect << "\n" << r.output;
  EXPECT_NE(r.output.find("peer        none"), std::string::npos) << r.output;
  EXPECT_TRUE(std::filesystem::exists(dir.file("b.png")));

  // A node graph has no pools to bench; the peer's options need a grid.
  EXPECT_EQ(run_cli_split("volume bench procedural:menger-recursive --size 8x8").exit_code, 2);
  EXPECT_EQ(run_cli_split("volume bench " + scene + " --size 8x8 --reference-step 0.5").exit_code,
            2);
  EXPECT_EQ(run_cli_split("volume bench " + scene + " --size 8x8 --dof 0.1,1").exit_code, 2);
  EXPECT_EQ(run_cli_split("volume bench " + scene + " --size 8x8 --budget 1M,").exit_code, 2);
}

}  // namespace
}  // namespace voxcast::giga
