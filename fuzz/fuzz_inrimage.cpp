// libFuzzer target: arbitrary bytes as an INRIMAGE-4 volume
// (gigavoxels.hpp parse_inrimage). Whatever parses must make a producer
// whose root brick can be produced; everything else must be a clean
// voxcast::Error, never a crash, a hang or an oversized allocation (the
// parser checks the announced size against the bytes present first).
#include <cstddef>
#include <cstdint>
#include <span>

#include "volume_fuzz.hpp"
#include "voxcast/error.hpp"
#include "voxcast/gigavoxels.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace voxcast;
  try {
    const giga::ScalarVolume v = giga::parse_inrimage(std::span(data, size));
    fuzz_volume_through_producer(v);
  } catch (const Error&) {
  }
  return 0;
}
