// Brickmap worlds on disk (include/voxcast/brickmap_file.hpp, issue 11 item
// 5): edits saved in place through the journal and reloaded exactly, a save
// killed with SIGKILL at every step (and at random times) never loses an
// acknowledged edit nor leaves a torn chunk, a journal cut at any byte
// replays exactly the transactions it holds whole, and a damaged chunk is
// refused while the rest of the world loads.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>
#include <xxhash.h>

#include <algorithm>
#include <bit>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>
#include <string>
#include <thread>
#include <tuple>
#include <vector>

#include "support/brickmap_testing.hpp"
#include "support/cli_runner.hpp"
#include "support/esvo_testing.hpp"
#include "support/file_bytes.hpp"
#include "voxcast/brickmap.hpp"
#include "voxcast/brickmap_file.hpp"
#include "voxcast/brickmap_stream.hpp"
#include "voxcast/error.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/scene_file.hpp"

namespace voxcast {
namespace {

using namespace brickmap;
namespace fs = std::filesystem;

using Voxels = testing::BrickmapVoxels;
Voxels contents(const World& w) {
  return testing::brickmap_contents(w);
}

// A 256^3 world (8 chunks) of scattered voxels, and brushes that cross
// chunk boundaries (the grid's middle planes).
World base_world() {
  VoxelSet v = testing::make_random_voxels(8, 4000, 5);
  testing::fill_random_attributes(v, 6);
  return build_world(v);
}

struct Step {
  Brush brush;
  EditOp op;
  Color color;
};
// Groups of three: add a sphere or box, remove a box out of it, paint a
// sphere over it (so that every step changes the world).
std::vector<Step> edit_steps(int n) {
  std::mt19937 rng(17);
  std::uniform_real_distribution<double> pos(0.4, 0.6), rad(0.03, 0.06);
  std::vector<Step> out;
  Vec3d c;
  double r = 0;
  for (int i = 0; i < n; ++i) {
    const Color col{float(i + 1) / float(n + 1), 0.3f, 0.9f - 0.05f * float(i), 1.f};
    if (i % 3 == 0) {
      c = Vec3d{pos(rng), pos(rng), pos(rng)}, r = rad(rng);
      const Vec3d e{r, 0.8 * r, 0.9 * r};
      out.push_back({i % 2 ? Brush::box(c - e, c + e) : Brush::sphere(c, r), EditOp::Add, col});
    } else if (i % 3 == 1) {
      out.push_back({Brush::box(c - Vec3d{0.5 * r, 0.5 * r, 2 * r}, c + Vec3d{0.4 * r, 0.3 * r, 0}),
                     EditOp::Remove, col});
    } else {
      out.push_back({Brush::sphere(c + Vec3d{0.5 * r, 0, 0}, 0.7 * r), EditOp::Paint, col});
    }
  }
  return out;
}

std::vector<uint8_t> bytes_of(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::vector<uint8_t>(std::istreambuf_iterator<char>(in), {});
}
void write_bytes(const fs::path& p, const std::vector<uint8_t>& b, size_t n) {
  std::ofstream out(p, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(b.data()), std::streamsize(n));
}

TEST(BrickmapPersist, EditsSavedInPlaceReloadExactlyAndCheckpointFoldsTheJournal) {
  testing::TempDir dir;
  const fs::path path = dir.file("world.vxc");
  World w = base_world();
  const SceneInfo info{"t", "conservative", 0, w.stats().voxels};
  save_scene(path, w, info);
  const std::vector<uint8_t> before = bytes_of(path);
  uint64_t last = 0;
  for (const Step& s : edit_steps(5)) {
    const EditResult r = edit(w, s.brush, s.op, s.color);
    ASSERT_FALSE(r.cells.empty());
    const uint64_t size = commit_edits(path, w, r.cells);
    EXPECT_GT(size, last);
    last = size;
    OpenReport rep;
    SceneInfo got;
    const World back = open_world(path, &got, &rep);
    EXPECT_EQ(contents(back), contents(w));
    EXPECT_EQ(got.leaf_voxels, w.stats().voxels);
    EXPECT_EQ(rep.ignored_bytes, 0u);
  }
  // Saved in place without touching the scene file; load_scene sees it.
  EXPECT_EQ(bytes_of(path), before);
  EXPECT_TRUE(fs::exists(journal_path(path)));
  const LoadedScene scene = load_scene(path);
  EXPECT_EQ(contents(dynamic_cast<const BrickmapStructure&>(*scene.structure).world()),
            contents(w));
  EXPECT_EQ(scene.info.leaf_voxels, w.stats().voxels);
  checkpoint_world(path, w, SceneInfo{"t", "conservative", 0, w.stats().voxels});
  EXPECT_FALSE(fs::exists(journal_path(path)));
  EXPECT_EQ(contents(load_world(Container::read(path))), contents(w));
  // A journal of another world is refused, not replayed.
  const World other(GridTransform::fit(Aabb{{0, 0, 0}, {1, 1, 1}}, 64));
  save_scene(dir.file("other.vxc"), other, SceneInfo{"t", "conservative", 0, 0});
  commit_edits(dir.file("other.vxc"), other, {});
  fs::copy_file(journal_path(dir.file("other.vxc")), journal_path(path));
  EXPECT_NE(std::string(testing::error_of([&] {
              (void)open_world(path);
            })).find("belongs to another version of the world"),
            std::string::npos);
}

// A format-2 journal (written by the previous version) still replays; the
// first save of this version rewrites it with format 3's head before
// appending, so that an older voxcast refuses it instead of stopping at
// the first record type it does not know.
TEST(BrickmapPersist, AFormat2JournalReplaysAndIsUpgradedBeforeThisVersionAppends) {
  testing::TempDir dir;
  const fs::path path = dir.file("world.vxc");
  World w = base_world();
  save_scene(path, w, SceneInfo{"t", "conservative", 0, w.stats().voxels});
  const std::vector<Step> steps = edit_steps(2);
  commit_edits(path, w, edit(w, steps[0].brush, steps[0].op, steps[0].color).cells);
  // The same journal as the previous version wrote it (its records are
  // format 2's; only the head's magic and hash differ).
  std::vector<uint8_t> j = bytes_of(journal_path(path));
  ASSERT_EQ(std::string(j.begin(), j.begin() + 8), "VXBMJRN3");
  j[7] = '2';
  const uint64_t h = XXH64(j.data(), 24, 0);
  std::memcpy(&j[24], &h, 8);
  testing::write_bytes(journal_path(path), j);
  OpenReport rep;
  EXPECT_EQ(contents(open_world(path, nullptr, &rep)), contents(w));
  EXPECT_EQ(rep.transactions, 1u);
  commit_edits(path, w, edit(w, steps[1].brush, steps[1].op, steps[1].color).cells);
  const std::vector<uint8_t> upgraded = bytes_of(journal_path(path));
  EXPECT_EQ(std::string(upgraded.begin(), upgraded.begin() + 8), "VXBMJRN3");
  EXPECT_TRUE(std::equal(j.begin() + 32, j.end(), upgraded.begin() + 32));  // records kept
  EXPECT_FALSE(fs::exists(journal_path(path).string() + ".tmp"));
  EXPECT_EQ(contents(open_world(path, nullptr, &rep)), contents(w));
  EXPECT_EQ(rep.transactions, 2u);
}

// The journal is bound to the exact file it was written against
// (brickmap_file.hpp): world B of the same grid size copied over world A's
// file refuses A's journal everywhere (open, load_scene, streaming, saving),
// changing neither file; A's bytes under another name keep replaying it.
TEST(BrickmapPersist, AJournalBesideAnotherWorldOfTheSameSizeIsRefusedNotReplayed) {
  testing::TempDir dir;
  const fs::path a = dir.file("a.vxc"), b = dir.file("b.vxc"), w = dir.file("w.vxc"),
                 c = dir.file("c.vxc");
  World wa = base_world();
  VoxelSet vb = testing::make_random_voxels(8, 4000, 9);
  testing::fill_random_attributes(vb, 10);
  const World wb = build_world(vb);
  ASSERT_EQ(wa.cells().size(), wb.cells().size());
  save_scene(a, wa, SceneInfo{"t", "conservative", 0, wa.stats().voxels});
  save_scene(b, wb, SceneInfo{"t", "conservative", 0, wb.stats().voxels});
  const Voxels b_state = contents(wb);
  for (const Step& s : edit_steps(2)) commit_edits(a, wa, edit(wa, s.brush, s.op, s.color).cells);
  fs::copy_file(b, w);
  fs::copy_file(journal_path(a), journal_path(w));
  const std::vector<uint8_t> world_bytes = bytes_of(w), journal_bytes = bytes_of(journal_path(w));
  const std::string message =
      "journal '" + journal_path(w).string() + "' belongs to another version of the world";
  const auto refused = [&](const std::string& e) {
    EXPECT_NE(e.find(message), std::string::npos) << e;
    EXPECT_NE(e.find("remove the journal"), std::string::npos) << e;
  };
  refused(testing::error_of([&] { (void)open_world(w); }));
  refused(testing::error_of([&] { (void)open_world(w, nullptr, nullptr, true); }));
  refused(testing::error_of([&] { (void)load_scene(w); }));
  refused(testing::error_of([&] { StreamingWorld s(w, StreamOptions{}); }));
  World loaded = load_world(Container::read(w));
  EXPECT_EQ(contents(loaded), b_state);
  const EditResult r = edit(loaded, edit_steps(1)[0].brush, EditOp::Add, Color{1, 0, 0, 1});
  refused(testing::error_of([&] { commit_edits(w, loaded, r.cells); }));
  refused(testing::error_of([&] {
    checkpoint_world(w, loaded, SceneInfo{"t", "conservative", 0, loaded.stats().voxels});
  }));
  EXPECT_EQ(bytes_of(w), world_bytes);
  EXPECT_EQ(bytes_of(journal_path(w)), journal_bytes);
  EXPECT_FALSE(fs::exists(dir.file("w.vxc.checkpoint")));
  // The journal removed: B as it is.
  fs::remove(journal_path(w));
  EXPECT_EQ(contents(open_world(w)), b_state);
  // The same bytes copied: the journal replays.
  fs::copy_file(a, c);
  fs::copy_file(journal_path(a), journal_path(c));
  OpenReport rep;
  EXPECT_EQ(contents(open_world(c, nullptr, &rep)), contents(wa));
  EXPECT_EQ(rep.transactions, 2u);
  // A world saved whole over the file takes the stale journal with it.
  save_scene(c, wb, SceneInfo{"t", "conservative", 0, wb.stats().voxels});
  EXPECT_FALSE(fs::exists(journal_path(c)));
  EXPECT_EQ(contents(open_world(c)), b_state);
}

// A checkpoint cut off between its rename and the journal's removal: the
// journal's rebase record names the new file, which holds its
// transactions; nothing is replayed and the next save starts it anew.
TEST(BrickmapPersist, ACheckpointCutOffBeforeTheJournalsRemovalLeavesItFoldedIn) {
  testing::TempDir dir;
  const fs::path path = dir.file("world.vxc");
  World w = base_world();
  save_scene(path, w, SceneInfo{"t", "conservative", 0, w.stats().voxels});
  const std::vector<Step> steps = edit_steps(3);
  for (const Step& s : {steps[0], steps[1]})
    commit_edits(path, w, edit(w, s.brush, s.op, s.color).cells);
  struct Cut {};
  set_save_step_hook([](const char* name) {
    if (std::string(name) == "checkpoint renamed") throw Cut{};
  });
  EXPECT_THROW(checkpoint_world(path, w, SceneInfo{"t", "conservative", 0, w.stats().voxels}), Cut);
  set_save_step_hook(nullptr);
  ASSERT_TRUE(fs::exists(journal_path(path)));
  OpenReport rep;
  EXPECT_EQ(contents(open_world(path, nullptr, &rep)), contents(w));
  EXPECT_EQ(rep.transactions, 0u);
  EXPECT_NO_THROW((void)load_scene(path));
  commit_edits(path, w, edit(w, steps[2].brush, steps[2].op, steps[2].color).cells);
  const std::vector<uint8_t> j = bytes_of(journal_path(path));
  ASSERT_GT(j.size(), 48u);
  uint64_t first_txn = 0;
  std::memcpy(&first_txn, &j[32 + 8], 8);  // the first record's transaction
  EXPECT_EQ(first_txn, 1u) << "the journal started anew";
  rep = {};
  EXPECT_EQ(contents(open_world(path, nullptr, &rep)), contents(w));
  EXPECT_EQ(rep.transactions, 1u);
}

// The states after 0, 1, ... edits of the crash run, and the run itself:
// edits, each committed and then acknowledged on `ack` (one byte), a
// checkpoint after every fourth.
constexpr int kCrashEdits = 8;
void crash_run(const fs::path& path, int ack) {
  SceneInfo info;
  World w = open_world(path, &info);
  const std::vector<Step> steps = edit_steps(kCrashEdits);
  for (int i = 0; i < kCrashEdits; ++i) {
    const EditResult r =
        edit(w, steps[size_t(i)].brush, steps[size_t(i)].op, steps[size_t(i)].color);
    commit_edits(path, w, r.cells);
    const char c = char('0' + i + 1);
    if (ack >= 0 && ::write(ack, &c, 1) != 1) _exit(3);
    if ((i + 1) % 4 == 0) {
      info.leaf_voxels = w.stats().voxels;
      checkpoint_world(path, w, info);
    }
  }
}

struct CrashOutcome {
  int acked = 0;
  bool killed = false;
};
// Runs crash_run in a child on a fresh copy of `base`; the child kills
// itself at save step `kill_step` (1-based; 0: never) or the parent kills it
// after `delay` (when > 0).
CrashOutcome crash_child(const fs::path& path, const std::vector<uint8_t>& base, int kill_step,
                         std::chrono::microseconds delay) {
  write_bytes(path, base, base.size());
  fs::remove(journal_path(path));
  int fds[2];
  EXPECT_EQ(::pipe(fds), 0);
  const pid_t pid = ::fork();
  if (pid == 0) {
    ::close(fds[0]);
    int seen = 0;
    if (kill_step > 0)
      set_save_step_hook([&](const char*) {
        if (++seen == kill_step) ::raise(SIGKILL);
      });
    try {
      crash_run(path, fds[1]);
    } catch (...) {
      _exit(2);
    }
    _exit(0);
  }
  ::close(fds[1]);
  if (delay.count() > 0) {
    std::this_thread::sleep_for(delay);
    ::kill(pid, SIGKILL);
  }
  CrashOutcome out;
  char c;
  while (::read(fds[0], &c, 1) == 1) out.acked = c - '0';
  ::close(fds[0]);
  out.killed = testing::reap_child_killed(pid);
  return out;
}

TEST(BrickmapPersist, SigkillDuringSavesNeverLosesAnAcknowledgedEditNorTearsAChunk) {
  testing::TempDir dir;
  const fs::path path = dir.file("world.vxc");
  World w = base_world();
  save_scene(path, w, SceneInfo{"t", "conservative", 0, w.stats().voxels});
  const std::vector<uint8_t> base = bytes_of(path);
  // The oracle: the states after each edit, applied in memory.
  std::vector<Voxels> states{contents(w)};
  for (const Step& s : edit_steps(kCrashEdits)) {
    edit(w, s.brush, s.op, s.color);
    states.push_back(contents(w));
  }
  for (int i = 1; i <= kCrashEdits; ++i) ASSERT_NE(states[size_t(i)], states[size_t(i - 1)]);
  // The save steps of one whole run (counted in this process).
  int steps = 0;
  set_save_step_hook([&](const char*) { ++steps; });
  write_bytes(path, base, base.size());
  const auto t0 = std::chrono::steady_clock::now();
  crash_run(path, -1);
  const auto run_time = std::chrono::steady_clock::now() - t0;
  set_save_step_hook(nullptr);
  ASSERT_GT(steps, 4 * kCrashEdits);
  // Verifies what a crashed run left: exactly the state after the acked
  // edits, or after the one in flight; every chunk intact.
  size_t in_flight = 0;
  const auto check = [&](const CrashOutcome& o, const std::string& what) {
    OpenReport rep;
    World back(GridTransform::fit(Aabb{{0, 0, 0}, {1, 1, 1}}, 8));
    try {
      back = open_world(path, nullptr, &rep, true);
    } catch (const Error& e) {
      ADD_FAILURE() << what << ": the world does not open: " << e.what();
      return;
    }
    EXPECT_TRUE(rep.refused.empty()) << what << ": " << rep.refused.front().reason;
    const Voxels got = contents(back);
    const bool acked_state = got == states[size_t(o.acked)];
    const bool next_state = o.acked < kCrashEdits && got == states[size_t(o.acked + 1)];
    EXPECT_TRUE(acked_state || next_state)
        << what << ": " << o.acked << " edits acknowledged, the world holds neither that state "
        << "nor the next";
    in_flight += next_state;
    // Strict loading (load_scene) accepts what the crash left, too.
    EXPECT_NO_THROW((void)load_scene(path)) << what;
  };
  for (int k = 1; k <= steps; ++k) {
    const CrashOutcome o = crash_child(path, base, k, {});
    EXPECT_TRUE(o.killed) << "step " << k;
    check(o, "killed at save step " + std::to_string(k));
    if (HasFailure()) return;
  }
  // And by the parent at times spread over a run (not only at the steps).
  const auto span = std::chrono::duration_cast<std::chrono::microseconds>(run_time);
  for (int k = 1; k <= 12; ++k) {
    const CrashOutcome o = crash_child(path, base, 0, span * k / 12);
    check(o, "killed after " + std::to_string((span * k / 12).count()) + " us");
  }
  std::printf("%d save steps; %zu crashes left the edit in flight saved\n", steps, in_flight);
  // A run that completes holds every edit.
  const CrashOutcome full = crash_child(path, base, 0, {});
  EXPECT_FALSE(full.killed);
  EXPECT_EQ(full.acked, kCrashEdits);
  EXPECT_EQ(contents(open_world(path)), states.back());
}

TEST(BrickmapPersist, AJournalCutAtAnyByteReplaysTheTransactionsItHoldsWhole) {
  testing::TempDir dir;
  const fs::path path = dir.file("world.vxc");
  World w = base_world();
  save_scene(path, w, SceneInfo{"t", "conservative", 0, w.stats().voxels});
  std::vector<Voxels> states{contents(w)};
  std::vector<uint64_t> ends;  // journal size after each commit
  for (const Step& s : edit_steps(3)) {
    const EditResult r = edit(w, s.brush, s.op, s.color);
    ends.push_back(commit_edits(path, w, r.cells));
    states.push_back(contents(w));
  }
  const std::vector<uint8_t> journal = bytes_of(journal_path(path));
  ASSERT_EQ(journal.size(), ends.back());
  // Every length from the bare head (32 bytes, brickmap_file.hpp) on: a
  // sample of 200 lengths plus the lengths around each commit's end.
  constexpr size_t kHead = 32;
  std::vector<size_t> lengths;
  std::mt19937 rng(3);
  for (int k = 0; k < 200; ++k) lengths.push_back(kHead + rng() % (journal.size() - kHead + 1));
  for (uint64_t e : ends)
    for (int d = -41; d <= 1; d += (d < -38 || d > -3) ? 1 : 9)
      if (int64_t(e) + d >= int64_t(kHead) && uint64_t(int64_t(e) + d) <= journal.size())
        lengths.push_back(size_t(int64_t(e) + d));
  for (size_t n : lengths) {
    write_bytes(journal_path(path), journal, n);
    OpenReport rep;
    const World back = open_world(path, nullptr, &rep);
    const size_t whole =
        size_t(std::count_if(ends.begin(), ends.end(), [&](uint64_t e) { return e <= n; }));
    ASSERT_EQ(rep.transactions, whole) << "journal cut at " << n;
    ASSERT_EQ(contents(back), states[whole]) << "journal cut at " << n;
    EXPECT_EQ(rep.ignored_bytes, n - (whole ? ends[whole - 1] : kHead)) << n;
  }
  // The next commit cuts the torn tail off and appends after the last whole
  // transaction.
  write_bytes(journal_path(path), journal, size_t(ends[1] + 17));
  World resumed = open_world(path);
  ASSERT_EQ(contents(resumed), states[2]);
  const Step s = edit_steps(4)[3];
  const EditResult r = edit(resumed, s.brush, s.op, s.color);
  commit_edits(path, resumed, r.cells);
  OpenReport rep;
  EXPECT_EQ(contents(open_world(path, nullptr, &rep)), contents(resumed));
  EXPECT_EQ(rep.transactions, 3u);
  EXPECT_EQ(rep.ignored_bytes, 0u);
}

TEST(BrickmapPersist, ADamagedChunkIsRefusedWhileTheRestOfTheWorldLoads) {
  testing::TempDir dir;
  const fs::path path = dir.file("world.vxc");
  const World w = base_world();
  save_scene(path, w, SceneInfo{"t", "conservative", 0, w.stats().voxels});
  // Chunk 5's LZ4 block, located through the chunk table.
  const Container c = Container::read(path);
  const std::vector<uint8_t>& table = c.get(fourcc("BMCT"));
  const uint64_t chunk = 5;
  uint64_t offset;
  uint32_t zsize;
  std::memcpy(&offset, &table[8 + 24 * chunk], 8);
  std::memcpy(&zsize, &table[8 + 24 * chunk + 8], 4);
  ASSERT_GT(zsize, 0u);
  const uint64_t at =
      ContainerReader::open(path).section(fourcc("BMCK")).offset + offset + zsize / 2;
  std::vector<uint8_t> bytes = bytes_of(path);
  bytes[size_t(at)] ^= 0x5A;
  write_bytes(path, bytes, bytes.size());
  // Strict loading refuses the file ...
  EXPECT_THROW((void)load_scene(path), Error);
  EXPECT_THROW((void)open_world(path), Error);
  // ... a tolerant open refuses that chunk alone.
  OpenReport rep;
  const World back = open_world(path, nullptr, &rep, true);
  ASSERT_EQ(rep.refused.size(), 1u);
  EXPECT_EQ(rep.refused[0].chunk, chunk);
  EXPECT_NE(rep.refused[0].reason.find("checksum"), std::string::npos) << rep.refused[0].reason;
  // Every voxel outside chunk 5 (16^3 cells = 128^3 voxels, chunk (1,0,1))
  // loaded; none inside.
  Voxels want;
  for (const auto& v : contents(w)) {
    const MortonCoord p = morton_decode(std::get<0>(v));
    const bool in5 = p.x >= 128 && p.y < 128 && p.z >= 128;
    if (!in5) want.push_back(v);
  }
  ASSERT_LT(want.size(), contents(w).size());
  EXPECT_EQ(contents(back), want);
}

}  // namespace
}  // namespace voxcast
