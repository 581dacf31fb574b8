// The brickmap lane walk (packet_walk_kernel.hpp), 8 lanes: compiled with
// the baseline flags.
#include "brickmap/packet_walk_kernel.hpp"

namespace voxcast::brickmap::detail {

void packet_walk_avx2(const PacketWorld& w, const PacketRays& q, uint8_t* status,
                      PacketFound* out) {
  packet_walk<8>(w, q, status, out);
}

}  // namespace voxcast::brickmap::detail
