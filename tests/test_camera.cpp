// Camera parsing/printing, the primary-ray contract (camera.hpp), automatic
// framing, --orbit/--look-at cameras and the orthographic camera through the
// renderer's paths (caster, LOD, beam, depth, effects, post-filter).
#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <filesystem>
#include <memory>
#include <numbers>
#include <utility>
#include <vector>

#include "support/dda_oracle.hpp"
#include "support/render_testing.hpp"
#include "support/shared_meshes.hpp"
#include "voxcast/camera.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/render.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast {
namespace {

const std::filesystem::path kMeshes = std::filesystem::path(VOXCAST_TEST_DATA_DIR) / "meshes";

// The aspect ratios the framing must handle: 1:1, 4:3, 16:9, 9:16.
const std::pair<int, int> kAspects[] = {{96, 96}, {128, 96}, {160, 90}, {90, 160}};

TEST(Camera, ParseAndRoundTrip) {
  const Camera c = Camera::parse("1.5,2,-3, 0.1,0.2,0.3, 0,1,0, 50");
  EXPECT_EQ(c.eye.x, 1.5f);
  EXPECT_EQ(c.eye.z, -3.f);
  EXPECT_EQ(c.target.y, 0.2f);
  EXPECT_EQ(c.up.y, 1.f);
  EXPECT_EQ(c.fovy_degrees, 50.f);
  EXPECT_EQ(c.projection, Projection::Perspective);
  Camera odd;
  odd.eye = {0.1f, 1.f / 3.f, -1e-7f};
  odd.target = {123456.789f, -2.f / 7.f, 3.14159265f};
  odd.up = {0.3f, 0.9f, 0.1f};
  odd.fovy_degrees = 33.3333f;
  const Camera back = Camera::parse(odd.to_string());
  EXPECT_EQ(back.eye.y, odd.eye.y);
  EXPECT_EQ(back.eye.z, odd.eye.z);
  EXPECT_EQ(back.target.x, odd.target.x);
  EXPECT_EQ(back.target.y, odd.target.y);
  EXPECT_EQ(back.target.z, odd.target.z);
  EXPECT_EQ(back.up.x, odd.up.x);
  EXPECT_EQ(back.fovy_degrees, odd.fovy_degrees);
  EXPECT_EQ(back.to_string(), odd.to_string());
  // Orthographic: "ortho," and the width in place of fovy.
  const Camera o = Camera::parse("ortho,0,0,5,0,0,0,0,1,0,2.5");
  EXPECT_EQ(o.projection, Projection::Orthographic);
  EXPECT_EQ(o.ortho_width, 2.5f);
  EXPECT_EQ(o.eye.z, 5.f);
  odd.projection = Projection::Orthographic;
  odd.ortho_width = 1.f / 7.f;
  const std::string text = odd.to_string();
  EXPECT_EQ(text.rfind("ortho,", 0), 0u) << text;
  const Camera ob = Camera::parse(text);
  EXPECT_EQ(ob.projection, Projection::Orthographic);
  EXPECT_EQ(ob.ortho_width, odd.ortho_width);
  EXPECT_EQ(ob.to_string(), text);
}

TEST(Camera, RejectsBadStrings) {
  const char* bad[] = {
      "",                                 // nothing
      "1,2,3,4,5,6,7,8,9",                // 9 numbers
      "1,2,3,4,5,6,0,1,0,45,1",           // 11 numbers
      "1,2,3,4,5,6,0,1,0,abc",            // not a number
      "1,2,3,4,5,6,0,1,0,45x",            // trailing junk
      "1,2,3,,5,6,0,1,0,45",              // empty field
      "nan,2,3,4,5,6,0,1,0,45",           // NaN
      "inf,2,3,4,5,6,0,1,0,45",           // infinity
      "1e39,2,3,4,5,6,0,1,0,45",          // overflows float
      "1,2,3,4,5,6,0,1,0,0",              // fovy 0
      "1,2,3,4,5,6,0,1,0,180",            // fovy 180
      "1,2,3,4,5,6,0,1,0,-10",            // negative fovy
      "1,2,3,1,2,3,0,1,0,45",             // eye == target
      "0,0,0,0,5,0,0,1,0,45",             // up parallel to forward
      "0,0,0,1,0,0,0,0,0,45",             // zero up
      "ortho,1,2,3,4,5,6,0,1,0,0",        // ortho width 0
      "ortho,1,2,3,4,5,6,0,1,0,-1",       // negative width
      "ortho,1,2,3,4,5,6,0,1,0",          // 9 numbers
      "ortho",                            // no numbers
      "ortho,0,0,0,0,5,0,0,1,0,1",        // up parallel to forward
      "orthographic,0,0,5,0,0,0,0,1,0,1"  // not the keyword
  };
  for (const char* s : bad) EXPECT_THROW(Camera::parse(s), Error) << "'" << s << "'";
}

void expect_dir(Vec3 a, Vec3 b, float tol = 1e-6f) {
  EXPECT_NEAR(a.x, b.x, tol);
  EXPECT_NEAR(a.y, b.y, tol);
  EXPECT_NEAR(a.z, b.z, tol);
}

TEST(Camera, RaysFollowTheContract) {
  // Looking down -z from +z with y up: right = +x, true_up = +y.
  Camera c = Camera::parse("0,0,5,0,0,0,0,1,0,90");
  const int W = 7, H = 5;  // odd: the middle pixel's center is the image center
  const CameraRays rays(c, W, H);
  expect_dir(rays.direction(3, 2), {0, 0, -1});
  EXPECT_FLOAT_EQ(length(rays.direction(0, 0)), 1.f);
  // tan(45 deg) = 1: pixel (x, y) offsets are (2(x+.5)/W - 1) * W/H and 1 - 2(y+.5)/H.
  for (int y : {0, 2, 4})
    for (int x : {0, 3, 6}) {
      const float sx = (2.f * (x + 0.5f) / W - 1.f) * float(W) / H;
      const float sy = 1.f - 2.f * (y + 0.5f) / H;
      expect_dir(rays.direction(x, y), normalize(Vec3{sx, sy, -1}));
    }
  // Top-left is up-left: y = 0 is the top row.
  EXPECT_LT(rays.direction(0, 0).x, 0.f);
  EXPECT_GT(rays.direction(0, 0).y, 0.f);
  const Ray r = rays.ray(6, 4);
  EXPECT_EQ(r.origin.z, 5.f);
  EXPECT_GT(r.dir.x, 0.f);
  EXPECT_LT(r.dir.y, 0.f);
  // pixel_angle: one pixel of footprint per unit distance at the center.
  EXPECT_NEAR(rays.pixel_angle(), 2.f / H, 1e-7f);
  EXPECT_EQ(rays.pixel_size(), 0.f);

  // A general basis: the center ray is forward, and up/right are orthogonal.
  c = Camera::parse("1,2,3,-4,0.5,2,0.2,1,0.1,30");
  const CameraRays g(c, 9, 3);
  expect_dir(g.direction(4, 1), normalize(c.target - c.eye));
  EXPECT_NEAR(dot(g.right, g.forward), 0.f, 1e-6f);
  EXPECT_NEAR(dot(g.true_up, g.forward), 0.f, 1e-6f);
  EXPECT_NEAR(length(g.true_up), 1.f, 1e-6f);
  EXPECT_GT(dot(g.true_up, c.up), 0.f);

  // Orthographic, 4 wide: every ray runs along forward (-z) from the eye
  // plane, pixel (x, y) from eye + sx * 2 right + sy * 2 (H/W) up.
  const Camera o = Camera::parse("ortho,1,2,5,1,2,0,0,1,0,4");
  const CameraRays orays(o, W, H);
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const Ray ray = orays.ray(x, y);
      EXPECT_EQ(ray.dir.x, 0.f);
      EXPECT_EQ(ray.dir.y, 0.f);
      EXPECT_EQ(ray.dir.z, -1.f);
      const float sx = 2.f * (x + 0.5f) / W - 1.f, sy = 1.f - 2.f * (y + 0.5f) / H;
      expect_dir(ray.origin, Vec3{1.f + 2.f * sx, 2.f + 2.f * sy * H / W, 5.f}, 1e-6f);
    }
  // Square pixels of 4/W, whatever the distance.
  EXPECT_NEAR(orays.pixel_size(), 4.f / W, 1e-7f);
  EXPECT_EQ(orays.pixel_angle(), 0.f);
  EXPECT_NEAR(orays.ray(1, 0).origin.x - orays.ray(0, 0).origin.x, 4.f / W, 1e-6f);
  EXPECT_NEAR(orays.ray(0, 0).origin.y - orays.ray(0, 1).origin.y, 4.f / W, 1e-6f);
}

