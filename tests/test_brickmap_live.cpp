// Edits on a worker thread while frames render (include/voxcast/brickmap_live.hpp):
// every frame shows the world after a whole number of edits, in order, and
// the last one the world a sequential oracle edits the same way; edits saved
// through the journal reload exactly, and a process killed (SIGKILL) while it
// edits and renders never loses an acknowledged edit.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "support/brickmap_testing.hpp"
#include "support/cli_runner.hpp"
#include "support/esvo_testing.hpp"
#include "support/file_bytes.hpp"
#include "voxcast/brickmap.hpp"
#include "voxcast/brickmap_file.hpp"
#include "voxcast/brickmap_live.hpp"
#include "voxcast/camera.hpp"
#include "voxcast/error.hpp"
#include "voxcast/image.hpp"
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

// A 256^3 world of scattered voxels and edits across its chunks: adds,
// removals out of them and paints, every one changing the world.
struct LiveEdit {
  Brush b;
  EditOp op;
  Color c;
};
World journal_world() {
  VoxelSet v = testing::make_random_voxels(8, 4000, 5);
  testing::fill_random_attributes(v, 6);
  return build_world(v);
}
std::vector<LiveEdit> journal_edits(int n) {
  std::vector<LiveEdit> out;
  for (int i = 0; i < n; ++i) {
    const Vec3d c{0.3 + 0.05 * i, 0.45 + 0.01 * i, 0.5 - 0.03 * i};
    const Color col{float(i + 1) / float(n + 1), 0.4f, 0.8f, 1.f};
    if (i % 3 == 0)
      out.push_back({Brush::sphere(c, 0.06), EditOp::Add, col});
    else if (i % 3 == 1)
      out.push_back({Brush::box(c - Vec3d{0.08, 0.02, 0.02}, c + Vec3d{0.02, 0.03, 0.02}),
                     EditOp::Remove, col});
    else
      out.push_back({Brush::sphere(c - Vec3d{0.03, 0, 0}, 0.05), EditOp::Paint, col});
  }
  return out;
}
// The states after 0, 1, ... of the edits.
std::vector<testing::BrickmapVoxels> journal_states(World w, const std::vector<LiveEdit>& edits) {
  std::vector<testing::BrickmapVoxels> out{testing::brickmap_contents(w)};
  for (const LiveEdit& e : edits) {
    edit(w, e.b, e.op, e.c);
    out.push_back(testing::brickmap_contents(w));
  }
  return out;
}

TEST(BrickmapLive, EditsSavedThroughTheJournalReloadExactly) {
  testing::TempDir dir;
  const std::filesystem::path path = dir.file("w.vxc");
  const World start = journal_world();
  save_scene(path, start, SceneInfo{"t", "conservative", 0, start.stats().voxels});
  std::vector<LiveEdit> edits = journal_edits(9);
  const std::vector<testing::BrickmapVoxels> states = journal_states(start, edits);
  for (size_t i = 1; i < states.size(); ++i) ASSERT_NE(states[i], states[i - 1]) << i;
  edits.push_back({Brush::sphere({0.5, 0.5, 0.5}, -1.0), EditOp::Add, {}});  // refused
  RenderOptions o;
  o.width = 32, o.height = 24;
  o.camera = Camera::orbit(start.occupied_bounds(), o.width, o.height, 0.f, -60.f);
  for (const uint32_t group : {1u, 64u}) {
    remove_journal(path);
    std::vector<uint64_t> acks;
    {
      LiveOptions lo;
      lo.save_to = path;
      lo.max_group = group;
      lo.on_saved = [&](uint64_t n) { acks.push_back(n); };
      LiveWorld live(open_world(path), lo);
      for (const LiveEdit& e : edits) live.submit(e.b, e.op, e.c);
      for (uint32_t f = 0; live.applied() < edits.size() && f < 100000; ++f) {
        o.frame = f;
        (void)render(live, o);
      }
      live.wait_worker();
      EXPECT_EQ(live.saved(), edits.size()) << live.save_error();
      EXPECT_EQ(live.save_error(), "");
      // What is saved is what is rendered.
      EXPECT_EQ(testing::brickmap_contents(live.world()), states.back());
    }
    ASSERT_FALSE(acks.empty());
    EXPECT_TRUE(std::is_sorted(acks.begin(), acks.end()));
    EXPECT_EQ(acks.back(), edits.size());
    OpenReport rep;
    EXPECT_EQ(testing::brickmap_contents(open_world(path, nullptr, &rep)), states.back())
        << "max_group " << group;
    EXPECT_EQ(rep.ignored_bytes, 0u);
    // One transaction per edit that changed something, or fewer when grouped.
    if (group == 1) {
      EXPECT_EQ(rep.transactions, states.size() - 1);
      EXPECT_EQ(acks.size(), edits.size());
    } else {
      EXPECT_LE(rep.transactions, states.size() - 1);
    }
  }
  // A save that fails is reported and leaves the edit unacknowledged; the
  // next edit's save writes both.
  remove_journal(path);
  const std::filesystem::path jp = journal_path(path);
  {
    LiveOptions lo;
    lo.save_to = path;
    LiveWorld live(open_world(path), lo);
    std::filesystem::create_directory(jp);  // the journal cannot be written
    live.submit(edits[0].b, edits[0].op, edits[0].c);
    live.wait_worker();
    EXPECT_EQ(live.saved(), 0u);
    EXPECT_NE(live.save_error().find("journal"), std::string::npos) << live.save_error();
    std::filesystem::remove(jp);
    live.submit(edits[1].b, edits[1].op, edits[1].c);
    live.wait_worker();
    EXPECT_EQ(live.saved(), 2u);
    EXPECT_EQ(live.save_error(), "");
  }
  EXPECT_EQ(testing::brickmap_contents(open_world(path)), states[2]);
}

