#pragma once
// Beam optimization (esvo §6.2), renderer side: the pyramid of rays through
// a block of pixels, handed to SurfaceQuery::beam_start.
#include "voxcast/camera.hpp"
#include "voxcast/structure.hpp"

namespace voxcast::detail {

/// Beam of the primary rays of pixels [x0, x1) x [y0, y1). Its edges pass one
/// pixel outside the block's outer pixel corners (1.5 pixels outside the
/// outermost ray), so the float rounding of CameraRays::direction can never
/// put a ray of the block outside it.
BeamFrustum block_beam(const CameraRays& cam, int x0, int y0, int x1, int y1,
                       const LodFootprint& lod);

}  // namespace voxcast::detail
