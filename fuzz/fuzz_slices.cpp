// libFuzzer target: arbitrary bytes as an ESVO slice file (esvo §7,
// include/voxcast/esvo_slices.hpp). The first byte picks the mode: odd =
// the rest with every slice hash and the directory hash recomputed (so
// byte mutations reach the hierarchy and slice validators behind the
// hashes), even = the rest as it is. A refused file must be a clean
// voxcast::Error; an accepted one is streamed (unlimited and tiny budgets,
// a few frames, every invariant after every pass: tests/support/slice_check).
#include <cstddef>
#include <cstdint>
#include <vector>

#include "support/slice_check.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0) return 0;
  std::vector<uint8_t> bytes(data + 1, data + size);
  if (data[0] & 1) voxcast::testing::rehash_slice_file(bytes);
  (void)voxcast::testing::check_slice_file(bytes);
  return 0;
}