// `voxcast edit W --batch FILE --render OUT.png`: the brushes on the live
// worker while frames render, saved through the journal as they finish: the
// world reloads as the library edits it.
TEST(BrickmapLive, CliRenderedBatchIsSavedThroughTheJournal) {
  testing::TempDir dir;
  const std::filesystem::path path = dir.file("w.vxc"), batch = dir.file("edits.txt");
  World w = journal_world();
  save_scene(path, w, SceneInfo{"t", "conservative", 0, w.stats().voxels});
  {
    std::ofstream out(batch);
    out << "sphere 0.4,0.5,0.5,0.06 add 0.9,0.2,0.1\n"
        << "box 0.35,0.45,0.45,0.45,0.55,0.55 remove\n"
        << "sphere 0.42,0.5,0.5,0.05 paint 0.1,0.2,0.9\n";
  }
  const auto srgb = [](float r, float g, float b) {
    return Color{srgb_to_linear(r), srgb_to_linear(g), srgb_to_linear(b), 1.f};
  };
  edit(w, Brush::sphere({0.4f, 0.5f, 0.5f}, 0.06), EditOp::Add, srgb(0.9f, 0.2f, 0.1f));
  edit(w, Brush::box({0.35f, 0.45f, 0.45f}, {0.45f, 0.55f, 0.55f}), EditOp::Remove);
  edit(w, Brush::sphere({0.42f, 0.5f, 0.5f}, 0.05), EditOp::Paint, srgb(0.1f, 0.2f, 0.9f));
  const testing::CliResult r =
      testing::run_cli("edit '" + path.string() + "' --batch '" + batch.string() + "' --render '" +
                       dir.file("f.png") + "' --render-size 32x24");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("3 of 3 edits visible"), std::string::npos) << r.output;
  EXPECT_TRUE(std::filesystem::exists(dir.file("f.png")));
  EXPECT_TRUE(std::filesystem::exists(journal_path(path)));
  EXPECT_EQ(testing::brickmap_contents(open_world(path)), testing::brickmap_contents(w));
}

