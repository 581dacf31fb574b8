#pragma once
// The any-hit packet casters (voxcast/occlusion_packets.hpp) for `voxcast
// bench --effects`. They exist for the octree family only and are not part
// of SurfaceQuery (which answers batches through transmittance_batch), so
// the bench rows that time them directly find them here; cmd_bench.cpp
// itself names no structure.
#include <cstddef>
#include <cstdint>
#include <functional>

#include "voxcast/math.hpp"
#include "voxcast/occlusion_packets.hpp"
#include "voxcast/structure.hpp"

namespace voxcast::cli {

/// occluded[i] for rays [0, n) at the finest level, as occluded_anyhit().
using AnyHitCaster = std::function<void(const Ray* rays, size_t n, uint8_t* occluded,
                                        const AnyHitOptions& o, AnyHitStats* stats)>;

/// The structure's any-hit packet caster, or empty when it has none.
AnyHitCaster anyhit_caster(const Structure& st);

}  // namespace voxcast::cli
