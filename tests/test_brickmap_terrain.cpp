// Procedural brickmap terrain (include/voxcast/brickmap_terrain.hpp, issue 11
// item 7): the voxels, colors and normals written chunk by chunk equal a
// brute-force evaluation of the density function voxel by voxel; the bytes
// are the same on 1, 2 and 3 threads; the world loads, renders and streams;
// the generator's memory does not grow with the world (only its brickgrid
// header does); the CLI writes it and refuses bad sizes with one line.
// DXT1 colors of the render-side pool (brickmap.hpp, §3.1.3): blocks within
// their error bounds; a streamed terrain with DXT1 colors has the same hits,
// depths and normals as with raw colors and close colors. Snowfall (§5.5)
// lands only on the open tops of the columns, piles up, and persists
// through the CLI's journal.
#include <gtest/gtest.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <nlohmann/json.hpp>
#include <random>
#include <set>
#include <string>
#include <tuple>
#include <vector>

#include "support/brickmap_testing.hpp"
#include "support/cli_runner.hpp"
#include "support/esvo_testing.hpp"
#include "support/file_bytes.hpp"
#include "voxcast/brickmap.hpp"
#include "voxcast/brickmap_file.hpp"
#include "voxcast/brickmap_live.hpp"
#include "voxcast/brickmap_stream.hpp"
#include "voxcast/brickmap_terrain.hpp"
#include "voxcast/camera.hpp"
#include "voxcast/container.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/render.hpp"
#include "voxcast/scene_file.hpp"

namespace voxcast {
namespace {

using namespace brickmap;
namespace fs = std::filesystem;

TerrainOptions terrain(uint32_t x, uint32_t y, uint32_t z, uint64_t seed = 7, int threads = 2) {
  TerrainOptions o;
  o.size[0] = x, o.size[1] = y, o.size[2] = z;
  o.seed = seed;
  o.threads = threads;
  return o;
}

std::vector<uint8_t> bytes_of(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), {}};
}

TEST(BrickmapTerrain, VoxelsColorsAndNormalsEqualABruteForceEvaluationOfTheDensity) {
  testing::TempDir dir;
  const fs::path path = dir.file("t.vxc");
  // Not whole chunks in x and z (128 voxels), not whole bricks in y.
  const TerrainOptions o = terrain(150, 44, 136);
  const TerrainStats st = write_terrain(path, o);
  const World w = load_world(ContainerReader::open(path));
  // The oracle: terrain_solid voxel by voxel over the box and one voxel
  // around it, then the voxels with an empty 6-neighbour.
  const int X = 150, Y = 44, Z = 136;
  const auto at = [&](int x, int y, int z) {
    return (size_t(z + 1) * (Y + 2) + size_t(y + 1)) * (X + 2) + size_t(x + 1);
  };
  std::vector<uint8_t> solid(size_t(X + 2) * (Y + 2) * (Z + 2));
  for (int z = -1; z <= Z; ++z)
    for (int y = -1; y <= Y; ++y)
      for (int x = -1; x <= X; ++x) solid[at(x, y, z)] = terrain_solid(o, x, y, z);
  std::vector<uint64_t> want;
  uint64_t solid_count = 0, under_something = 0;
  for (int z = 0; z < Z; ++z)
    for (int x = 0; x < X; ++x) {
      bool roof = false;  // a solid voxel above this one in the column
      for (int y = Y - 1; y >= 0; --y) {
        if (!solid[at(x, y, z)]) {
          under_something += roof;
          continue;
        }
        roof = true;
        ++solid_count;
        if (solid[at(x - 1, y, z)] && solid[at(x + 1, y, z)] && solid[at(x, y - 1, z)] &&
            solid[at(x, y + 1, z)] && solid[at(x, y, z - 1)] && solid[at(x, y, z + 1)])
          continue;
        want.push_back(morton_encode(uint32_t(x), uint32_t(y), uint32_t(z)));
      }
    }
  std::sort(want.begin(), want.end());
  EXPECT_GT(under_something, 100u) << "overhangs and caves: empty voxels below solid ones";
  EXPECT_LT(want.size() * 2, solid_count) << "the hidden voxels are not stored";
  const std::vector<uint64_t> got = w.decode_voxels();
  ASSERT_EQ(got.size(), want.size());
  EXPECT_TRUE(got == want);
  EXPECT_EQ(st.voxels, want.size());
  EXPECT_EQ(st.bricks, w.stats().bricks);
  // Colors and normals: every 7th voxel against the functions.
  size_t checked = 0, mismatched = 0;
  for (size_t i = 0; i < want.size(); i += 7) {
    const MortonCoord c = morton_decode(want[i]);
    const uint32_t cell = w.cell(w.cell_index(c.x >> 3, c.y >> 3, c.z >> 3));
    ASSERT_EQ(cell_state(cell), kStateResident);
    const Brick& b = w.brick(cell_brick(cell));
    const uint32_t k = b.color + uint32_t(rank_below(b, voxel_bit(c.x & 7, c.y & 7, c.z & 7)));
    ++checked;
    mismatched += w.colors()[k] != terrain_color(o, c.x, c.y, c.z) ||
                  w.normals()[k] != terrain_normal(o, c.x, c.y, c.z);
  }
  EXPECT_GT(checked, 1000u);
  EXPECT_EQ(mismatched, 0u);
  // More than one material on the tops.
  std::vector<uint32_t> colors;
  for (size_t i = 0; i < want.size(); i += 97) {
    const MortonCoord c = morton_decode(want[i]);
    colors.push_back(terrain_color(o, c.x, c.y, c.z) & 0xC0C0C0);
  }
  std::sort(colors.begin(), colors.end());
  EXPECT_GE(std::unique(colors.begin(), colors.end()) - colors.begin(), 3);
}

