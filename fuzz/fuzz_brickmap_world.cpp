// libFuzzer target for the brickmap scene reader (src/brickmap/format.cpp)
// and the edit journal's replay (src/brickmap/persist.cpp).
// Structure-aware without a custom mutator: the first input byte picks one
// section of a valid brickmap world built here (META, BMGH, BMCT or BMCK)
// whose bytes the rest of the input replaces, or (byte % 5 == 4) the
// world's edit journal: the rest is replayed onto the world after a valid
// journal head, so that the records are reached. The container is
// handed to brickmap::load_world with every other section intact, so the
// fuzzer's effort goes into the LZ4 blocks, the chunk table and the brick
// records instead of dying at a container hash. An accepted world is traced
// with a few rays (and its statistics computed); a clean voxcast::Error is
// the expected outcome for most inputs, anything else (a crash, an ASan or
// UBSan report, another exception) is a finding.
#include <xxhash.h>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

#include "voxcast/brickmap.hpp"
#include "voxcast/brickmap_file.hpp"
#include "voxcast/error.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/scene_file.hpp"

namespace {

using namespace voxcast;

// A 64^3 sphere shell with colors and normals (2 x 2 x 2 file chunks would
// need 256^3; 64^3 keeps every input fast and still has many bricks).
const Container& seed_world() {
  static const Container c = [] {
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
    return brickmap::save_world(brickmap::build_world(v), SceneInfo{"fuzz", "conservative", 0, 0});
  }();
  return c;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0) return 0;
  static const uint32_t ids[4] = {fourcc("META"), fourcc("BMGH"), fourcc("BMCT"), fourcc("BMCK")};
  Container c = seed_world();
  const bool journal = data[0] % 5 == 4;
  if (!journal) c.add(ids[data[0] % 5], std::vector<uint8_t>(data + 1, data + size));
  try {
    const auto w = std::make_shared<brickmap::World>(brickmap::load_world(c));
    if (journal) {
      // The journal head of this world (brickmap_file.hpp), then the input.
      static const std::vector<uint8_t> head = [&] {
        std::vector<uint8_t> h = {'V', 'X', 'B', 'M', 'J', 'R', 'N', '1'};
        const uint64_t cells = w->cells().size();
        for (int i = 0; i < 8; ++i) h.push_back(uint8_t(cells >> (8 * i)));
        const uint64_t hash = XXH64(h.data(), h.size(), 0);
        for (int i = 0; i < 8; ++i) h.push_back(uint8_t(hash >> (8 * i)));
        return h;
      }();
      std::vector<uint8_t> j = head;
      j.insert(j.end(), data + 1, data + size);
      brickmap::replay_journal_bytes(j, *w, nullptr, nullptr);
    }
    (void)w->stats();
    (void)w->occupied_bounds();
    const brickmap::BrickmapStructure s(w);
    TraceContext ctx;
    ctx.requests.reserve(4);
    for (int i = 0; i < 16; ++i) {
      const float a = float(i) * 0.4f;
      const Ray ray{{0.5f + 2 * std::cos(a), 0.5f + 0.3f * float(i % 3), 0.5f + 2 * std::sin(a)},
                    normalize(Vec3{-std::cos(a), 0.f, -std::sin(a)})};
      SurfaceHit h;
      if (s.trace(ray, LodFootprint{0.f, 0.002f * float(i % 4)}, ctx, &h)) {
        Color col;
        Vec3 n;
        s.attributes(h, ctx, &col, &n);
      }
    }
  } catch (const Error&) {
  }
  return 0;
}