// A child edits through LiveWorld while it renders, acknowledging each save
// on a pipe; it is killed (SIGKILL) at each step of its saves, right after
// each acknowledgement and at times spread over a run. What it leaves opens
// as the state after a whole number of edits, at least the acknowledged ones.
TEST(BrickmapLive, SigkillWhileEditingLiveNeverLosesAnAcknowledgedEdit) {
  testing::TempDir dir;
  const std::filesystem::path path = dir.file("w.vxc");
  const World start = journal_world();
  save_scene(path, start, SceneInfo{"t", "conservative", 0, start.stats().voxels});
  const std::vector<uint8_t> base = testing::read_bytes(path);
  constexpr int kEdits = 8;
  const std::vector<LiveEdit> edits = journal_edits(kEdits);
  const std::vector<testing::BrickmapVoxels> states = journal_states(start, edits);
  // kill_step > 0: the child kills itself at that save step; kill_after > 0:
  // the parent kills it once that many edits are acknowledged; delay: the
  // parent kills it after that long.
  struct Outcome {
    int acked = 0;
    bool killed = false;
  };
  const auto run = [&](int kill_step, int kill_after, std::chrono::microseconds delay,
                       uint32_t group) {
    testing::write_bytes(path, base);
    remove_journal(path);
    int fds[2];
    EXPECT_EQ(::pipe(fds), 0);
    const pid_t pid = ::fork();
    if (pid == 0) {
      ::close(fds[0]);
      std::atomic<int> seen{0};
      if (kill_step > 0)
        set_save_step_hook([&](const char*) {
          if (++seen == kill_step) ::raise(SIGKILL);
        });
      try {
        LiveOptions lo;
        lo.save_to = path;
        lo.max_group = group;
        lo.on_saved = [&](uint64_t n) {
          const char c = char('0' + n);
          if (::write(fds[1], &c, 1) != 1) _exit(3);
        };
        LiveWorld live(open_world(path), lo);
        for (const LiveEdit& e : edits) live.submit(e.b, e.op, e.c);
        RenderOptions o;
        o.width = 16, o.height = 12;
        o.camera = Camera::orbit(start.occupied_bounds(), o.width, o.height, 0.f, -60.f);
        for (uint32_t f = 0; live.saved() < uint64_t(kEdits); ++f) {
          o.frame = f;
          (void)render(live, o);
        }
      } catch (...) {
        _exit(2);
      }
      _exit(0);
    }
    ::close(fds[1]);
    Outcome out;
    if (delay.count() > 0) {
      std::this_thread::sleep_for(delay);
      ::kill(pid, SIGKILL);
    }
    char c;
    while (::read(fds[0], &c, 1) == 1) {
      out.acked = c - '0';
      if (kill_after > 0 && out.acked >= kill_after) ::kill(pid, SIGKILL);
    }
    ::close(fds[0]);
    out.killed = testing::reap_child_killed(pid);
    return out;
  };
  const auto check = [&](const Outcome& o, const std::string& what) {
    testing::BrickmapVoxels got;
    try {
      got = testing::brickmap_contents(open_world(path));
    } catch (const Error& e) {
      ADD_FAILURE() << what << ": the world does not open: " << e.what();
      return;
    }
    const auto at = std::find(states.begin(), states.end(), got);
    ASSERT_NE(at, states.end()) << what << ": not the state after a whole number of edits";
    EXPECT_GE(at - states.begin(), o.acked)
        << what << ": " << o.acked << " edits acknowledged, fewer saved";
  };
  // The save steps of a whole run with one transaction per edit.
  std::atomic<int> steps{0};
  set_save_step_hook([&](const char*) { ++steps; });
  const auto t0 = std::chrono::steady_clock::now();
  {
    LiveOptions lo;
    lo.save_to = path;
    lo.max_group = 1;
    LiveWorld live(open_world(path), lo);
    for (const LiveEdit& e : edits) live.submit(e.b, e.op, e.c);
    live.wait_worker();
  }
  const auto span =
      std::chrono::duration_cast<std::chrono::microseconds>(std::chrono::steady_clock::now() - t0);
  set_save_step_hook(nullptr);
  ASSERT_GE(steps.load(), 4 * kEdits);
  for (int k = 1; k <= steps.load(); ++k) {
    const Outcome o = run(k, 0, {}, 1);
    EXPECT_TRUE(o.killed) << "step " << k;
    check(o, "killed at save step " + std::to_string(k));
    if (HasFailure()) return;
  }
  for (int k = 1; k <= kEdits; ++k) {
    const Outcome o = run(0, k, {}, k % 2 ? 1u : 64u);
    EXPECT_GE(o.acked, k);
    check(o, "killed after " + std::to_string(k) + " acknowledged edits");
  }
  for (int k = 1; k <= 8; ++k) {
    const Outcome o = run(0, 0, span * k / 8, 64);
    check(o, "killed after " + std::to_string((span * k / 8).count()) + " us");
  }
  const Outcome full = run(0, 0, {}, 64);
  EXPECT_FALSE(full.killed);
  EXPECT_EQ(full.acked, kEdits);
  EXPECT_EQ(testing::brickmap_contents(open_world(path)), states.back());
}

}  // namespace
}  // namespace voxcast