TEST(BrickmapTerrain, SameBytesOnOneTwoAndThreeThreads) {
  testing::TempDir dir;
  std::vector<uint8_t> first;
  for (const char* name : {"1", "2", "3"}) {
    const int threads = name[0] - '0';
    const fs::path p = dir.file(std::string(name) + ".vxc");
    write_terrain(p, terrain(300, 64, 260, 3, threads));
    const std::vector<uint8_t> b = bytes_of(p);
    ASSERT_GT(b.size(), 10000u);
    if (first.empty())
      first = b;
    else
      EXPECT_TRUE(b == first) << threads << " threads";
  }
  // Another seed, another world.
  write_terrain(dir.file("s.vxc"), terrain(300, 64, 260, 4, 2));
  EXPECT_FALSE(bytes_of(dir.file("s.vxc")) == first);
}

TEST(BrickmapTerrain, TheWorldLoadsRendersAndStreamsToTheSameImage) {
  testing::TempDir dir;
  const fs::path path = dir.file("t.vxc");
  write_terrain(path, terrain(256, 96, 256));
  const LoadedScene scene = load_scene(path);
  const auto world = std::make_shared<World>(load_world(ContainerReader::open(path)));
  const BrickmapStructure in_ram(world);
  RenderOptions o;
  o.width = 96, o.height = 64;
  o.camera = Camera::orbit(world->occupied_bounds(), o.width, o.height, 35.f, 30.f);
  const RenderResult want = render(in_ram, o);
  EXPECT_GT(want.hits, uint64_t(o.width * o.height / 4));
  EXPECT_EQ(render(*scene.structure, o).color.pixels, want.color.pixels);
  StreamOptions so;
  so.budget_bytes = 8u << 20;
  so.uploads_per_pass = 64;
  StreamingWorld s(path, so);
  RenderResult last;
  int frames = 0;
  for (; frames < 400; ++frames) {
    o.frame = uint32_t(frames);
    const uint64_t before = s.stats().uploaded;
    last = render(s, o);
    if (frames > 0 && s.stats().uploaded == before) break;
  }
  EXPECT_GT(frames, 2);
  EXPECT_EQ(last.color.pixels, want.color.pixels);
}

// Peak resident memory of a child process writing the terrain (KiB).
long child_peak_kib(const fs::path& path, const TerrainOptions& o, TerrainStats* st) {
  int fd[2];
  if (pipe(fd) != 0) return -1;
  const pid_t pid = fork();
  if (pid == 0) {
    close(fd[0]);
    TerrainStats s = write_terrain(path, o);
    const ssize_t n = write(fd[1], &s, sizeof s);
    _exit(n == ssize_t(sizeof s) ? 0 : 1);
  }
  close(fd[1]);
  const ssize_t n = read(fd[0], st, sizeof *st);
  close(fd[0]);
  int status = 0;
  rusage ru{};
  wait4(pid, &status, 0, &ru);
  if (n != ssize_t(sizeof *st) || !WIFEXITED(status) || WEXITSTATUS(status) != 0) return -1;
  return ru.ru_maxrss;
}

