// The .vxc container and ESVO scene files: round trip, and that every kind of
// damage (truncation, byte corruption, structurally bad contents behind a
// valid checksum, bad metadata) ends in a voxcast::Error, never a crash.
#include <gtest/gtest.h>
#include <unistd.h>
#include <xxhash.h>

#include <bit>
#include <cstring>
#include <fstream>
#include <random>

#include "support/esvo_testing.hpp"
#include "support/file_bytes.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/esvo_format.hpp"
#include "voxcast/scene_file.hpp"

namespace voxcast {
namespace {

using testing::error_of;
using testing::read_bytes;
using testing::write_bytes;

namespace fs = std::filesystem;
using esvo::EsvoOctree;

class SceneFile : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("voxcast_test_scene_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path path(const std::string& name) const { return dir_ / name; }
  fs::path dir_;
};

SceneInfo sample_info() {
  SceneInfo info;
  info.source = "bunny.obj";
  info.voxelization = "conservative";
  info.source_triangles = 69451;
  info.leaf_voxels = 60;
  return info;
}

/// A small but complete scene: one 8 KiB page of words plus META.
EsvoOctree small_octree() {
  VoxelSet v = testing::make_random_voxels(3, 60, 42);
  v.grid.origin = {-1.25f, 0.5f, 3.f};
  v.grid.voxel_size = 0.125;
  return esvo::build_octree(v);
}

void expect_same(const EsvoOctree& a, const EsvoOctree& b) {
  EXPECT_EQ(a.words, b.words);
  EXPECT_EQ(a.block_count, b.block_count);
  EXPECT_EQ(a.grid.origin.x, b.grid.origin.x);
  EXPECT_EQ(a.grid.origin.y, b.grid.origin.y);
  EXPECT_EQ(a.grid.origin.z, b.grid.origin.z);
  EXPECT_EQ(a.grid.voxel_size, b.grid.voxel_size);
  EXPECT_EQ(a.grid.resolution, b.grid.resolution);
  EXPECT_EQ(a.grid.levels, b.grid.levels);
}

/// Exercises everything a renderer does with an octree that validate()
/// accepted: full traversal, every attribute lookup, the statistics.
void use_everything(const EsvoOctree& o) {
  (void)esvo::decode_leaves(o);
  (void)o.level_stats();
  (void)o.memory_stats();
  std::vector<std::pair<uint32_t, int>> stack{{o.root_slot(), 0}};
  while (!stack.empty()) {
    const auto [slot, depth] = stack.back();
    stack.pop_back();
    const uint32_t w0 = o.slot_ptr(slot)[0];
    const uint32_t valid = esvo::layout::ValidMask::get(w0),
                   nl = valid & ~esvo::layout::LeafMask::get(w0);
    for (int i = 0; i < 8; ++i) {
      if (!(valid >> i & 1)) continue;
      Color c;
      Vec3 n;
      o.attributes(slot, i, &c, &n);
      ASSERT_TRUE(std::isfinite(c.r) && std::isfinite(n.x));
    }
    if (!nl || depth + 1 >= o.levels()) continue;
    uint32_t g = slot + esvo::layout::ChildPointer::get(w0);
    if (esvo::layout::FarBit::test(w0)) g = uint32_t(int64_t(slot) + int32_t(o.slot_ptr(g)[0]));
    for (int k = 0; k < std::popcount(nl); ++k) stack.push_back({g + uint32_t(k), depth + 1});
  }
}

TEST_F(SceneFile, RoundTrip) {
  const EsvoOctree o = small_octree();
  save_esvo_scene(path("a.vxc"), o, sample_info());
  SceneInfo info;
  const EsvoOctree back = load_esvo_scene(path("a.vxc"), &info);
  expect_same(o, back);
  EXPECT_EQ(info.source, "bunny.obj");
  EXPECT_EQ(info.voxelization, "conservative");
  EXPECT_EQ(info.source_triangles, 69451u);
  EXPECT_EQ(info.leaf_voxels, 60u);

  // Multi-block octrees survive too.
  const VoxelSet v = testing::make_random_voxels(6, 3000, 8);
  const EsvoOctree multi = esvo::build_octree(v, {64, 256});
  ASSERT_GT(multi.block_count, 1u);
  save_esvo_scene(path("b.vxc"), multi, sample_info());
  const EsvoOctree multi_back = load_esvo_scene(path("b.vxc"));
  expect_same(multi, multi_back);
  EXPECT_EQ(esvo::decode_leaves(multi_back), v.codes);
}

TEST_F(SceneFile, ContainerSections) {
  Container c;
  c.add(fourcc("ABCD"), {1, 2, 3});
  c.add(fourcc("EMPT"), {});
  c.add(fourcc("XYZW"), std::vector<uint8_t>(17, 9));
  const std::vector<uint8_t> bytes = c.serialize();
  EXPECT_EQ(bytes.size() % 8, 0u);
  const Container back = Container::parse(bytes.data(), bytes.size());
  EXPECT_EQ(back.section_ids(), c.section_ids());
  EXPECT_EQ(back.get(fourcc("ABCD")), (std::vector<uint8_t>{1, 2, 3}));
  EXPECT_TRUE(back.get(fourcc("EMPT")).empty());
  EXPECT_EQ(back.get(fourcc("XYZW")).size(), 17u);
  EXPECT_THROW(back.get(fourcc("NONE")), Error);
  // Duplicate section: copy directory entry 0 over entry 1 and recompute the
  // directory hash (header bytes 0..31, then the directory: container.hpp),
  // so only the duplicate id is wrong.
  std::vector<uint8_t> dup = bytes;
  uint64_t dir = 0, dir_bytes = 0;
  std::memcpy(&dir, &dup[16], 8);
  std::memcpy(&dir_bytes, &dup[24], 8);
  std::memcpy(&dup[size_t(dir) + 32], &dup[size_t(dir)], 32);
  XXH64_state_t* st = XXH64_createState();
  XXH64_reset(st, 0);
  XXH64_update(st, dup.data(), 32);
  XXH64_update(st, dup.data() + dir, size_t(dir_bytes));
  const uint64_t h = XXH64_digest(st);
  XXH64_freeState(st);
  std::memcpy(&dup[32], &h, 8);
  EXPECT_NE(error_of([&] { Container::parse(dup.data(), dup.size()); }).find("duplicate"),
            std::string::npos);
}

TEST_F(SceneFile, EveryTruncationIsRejected) {
  save_esvo_scene(path("a.vxc"), small_octree(), sample_info());
  const std::vector<uint8_t> bytes = read_bytes(path("a.vxc"));
  ASSERT_LT(bytes.size(), 16384u);  // small enough to try every length
  for (size_t len = 0; len < bytes.size(); ++len) {
    // In memory for every length, through a file for a sample.
    EXPECT_THROW(Container::parse(bytes.data(), len).get(fourcc("ESVO")), Error) << len;
    if (len % 97 == 0 || len + 64 > bytes.size() || len < 64) {
      write_bytes(path("t.vxc"), std::vector<uint8_t>(bytes.begin(), bytes.begin() + long(len)));
      EXPECT_THROW(load_esvo_scene(path("t.vxc")), Error) << len;
    }
  }
}

TEST_F(SceneFile, SingleByteCorruptionsAreRejected) {
  const EsvoOctree o = small_octree();
  save_esvo_scene(path("a.vxc"), o, sample_info());
  const std::vector<uint8_t> bytes = read_bytes(path("a.vxc"));
  std::mt19937_64 rng(2024);
  int rejected = 0, identical = 0;
  for (int trial = 0; trial < 2500; ++trial) {
    std::vector<uint8_t> bad = bytes;
    const size_t pos = rng() % bad.size();
    bad[pos] = uint8_t(bad[pos] ^ (1 + rng() % 255));  // always a different value
    try {
      // Through a real file for a sample, from memory for the rest (faster).
      EsvoOctree back;
      if (trial % 10 == 0) {
        write_bytes(path("c.vxc"), bad);
        back = load_esvo_scene(path("c.vxc"));
      } else {
        back = esvo_scene_from_container(Container::parse(bad.data(), bad.size()));
      }
      expect_same(o, back);  // only acceptable if nothing that matters changed
      ++identical;
    } catch (const Error& e) {
      ++rejected;
      EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos);
    }
  }
  // The container hashes or checks every byte, so nothing loads unchanged.
  EXPECT_EQ(identical, 0);
  EXPECT_EQ(rejected, 2500);
}

TEST_F(SceneFile, StructuralCorruptionBehindValidChecksum) {
  // Multi-block with tiny blocks: far pointers, several info sections and
  // attachments, page headers: every kind of word gets hit.
  const VoxelSet v = testing::make_random_voxels(5, 1500, 77);
  const EsvoOctree good = esvo::build_octree(v, {64, 256});
  ASSERT_GT(good.block_count, 2u);
  ASSERT_GT(good.memory_stats().far_pointer_bytes, 0u);
  // The words that are actually used (the tail of the last page is zero padding).
  size_t used = good.words.size();
  while (used > 0 && good.words[used - 1] == 0) --used;
  // Half of the edits aim at structure: descriptors, far pointers, page
  // headers, info sections and lookup entries (most other words are colors
  // and normals, whose corruption is harmless by design).
  std::vector<size_t> structure;
  for (size_t b = 0; b < good.words.size(); b += esvo::kPageWords) {
    structure.push_back(b);  // page header (or attachment/padding words)
    const uint32_t info = uint32_t(b + good.words[b]);
    if (b == 0 ||
        (info > b && info + 6 < good.words.size() && good.words[info] == esvo::kInfoMagic)) {
      for (size_t k = b; k < info && k < good.words.size(); k += 2) structure.push_back(k);
      for (size_t k = info; k < info + 8 + (info - b) / 2 && k < good.words.size(); ++k)
        structure.push_back(k);
    }
  }
  std::mt19937_64 rng(99);
  int rejected = 0, accepted = 0;
  for (int trial = 0; trial < 4000; ++trial) {
    EsvoOctree bad = good;
    const int edits = 1 + int(rng() % 3);
    for (int e = 0; e < edits; ++e) {
      const size_t wi = rng() % 2 ? structure[rng() % structure.size()] : rng() % used;
      switch (rng() % 4) {
        case 0:
          bad.words[wi] ^= 1u << (rng() % 32);
          break;  // bit flip
        case 1:
          bad.words[wi] = uint32_t(rng());
          break;  // random word
        case 2:
          bad.words[wi] += uint32_t(rng() % 5) - 2;
          break;  // off by a little
        case 3:
          bad.words[wi] ^=
              esvo::layout::ChildPointer::put(uint32_t(rng() % esvo::layout::ChildPointer::max));
          break;  // child pointer field
      }
    }
    if (trial % 20 == 0) {  // through a real file with a recomputed checksum
      save_esvo_scene(path("s.vxc"), bad, sample_info());
      try {
        const EsvoOctree back = load_esvo_scene(path("s.vxc"));
        use_everything(back);
        ++accepted;
      } catch (const Error&) {
        ++rejected;
      }
      continue;
    }
    try {
      bad.validate();
      use_everything(bad);
      ++accepted;
    } catch (const Error& e) {
      ++rejected;
      EXPECT_EQ(std::string(e.what()).rfind("corrupt scene:", 0), 0u) << e.what();
    }
  }
  // Both outcomes must occur (e.g. color bits are harmless, pointers are not).
  EXPECT_GT(rejected, 500);
  EXPECT_GT(accepted, 100);
}

TEST_F(SceneFile, BadMetadataIsRejected) {
  const EsvoOctree o = small_octree();
  save_esvo_scene(path("a.vxc"), o, sample_info());
  const std::vector<uint8_t> bytes = read_bytes(path("a.vxc"));
  const Container good = Container::parse(bytes.data(), bytes.size());
  const std::string meta(good.get(fourcc("META")).begin(), good.get(fourcc("META")).end());
  const auto with_meta = [&](const std::string& text) {
    Container c = good;
    c.add(fourcc("META"), std::vector<uint8_t>(text.begin(), text.end()));
    c.write(path("m.vxc"));
    return error_of([&] { load_esvo_scene(path("m.vxc")); });
  };
  const auto replaced = [&](const std::string& from, const std::string& to) {
    std::string m = meta;
    const size_t at = m.find(from);
    EXPECT_NE(at, std::string::npos) << from;
    return m.replace(at, from.size(), to);
  };
  EXPECT_EQ(with_meta(meta), "<no error>");
  // (voxel_size 1e300 and 1e38 are finite, but the world cube is not in
  // float, so no camera could frame it, and 1e-300 collapses it to a point:
  // refused, or info would accept what render refuses.)
  for (const std::string& m : {std::string("{"),
                               std::string("[]"),
                               std::string("not json"),
                               std::string(""),
                               replaced("\"levels\": 3", "\"levels\": 0"),
                               replaced("\"levels\": 3", "\"levels\": 21"),
                               replaced("\"levels\": 3", "\"levels\": \"3\""),
                               replaced("\"levels\": 3", "\"levels\": -3"),
                               replaced("\"levels\": 3", "\"levels\": 4"),
                               replaced("\"resolution\": 8", "\"resolution\": 9"),
                               replaced("\"voxel_size\": 0.125", "\"voxel_size\": -0.125"),
                               replaced("\"voxel_size\": 0.125", "\"voxel_size\": 0"),
                               replaced("\"voxel_size\": 0.125", "\"voxel_size\": 1e400"),
                               replaced("\"voxel_size\": 0.125", "\"voxel_size\": 1e300"),
                               replaced("\"voxel_size\": 0.125", "\"voxel_size\": 1e38"),
                               replaced("\"voxel_size\": 0.125", "\"voxel_size\": 1e-300"),
                               replaced("\"format\": \"esvo\"", "\"format\": \"dag\""),
                               replaced("\"block_count\": 1", "\"block_count\": 0"),
                               replaced("\"block_count\": 1", "\"block_count\": 2"),
                               replaced("\"source\": \"bunny.obj\"", "\"source\": 5"),
                               replaced("\"source_triangles\": 69451", "\"source_triangles\": 1.5"),
                               replaced("-1.25", "1e39"),
                               replaced("-1.25", "\"x\"")}) {
    const std::string err = with_meta(m);
    EXPECT_NE(err, "<no error>") << m;
    EXPECT_EQ(err.find('\n'), std::string::npos) << err;
  }
  // ESVO section of a bad size.
  Container c = good;
  c.add(fourcc("ESVO"), std::vector<uint8_t>(100, 0));
  c.write(path("e.vxc"));
  EXPECT_THROW(load_esvo_scene(path("e.vxc")), Error);
  Container no_esvo;
  no_esvo.add(fourcc("META"), good.get(fourcc("META")));
  no_esvo.write(path("n.vxc"));
  EXPECT_NE(error_of([&] { load_esvo_scene(path("n.vxc")); }).find("ESVO"), std::string::npos);
}

TEST_F(SceneFile, FileSystemErrors) {
  EXPECT_NE(error_of([&] { load_esvo_scene(path("missing.vxc")); }).find("no such file"),
            std::string::npos);
  write_bytes(path("empty.vxc"), {});
  EXPECT_NE(error_of([&] { load_esvo_scene(path("empty.vxc")); }).find("too short"),
            std::string::npos);
  fs::create_directories(path("dir.vxc"));
  EXPECT_NE(error_of([&] { load_esvo_scene(path("dir.vxc")); }).find("directory"),
            std::string::npos);
  write_bytes(path("text.vxc"), {'h', 'e', 'l', 'l', 'o', ' ', 'w', 'o', 'r', 'l', 'd', '!', '!',
                                 '!', '!', '!', '!'});
  EXPECT_NE(error_of([&] { load_esvo_scene(path("text.vxc")); }).find("bad magic"),
            std::string::npos);

  save_esvo_scene(path("a.vxc"), small_octree(), sample_info());
  std::vector<uint8_t> bytes = read_bytes(path("a.vxc"));
  bytes[8] = uint8_t(kSceneFormatVersion + 1);
  write_bytes(path("new.vxc"), bytes);
  EXPECT_EQ(error_of([&] { load_esvo_scene(path("new.vxc")); }),
            "scene file version " + std::to_string(kSceneFormatVersion + 1) +
                " is newer than this voxcast (" + std::to_string(kSceneFormatVersion) + ")");
  // Checksum message names the section.
  bytes = read_bytes(path("a.vxc"));
  bytes[bytes.size() - 4000] ^= 0x40;  // inside the ESVO words (the last section)
  write_bytes(path("sum.vxc"), bytes);
  EXPECT_EQ(error_of([&] { load_esvo_scene(path("sum.vxc")); }),
            "corrupt scene: checksum mismatch in section ESVO");
}

}  // namespace
}  // namespace voxcast
