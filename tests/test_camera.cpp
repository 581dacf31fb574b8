// Camera parsing/printing, the primary-ray contract (camera.hpp) and framing.
#include <gtest/gtest.h>

#include <cmath>

#include "voxcast/camera.hpp"
#include "voxcast/error.hpp"

namespace voxcast {
namespace {

TEST(Camera, ParseAndRoundTrip) {
  const Camera c = Camera::parse("1.5,2,-3, 0.1,0.2,0.3, 0,1,0, 50");
  EXPECT_EQ(c.eye.x, 1.5f);
  EXPECT_EQ(c.eye.z, -3.f);
  EXPECT_EQ(c.target.y, 0.2f);
  EXPECT_EQ(c.up.y, 1.f);
  EXPECT_EQ(c.fovy_degrees, 50.f);
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
}

TEST(Camera, RejectsBadStrings) {
  const char* bad[] = {
      "",                         // nothing
      "1,2,3,4,5,6,7,8,9",        // 9 numbers
      "1,2,3,4,5,6,0,1,0,45,1",   // 11 numbers
      "1,2,3,4,5,6,0,1,0,abc",    // not a number
      "1,2,3,4,5,6,0,1,0,45x",    // trailing junk
      "1,2,3,,5,6,0,1,0,45",      // empty field
      "nan,2,3,4,5,6,0,1,0,45",   // NaN
      "inf,2,3,4,5,6,0,1,0,45",   // infinity
      "1e39,2,3,4,5,6,0,1,0,45",  // overflows float
      "1,2,3,4,5,6,0,1,0,0",      // fovy 0
      "1,2,3,4,5,6,0,1,0,180",    // fovy 180
      "1,2,3,4,5,6,0,1,0,-10",    // negative fovy
      "1,2,3,1,2,3,0,1,0,45",     // eye == target
      "0,0,0,0,5,0,0,1,0,45",     // up parallel to forward
      "0,0,0,1,0,0,0,0,0,45",     // zero up
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

  // A general basis: the center ray is forward, and up/right are orthogonal.
  c = Camera::parse("1,2,3,-4,0.5,2,0.2,1,0.1,30");
  const CameraRays g(c, 9, 3);
  expect_dir(g.direction(4, 1), normalize(c.target - c.eye));
  EXPECT_NEAR(dot(g.right, g.forward), 0.f, 1e-6f);
  EXPECT_NEAR(dot(g.true_up, g.forward), 0.f, 1e-6f);
  EXPECT_NEAR(length(g.true_up), 1.f, 1e-6f);
  EXPECT_GT(dot(g.true_up, c.up), 0.f);
}

TEST(Camera, FrameCentersAndFillsTheImage) {
  Aabb box;
  box.extend({-1.f, 2.f, 10.f});
  box.extend({3.f, 3.f, 12.f});
  for (auto [W, H] : {std::pair{256, 192}, std::pair{100, 300}, std::pair{1024, 768}}) {
    const Camera c = Camera::frame(box, W, H);
    expect_dir(c.target, box.center(), 1e-5f);
    // Eye front-right-above.
    EXPECT_GT(c.eye.x, c.target.x);
    EXPECT_GT(c.eye.y, c.target.y);
    EXPECT_GT(c.eye.z, c.target.z);
    const CameraRays rays(c, W, H);
    auto project = [&](Vec3 p, float* u, float* w) {
      const Vec3 v = p - c.eye;
      const float z = dot(v, rays.forward);
      ASSERT_GT(z, 0.f);
      *u = dot(v, rays.right) / (z * rays.tan_half * rays.aspect);  // [-1,1] across the image
      *w = dot(v, rays.true_up) / (z * rays.tan_half);
    };
    // The box center is the image center.
    float u, w;
    project(box.center(), &u, &w);
    EXPECT_NEAR(u, 0.f, 1e-5f);
    EXPECT_NEAR(w, 0.f, 1e-5f);
    // The ellipsoid inscribed in the box is inside the image and fills a good
    // part of it (frame() fits it, not the corners: real shapes rarely reach them).
    const Vec3 e = box.extent() * 0.5f;
    float max_extent = 0.f;
    for (int i = 0; i < 2000; ++i) {
      const float a = 6.2831853f * float(i % 50) / 50.f,
                  b = 3.14159265f * (float(i / 50) + 0.5f) / 40.f;
      const Vec3 s{std::cos(a) * std::sin(b), std::sin(a) * std::sin(b), std::cos(b)};
      project(box.center() + e * s, &u, &w);
      EXPECT_LE(std::fabs(u), 1.f);
      EXPECT_LE(std::fabs(w), 1.f);
      max_extent = std::max({max_extent, std::fabs(u), std::fabs(w)});
    }
    EXPECT_GT(max_extent, 0.75f);
  }
  EXPECT_THROW(Camera::frame(Aabb{}, 10, 10), Error);
  // A single point can be framed (any distance).
  Aabb point;
  point.extend({1, 1, 1});
  const Camera pc = Camera::frame(point, 10, 10);
  EXPECT_GT(length(pc.eye - pc.target), 0.f);
}

}  // namespace
}  // namespace voxcast
