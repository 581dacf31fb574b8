// The brickmap lane walk (packet_walk_kernel.hpp), 16 lanes: compiled with
// -march=x86-64-v4 (CMakeLists.txt, *_avx512.cpp); only called when the caller's Isa says the CPU
// has AVX-512.
#include "brickmap/packet_walk_kernel.hpp"

namespace voxcast::brickmap::detail {

void packet_walk_avx512(const PacketWorld& w, const PacketRays& q, uint8_t* status,
                        PacketFound* out) {
  packet_walk<16>(w, q, status, out);
}

}  // namespace voxcast::brickmap::detail
