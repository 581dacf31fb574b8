// libFuzzer target for the brickmap scene readers (src/brickmap/format.cpp,
// the streaming reader src/brickmap/stream.cpp) and the edit journal's
// replay (src/brickmap/persist.cpp).
//
// Structure-aware without a custom mutator. The first input byte b chooses:
//   b % 6            what the rest of the input is: 0..3 the bytes of one
//                    section (META, BMGH, BMCT, BMCK) of a valid seed world,
//                    the other sections kept intact, so the fuzzer's effort
//                    goes into the LZ4 blocks, the chunk table and the brick
//                    records instead of dying at a container hash; 4 the
//                    records of the world's edit journal, after a valid
//                    journal head, so that the records are reached (the
//                    terrain's journal holds carved records, format 3); 5 the
//                    carved-voxel section BMCV of the seed world as saved
//                    after its edits (the terrain's lists the cells the
//                    remove brush carved; the sphere's world has none, and
//                    any BMCV there must be refused);
//   (b / 6) % 2      the seed world: a 64^3 sphere shell from the builder
//                    (what `build --format brickmap` writes), or a terrain
//                    whose brickgrid is cut off in y (what `generate terrain`
//                    writes, brickmap_terrain.hpp);
//   (b / 12) % 2     the reader: the whole world in RAM (load_world, then
//                    the journal replayed), or the streaming reader on the
//                    file and its journal, which reads META, the header and
//                    the table strictly and each chunk only when a ray asks
//                    for one of its bricks (a chunk that fails is refused on
//                    its own, brickmap_stream.hpp);
//   (b / 24) % 2     streaming only: colors uploaded as DXT1 blocks (§3.1.3).
// An accepted world is traced (a few rays in RAM, three 16x12 frames with a
// tiny budget when streamed, so uploads, evictions and hidden-voxel removal
// run) and its statistics computed. A clean voxcast::Error is the expected
// outcome for most inputs; anything else (a crash, an ASan or UBSan report,
// another exception) is a finding.
//
// VOXCAST_WRITE_SEEDS=DIR writes the seed inputs (every choice above with the
// seed world's own section bytes, and the journal a few edits and a snowfall
// wrote through commit_edits, `voxcast edit`'s saving path) and exits.
#include <unistd.h>
#include <xxhash.h>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <memory>
#include <string>
#include <vector>

#include "voxcast/brickmap.hpp"
#include "voxcast/brickmap_file.hpp"
#include "voxcast/brickmap_stream.hpp"
#include "voxcast/brickmap_terrain.hpp"
#include "voxcast/camera.hpp"
#include "voxcast/error.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/render.hpp"
#include "voxcast/scene_file.hpp"