// The camera contract's basis evaluated independently, in double.
struct DoubleBasis {
  double e[3], f[3], r[3], u[3];
  explicit DoubleBasis(const Camera& c) {
    const double up[3] = {c.up.x, c.up.y, c.up.z};
    for (int k = 0; k < 3; ++k) e[k] = c.eye[k], f[k] = double(c.target[k]) - e[k];
    auto norm = [](double* v) {
      const double l = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
      for (int k = 0; k < 3; ++k) v[k] /= l;
    };
    auto crossd = [](const double* a, const double* b, double* out) {
      out[0] = a[1] * b[2] - a[2] * b[1];
      out[1] = a[2] * b[0] - a[0] * b[2];
      out[2] = a[0] * b[1] - a[1] * b[0];
    };
    norm(f);
    crossd(f, up, r);
    norm(r);
    crossd(r, f, u);
  }
};

// A point's screen coordinates (|s| <= 1 inside the image) and its depth
// along forward, by the contract.
struct Projected {
  double sx, sy, z;
};
Projected project(const Camera& c, int W, int H, Vec3 p) {
  const DoubleBasis B(c);
  const double v[3] = {p.x - B.e[0], p.y - B.e[1], p.z - B.e[2]};
  const double a = v[0] * B.r[0] + v[1] * B.r[1] + v[2] * B.r[2];
  const double b = v[0] * B.u[0] + v[1] * B.u[1] + v[2] * B.u[2];
  const double z = v[0] * B.f[0] + v[1] * B.f[1] + v[2] * B.f[2];
  if (c.projection == Projection::Orthographic) {
    const double half_w = 0.5 * c.ortho_width, half_h = half_w * H / W;
    return {a / half_w, b / half_h, z};
  }
  const double t = std::tan(0.5 * double(c.fovy_degrees) * std::numbers::pi / 180.0);
  return {a / (z * t * W / H), b / (z * t), z};
}

