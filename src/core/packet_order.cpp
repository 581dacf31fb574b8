// The packet casters' helpers that name no structure
// (voxcast/packet_caster.hpp): the caster names and the 4x4 block order. The
// casters themselves are OctreeStructure's members (core/octree_packets.hpp).
#include <cstdint>
#include <vector>

#include "voxcast/packet_caster.hpp"

namespace voxcast {

const char* caster_name(Caster c) {
  return c == Caster::Tile ? "tile" : c == Caster::Packet ? "packet" : "scalar";
}

void block_order(int x0, int y0, int w, int h, std::vector<uint32_t>* out) {
  for (int by = 0; by < h; by += 4)
    for (int bx = 0; bx < w; bx += 4)
      for (int y = by; y < by + 4 && y < h; ++y)
        for (int x = bx; x < bx + 4 && x < w; ++x)
          out->push_back(uint32_t(x0 + x) | uint32_t(y0 + y) << 16);
}

}  // namespace voxcast
