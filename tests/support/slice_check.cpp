// Slice-file checks shared by the fuzz target and the regression test
// (slice_check.hpp).
#include "support/slice_check.hpp"

#include <unistd.h>
#include <xxhash.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>

#include "voxcast/error.hpp"
#include "voxcast/esvo_slices.hpp"
#include "voxcast/render.hpp"

namespace voxcast::testing {

namespace {
template <class T>
T get(const std::vector<uint8_t>& b, size_t at) {
  T v;
  std::memcpy(&v, b.data() + at, sizeof v);
  return v;
}
template <class T>
void put(std::vector<uint8_t>& b, size_t at, T v) {
  std::memcpy(b.data() + at, &v, sizeof v);
}
}  // namespace

void rehash_slice_file(std::vector<uint8_t>& b) {
  constexpr size_t kHeader = 128, kEntry = 64;
  if (b.size() < kHeader) return;
  const uint64_t count = get<uint32_t>(b, 24);
  for (uint64_t i = 0; i < count && kHeader + (i + 1) * kEntry <= b.size(); ++i) {
    const size_t e = kHeader + i * kEntry;
    const uint64_t offset = get<uint64_t>(b, e + 8), bytes = get<uint32_t>(b, e + 24);
    if (offset <= b.size() && bytes <= b.size() - offset)
      put<uint64_t>(b, e + 16, XXH64(b.data() + offset, bytes, 0));
  }
  const size_t dir = std::min<uint64_t>(count * kEntry, b.size() - kHeader);
  XXH64_state_t* state = XXH64_createState();
  XXH64_reset(state, 0);
  XXH64_update(state, b.data(), 120);
  XXH64_update(state, b.data() + kHeader, dir);
  put<uint64_t>(b, 120, XXH64_digest(state));
  XXH64_freeState(state);
}

std::string check_slice_file(std::span<const uint8_t> bytes) {
  char name[] = "/tmp/voxcast-slice-check-XXXXXX";
  const int fd = mkstemp(name);
  if (fd < 0) std::abort();
  for (size_t at = 0; at < bytes.size();) {
    const ssize_t n = ::write(fd, bytes.data() + at, bytes.size() - at);
    if (n <= 0) std::abort();
    at += size_t(n);
  }
  ::close(fd);
  std::shared_ptr<esvo::SliceFile> file;
  try {
    file = esvo::SliceFile::open(name);
  } catch (const Error& e) {
    std::filesystem::remove(name);
    return e.what();
  }
  auto fail = [&](const char* what) {
    std::fprintf(stderr, "slice check: accepted file broke: %s\n", what);
    std::abort();
  };
  try {
    // The automatic camera's box: read from the top slices, damaged ones
    // ending the walk early; never outside the grid's cube.
    const Aabb ob = file->occupied_bounds();
    const GridTransform g = file->grid();
    const Vec3 lo = g.origin,
               hi = g.origin + Vec3{float(g.side()), float(g.side()), float(g.side())};
    // Float rounding of the cube corners, relative to the coordinates' size.
    const float slack =
        1e-5f * (float(g.side()) + std::max({std::fabs(lo.x), std::fabs(lo.y), std::fabs(lo.z)}));
    for (int a = 0; a < 3; ++a)
      if (ob.lo[a] <= ob.hi[a] && (ob.lo[a] < lo[a] - slack || ob.hi[a] > hi[a] + slack))
        fail("occupied bounds outside the grid");
    // A budget too small for the root is refused (an Error), any other is kept.
    for (const uint64_t budget : {uint64_t(0), uint64_t(4096)}) {
      esvo::StreamOptions so;
      so.budget_bytes = budget;
      std::unique_ptr<esvo::StreamedEsvo> s;
      try {
        s = std::make_unique<esvo::StreamedEsvo>(file, so);
      } catch (const Error&) {
        continue;  // a corrupt root slice, or the budget below the root
      }
      RenderOptions ro;
      ro.width = ro.height = 16;
      for (int f = 0; f < 6; ++f) {
        ro.camera = Camera::orbit(s->bounds(), 16, 16, 40.f * float(f), 15.f);
        ro.beam = (f & 1) != 0 ? 4 : 0;  // the coarse pass over a partly resident octree too
        render(static_cast<Structure&>(*s), ro);
        s->check_invariants();
      }
      if (budget == 0) {
        try {
          s->load_all();
        } catch (const Error&) {
          // more slices than resident blocks: refused as a whole
        }
        s->check_invariants();
        render(static_cast<Structure&>(*s), ro);
      }
    }
  } catch (const Error& e) {
    fail(e.what());
  }
  std::filesystem::remove(name);
  return "";
}

}  // namespace voxcast::testing