TEST(BrickmapTerrain, GeneratorMemoryDoesNotGrowWithTheWorldButItsHeader) {
  testing::TempDir dir;
  TerrainStats small, big;
  const long a = child_peak_kib(dir.file("a.vxc"), terrain(512, 128, 512, 5, 2), &small);
  const long b = child_peak_kib(dir.file("b.vxc"), terrain(1536, 128, 1536, 5, 2), &big);
  ASSERT_GT(a, 0);
  ASSERT_GT(b, 0);
  // 9x the area: the chunks' raw bytes (what a world in RAM holds) grow by
  // tens of MB, the generator by the brickgrid header only (4 B per cell)
  // plus slack.
  const double grown = double(b - a) * 1024, header = 4.0 * double(big.header_cells);
  const double raw_grown = double(big.raw_bytes - small.raw_bytes);
  std::printf("peak RSS %.1f MiB -> %.1f MiB; raw chunk bytes %.1f MiB -> %.1f MiB\n", a / 1024.0,
              b / 1024.0, double(small.raw_bytes) / 1048576.0, double(big.raw_bytes) / 1048576.0);
  EXPECT_GT(raw_grown, 30e6);
  EXPECT_LT(grown, header + 8e6);
  EXPECT_LT(grown * 3, raw_grown);
}

TEST(BrickmapTerrain, BadBrickgridDimsAreRefusedWithOneLine) {
  testing::TempDir dir;
  const fs::path path = dir.file("t.vxc");
  write_terrain(path, terrain(128, 40, 128));  // brickgrid 16 x 5 x 16
  const Container good = Container::read(path);
  EXPECT_EQ(load_world(good).dims()[1], 5u);
  const std::string meta(good.get(fourcc("META")).begin(), good.get(fourcc("META")).end());
  const size_t at = meta.find("\"dims\"");
  ASSERT_NE(at, std::string::npos) << meta;
  const size_t end = meta.find(']', at);
  for (const char* dims :
       {"[16, 17, 16]", "[16, 0, 16]", "[16, 5, 8]", "[8, 5, 16]", "[16, 4, 16]"}) {
    Container bad = good;
    const std::string m = meta.substr(0, at) + "\"dims\": " + dims + meta.substr(end + 1);
    bad.add(fourcc("META"), std::vector<uint8_t>(m.begin(), m.end()));
    try {
      load_world(bad);
      ADD_FAILURE() << dims << " was accepted";
    } catch (const Error& e) {
      EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("corrupt scene"), std::string::npos) << e.what();
    }
  }
}

TEST(BrickmapTerrain, CliWritesAWorldAndRefusesBadSizes) {
  testing::TempDir dir;
  const std::string out = dir.file("w.vxc");
  const testing::CliResult g =
      testing::run_cli("generate terrain --size 160x144x48 --seed 2 -q -o '" + out + "'");
  ASSERT_EQ(g.exit_code, 0) << g.output;
  EXPECT_NE(g.output.find("brickmap terrain 160x144x48"), std::string::npos) << g.output;
  TerrainOptions o = terrain(160, 48, 144, 2);
  write_terrain(dir.file("lib.vxc"), o);
  EXPECT_TRUE(bytes_of(out) == bytes_of(dir.file("lib.vxc")))
      << "the CLI writes what the library does";
  const testing::CliResult i = testing::run_cli("info '" + out + "'");
  ASSERT_EQ(i.exit_code, 0) << i.output;
  EXPECT_NE(i.output.find("brickgrid 32x6x32"), std::string::npos) << i.output;
  for (const char* bad : {"8x8x8", "100x100", "100x100x0", "70000x64x64", "axbxc"}) {
    const testing::CliResult r = testing::run_cli_split(std::string("generate terrain --size ") +
                                                        bad + " -o '" + dir.file("bad.vxc") + "'");
    EXPECT_NE(r.exit_code, 0) << bad;
    EXPECT_EQ(std::count(r.errors.begin(), r.errors.end(), '\n'), 1) << bad << ": " << r.errors;
    EXPECT_FALSE(fs::exists(dir.file("bad.vxc")));
  }
  // A mesh still comes out for .obj.
  const testing::CliResult m =
      testing::run_cli("generate terrain --size 33 -q -o '" + dir.file("t.obj") + "'");
  ASSERT_EQ(m.exit_code, 0) << m.output;
  EXPECT_TRUE(fs::exists(dir.file("t.obj")));
}

// Per-channel |a - b| of two ABGR8 colors, the largest.
int channel_error(uint32_t a, uint32_t b) {
  int e = 0;
  for (int s = 0; s < 24; s += 8) e = std::max(e, std::abs(int(a >> s & 255) - int(b >> s & 255)));
  return e;
}