std::vector<Vec3> box_corners(const Aabb& b) {
  std::vector<Vec3> v;
  for (int i = 0; i < 8; ++i)
    v.push_back({(i & 1) ? b.hi.x : b.lo.x, (i & 2) ? b.hi.y : b.lo.y, (i & 4) ? b.hi.z : b.lo.z});
  return v;
}

// Largest |sx|, |sy| over `points`; fails if one is behind the eye or outside
// the framing margin.
double max_screen_extent(const Camera& c, int W, int H, const std::vector<Vec3>& points) {
  double m = 0;
  for (const Vec3& p : points) {
    const Projected q = project(c, W, H, p);
    EXPECT_GT(q.z, 0.0) << "behind the eye: " << c.to_string();
    EXPECT_LE(std::fabs(q.sx), Camera::kFrameFill + 1e-4) << c.to_string() << " " << W << "x" << H;
    EXPECT_LE(std::fabs(q.sy), Camera::kFrameFill + 1e-4) << c.to_string() << " " << W << "x" << H;
    m = std::max({m, std::fabs(q.sx), std::fabs(q.sy)});
  }
  return m;
}

TEST(Camera, FrameKeepsEveryBoxCornerInViewAndFillsTheImage) {
  Aabb box;
  box.extend({-1.f, 2.f, 10.f});
  box.extend({3.f, 3.f, 12.f});
  Aabb tall;  // a flat, tall box seen from the side
  tall.extend({0.f, 0.f, 0.f});
  tall.extend({0.1f, 5.f, 1.f});
  for (const Aabb& b : {box, tall})
    for (auto [W, H] : kAspects)
      for (Projection p : {Projection::Perspective, Projection::Orthographic}) {
        const Camera c = Camera::frame(b, W, H, p);
        EXPECT_EQ(c.projection, p);
        expect_dir(c.target, b.center(), 1e-5f);
        // Eye front-right-above, the documented direction.
        expect_dir(normalize(c.eye - c.target), Camera::auto_view_direction(), 1e-5f);
        // The box center is the image center.
        const Projected center = project(c, W, H, b.center());
        EXPECT_NEAR(center.sx, 0.0, 1e-5);
        EXPECT_NEAR(center.sy, 0.0, 1e-5);
        // Every corner inside with the margin, and the tightest one on it:
        // the framing is exact, not merely safe.
        EXPECT_GT(max_screen_extent(c, W, H, box_corners(b)), Camera::kFrameFill - 1e-3);
      }
  EXPECT_THROW(Camera::frame(Aabb{}, 10, 10), Error);
  EXPECT_THROW(Camera::frame(box, 0, 10), Error);
  // A single point can be framed (any distance and width).
  Aabb point;
  point.extend({1, 1, 1});
  for (Projection p : {Projection::Perspective, Projection::Orthographic}) {
    const Camera pc = Camera::frame(point, 10, 10, p);
    EXPECT_GT(length(pc.eye - pc.target), 0.f);
    EXPECT_NO_THROW(CameraRays(pc, 10, 10));
  }
}

