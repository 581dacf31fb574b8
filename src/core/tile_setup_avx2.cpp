// The tile caster's ray set-up (core/tile_setup_body.hpp), 8 lanes.
#include "core/tile_setup_body.hpp"

namespace voxcast::detail {

void tile_rays_avx2(const CameraRays& cam, const OctreeFrame& frame, int x0, int y0, int x1, int y1,
                    TileRays* r) {
  tile_rays_lanes<8>(cam, frame, x0, y0, x1, y1, r);
}

}  // namespace voxcast::detail