TEST(BrickmapDxt1, BlocksStayWithinTheirErrorBounds) {
  std::mt19937 rng(11);
  const auto color = [&] { return uint32_t(rng()) & 0xFFFFFF; };
  double dxt_err2 = 0, mean_err2 = 0;
  for (int trial = 0; trial < 2000; ++trial) {
    const int count = 1 + int(rng() % 16);
    uint32_t c[16];
    const int kind = trial % 4;
    const uint32_t a = color(), b = color();
    for (int i = 0; i < count; ++i) {
      if (kind == 0) {
        c[i] = a;  // one color
      } else if (kind == 1) {
        c[i] = (rng() & 1) ? a : b;  // two colors
      } else if (kind == 2) {
        // A gradient between a and b.
        const int t = int(rng() % 256);
        uint32_t v = 0;
        for (int s = 0; s < 24; s += 8)
          v |= uint32_t(((int(a >> s & 255) * (255 - t) + int(b >> s & 255) * t) / 255)) << s;
        c[i] = v;
      } else {
        c[i] = color();
      }
      c[i] |= 0xFF000000u;
    }
    const uint64_t block = dxt1_encode(c, count);
    int lo[3] = {255, 255, 255}, hi[3] = {0, 0, 0};
    double mean[3] = {0, 0, 0};
    for (int i = 0; i < count; ++i)
      for (int k = 0; k < 3; ++k) {
        const int v = int(c[i] >> (8 * k) & 255);
        lo[k] = std::min(lo[k], v), hi[k] = std::max(hi[k], v), mean[k] += v / double(count);
      }
    for (int i = 0; i < count; ++i) {
      const uint32_t d = dxt1_decode(block, i);
      ASSERT_EQ(d >> 24, 255u);
      // Quantization to 5/6/5 bits moves a channel by at most 4.
      if (kind <= 1) {
        ASSERT_LE(channel_error(d, c[i]), 4) << "trial " << trial;
      }
      int range = 0;
      for (int k = 0; k < 3; ++k) {
        const int v = int(d >> (8 * k) & 255);
        ASSERT_GE(v, lo[k] - 4) << "trial " << trial;
        ASSERT_LE(v, hi[k] + 4) << "trial " << trial;
        range = std::max(range, hi[k] - lo[k]);
        const double e = v - double(c[i] >> (8 * k) & 255),
                     m = mean[k] - double(c[i] >> (8 * k) & 255);
        dxt_err2 += e * e, mean_err2 += m * m;
      }
      // On a line the palette's 4 points are at most a sixth of the range apart from any color.
      if (kind == 2) {
        ASSERT_LE(channel_error(d, c[i]), range / 6 + 5) << "trial " << trial;
      }
    }
  }
  EXPECT_LT(dxt_err2, 0.5 * mean_err2) << "4 palette colors beat the block's mean color";
}

TEST(BrickmapDxt1, StreamedTerrainKeepsItsHitsDepthsAndNormalsWithCloseColors) {
  testing::TempDir dir;
  const fs::path path = dir.file("t.vxc");
  write_terrain(path, terrain(256, 96, 256));
  RenderOptions o;
  o.width = 128, o.height = 96;
  o.want_depth = true;
  o.want_normal = true;
  o.max_passes = 1000;  // until nothing is asked for
  o.lod_pixels = 0;     // every hit a voxel (its color from the pool)
  RenderResult r[2];
  uint64_t color_bytes[2], resident[2];
  for (int dxt = 0; dxt < 2; ++dxt) {
    StreamOptions so;
    so.budget_bytes = 64u << 20;
    so.dxt1 = dxt == 1;
    StreamingWorld s(path, so);
    o.camera = Camera::orbit(s.world().occupied_bounds(), o.width, o.height, 35.f, 30.f);
    r[dxt] = render(s, o);
    color_bytes[dxt] = s.world().stats().color_bytes;
    resident[dxt] = s.stats().resident_bytes;
    EXPECT_EQ(s.world().dxt1(), dxt == 1);
  }
  EXPECT_GT(r[0].hits, uint64_t(o.width * o.height / 4));
  EXPECT_EQ(r[1].hits, r[0].hits);
  EXPECT_EQ(r[1].depth.pixels, r[0].depth.pixels);
  EXPECT_EQ(r[1].normal.pixels, r[0].normal.pixels);
  double sum = 0, worst = 0;
  for (size_t i = 0; i < r[0].color.pixels.size(); ++i) {
    const double d = std::fabs(double(r[1].color.pixels[i]) - double(r[0].color.pixels[i]));
    sum += d, worst = std::max(worst, d);
  }
  const double mean = sum / double(r[0].color.pixels.size());
  std::printf("DXT1 vs raw: mean |linear difference| %.5f, largest %.4f; colors %llu vs %llu B\n",
              mean, worst, (unsigned long long)color_bytes[1], (unsigned long long)color_bytes[0]);
  EXPECT_GT(sum, 0) << "DXT1 is lossy on varied colors";
  EXPECT_LT(mean, 0.01);
  EXPECT_LT(worst, 0.25);
  EXPECT_EQ(color_bytes[1] * 8, color_bytes[0]);
  EXPECT_LT(resident[1], resident[0]);
}