TEST(Camera, OrbitAndLookAtAreTheDocumentedCameras) {
  Aabb b;
  b.extend({1.f, 2.f, 3.f});
  b.extend({3.f, 3.f, 4.f});
  const Vec3 c = b.center();
  // az 0, el 0 at distance 5: from +z, up +y.
  Camera o = Camera::parse_orbit("0,0,5", b, 64, 48);
  expect_dir(o.eye, c + Vec3{0, 0, 5}, 1e-5f);
  expect_dir(o.target, c);
  expect_dir(normalize(o.up), {0, 1, 0});
  EXPECT_EQ(o.fovy_degrees, Camera::kDefaultFovy);
  // az 90: from +x; el 30: raised by sin 30.
  o = Camera::parse_orbit("90,30,2", b, 64, 48);
  expect_dir(o.eye, c + Vec3{2.f * std::cos(0.5235988f), 2.f * 0.5f, 0.f}, 1e-5f);
  {
    const CameraRays rays(o, 64, 48);  // true up = +y tilted back towards the model
    EXPECT_GT(rays.true_up.y, 0.8f);
    EXPECT_NEAR(dot(rays.right, Vec3{0, 1, 0}), 0.f, 1e-6f);  // horizon level
    expect_dir(rays.right, {0, 0, -1}, 1e-5f);                // from +x, right is -z
  }
  // Straight down (el 90) is defined: up is the direction of increasing elevation.
  o = Camera::parse_orbit("0,90,3", b, 64, 48);
  expect_dir(o.eye, c + Vec3{0, 3, 0}, 1e-5f);
  expect_dir(normalize(o.up), {0, 0, -1}, 1e-6f);
  EXPECT_NO_THROW(CameraRays(o, 64, 48));
  // Without DIST: the framing distance along that direction (every corner in view).
  for (auto [W, H] : kAspects) {
    o = Camera::parse_orbit("200,-25", b, W, H);
    expect_dir(normalize(o.eye - c),
               normalize(Vec3{std::sin(3.4906585f) * std::cos(0.4363323f), -std::sin(0.4363323f),
                              std::cos(3.4906585f) * std::cos(0.4363323f)}),
               1e-5f);
    EXPECT_GT(max_screen_extent(o, W, H, box_corners(b)), Camera::kFrameFill - 1e-3);
    const Camera oo = Camera::parse_orbit("200,-25", b, W, H, Projection::Orthographic);
    expect_dir(oo.eye, o.eye, 1e-5f);  // same eye, framing width
    EXPECT_GT(max_screen_extent(oo, W, H, box_corners(b)), Camera::kFrameFill - 1e-3);
  }
  for (const char* bad : {"", "1", "1,2,3,4", "0,91", "0,-95", "0,0,0", "0,0,-1", "a,b", "nan,0"})
    EXPECT_THROW(Camera::parse_orbit(bad, b, 64, 48), Error) << bad;

  // Look-at: eye and target; up and fovy default to +y and 40 degrees.
  Camera l = Camera::parse_look_at("1,2,3,4,5,7");
  expect_dir(l.eye, {1, 2, 3});
  expect_dir(l.target, {4, 5, 7});
  expect_dir(l.up, {0, 1, 0});
  EXPECT_EQ(l.fovy_degrees, 40.f);
  EXPECT_EQ(l.projection, Projection::Perspective);
  l = Camera::parse_look_at("1,2,3,4,5,7,1,0,0");
  expect_dir(l.up, {1, 0, 0});
  l = Camera::parse_look_at("1,2,3,4,5,7,1,0,0,25");
  EXPECT_EQ(l.fovy_degrees, 25.f);
  EXPECT_EQ(l.to_string(), Camera::parse("1,2,3,4,5,7,1,0,0,25").to_string());
  for (const char* bad : {"1,2,3", "1,2,3,4,5,6,7", "1,2,3,4,5,6,0,1,0,45,1", "0,0,0,0,5,0",
                          "1,2,3,1,2,3", "1,2,3,4,5,6,0,1,0,0"})
    EXPECT_THROW(Camera::parse_look_at(bad), Error) << bad;

  // Making a camera orthographic keeps eye, target and up; the default width frames the box.
  const Camera lo = Camera::parse_look_at("8,6,9,2,2.5,3.5").orthographic(b, 80, 60);
  EXPECT_EQ(lo.projection, Projection::Orthographic);
  expect_dir(lo.eye, {8, 6, 9});
  expect_dir(lo.target, {2, 2.5f, 3.5f});
  EXPECT_GT(max_screen_extent(lo, 80, 60, box_corners(b)), Camera::kFrameFill - 1e-3);
  EXPECT_EQ(Camera::parse_look_at("8,6,9,2,2.5,3.5").orthographic(b, 80, 60, 7.f).ortho_width, 7.f);
}

