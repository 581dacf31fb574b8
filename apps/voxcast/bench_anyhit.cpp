#include "bench_anyhit.hpp"

#include "voxcast/dag.hpp"
#include "voxcast/esvo_structure.hpp"

namespace voxcast::cli {

AnyHitCaster anyhit_caster(const Structure& st) {
  if (const auto* e = dynamic_cast<const esvo::EsvoStructure*>(&st))
    return [e](const Ray* rays, size_t n, uint8_t* occ, const AnyHitOptions& o, AnyHitStats* s) {
      occluded_anyhit(*e, rays, n, LodFootprint{}, occ, o, s);
    };
  if (const auto* d = dynamic_cast<const dag::DagStructure*>(&st))
    return [d](const Ray* rays, size_t n, uint8_t* occ, const AnyHitOptions& o, AnyHitStats* s) {
      occluded_anyhit(*d, rays, n, LodFootprint{}, occ, o, s);
    };
  return {};
}

}  // namespace voxcast::cli
