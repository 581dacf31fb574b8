// libFuzzer target: arbitrary bytes as a MagicaVoxel .vox (or, after a
// "#binvox" line, a .binvox) file. Whatever is accepted must be a valid voxel
// set that survives a write and a second read unchanged (positions relative
// to the occupied box, colors exactly: an accepted file has at most 255
// palette colors); anything else must be refused with voxcast::Error.
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <span>

#include "support/voxel_compare.hpp"
#include "voxcast/error.hpp"
#include "voxcast/image.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/voxel_io.hpp"

namespace {

using namespace voxcast;

void check(bool ok) {
  if (!ok) std::abort();
}

void check_valid(const VoxelSet& s) {
  check(!s.codes.empty() && std::is_sorted(s.codes.begin(), s.codes.end()));
  check(std::adjacent_find(s.codes.begin(), s.codes.end()) == s.codes.end());
  check(s.colors.size() == s.size() && s.normals.size() == s.size());
  for (uint64_t c : s.codes) {
    const MortonCoord m = morton_decode(c);
    check(std::max({m.x, m.y, m.z}) < s.grid.resolution);
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  VoxelReadOptions options;
  options.memory_budget = uint64_t(64) << 20;
  const std::span<const uint8_t> bytes(data, size);
  const bool binvox = size >= 7 && std::memcmp(data, "#binvox", 7) == 0;
  VoxelSet a;
  try {
    a = binvox ? parse_binvox(bytes, options) : parse_vox(bytes, options);
  } catch (const Error&) {
    return 0;
  }
  check_valid(a);
  if (binvox) {
    const VoxelSet b = parse_binvox(encode_binvox(a), options);
    check(b.codes == a.codes && b.grid.resolution == a.grid.resolution);
    return 0;
  }
  const VoxelSet b = parse_vox(encode_vox(a), options);
  check_valid(b);
  check(b.size() == a.size());
  // Both sides in the same relative Morton order (a shift keeps the order
  // only when it is zero; compare sorted pairs).
  std::vector<std::pair<uint64_t, std::array<float, 4>>> pa, pb;
  const auto ra = testing::box_relative_codes(a), rb = testing::box_relative_codes(b);
  for (size_t i = 0; i < a.size(); ++i) {
    pa.push_back({ra[i], {a.colors[i].r, a.colors[i].g, a.colors[i].b, a.colors[i].a}});
    pb.push_back({rb[i], {b.colors[i].r, b.colors[i].g, b.colors[i].b, b.colors[i].a}});
  }
  std::sort(pa.begin(), pa.end());
  std::sort(pb.begin(), pb.end());
  for (size_t i = 0; i < pa.size(); ++i) {
    check(pa[i].first == pb[i].first);
    for (int ch = 0; ch < 4; ++ch) check(std::fabs(pa[i].second[ch] - pb[i].second[ch]) < 1e-6f);
  }
  return 0;
}