// ---- Automatic framing of real models ----

class CameraFraming : public ::testing::TestWithParam<const char*> {};

// Every corner of every occupied voxel is inside the image with the margin,
// for the occupied bounds the scene loader gives the CLI (esvo::occupied_bounds),
// at every aspect ratio and both projections; and the rendered image's
// border pixels are all background (the caster agrees nothing is cropped).
TEST_P(CameraFraming, EveryOccupiedVoxelCornerInView) {
  const Mesh mesh = load_mesh(kMeshes / GetParam());
  VoxelizeOptions vo;
  const VoxelSet voxels = voxelize(mesh, GridTransform::fit(mesh.bounds(), 64), vo);
  ASSERT_GT(voxels.size(), 100u);
  auto octree = std::make_shared<esvo::EsvoOctree>(esvo::build_octree(voxels));
  const esvo::EsvoStructure structure(octree);
  const Aabb occupied = esvo::occupied_bounds(*octree);
  // Voxel corners, deduplicated through the grid (corner (i,j,k) of the
  // (N+1)^3 lattice), in world coordinates.
  const GridTransform& g = voxels.grid;
  const uint32_t n1 = g.resolution + 1;
  std::vector<bool> seen(size_t(n1) * n1 * n1, false);
  std::vector<Vec3> corners;
  for (uint64_t code : voxels.codes) {
    const MortonCoord m = morton_decode(code);
    for (int c = 0; c < 8; ++c) {
      const uint32_t i = m.x + (c & 1), j = m.y + ((c >> 1) & 1), k = m.z + ((c >> 2) & 1);
      const size_t idx = (size_t(k) * n1 + j) * n1 + i;
      if (seen[idx]) continue;
      seen[idx] = true;
      corners.push_back({float(g.origin.x + double(i) * g.voxel_size),
                         float(g.origin.y + double(j) * g.voxel_size),
                         float(g.origin.z + double(k) * g.voxel_size)});
    }
  }
  for (auto [W, H] : kAspects)
    for (Projection p : {Projection::Perspective, Projection::Orthographic}) {
      SCOPED_TRACE(std::to_string(W) + "x" + std::to_string(H) +
                   (p == Projection::Orthographic ? " ortho" : " perspective"));
      const Camera c = Camera::frame(occupied, W, H, p);
      // The model reaches near the margin on at least one axis (not lost in
      // the middle of the frame): real models reach well past half of it.
      EXPECT_GT(max_screen_extent(c, W, H, corners), 0.5);
      const RenderResult r = render(structure, testing::depth_render_options(c, W, H));
      EXPECT_GT(r.hits, r.rays / 50);  // thin models (elephant at 16:9) cover ~7 %
      size_t border_hits = 0;
      for (int x = 0; x < W; ++x)
        border_hits += std::isfinite(*r.depth.at(x, 0)) + std::isfinite(*r.depth.at(x, H - 1));
      for (int y = 0; y < H; ++y)
        border_hits += std::isfinite(*r.depth.at(0, y)) + std::isfinite(*r.depth.at(W - 1, y));
      EXPECT_EQ(border_hits, 0u);
    }
}

