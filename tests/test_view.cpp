// The viewer's window-free parts: the camera path format (round trip, errors,
// interpolation), the orbit/fly controller against rotations computed here,
// and the refinement accumulator (with the post-filter linearity it relies on).
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "view/camera_controller.hpp"
#include "view/camera_path.hpp"
#include "view/progressive.hpp"
#include "voxcast/error.hpp"
#include "voxcast/render.hpp"

using namespace voxcast;
using namespace voxcast::view;

namespace {

bool bits_equal(float a, float b) {
  return std::memcmp(&a, &b, sizeof a) == 0;
}
bool bits_equal(Vec3 a, Vec3 b) {
  return bits_equal(a.x, b.x) && bits_equal(a.y, b.y) && bits_equal(a.z, b.z);
}
void expect_same_camera(const Camera& a, const Camera& b) {
  EXPECT_TRUE(bits_equal(a.eye, b.eye));
  EXPECT_TRUE(bits_equal(a.target, b.target));
  EXPECT_TRUE(bits_equal(a.up, b.up));
  EXPECT_EQ(a.projection, b.projection);
  if (a.projection == Projection::Orthographic)
    EXPECT_TRUE(bits_equal(a.ortho_width, b.ortho_width));
  else
    EXPECT_TRUE(bits_equal(a.fovy_degrees, b.fovy_degrees));
}
void expect_near(Vec3 a, Vec3 b, float eps) {
  EXPECT_NEAR(a.x, b.x, eps);
  EXPECT_NEAR(a.y, b.y, eps);
  EXPECT_NEAR(a.z, b.z, eps);
}

std::string path_with(const std::string& keyframes) {
  return "{\"voxcast_camera_path\": 1, \"keyframes\": [" + keyframes + "]}";
}

// The error a parse must fail with (substring of the one-line message).
void expect_rejected(const std::string& json, const std::string& needle) {
  try {
    CameraPath::parse(json);
    ADD_FAILURE() << "accepted: " << json;
  } catch (const Error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find(needle), std::string::npos) << what << "\n  for: " << json;
    EXPECT_EQ(what.find('\n'), std::string::npos) << what;
  }
}

}  // namespace

TEST(ViewCameraPath, JsonRoundTripIsBitExact) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(-100.f, 100.f);
  CameraPath p;
  double t = 0;
  for (int i = 0; i < 50; ++i) {
    CameraKeyframe k;
    if (i % 3 == 0) k.name = "key" + std::to_string(i);
    t += 0.001 + double(i) * 0.37;
    k.time = t;
    k.camera.eye = {u(rng), u(rng), u(rng)};
    k.camera.target = {u(rng), u(rng), u(rng)};
    k.camera.up = normalize(Vec3{u(rng), 100.f, u(rng)});
    if (i % 4 == 1) {
      k.camera.projection = Projection::Orthographic;
      k.camera.ortho_width = 0.001f + std::fabs(u(rng));
    } else {
      k.camera.fovy_degrees = 1.f + std::fabs(u(rng)) * 1.5f;
    }
    k.camera.validate();
    p.keyframes.push_back(k);
  }
  const CameraPath q = CameraPath::parse(p.to_json());
  ASSERT_EQ(q.keyframes.size(), p.keyframes.size());
  for (size_t i = 0; i < p.keyframes.size(); ++i) {
    EXPECT_EQ(q.keyframes[i].name, p.keyframes[i].name);
    EXPECT_EQ(q.keyframes[i].time, p.keyframes[i].time);
    expect_same_camera(q.keyframes[i].camera, p.keyframes[i].camera);
  }
}

TEST(ViewCameraPath, DefaultsOfOptionalKeys) {
  const CameraPath p =
      CameraPath::parse(path_with(R"({"time": 0, "eye": [0, 0, 5], "target": [0, 0, 0]})"));
  ASSERT_EQ(p.keyframes.size(), 1u);
  const Camera& c = p.keyframes[0].camera;
  EXPECT_EQ(c.projection, Projection::Perspective);
  EXPECT_EQ(c.fovy_degrees, Camera::kDefaultFovy);
  EXPECT_TRUE(bits_equal(c.up, Vec3{0, 1, 0}));
  EXPECT_TRUE(p.keyframes[0].name.empty());
}

