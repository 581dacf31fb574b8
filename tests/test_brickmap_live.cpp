// Edits on a worker thread while frames render (include/voxcast/brickmap_live.hpp):
// every frame shows the world after a whole number of edits, in order, and
// the last one the world a sequential oracle edits the same way.
#include <gtest/gtest.h>

#include <memory>
#include <vector>

#include "support/esvo_testing.hpp"
#include "voxcast/brickmap.hpp"
#include "voxcast/brickmap_live.hpp"
#include "voxcast/camera.hpp"
#include "voxcast/error.hpp"
#include "voxcast/render.hpp"

namespace voxcast {
namespace {

using namespace brickmap;

TEST(BrickmapLive, FramesRenderedDuringWorkerEditsShowWholeEditsInOrder) {
  const World start = build_world(testing::make_sphere_shell(6));
  struct E {
    Brush b;
    EditOp op;
    Color c;
  };
  std::vector<E> edits;
  for (int i = 0; i < 12; ++i) {
    const double x = 0.3 + 0.04 * i;
    edits.push_back({Brush::sphere({x, 0.5, 0.1 + 0.02 * i}, 0.12),
                     i % 3 == 2 ? EditOp::Remove : EditOp::Add,
                     Color{0.1f * float(i % 10), 0.8f, 0.2f, 1.f}});
    edits.push_back({Brush::box({x - 0.1, 0.3, 0}, {x + 0.1, 0.7, 0.6}), EditOp::Paint,
                     Color{0.9f, 0.1f * float(i % 10), 0.1f, 1.f}});
  }
  edits.push_back({Brush::sphere({0.5, 0.5, 0.5}, -1.0), EditOp::Add, {}});  // refused
  // The oracle: the image after each prefix of the edits.
  RenderOptions o;
  o.width = 64, o.height = 48;
  o.camera = Camera::orbit(start.occupied_bounds(), o.width, o.height, 0.f, -60.f);
  std::vector<std::vector<float>> states;
  {
    auto w = std::make_shared<World>(start);
    states.push_back(render(BrickmapStructure(w), o).color.pixels);
    for (const E& e : edits) {
      try {
        edit(*w, e.b, e.op, e.c);
      } catch (const Error&) {
      }
      states.push_back(render(BrickmapStructure(w), o).color.pixels);
    }
  }
  LiveWorld live(start);
  for (const E& e : edits) live.submit(e.b, e.op, e.c);
  size_t last = 0, frames = 0;
  for (uint32_t f = 0; live.applied() < edits.size() && f < 100000; ++f) {
    o.frame = f;
    const RenderResult r = render(live, o);  // publishes finished edits first
    const size_t k = size_t(live.applied());
    ASSERT_GE(k, last) << "edits became visible out of order";
    EXPECT_EQ(r.color.pixels, states[k]) << "frame " << f << " after " << k << " edits";
    last = k, ++frames;
  }
  EXPECT_EQ(live.applied(), edits.size());
  live.wait_worker();
  EXPECT_NE(live.last_error().find("sphere"), std::string::npos) << live.last_error();
  const LiveWorld::Throughput t = live.throughput();
  EXPECT_GT(t.voxels, 1000u);
  EXPECT_GT(t.bricks, 10u);
  std::printf(
      "%zu frames while %zu edits ran: %llu voxels, %llu bricks in %.2f ms (%.3g voxels/s)\n",
      frames, edits.size(), (unsigned long long)t.voxels, (unsigned long long)t.bricks,
      t.seconds * 1e3, t.seconds > 0 ? double(t.voxels) / t.seconds : 0.0);
  // Stamps go through the worker too.
  VoxelSet s = testing::make_random_voxels(6, 500, 4);
  testing::fill_random_attributes(s, 5);
  s.grid = start.grid();
  World want = live.world();
  stamp(want, s, EditOp::Add);
  live.submit(s, EditOp::Add);
  live.wait_worker();
  live.publish();
  EXPECT_EQ(live.world().decode_voxels(), want.decode_voxels());
}

}  // namespace
}  // namespace voxcast