INSTANTIATE_TEST_SUITE_P(SharedMeshes, CameraFraming, voxcast::testing::all_shared_meshes(),
                         voxcast::testing::mesh_test_name);

// ---- Orthographic rays through the renderer ----

VoxelSet bunny_voxels(uint32_t resolution) {
  const Mesh mesh = load_mesh(kMeshes / "stanford-bunny.obj");
  return voxelize(mesh, GridTransform::fit(mesh.bounds(), resolution), VoxelizeOptions{});
}

// The bunny's voxels as an ESVO octree and as a DAG, with the occupied
// bounds the scene loader would give the CLI.
struct BunnyScene {
  VoxelSet voxels;
  std::shared_ptr<esvo::EsvoOctree> octree;
  esvo::EsvoStructure esvo_structure;
  dag::DagStructure dag_structure;
  Aabb occupied;
  explicit BunnyScene(uint32_t resolution)
      : voxels(bunny_voxels(resolution)),
        octree(std::make_shared<esvo::EsvoOctree>(esvo::build_octree(voxels))),
        esvo_structure(octree),
        dag_structure(std::make_shared<dag::SparseVoxelDag>(dag::build_dag(voxels))),
        occupied(esvo::occupied_bounds(*octree)) {}
  std::vector<const Structure*> structures() const { return {&esvo_structure, &dag_structure}; }
};

std::vector<Camera> ortho_cameras(const Aabb& b, int W, int H) {
  std::vector<Camera> cams;
  cams.push_back(Camera::frame(b, W, H, Projection::Orthographic));
  cams.push_back(Camera::orbit(b, W, H, 0.f, 90.f, 0.f, Projection::Orthographic));  // axis-aligned
  Camera narrow = Camera::orbit(b, W, H, 200.f, -30.f, 0.f, Projection::Orthographic);
  narrow.ortho_width *= 0.3f;  // zoomed into the middle
  cams.push_back(narrow);
  // Eye inside the model's box: ray origins in occupied space.
  Camera inside;
  inside.projection = Projection::Orthographic;
  inside.eye = b.center() + Vec3{0.1f, 0.05f, 0.f} * length(b.extent());
  inside.target = inside.eye + Vec3{-1.f, -0.2f, 0.3f};
  inside.ortho_width = 0.8f * length(b.extent());
  cams.push_back(inside);
  return cams;
}

