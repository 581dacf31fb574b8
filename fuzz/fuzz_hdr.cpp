// libFuzzer target: arbitrary bytes as a Radiance .hdr environment map
// (environment.hpp parse_hdr). Whatever parses must be a well-formed image
// of finite, non-negative radiance that makes an Environment; everything
// else must be a clean voxcast::Error, never a crash, a hang or an
// oversized allocation (the announced size is checked against the bytes
// present before decoding).
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <span>

#include "voxcast/environment.hpp"
#include "voxcast/error.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace voxcast;
  try {
    Image img = parse_hdr(std::span(data, size));
    if (img.channels != 3 || img.pixels.size() != size_t(img.width) * size_t(img.height) * 3)
      std::abort();
    for (float p : img.pixels)
      if (!(p >= 0.f) || !std::isfinite(p)) std::abort();
    const Environment env(std::move(img));
    (void)env.radiance({0.f, 1.f, 0.f});
  } catch (const Error&) {
  }
  return 0;
}