// Highest solid voxel per column (x, z) of a set of Morton codes.
std::map<std::pair<uint32_t, uint32_t>, uint32_t> column_tops(const std::vector<uint64_t>& codes) {
  std::map<std::pair<uint32_t, uint32_t>, uint32_t> top;
  for (uint64_t c : codes) {
    const MortonCoord m = morton_decode(c);
    auto [it, fresh] = top.try_emplace({m.x, m.z}, m.y);
    if (!fresh) it->second = std::max(it->second, m.y);
  }
  return top;
}

TEST(BrickmapSnow, SnowLandsOnlyOnTheOpenTopsAndPilesUp) {
  testing::TempDir dir;
  const fs::path path = dir.file("t.vxc");
  write_terrain(path, terrain(160, 64, 144, 9));
  const World start = load_world(ContainerReader::open(path));
  const std::vector<uint64_t> before = start.decode_voxels();
  const auto tops = column_tops(before);
  // Rate 1: every column grows by one voxel per step.
  {
    World w = start;
    SnowOptions o;
    o.rate = 1;
    for (uint32_t s = 0; s < 3; ++s) EXPECT_GT(snow_step(w, s, o).voxels, 0u);
    std::set<uint64_t> want(before.begin(), before.end());
    for (const auto& [xz, y] : tops)
      for (uint32_t s = 1; s <= 3; ++s)
        if (y + s < 64) want.insert(morton_encode(xz.first, y + s, xz.second));
    const std::vector<uint64_t> got = w.decode_voxels();
    EXPECT_TRUE(got == std::vector<uint64_t>(want.begin(), want.end()));
  }
  // Rate 0.5: about half the columns per step; every snow voxel rests on a
  // solid one and has nothing above it; nothing else changed.
  World w = start;
  uint64_t added = 0;
  for (uint32_t s = 0; s < 4; ++s) added += snow_step(w, s).voxels;
  const std::vector<uint64_t> after = w.decode_voxels();
  std::vector<uint64_t> snow;
  std::set_difference(after.begin(), after.end(), before.begin(), before.end(),
                      std::back_inserter(snow));
  EXPECT_TRUE(std::includes(after.begin(), after.end(), before.begin(), before.end()));
  EXPECT_EQ(snow.size(), added);
  EXPECT_GT(double(added), 0.35 * 4 * double(tops.size()));
  EXPECT_LT(double(added), 0.65 * 4 * double(tops.size()));
  const auto after_tops = column_tops(after);
  const std::set<uint64_t> solid(after.begin(), after.end());
  for (uint64_t c : snow) {
    const MortonCoord m = morton_decode(c);
    ASSERT_TRUE(solid.count(morton_encode(m.x, m.y - 1, m.z))) << "snow rests on something";
    ASSERT_EQ(after_tops.at({m.x, m.z}) >= m.y, true);
    ASSERT_GT(m.y, tops.at({m.x, m.z})) << "no snow under an overhang or in a cave";
  }
  // Its color and +y normal.
  const MortonCoord m = morton_decode(snow.front());
  const uint32_t cell = w.cell(w.cell_index(m.x >> 3, m.y >> 3, m.z >> 3));
  const Brick& b = w.brick(cell_brick(cell));
  const uint32_t k = b.color + uint32_t(rank_below(b, voxel_bit(m.x & 7, m.y & 7, m.z & 7)));
  EXPECT_EQ(w.colors()[k], esvo::encode_color_abgr(SnowOptions{}.color));
  EXPECT_EQ(w.normals()[k], esvo::encode_normal_cube({0, 1, 0}));
  EXPECT_THROW(snow_step(w, 0, SnowOptions{1, 1.5}), Error);
}