// Parallel rays against the brute-force DDA over the dense grid (double,
// ray origins from the contract evaluated here): the same first voxel and
// depth, at the finest level and at a constant LOD footprint of 2.5 voxels,
// which must stop at the 2-voxel cubes (the grid coarsened once) everywhere.
TEST(CameraOrtho, RendersAgreeWithTheDdaOracle) {
  const BunnyScene scene(64);
  const VoxelSet& voxels = scene.voxels;
  const GridTransform& g = voxels.grid;
  const int W = 96, H = 72;
  size_t rays = 0, hits = 0, ties = 0;
  for (const Structure* s : scene.structures())
    for (const Camera& cam : ortho_cameras(scene.occupied, W, H))
      for (int lod_level : {0, 1}) {
        SCOPED_TRACE(s->name() + " " + cam.to_string() + " lod level " + std::to_string(lod_level));
        const testing::DenseGrid grid =
            testing::DenseGrid::from_voxels(voxels, g.levels - lod_level);
        const double cell = g.voxel_size * double(1 << lod_level);
        const double pixel = double(cam.ortho_width) / W;
        const float lod_pixels = lod_level == 0 ? 0.f : float(2.5 * g.voxel_size / pixel);
        const RenderResult r = render(*s, testing::depth_render_options(cam, W, H, lod_pixels));
        const DoubleBasis B(cam);  // the contract, in double
        const double half_w = 0.5 * cam.ortho_width, half_h = half_w * H / W;
        auto cast = [&](double sx, double sy) {
          testing::DVec3 org, dir;
          double oa[3], da[3];
          for (int k = 0; k < 3; ++k) {
            const double world = B.e[k] + sx * half_w * B.r[k] + sy * half_h * B.u[k];
            oa[k] = (world - double(g.origin[k])) / cell;
            da[k] = B.f[k] / cell;
          }
          org = {oa[0], oa[1], oa[2]};
          dir = {da[0], da[1], da[2]};
          return grid.cast(org, dir, INFINITY);  // t in world units: |d| = 1 / cell
        };
        const double tol = 2e-3 * g.voxel_size;
        for (int y = 0; y < H; ++y)
          for (int x = 0; x < W; ++x) {
            const double sx = 2.0 * (x + 0.5) / W - 1.0, sy = 1.0 - 2.0 * (y + 0.5) / H;
            const float depth = *r.depth.at(x, y);
            auto agrees = [&](const testing::DdaHit& h) {
              if (h.hit != std::isfinite(depth)) return false;
              return !h.hit || std::fabs(h.t_enter - double(depth)) <= tol + 1e-6 * h.t_enter;
            };
            ++rays;
            hits += std::isfinite(depth);
            if (agrees(cast(sx, sy))) continue;
            // Float ray origins differ from the exact ones by ~1e-7 of the
            // coordinates: a ray through a voxel edge may go either way.
            // Accept only if a ray 1e-4 voxel to the side agrees.
            const double e = 1e-4 * g.voxel_size;
            bool tie = false;
            for (auto [dx, dy] : {std::pair{e, 0.0}, {-e, 0.0}, {0.0, e}, {0.0, -e}})
              tie = tie || agrees(cast(sx + dx / half_w, sy + dy / half_h));
            ASSERT_TRUE(tie) << "pixel " << x << "," << y << " depth " << depth;
            ++ties;
          }
      }
  EXPECT_GT(hits, rays / 5);
  EXPECT_LE(ties, rays / 200);
}

