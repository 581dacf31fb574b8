// libFuzzer target: arbitrary bytes as a MetaImage volume with its data in
// the same file (gigavoxels.hpp parse_metaimage, ElementDataFile = LOCAL; a
// named data file is answered with the input's own bytes). Whatever parses
// must make a producer whose root brick can be produced; everything else
// must be a clean voxcast::Error, never a crash, a hang or an oversized
// allocation (the announced size is checked against the bytes present first).
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "volume_fuzz.hpp"
#include "voxcast/error.hpp"
#include "voxcast/gigavoxels.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace voxcast;
  try {
    const std::span<const unsigned char> bytes(data, size);
    const giga::ScalarVolume v = giga::parse_metaimage(bytes, [&](const std::string&) {
      return std::vector<unsigned char>(bytes.begin(), bytes.end());
    });
    fuzz_volume_through_producer(v);
  } catch (const Error&) {
  }
  return 0;
}
