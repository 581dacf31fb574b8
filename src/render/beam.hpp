#pragma once
// Beam optimization (esvo §6.2), renderer side: the pyramid of rays through
// a block of pixels, handed to SurfaceQuery::beam_start; and a tile's camera
// rays in packet order with the coarse pass of their blocks (PacketTile).
#include <cstddef>
#include <cstdint>
#include <vector>

#include "voxcast/camera.hpp"
#include "voxcast/packet_caster.hpp"
#include "voxcast/structure.hpp"

namespace voxcast::detail {

/// Beam of the primary rays of pixels [x0, x1) x [y0, y1). Its edges pass one
/// pixel outside the block's outer pixel corners (1.5 pixels outside the
/// outermost ray), so the float rounding of CameraRays::direction can never
/// put a ray of the block outside it.
BeamFrustum block_beam(const CameraRays& cam, int x0, int y0, int x1, int y1,
                       const LodFootprint& lod);

/// The camera rays of one tile [x0, x1) x [y0, y1) in packet order (4x4
/// pixel blocks, block_order), the queue a SurfacePackets::trace_packets
/// call takes whole, with room for its answers. One per thread, reused from
/// tile to tile: the vectors grow to the largest tile once, then no tile
/// allocates.
struct PacketTile {
  std::vector<uint32_t> order;  // pixel of ray i: x | y << 16
  std::vector<Ray> rays;
  std::vector<SurfaceHit> hits;
  std::vector<uint8_t> found;
  std::vector<BeamStart> starts;        // per K x K block, row by row
  std::vector<const BeamStart*> beams;  // per ray: its block's start

  int x(size_t i) const { return int(order[i] & 0xFFFF); }
  int y(size_t i) const { return int(order[i] >> 16); }

  /// The tile's rays from `cam`; no beam (beam_list() is null).
  void generate(const CameraRays& cam, int x0, int y0, int x1, int y1) {
    order.clear();
    block_order(x0, y0, x1 - x0, y1 - y0, &order);
    const size_t n = order.size();
    rays.resize(n), hits.resize(n), found.resize(n);
    for (size_t i = 0; i < n; ++i) rays[i] = cam.ray(x(i), y(i));
    beams.clear();
  }

  /// The coarse pass (§6.2) of every K x K block of the tile (blocks start
  /// at the tile's corner, clipped to it): coarse(bx, by, &start) per block,
  /// then each ray points at its block's start (beam_list()).
  template <class Coarse>
  void coarse_pass(int x0, int y0, int x1, int y1, int k, const Coarse& coarse) {
    const int bw = (x1 - x0 + k - 1) / k, bh = (y1 - y0 + k - 1) / k;
    starts.resize(size_t(bw) * size_t(bh));
    for (int j = 0; j < bh; ++j)
      for (int i = 0; i < bw; ++i) coarse(x0 + i * k, y0 + j * k, &starts[size_t(j * bw + i)]);
    beams.resize(order.size());
    for (size_t i = 0; i < order.size(); ++i)
      beams[i] = &starts[size_t((y(i) - y0) / k * bw + (x(i) - x0) / k)];
  }

  /// The tile frustum pass's blocks (render --frustum K): per K x K block
  /// the cubes within the tile's list `tile` (SurfaceQuery::frustum_start
  /// for the block's beam and the octant of its center ray), each ray
  /// pointing at its block's list. A block that is the whole tile (K at
  /// least the tile's sides) has the tile's beam: its rays take the tile's
  /// list as it is, without a second pass. `tile` must outlive the trace.
  void frustum_blocks(const SurfaceQuery& q, const CameraRays& cam, const LodFootprint& lod, int x0,
                      int y0, int x1, int y1, int k, TraceContext& ctx, const BeamStart& tile);

  /// The per-ray beam starts for trace_packets, or null without a coarse pass.
  const BeamStart* const* beam_list() const { return beams.empty() ? nullptr : beams.data(); }
};

}  // namespace voxcast::detail
