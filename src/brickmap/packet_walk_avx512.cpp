// The brickmap lane walk (packet_walk_kernel.hpp), 16 lanes: compiled with
// -march=x86-64-v4 (CMakeLists.txt, *_avx512.cpp); only called when the caller's Isa says the CPU
// has AVX-512.
#include "brickmap/packet_walk_kernel.hpp"

namespace voxcast::brickmap::detail {

void packet_walk_avx512(const PacketWorld& w, const PacketRays& q, uint8_t* status,
                        PacketFound* out) {
  packet_walk<16>(w, q, status, out);
}

int packet_setup_avx512(const PacketSetupIn& in, uint32_t id0, float* const f[16], int32_t* axis,
                        uint32_t* id, uint32_t* scalar, int* n_scalar) {
  return packet_setup<16>(in, id0, f, axis, id, scalar, n_scalar);
}

}  // namespace voxcast::brickmap::detail
