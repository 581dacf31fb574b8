#pragma once
// The Embree reference path tracer: the GI integrator's sampling math
// (gi_integrator.hpp, render/path_tracer.hpp) on the source mesh, with the
// mesh's surface colors as albedo and its interpolated normals as shading
// normals. The oracle of the GI convergence test and the peer of the GI
// samples/s measurement (docs/BENCHMARKS.md). Part of the Embree oracle
// target, like embree_reference.hpp.
#include "voxcast/camera.hpp"
#include "voxcast/embree_reference.hpp"
#include "voxcast/gi_integrator.hpp"
#include "voxcast/image.hpp"
#include "voxcast/mesh.hpp"

namespace voxcast {

struct EmbreePathResult {
  Image color;  // 3 channels, mean radiance of options.spp samples
  GiStats stats;
};

/// options.spp samples per pixel (sample indices 0..spp-1, the GI
/// integrator's first frame) of `mesh`, which must be the mesh `scene` was
/// built from. Throws voxcast::Error for invalid options or size.
EmbreePathResult embree_path_trace(const EmbreeScene& scene, const Mesh& mesh, const Camera& camera,
                                   int width, int height, const GiOptions& options);

}  // namespace voxcast
