// The Embree reference path tracer (include/voxcast/embree_path.hpp): the
// path loop of render/path_tracer.hpp with triangles instead of voxels.
#include "voxcast/embree_path.hpp"

#include <algorithm>
#include <cmath>
#include <mutex>

#include "render/path_tracer.hpp"
#include "render/tiling.hpp"
#include "voxcast/error.hpp"

namespace voxcast {
namespace {

/// The mesh side of path_tracer.hpp's Scene. Rays leaving a hit start a
/// small distance off the triangle along its geometric normal (on the side
/// the ray came from): 1e-4 of the bounds' diagonal, far above float
/// rounding at the scene's scale and far below any feature the test scenes
/// resolve.
struct MeshScene {
  const EmbreeScene& embree;
  const Mesh& mesh;
  float offset;

  bool intersect(const Ray& ray, int, detail::PathVertex* v) const {
    const EmbreeScene::Hit h = embree.intersect_hit(ray);
    if (!std::isfinite(h.t)) return false;
    Vec3 ng = normalize(h.ng);
    if (dot(ng, ray.dir) > 0.f) ng = -ng;
    Vec3 n = mesh.surface_normal(h.triangle, h.u, h.v);
    if (!(length(n) > 0.5f)) n = ng;
    if (dot(n, ray.dir) > 0.f) n = -n;
    const Color c = mesh.surface_color(h.triangle, h.u, h.v);
    v->t = h.t;
    v->normal = n;
    v->albedo = {std::clamp(c.r, 0.f, 1.f), std::clamp(c.g, 0.f, 1.f), std::clamp(c.b, 0.f, 1.f),
                 1.f};
    v->origin = ray.origin + ray.dir * h.t + ng * offset;
    return true;
  }
  bool occluded(const Ray& ray, int) const { return embree.occluded(ray); }
};

}  // namespace

EmbreePathResult embree_path_trace(const EmbreeScene& scene, const Mesh& mesh, const Camera& camera,
                                   int width, int height, const GiOptions& options) {
  validate(options);
  GiOptions o = options;
  if (o.sun) o.sun_dir = normalize(o.sun_dir);
  const Environment constant;
  const Environment& env = o.environment ? *o.environment : constant;
  const CameraRays cam(camera, width, height);
  const MeshScene ms{scene, mesh, 1e-4f * length(mesh.bounds().extent())};
  EmbreePathResult r;
  r.color = Image(width, height, 3);
  std::mutex m;
  r.stats.seconds = detail::for_each_tile(width, height, 16, [&](const detail::Tile& t) {
    detail::PathCounts counts;
    for (int y = t.y0; y < t.y1; ++y)
      for (int x = t.x0; x < t.x1; ++x) {
        double acc[3] = {0, 0, 0};
        for (uint32_t s = 0; s < uint32_t(o.spp); ++s) {
          detail::PathRng rng(x, y, o.seed, s);
          const Ray ray = detail::jittered_ray(cam, x, y, rng);
          const Color c = detail::trace_path(ms, ray, o, env, rng, &counts, nullptr);
          acc[0] += c.r, acc[1] += c.g, acc[2] += c.b;
        }
        float* out = r.color.at(x, y);
        for (int k = 0; k < 3; ++k) out[k] = float(acc[k] / double(o.spp));
      }
    std::lock_guard<std::mutex> lock(m);
    r.stats.samples += uint64_t(t.x1 - t.x0) * uint64_t(t.y1 - t.y0) * uint64_t(o.spp);
    r.stats.bounce_rays += counts.bounce_rays;
    r.stats.shadow_rays += counts.shadow_rays;
  });
  r.stats.rays = r.stats.samples + r.stats.bounce_rays + r.stats.shadow_rays;
  return r;
}

}  // namespace voxcast