TEST(ViewCameraPath, MalformedFilesAreRefusedWithOneLine) {
  const std::string ok = R"("time": 0, "eye": [0, 0, 5], "target": [0, 0, 0])";
  expect_rejected("not json", "not valid JSON");
  expect_rejected("[]", "JSON object");
  expect_rejected(R"({"keyframes": [{)" + ok + "}]}", "voxcast_camera_path");
  expect_rejected(R"({"voxcast_camera_path": 2, "keyframes": [{)" + ok + "}]}", "version 2");
  expect_rejected(R"({"voxcast_camera_path": 1, "keyframes": []})", "non-empty");
  expect_rejected(R"({"voxcast_camera_path": 1, "frames": []})", "unknown key 'frames'");
  expect_rejected(path_with("{" + ok + ", \"fov\": 30}"), "unknown key 'fov'");
  expect_rejected(path_with(R"({"eye": [0, 0, 5], "target": [0, 0, 0]})"), "missing 'time'");
  expect_rejected(path_with(R"({"time": 0, "target": [0, 0, 0]})"), "missing 'eye'");
  expect_rejected(path_with(R"({"time": 0, "eye": [0, 0], "target": [0, 0, 0]})"), "'eye'");
  expect_rejected(path_with(R"({"time": 0, "eye": [0, "a", 5], "target": [0, 0, 0]})"), "'eye'");
  expect_rejected(path_with(R"({"time": 0, "eye": [0, 0, 1e39], "target": [0, 0, 0]})"), "finite");
  expect_rejected(path_with(R"({"time": -1, "eye": [0, 0, 5], "target": [0, 0, 0]})"), "'time'");
  expect_rejected(path_with("{" + ok + "}, {" + ok + "}"), "keyframe 1: 'time' must be greater");
  expect_rejected(path_with(R"({"time": 0, "eye": [0, 0, 0], "target": [0, 0, 0]})"),
                  "keyframe 0");  // eye == target (Camera::validate)
  expect_rejected(path_with("{" + ok + R"(, "up": [0, 0, 1]})"), "keyframe 0");  // up || view
  expect_rejected(path_with("{" + ok + R"(, "fovy": 180})"), "keyframe 0");
  expect_rejected(path_with("{" + ok + R"(, "projection": "orthographic"})"), "ortho_width");
  expect_rejected(path_with("{" + ok + R"(, "ortho_width": 2})"), "orthographic");
  expect_rejected(path_with("{" + ok + R"(, "projection": "fisheye"})"), "'projection'");
  expect_rejected(path_with("{" + ok + R"(, "name": "a"}, {"time": 1, "eye": [1, 0, 5], )" +
                            R"("target": [0, 0, 0], "name": "a"})"),
                  "used twice");
}

