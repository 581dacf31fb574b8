#pragma once
// The path-tracing loop of the GI integrator (gi_integrator.hpp), written
// once over a Scene so that the Embree reference path tracer of the source
// mesh (embree_path.hpp) runs exactly the same sampling math: same random
// numbers in the same order, same jitter, bounce directions, next-event
// estimation (sun and environment map) and Russian roulette. The two differ only in geometry
// (voxels vs. triangles), which is what the convergence test measures.
//
// Scene concept:
//   bool intersect(const Ray& ray, int depth, PathVertex* v) const;
//     first hit of `ray` (depth 0 = the camera ray); fills v (albedo, normal
//     facing the ray, origin for the rays that leave the hit).
//   bool occluded(const Ray& ray, int depth) const;  // shadow ray from a depth-`depth` hit
#include <algorithm>
#include <cmath>
#include <cstdint>

#include "voxcast/camera.hpp"
#include "voxcast/effects.hpp"
#include "voxcast/environment.hpp"
#include "voxcast/gi_integrator.hpp"
#include "voxcast/math.hpp"

namespace voxcast::detail {

inline constexpr float kPathPi = 3.14159265358979f;

/// PCG32 (O'Neill 2014, XSH-RR output) seeded from the pixel, the image seed
/// and the sample index: the whole random stream of one sample.
class PathRng {
 public:
  PathRng(int x, int y, uint32_t seed, uint32_t sample) {
    state_ = (uint64_t(pixel_seed(x, y, seed)) << 32) | pixel_seed(int(sample), 0x5bd1e995, seed);
    inc_ = (uint64_t(pixel_seed(y, x, ~seed)) << 1) | 1u;  // any odd increment
    next_u32();
  }
  uint32_t next_u32() {
    const uint64_t old = state_;
    state_ = old * 6364136223846793005ull + inc_;
    const uint32_t xorshifted = uint32_t(((old >> 18u) ^ old) >> 27u);
    const uint32_t rot = uint32_t(old >> 59u);
    return (xorshifted >> rot) | (xorshifted << ((32u - rot) & 31u));
  }
  /// Uniform in [0, 1): the top 24 bits.
  float next() { return float(next_u32() >> 8) * 0x1p-24f; }

 private:
  uint64_t state_ = 0, inc_ = 1;
};

/// Cosine-weighted unit direction around the unit normal n (Malley: uniform
/// on the disc, lifted; pdf cos(theta) / pi) with a tangent frame from Duff
/// et al. 2017.
inline Vec3 cosine_direction(Vec3 n, float u1, float u2) {
  const float r = std::sqrt(u1), phi = 2.f * kPathPi * u2;
  const float a = r * std::cos(phi), b = r * std::sin(phi);
  const float c = std::sqrt(std::max(0.f, 1.f - u1));
  const float sign = std::copysign(1.f, n.z);
  const float e = -1.f / (sign + n.z);
  const float f = n.x * n.y * e;
  const Vec3 t{1.f + sign * n.x * n.x * e, sign * f, -sign * n.x};
  const Vec3 bt{f, sign + n.y * n.y * e, -n.y};
  return normalize(t * a + bt * b + n * c);
}

/// The camera ray through a uniformly jittered point of pixel (x, y) (two
/// numbers of the stream).
inline Ray jittered_ray(const CameraRays& cam, int x, int y, PathRng& rng) {
  const float jx = rng.next(), jy = rng.next();
  const float sx = cam.screen_x(float(x) + jx), sy = cam.screen_y(float(y) + jy);
  if (cam.ortho) return {cam.ortho_origin(sx, sy), cam.forward, INFINITY};
  return {cam.eye, cam.perspective_direction(sx, sy), INFINITY};
}

struct PathVertex {
  float t = INFINITY;
  Vec3 origin;  // where the rays leaving the hit start (offset off the surface)
  Vec3 normal;  // unit shading normal, facing the incoming ray
  Color albedo;
};

struct PathCounts {
  uint64_t bounce_rays = 0, shadow_rays = 0;
};

/// One sample: the radiance arriving along `ray`. `first` (may be null)
/// receives the primary hit (t = +inf on a miss).
template <class Scene>
Color trace_path(const Scene& scene, Ray ray, const GiOptions& o, const Environment& env,
                 PathRng& rng, PathCounts* counts, PathVertex* first) {
  float L[3] = {0, 0, 0}, beta[3] = {1, 1, 1};
  const Vec3 to_sun = normalize(-o.sun_dir);
  const bool env_nee = o.env_sampling && env.can_sample();
  // The cosine density of the bounce that led to the current ray (MIS
  // weight of an escaping bounce ray against the environment sample).
  float bounce_pdf = 0.f;
  // Power heuristic weight of the strategy with density a against b.
  auto mis = [](float a, float b) { return a * a / (a * a + b * b); };
  for (int depth = 0;; ++depth) {
    PathVertex v;
    const bool hit = scene.intersect(ray, depth, &v);
    if (depth == 0 && first) *first = v;
    if (!hit) {
      const Color e = env.radiance(ray.dir);
      const float w = env_nee && depth > 0 ? mis(bounce_pdf, env.pdf(ray.dir)) : 1.f;
      L[0] += beta[0] * e.r * w, L[1] += beta[1] * e.g * w, L[2] += beta[2] * e.b * w;
      break;
    }
    const float a[3] = {v.albedo.r, v.albedo.g, v.albedo.b};
    if (o.sun) {
      const float c = dot(v.normal, to_sun);
      if (c > 0.f) {
        ++counts->shadow_rays;
        if (!scene.occluded(Ray{v.origin, to_sun, INFINITY}, depth)) {
          const float k = c / kPathPi;
          const float E[3] = {o.sun_irradiance.r, o.sun_irradiance.g, o.sun_irradiance.b};
          for (int i = 0; i < 3; ++i) L[i] += beta[i] * a[i] * E[i] * k;
        }
      }
    }
    if (depth >= o.bounces) break;
    if (env_nee) {
      // The environment light this hit receives along an escaping bounce,
      // estimated from a luminance-sampled direction (the bounce below
      // carries the rest through its MIS weight).
      const float e1 = rng.next(), e2 = rng.next();
      const Environment::Sample es = env.sample(e1, e2);
      const float c = dot(v.normal, es.dir);
      if (es.pdf > 0.f && c > 0.f) {
        ++counts->shadow_rays;
        if (!scene.occluded(Ray{v.origin, es.dir, INFINITY}, depth)) {
          const Color e = env.radiance(es.dir);
          const float pc = c / kPathPi;
          const float k = pc * mis(es.pdf, pc) / es.pdf;
          L[0] += beta[0] * a[0] * e.r * k, L[1] += beta[1] * a[1] * e.g * k;
          L[2] += beta[2] * a[2] * e.b * k;
        }
      }
    }
    const float u1 = rng.next(), u2 = rng.next();
    const Vec3 dir = cosine_direction(v.normal, u1, u2);
    bounce_pdf = std::max(0.f, dot(v.normal, dir)) / kPathPi;
    for (int i = 0; i < 3; ++i) beta[i] *= a[i];
    if (depth + 1 >= o.rr_start) {
      const float q = std::min(1.f, std::max({beta[0], beta[1], beta[2]}));
      const float u = rng.next();
      if (!(u < q)) break;
      for (int i = 0; i < 3; ++i) beta[i] /= q;
    }
    ++counts->bounce_rays;
    ray = Ray{v.origin, dir, INFINITY};
  }
  return {L[0], L[1], L[2], 1.f};
}

}  // namespace voxcast::detail