// The beam (esvo §6.2) is a prism for parallel rays: identical color, depth
// and normal images with and without it (bit for bit), ESVO and DAG, LOD off
// and on, with shadows, AO and the post-filter; and it saves work.
TEST(CameraOrtho, BeamOnEqualsBeamOff) {
  const BunnyScene scene(256);
  const int W = 120, H = 90;
  auto same = [](const Image& a, const Image& c) {
    if (a.pixels.size() != c.pixels.size()) return false;
    for (size_t i = 0; i < a.pixels.size(); ++i)
      if (std::bit_cast<uint32_t>(a.pixels[i]) != std::bit_cast<uint32_t>(c.pixels[i]))
        return false;
    return true;
  };
  for (const Structure* s : scene.structures()) {
    const std::vector<Camera> cams = ortho_cameras(scene.occupied, W, H);
    for (size_t ci = 0; ci < cams.size(); ++ci)
      for (float lod : {0.f, 1.f}) {
        SCOPED_TRACE(s->name() + " " + cams[ci].to_string() + " lod " + std::to_string(lod));
        RenderOptions ro = testing::depth_render_options(cams[ci], W, H, lod);
        ro.want_normal = true;
        ro.collect_stats = true;
        const bool fx = ci == 0;  // effects and filter on the framed view
        if (fx) {
          ro.effects.shadows = ShadowMode::Hard;
          ro.effects.ao_rays = 4;
          ro.filter = true;
        }
        const RenderResult plain = render(*s, ro);
        EXPECT_GT(plain.hits, 0u);
        if (fx) {
          size_t shadowed = 0, occluded = 0;
          for (float v : plain.shadow.pixels) shadowed += v < 1.f;
          for (float v : plain.ao.pixels) occluded += v < 1.f;
          EXPECT_GT(shadowed, 0u);
          EXPECT_GT(occluded, 0u);
        }
        for (int K : {4, 8}) {
          ro.beam = K;
          const RenderResult beam = render(*s, ro);
          EXPECT_TRUE(same(plain.color, beam.color)) << "K " << K;
          EXPECT_TRUE(same(plain.depth, beam.depth)) << "K " << K;
          EXPECT_TRUE(same(plain.normal, beam.normal)) << "K " << K;
          if (fx) {
            EXPECT_TRUE(same(plain.shadow, beam.shadow)) << "K " << K;
            EXPECT_TRUE(same(plain.ao, beam.ao)) << "K " << K;
          }
          // The coarse pass did its job: rays start later (framed views; the
          // eye-inside view starts in occupied space anyway).
          if (ci == 0) {
            EXPECT_LT(beam.counters.iterations, plain.counters.iterations) << K;
          }
        }
      }
  }
}

// LOD with parallel rays: the footprint is the same at every distance, so a
// footprint of 2.5 voxels stops every hit at the 2-voxel level whatever the
// depth (a perspective camera's stop level changes with distance).
TEST(CameraOrtho, LodFootprintIsConstant) {
  const BunnyScene scene(128);
  const VoxelSet& voxels = scene.voxels;
  const esvo::EsvoStructure& s = scene.esvo_structure;
  const int W = 80, H = 60;
  const Camera cam = Camera::frame(scene.occupied, W, H, Projection::Orthographic);
  const CameraRays rays(cam, W, H);
  const double vs = voxels.grid.voxel_size;
  const float lod_pixels = float(2.5 * vs / rays.pixel_size());
  LodFootprint lod;  // as render() sets it
  lod.size_at_origin = lod_pixels * rays.pixel_size();
  lod.size_per_t = lod_pixels * rays.pixel_angle();
  EXPECT_EQ(lod.size_per_t, 0.f);
  size_t hits = 0;
  float tmin = INFINITY, tmax = 0;
  TraceContext ctx;
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      SurfaceHit hit;
      if (!s.trace(rays.ray(x, y), lod, ctx, &hit)) continue;
      ++hits;
      tmin = std::min(tmin, hit.t), tmax = std::max(tmax, hit.t);
      EXPECT_NEAR(hit.voxel_size, 2.0 * vs, 1e-6 * vs) << x << "," << y;
    }
  EXPECT_GT(hits, size_t(W * H / 5));
  EXPECT_GT(tmax - tmin, 20.f * float(vs));  // the hits span many voxels in depth
}

}  // namespace
}  // namespace voxcast