namespace {

using namespace voxcast;
namespace fs = std::filesystem;

constexpr uint32_t kSections[4] = {fourcc("META"), fourcc("BMGH"), fourcc("BMCT"), fourcc("BMCK")};
constexpr uint32_t kCarvedSection = fourcc("BMCV");

struct SeedWorld {
  Container container;
  Container edited;  // the world after the journal's edits, as save_scene writes it
  std::vector<uint8_t> journal_head;  // "VXBMJRN3", cells, world file id, hash (brickmap_file.hpp)
  std::vector<uint8_t> journal_records;  // what commit_edits appended after the head
};

// A private directory for the files the streaming reader and the journal
// writer need, removed at exit (the path is never destroyed, so the exit
// handler can still read it).
const fs::path& work_dir() {
  static const fs::path* dir = [] {
    std::string t = (fs::temp_directory_path() / "fuzz_brickmap_XXXXXX").string();
    if (!mkdtemp(t.data())) std::abort();
    return new fs::path(t);
  }();
  static const bool cleanup = [] { return std::atexit([] { fs::remove_all(*dir); }) == 0; }();
  (void)cleanup;
  return *dir;
}

std::vector<uint8_t> read_bytes(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

void write_bytes(const fs::path& p, const uint8_t* data, size_t size) {
  std::ofstream out(p, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(data), std::streamsize(size));
  if (!out) std::abort();
}

// A 64^3 sphere shell with colors and normals (2 x 2 x 2 file chunks would
// need 256^3; 64^3 keeps every input fast and still has many bricks).
brickmap::World sphere_world() {
  VoxelSet v;
  v.grid.levels = 6;
  v.grid.resolution = 64;
  v.grid.voxel_size = 1.0 / 64;
  for (uint32_t z = 0; z < 64; ++z)
    for (uint32_t y = 0; y < 64; ++y)
      for (uint32_t x = 0; x < 64; ++x) {
        const float dx = float(x) - 31.5f, dy = float(y) - 31.5f, dz = float(z) - 31.5f;
        const float r = std::sqrt(dx * dx + dy * dy + dz * dz);
        if (r < 24.f || r > 25.f) continue;
        v.codes.push_back(morton_encode(x, y, z));
      }
  std::sort(v.codes.begin(), v.codes.end());
  for (uint64_t code : v.codes) {
    const MortonCoord m = morton_decode(code);
    v.colors.push_back({float(m.x) / 64.f, float(m.y) / 64.f, float(m.z) / 64.f, 1.f});
    v.normals.push_back(
        normalize(Vec3{float(m.x) - 31.5f, float(m.y) - 31.5f, float(m.z) - 31.5f}));
    v.weights.push_back(1.f);
  }
  return brickmap::build_world(v);
}

// The seed world `which` as its writer stores it, and the journal that a few
// edits of it leave (commit_edits: one transaction per edit).
SeedWorld make_seed(int which) {
  const fs::path file = work_dir() / ("seed" + std::to_string(which) + ".vxc");
  if (which == 0) {
    brickmap::save_scene(file, sphere_world(), SceneInfo{"fuzz", "conservative", 0, 0});
  } else {
    brickmap::TerrainOptions t;
    t.size[0] = 72, t.size[1] = 40, t.size[2] = 64;  // a 128^3 grid, 16 x 5 x 16 cells
    t.seed = 5;
    t.threads = 1;
    brickmap::write_terrain(file, t);
  }
  SeedWorld s;
  s.container = Container::read(file);
  {
    // The file as the streamed mode writes it (c.serialize()): the journal
    // head names the exact file it belongs to (brickmap_file.hpp).
    const std::vector<uint8_t> bytes = s.container.serialize();
    write_bytes(file, bytes.data(), bytes.size());
  }
  brickmap::World w = brickmap::load_world(s.container);
  const Aabb b = w.occupied_bounds();
  const Vec3 c = b.center(), e = b.extent();
  const auto at = [&](float fx, float fy, float fz) {
    return Vec3d{c.x + fx * e.x, c.y + fy * e.y, c.z + fz * e.z};
  };
  std::vector<brickmap::EditResult> edits;
  edits.push_back(brickmap::edit(w, brickmap::Brush::sphere(at(0.3f, 0.2f, 0.1f), 0.1 * e.x),
                                 brickmap::EditOp::Add, Color{0.9f, 0.2f, 0.1f, 1.f}));
  edits.push_back(
      brickmap::edit(w, brickmap::Brush::box(at(-0.4f, -0.1f, -0.4f), at(-0.25f, 0.1f, -0.2f)),
                     brickmap::EditOp::Remove));
  edits.push_back(brickmap::edit(w, brickmap::Brush::sphere(at(0.f, 0.3f, 0.f), 0.2 * e.x),
                                 brickmap::EditOp::Paint, Color{0.1f, 0.3f, 0.8f, 1.f}));
  edits.push_back(brickmap::snow_step(w, 0));
  for (const brickmap::EditResult& r : edits) brickmap::commit_edits(file, w, r.cells);
  const std::vector<uint8_t> journal = read_bytes(brickmap::journal_path(file));
  if (journal.size() < 32) std::abort();
  s.journal_head.assign(journal.begin(), journal.begin() + 32);
  s.journal_records.assign(journal.begin() + 32, journal.end());
  fs::remove(file);
  fs::remove(brickmap::journal_path(file));
  // The edited world saved whole: the terrain's carries the BMCV section of
  // the voxels its remove brush carved (the seeds must reach that parser).
  if (which == 1 && w.carved().empty()) std::abort();
  brickmap::save_scene(file, w, SceneInfo{"fuzz", "conservative", 0, 0});
  s.edited = Container::read(file);
  fs::remove(file);
  return s;
}

const SeedWorld& seed_world(int which) {
  static const SeedWorld worlds[2] = {make_seed(0), make_seed(1)};
  return worlds[which];
}

// Three frames of the streamed world with a budget far below it: uploads,
// evictions, the chunk cache and hidden-voxel removal all run.
void stream(const fs::path& file, bool dxt1) {
  brickmap::StreamOptions so;
  so.budget_bytes = 48 << 10;
  so.uploads_per_pass = 16;
  so.dxt1 = dxt1;
  brickmap::StreamingWorld s(file, so);
  RenderOptions o;
  o.width = 16, o.height = 12;
  o.max_passes = 2;
  for (uint32_t f = 0; f < 3; ++f) {
    o.camera = Camera::orbit(s.world().occupied_bounds(), o.width, o.height, 40.f * float(f), 25.f);
    o.frame = f;
    (void)render(s, o);
  }
  (void)s.world().stats();
  (void)s.missing();
}

void in_ram(const Container& c, const std::vector<uint8_t>* journal) {
  const auto w = std::make_shared<brickmap::World>(brickmap::load_world(c));
  if (journal) brickmap::replay_journal_bytes(*journal, *w, nullptr, nullptr);
  (void)w->stats();
  (void)w->occupied_bounds();
  const brickmap::BrickmapStructure s(w);
  TraceContext ctx;
  ctx.requests.reserve(4);
  const float side = float(w->grid().side());
  const Vec3 center = w->grid().origin + Vec3{0.5f, 0.5f, 0.5f} * side;
  const float r = 2 * side;
  for (int i = 0; i < 16; ++i) {
    const float a = float(i) * 0.4f;
    const Ray ray{center + Vec3{r * std::cos(a), 0.15f * r * float(i % 3 - 1), r * std::sin(a)},
                  normalize(Vec3{-std::cos(a), 0.f, -std::sin(a)})};
    SurfaceHit h;
    if (s.trace(ray, LodFootprint{0.f, 0.002f * float(i % 4)}, ctx, &h)) {
      Color col;
      Vec3 n;
      s.attributes(h, ctx, &col, &n);
    }
  }
}

void write_seeds(const char* dir) {
  fs::create_directories(dir);
  int n = 0;
  for (int which = 0; which < 2; ++which) {
    const SeedWorld& s = seed_world(which);
    for (int mode = 0; mode < 6; ++mode)
      for (int reader = 0; reader < 2; ++reader)
        for (int dxt1 = 0; dxt1 < (reader ? 2 : 1); ++dxt1) {
          std::vector<uint8_t> in = {uint8_t(mode + 6 * which + 12 * reader + 24 * dxt1)};
          // The sphere's world has no BMCV: its seed is the terrain's list.
          const std::vector<uint8_t>& body = mode == 4   ? s.journal_records
                                             : mode == 5 ? seed_world(1).edited.get(kCarvedSection)
                                                         : s.container.get(kSections[mode]);
          in.insert(in.end(), body.begin(), body.end());
          write_bytes(fs::path(dir) / ("seed-" + std::to_string(in[0])), in.data(), in.size());
          ++n;
        }
  }
  std::printf("%d seeds written to %s\n", n, dir);
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  if (const char* dir = std::getenv("VOXCAST_WRITE_SEEDS")) {
    write_seeds(dir);
    std::exit(0);
  }
  (void)seed_world(0);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0) return 0;
  const int mode = data[0] % 6, which = data[0] / 6 % 2;
  const bool streamed = data[0] / 12 % 2, dxt1 = data[0] / 24 % 2;
  const SeedWorld& seed = seed_world(which);
  Container c = mode == 5 ? seed.edited : seed.container;
  std::vector<uint8_t> journal;
  if (mode < 4) {
    c.add(kSections[mode], std::vector<uint8_t>(data + 1, data + size));
  } else if (mode == 5) {
    c.add(kCarvedSection, std::vector<uint8_t>(data + 1, data + size));
  } else {
    journal = seed.journal_head;
    journal.insert(journal.end(), data + 1, data + size);
  }
  try {
    if (!streamed) {
      in_ram(c, mode == 4 ? &journal : nullptr);
    } else {
      const fs::path file = work_dir() / "input.vxc", jfile = brickmap::journal_path(file);
      const std::vector<uint8_t> bytes = c.serialize();
      write_bytes(file, bytes.data(), bytes.size());
      if (mode == 4)
        write_bytes(jfile, journal.data(), journal.size());
      else
        fs::remove(jfile);
      stream(file, dxt1);
    }
  } catch (const Error&) {
  }
  return 0;
}