TEST(BrickmapSnow, CliSnowfallPersistsAfterReload) {
  testing::TempDir dir;
  const std::string path = dir.file("w.vxc");
  write_terrain(path, terrain(128, 48, 128, 4));
  World want = load_world(ContainerReader::open(path));
  SnowOptions o;
  o.rate = 0.3;
  for (uint32_t s = 0; s < 3; ++s) snow_step(want, s, o);
  const testing::CliResult r = testing::run_cli("edit '" + path + "' --snow 3 --snow-rate 0.3 -q");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_TRUE(fs::exists(path + ".journal"));
  const World got = open_world(path);
  EXPECT_TRUE(got.decode_voxels() == want.decode_voxels());
  EXPECT_EQ(got.stats().voxels, want.stats().voxels);
  // The same steps on LiveWorld's worker while frames render.
  const std::string live = dir.file("live.vxc");
  write_terrain(live, terrain(128, 48, 128, 4));
  const testing::CliResult l =
      testing::run_cli("edit '" + live + "' --snow 3 --snow-rate 0.3 --render '" +
                       dir.file("f.png") + "' --render-size 64x48");
  ASSERT_EQ(l.exit_code, 0) << l.output;
  EXPECT_NE(l.output.find("3 of 3 snow steps visible"), std::string::npos) << l.output;
  EXPECT_TRUE(fs::exists(dir.file("f.png")));
  EXPECT_TRUE(open_world(live).decode_voxels() == want.decode_voxels());
  const testing::CliResult bad = testing::run_cli_split("edit '" + path + "' --snow 2 --remove");
  EXPECT_NE(bad.exit_code, 0);
  EXPECT_EQ(std::count(bad.errors.begin(), bad.errors.end(), '\n'), 1) << bad.errors;
}

TEST(BrickmapSnow, FramesRenderedWhileTheWorkerSnowsShowWholeStepsInOrder) {
  testing::TempDir dir;
  const fs::path path = dir.file("t.vxc");
  write_terrain(path, terrain(128, 64, 128, 6));
  const World start = load_world(ContainerReader::open(path));
  RenderOptions o;
  o.width = 64, o.height = 48;
  o.lod_pixels = 0;
  o.camera = Camera::orbit(start.occupied_bounds(), o.width, o.height, 30.f, 40.f);
  constexpr uint32_t kSteps = 6;
  // The oracle: the image after each number of steps, applied directly.
  std::vector<std::vector<float>> states;
  {
    auto w = std::make_shared<World>(start);
    states.push_back(render(BrickmapStructure(w), o).color.pixels);
    for (uint32_t s = 0; s < kSteps; ++s) {
      snow_step(*w, s);
      states.push_back(render(BrickmapStructure(w), o).color.pixels);
    }
  }
  LiveWorld live(start);
  for (uint32_t s = 0; s < kSteps; ++s) live.submit_snow(s);
  size_t last = 0;
  for (uint32_t f = 0; live.applied() < kSteps && f < 100000; ++f) {
    o.frame = f;
    const RenderResult r = render(live, o);
    const size_t k = size_t(live.applied());
    ASSERT_GE(k, last);
    EXPECT_EQ(r.color.pixels, states[k]) << "frame " << f << " after " << k << " steps";
    last = k;
  }
  EXPECT_EQ(live.applied(), kSteps);
  EXPECT_EQ(render(live, o).color.pixels, states.back());
  EXPECT_NE(states.back(), states.front());
  EXPECT_GT(live.throughput().voxels, 1000u);
}