TEST(ViewCameraPath, KeyframeTimesGiveTheKeyframeCameraExactly) {
  CameraPath p = CameraPath::parse(path_with(
      R"({"name": "a", "time": 0.5, "eye": [0.1, 0.2, 3.3], "target": [0, 0, 0], "fovy": 30},
         {"name": "b", "time": 1.25, "eye": [3.7, 1.1, 0.3], "target": [0.3, 0.1, 0], "fovy": 50},
         {"time": 4, "eye": [-2, 1, -2], "target": [0, 0.5, 0], "up": [0.1, 1, 0]})"));
  for (const CameraKeyframe& k : p.keyframes) expect_same_camera(p.at(k.time), k.camera);
  expect_same_camera(p.at(0.0), p.keyframes[0].camera);    // before the start
  expect_same_camera(p.at(100.0), p.keyframes[2].camera);  // after the end
  // In between: the blend computed here, component by component.
  const double t = 0.5 + 0.75 * 0.25;  // a quarter of the way from a to b
  const Camera c = p.at(t);
  const Camera &a = p.keyframes[0].camera, &b = p.keyframes[1].camera;
  expect_near(c.eye,
              Vec3{a.eye.x + 0.25f * (b.eye.x - a.eye.x), a.eye.y + 0.25f * (b.eye.y - a.eye.y),
                   a.eye.z + 0.25f * (b.eye.z - a.eye.z)},
              1e-6f);
  expect_near(c.target, Vec3{0.075f, 0.025f, 0.f}, 1e-6f);
  EXPECT_NEAR(c.fovy_degrees, 35.f, 1e-5f);
  EXPECT_EQ(p.find("b"), 1u);
  EXPECT_EQ(p.find("2"), 2u);
  EXPECT_THROW(p.find("c"), Error);
  EXPECT_THROW(p.find("3"), Error);
}

TEST(ViewCameraController, ResetCameraIsKeptExactlyUntilInput) {
  Camera c;
  c.eye = {0.3f, 1.7f, -2.9f};
  c.target = {0.1f, 0.2f, 0.05f};
  c.up = {0.f, 1.f, 0.2f};
  c.fovy_degrees = 33.f;
  CameraController ctl;
  ctl.reset(c, 2.f);
  expect_same_camera(ctl.camera(), c);
  ControllerInput idle;
  idle.dt = 0.1;
  EXPECT_FALSE(ctl.update(idle, 640, 480));
  expect_same_camera(ctl.camera(), c);
  EXPECT_FLOAT_EQ(ctl.speed(), 1.f);  // half the scene size per second
}

TEST(ViewCameraController, OrbitTurnsTheEyeAroundTheTarget) {
  Camera c;
  c.eye = {1.f, 2.f, 5.f};
  c.target = {1.f, 0.5f, 1.f};
  CameraController ctl;
  ctl.reset(c, 1.f);
  const Vec3 off = c.eye - c.target;
  // 90 degrees of azimuth = 90 / kDegreesPerPixel pixels dragged to the left
  // (dx < 0 raises the azimuth): a rotation about +y by +90 degrees, which
  // maps (x, y, z) to (z, y, -x).
  ControllerInput in;
  in.rotate = true;
  in.dx = -90.0 / double(CameraController::kDegreesPerPixel);
  EXPECT_TRUE(ctl.update(in, 640, 480));
  const Camera r = ctl.camera();
  expect_near(r.target, c.target, 1e-6f);
  expect_near(r.eye - r.target, Vec3{off.z, off.y, -off.x}, 1e-4f);
  EXPECT_NEAR(length(r.eye - r.target), length(off), 1e-4f);
  // Dragging far down cannot tip the view over the pole.
  in.dx = 0, in.dy = 1e5;
  ctl.update(in, 640, 480);
  EXPECT_NEAR(ctl.elevation(), CameraController::kMaxElevation, 1e-4f);
  EXPECT_NO_THROW(ctl.camera().validate());
  // The wheel moves the eye towards the target, along the view.
  const Camera before = ctl.camera();
  ControllerInput wheel;
  wheel.scroll = 2;
  ctl.update(wheel, 640, 480);
  const Camera after = ctl.camera();
  expect_near(after.target, before.target, 1e-6f);
  EXPECT_NEAR(length(after.eye - after.target), 0.81f * length(before.eye - before.target), 1e-4f);
  expect_near(normalize(after.eye - after.target), normalize(before.eye - before.target), 1e-5f);
}

TEST(ViewCameraController, FlyLooksAroundFromAFixedEyeAndWasdMoves) {
  Camera c;
  c.eye = {0.f, 1.f, 4.f};
  c.target = {0.f, 1.f, 0.f};
  CameraController ctl;
  ctl.reset(c, 2.f);  // 1 unit per second
  ctl.set_mode(CameraMode::Fly);
  ControllerInput look;
  look.rotate = true;
  look.dx = 90.0 / double(CameraController::kDegreesPerPixel);  // turn right by 90 degrees
  ctl.update(look, 640, 480);
  Camera r = ctl.camera();
  expect_near(r.eye, c.eye, 1e-5f);
  // Looking along -z, a right turn looks along +x.
  expect_near(normalize(r.target - r.eye), Vec3{1, 0, 0}, 1e-5f);
  ControllerInput walk;
  walk.forward = true;
  walk.dt = 0.5;
  ctl.update(walk, 640, 480);
  expect_near(ctl.camera().eye, r.eye + Vec3{0.5f, 0, 0}, 1e-5f);
  walk.forward = false, walk.left = true, walk.fast = true;  // 4x: 2 units along -right
  const Vec3 e0 = ctl.camera().eye;
  ctl.update(walk, 640, 480);
  // right = forward x up = (1,0,0) x (0,1,0) = (0,0,1); left is -z.
  expect_near(ctl.camera().eye, e0 + Vec3{0, 0, -2.f}, 1e-5f);
}

TEST(ViewCameraController, PanFollowsTheCursorAtTheTargetDistance) {
  Camera c;
  c.eye = {0.f, 0.f, 10.f};
  c.target = {0.f, 0.f, 0.f};
  c.fovy_degrees = 90.f;  // the image height spans 2 * 10 * tan(45) = 20 units at the target
  CameraController ctl;
  ctl.reset(c, 1.f);
  ControllerInput pan;
  pan.pan = true;
  // 100 of the 200 rows' worth of pixels: half the height, 10 units; the
  // target moves against the drag, so the scene follows the cursor.
  pan.dx = 100;
  ctl.update(pan, 400, 200);
  expect_near(ctl.camera().target, Vec3{-10.f, 0, 0}, 1e-4f);
}

TEST(ViewProgressive, MeanOfThePassesAndRestart) {
  Accumulator acc(3);
  std::vector<Image> passes;
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  for (int k = 0; k < 3; ++k) {
    Image im(5, 4, 3);
    for (float& v : im.pixels) v = u(rng);
    passes.push_back(im);
    EXPECT_FALSE(acc.done());
    EXPECT_EQ(acc.next_seed(10), uint32_t(10 + k));
    acc.add(im);
  }
  EXPECT_TRUE(acc.done());
  for (size_t i = 0; i < passes[0].pixels.size(); ++i)
    EXPECT_NEAR(acc.mean().pixels[i],
                (double(passes[0].pixels[i]) + passes[1].pixels[i] + passes[2].pixels[i]) / 3.0,
                1e-6);
  acc.reset();
  EXPECT_EQ(acc.passes(), 0);
  acc.add(passes[2]);
  EXPECT_EQ(acc.mean().pixels, passes[2].pixels);
  Image other(2, 2, 3);  // a new size starts over too
  acc.add(other);
  EXPECT_EQ(acc.passes(), 1);
  EXPECT_EQ(acc.mean().width, 2);
}

// progressive.hpp: the viewer filters every pass and averages, which is the
// post-filtered mean only because post_filter is linear for fixed radii.
TEST(ViewProgressive, FilterCommutesWithTheMean) {
  const int W = 40, H = 30;
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  std::uniform_int_distribution<int> code(0, 200);
  std::vector<uint8_t> radius(size_t(W) * H);
  for (uint8_t& r : radius) r = uint8_t(code(rng));
  Image a(W, H, 3), b(W, H, 3), mean(W, H, 3);
  for (size_t i = 0; i < a.pixels.size(); ++i) {
    a.pixels[i] = u(rng), b.pixels[i] = u(rng);
    mean.pixels[i] = 0.5f * (a.pixels[i] + b.pixels[i]);
  }
  const Image fa = post_filter(a, radius), fb = post_filter(b, radius);
  const Image fmean = post_filter(mean, radius);
  int blurred = 0;
  for (size_t i = 0; i < a.pixels.size(); ++i) {
    EXPECT_NEAR(0.5f * (fa.pixels[i] + fb.pixels[i]), fmean.pixels[i], 1e-5f);
    blurred += fa.pixels[i] != a.pixels[i];
  }
  EXPECT_GT(blurred, int(a.pixels.size()) / 2);  // the filter did blur
}