// A generated terrain keeps its exposed voxels only; removals carve into the
// hollow interior and must bring back the voxels they expose (edit.cpp,
// World::terrain). The oracle: the full solid set of the density function,
// edited voxel by voxel. After every edit, saved through the journal and
// reloaded (and after a checkpoint): the world's solid set (stored voxels
// plus the density's voxels not carved) is exactly the oracle's, every
// exposed voxel of the oracle is stored with the generator's color, and
// nothing outside the oracle is stored.
TEST(BrickmapTerrainRefill, EditsThenReloadGiveExactlyTheEditedSolidSet) {
  testing::TempDir dir;
  const fs::path path = dir.file("t.vxc");
  const TerrainOptions o = terrain(96, 64, 80, 11);
  write_terrain(path, o);
  World w = open_world(path);
  ASSERT_TRUE(w.terrain());
  const GridTransform& g = w.grid();
  const int N = int(g.resolution), Y = int(w.dims()[1]) * 8;
  const auto idx = [&](int x, int y, int z) { return (size_t(z) * size_t(Y) + size_t(y)) * N + x; };
  std::vector<uint8_t> oracle(size_t(N) * N * size_t(Y));
  for (int z = 0; z < N; ++z)
    for (int y = 0; y < Y; ++y)
      for (int x = 0; x < N; ++x) oracle[idx(x, y, z)] = terrain_solid(o, x, y, z);
  const auto oracle_at = [&](int x, int y, int z) {
    if (y < 0) return true;  // the ground goes on
    if (x < 0 || z < 0 || x >= N || z >= N || y >= Y) return false;
    return oracle[idx(x, y, z)] != 0;
  };
  const auto center = [&](int x, int y, int z) {
    return Vec3d{double(g.origin.x) + (double(x) + 0.5) * g.voxel_size,
                 double(g.origin.y) + (double(y) + 0.5) * g.voxel_size,
                 double(g.origin.z) + (double(z) + 0.5) * g.voxel_size};
  };
  const auto at_voxel = [&](double x, double y, double z) {
    return Vec3d{double(g.origin.x) + x * g.voxel_size, double(g.origin.y) + y * g.voxel_size,
                 double(g.origin.z) + z * g.voxel_size};
  };
  const auto surface = [&](int x, int z) {
    int y = Y - 1;
    while (y > 0 && !oracle_at(x, y, z)) --y;
    return y;
  };
  const double vs = g.voxel_size;
  struct Step {
    Brush brush;
    EditOp op;
  };
  // The highest columns of two areas: a hole there, a cavity deep below.
  const auto highest = [&](int x0, int x1, int z0, int z1) {
    std::array<int, 3> best{x0, 0, z0};
    for (int z = z0; z <= z1; ++z)
      for (int x = x0; x <= x1; ++x)
        if (surface(x, z) > best[1]) best = {x, surface(x, z), z};
    return best;
  };
  const std::array<int, 3> h1 = highest(28, 44, 28, 48), h2 = highest(56, 80, 16, 60);
  const int x1 = h1[0], s1 = h1[1], z1 = h1[2], x2 = h2[0], s2 = h2[1], z2 = h2[2];
  ASSERT_GT(s1, 12);
  ASSERT_GT(s2, 15) << x1 << "," << s1 << "," << z1 << " " << x2 << "," << z2;
  const std::vector<Step> steps = {
      // Into the surface and deep below it.
      {Brush::sphere(at_voxel(x1, s1, z1), 11 * vs), EditOp::Remove},
      // A cavity under the surface that touches no stored voxel.
      {Brush::sphere(at_voxel(x2, s2 - 10, z2), 4 * vs), EditOp::Remove},
      // A tunnel from the first hole into the interior, through the cavity's
      // column when it is in reach.
      {Brush::box(at_voxel(x1 + 4, s1 - 8, z1 - 2), at_voxel(x2 + 2, s1 - 5, z1 + 2)),
       EditOp::Remove},
      {Brush::box(at_voxel(x2 - 2, s2 - 13, std::min(z1, z2)),
                  at_voxel(x2 + 2, s2 - 8, std::max(z1, z2))),
       EditOp::Remove},
      // Solid voxels added in the first hole, then a removal through them
      // and the hole's wall.
      {Brush::sphere(at_voxel(x1, s1 - 4, z1), 5 * vs), EditOp::Add},
      {Brush::sphere(at_voxel(x1 - 4, s1 - 6, z1 + 4), 7 * vs), EditOp::Remove},
      {Brush::sphere(at_voxel(x1, s1, z1), 14 * vs), EditOp::Paint},
      // At the bottom of the grid (y = 0: the ground below stays solid).
      {Brush::box(at_voxel(10, -2, 10), at_voxel(16, 3, 16)), EditOp::Remove},
  };
  const uint32_t added = esvo::encode_color_abgr({0.9f, 0.1f, 0.1f, 1.f});
  const auto check = [&](const World& got, const std::string& what) {
    ASSERT_EQ(got.terrain(), w.terrain()) << what;
    uint64_t exposed = 0;
    for (int z = 0; z < N; ++z)
      for (int y = 0; y < Y; ++y)
        for (int x = 0; x < N; ++x) {
          const bool stored = got.voxel(uint32_t(x), uint32_t(y), uint32_t(z));
          const bool solid = stored || (!got.carved_voxel(uint32_t(x), uint32_t(y), uint32_t(z)) &&
                                        terrain_solid(o, x, y, z));
          const bool want = oracle_at(x, y, z);
          ASSERT_EQ(solid, want) << what << ": voxel " << x << "," << y << "," << z;
          const bool open = !oracle_at(x - 1, y, z) || !oracle_at(x + 1, y, z) ||
                            !oracle_at(x, y - 1, z) || !oracle_at(x, y + 1, z) ||
                            !oracle_at(x, y, z - 1) || !oracle_at(x, y, z + 1);
          if (want && open) {
            ++exposed;
            ASSERT_TRUE(stored) << what << ": exposed voxel " << x << "," << y << "," << z
                                << " is not stored (a hole into the hollow interior)";
          }
        }
    EXPECT_GT(exposed, 1000u) << what;
  };
  std::vector<std::tuple<int, int, int>> refilled;  // stored now, hidden at generation
  for (size_t i = 0; i < steps.size(); ++i) {
    const Step& st = steps[i];
    // The oracle, voxel by voxel.
    for (int z = 0; z < N; ++z)
      for (int y = 0; y < Y; ++y)
        for (int x = 0; x < N; ++x)
          if (st.brush.contains(center(x, y, z)) && st.op != EditOp::Paint)
            oracle[idx(x, y, z)] = st.op == EditOp::Add;
    const World before = w;
    const EditResult r = edit(w, st.brush, st.op, Color{0.9f, 0.1f, 0.1f, 1.f});
    ASSERT_FALSE(r.cells.empty()) << "step " << i;
    commit_edits(path, w, r.cells);
    check(w, "step " + std::to_string(i) + " in memory");
    check(open_world(path), "step " + std::to_string(i) + " reloaded");
    if (st.op == EditOp::Remove)
      for (int z = 0; z < N; ++z)
        for (int y = 0; y < Y; ++y)
          for (int x = 0; x < N; ++x)
            if (w.voxel(uint32_t(x), uint32_t(y), uint32_t(z)) &&
                !before.voxel(uint32_t(x), uint32_t(y), uint32_t(z)))
              refilled.emplace_back(x, y, z);
  }
  // The voxels brought back carry the generator's color (unless painted or added).
  ASSERT_GT(refilled.size(), 500u);
  size_t own = 0;
  const testing::BrickmapVoxels stored = testing::brickmap_contents(w);
  std::map<uint64_t, uint32_t> color;
  for (const auto& [code, c, n] : stored) color[code] = c;
  for (const auto& [x, y, z] : refilled) {
    const auto it = color.find(morton_encode(uint32_t(x), uint32_t(y), uint32_t(z)));
    if (it == color.end()) continue;  // removed again by a later step
    const uint32_t c = it->second;
    if (c == added) continue;
    EXPECT_EQ(c, terrain_color(o, x, y, z)) << x << "," << y << "," << z;
    ++own;
  }
  EXPECT_GT(own, 500u);
  // Folded into the scene file: the terrain and the carved voxels stay.
  checkpoint_world(path, w, SceneInfo{"terrain", "", 0, w.stats().voxels});
  EXPECT_FALSE(fs::exists(journal_path(path)));
  check(load_world(ContainerReader::open(path)), "after the checkpoint");
  // A damaged carved-voxel section or a terrain that does not match the grid
  // refuses the world with one line.
  const Container saved = Container::read(path);
  ASSERT_TRUE(saved.has(fourcc("BMCV")));
  const auto refused = [&](uint32_t id, std::vector<uint8_t> bytes, const std::string& why) {
    Container c;
    for (uint32_t s : saved.section_ids()) c.add(s, s == id ? bytes : saved.get(s));
    const std::string e = testing::error_of([&] { (void)load_world(c); });
    EXPECT_NE(e.find(why), std::string::npos) << e;
    EXPECT_EQ(e.find('\n'), std::string::npos) << e;
  };
  std::vector<uint8_t> cv = saved.get(fourcc("BMCV"));
  refused(fourcc("BMCV"), std::vector<uint8_t>(cv.begin(), cv.end() - 1), "BMCV");
  cv[15] ^= 0x80;  // the first cell index, far out of range
  refused(fourcc("BMCV"), cv, "BMCV");
  const std::vector<uint8_t>& meta = saved.get(fourcc("META"));
  nlohmann::json j = nlohmann::json::parse(meta.begin(), meta.end());
  ASSERT_EQ(j["terrain"]["seed"], 11u) << j.dump();
  j["terrain"]["size"][1] = 72;  // another brickgrid height
  const std::string bigger = j.dump();
  refused(fourcc("META"), std::vector<uint8_t>(bigger.begin(), bigger.end()),
          "'terrain' does not match the grid");
  // The CLI edits the same way: one removal on a fresh copy.
  const fs::path cli = dir.file("cli.vxc");
  write_terrain(cli, o);
  World lib = open_world(cli);
  // (The CLI reads the center as floats: the same floats here.)
  const Vec3d a = at_voxel(x1, s1, z1);
  const Vec3d c{double(float(a.x)), double(float(a.y)), double(float(a.z))};
  edit(lib, Brush::sphere(c, 11 * vs), EditOp::Remove);
  char sphere[160];
  std::snprintf(sphere, sizeof sphere, "%.9g,%.9g,%.9g,%.17g", c.x, c.y, c.z, 11 * vs);
  const testing::CliResult res =
      testing::run_cli("edit '" + cli.string() + "' --sphere " + sphere + " --remove -q");
  ASSERT_EQ(res.exit_code, 0) << res.output;
  const World back = open_world(cli);
  EXPECT_EQ(testing::brickmap_contents(back), testing::brickmap_contents(lib));
  EXPECT_EQ(back.carved(), lib.carved());
}

}  // namespace
}  // namespace voxcast
