// Shadows and ambient occlusion by occlusion rays (svdag §4; Laine & Karras
// 2010b for the AO sampling). See include/voxcast/effects.hpp for the
// contracts; the comments here explain the choices.
#include "voxcast/effects.hpp"

#include <algorithm>
#include <cmath>
#include <string>

#include "voxcast/error.hpp"

namespace voxcast {

namespace {

// lowbias32 (Wellons): a full-avalanche 32-bit integer hash.
uint32_t hash32(uint32_t x) {
  x ^= x >> 16;
  x *= 0x7feb352du;
  x ^= x >> 15;
  x *= 0x846ca68bu;
  x ^= x >> 16;
  return x;
}

// [0, 1) from the top 24 bits.
float unit_float(uint32_t h) {
  return float(h >> 8) * 0x1p-24f;
}

float frac(float x) {
  return x - std::floor(x);
}

// Radical inverses (van der Corput) in bases 2 and 3: the 2nd and 3rd
// Hammersley dimensions, one sample per 1/N stratum of each dimension.
float radical_inverse2(uint32_t i) {
  i = (i << 16) | (i >> 16);
  i = ((i & 0x00ff00ffu) << 8) | ((i & 0xff00ff00u) >> 8);
  i = ((i & 0x0f0f0f0fu) << 4) | ((i & 0xf0f0f0f0u) >> 4);
  i = ((i & 0x33333333u) << 2) | ((i & 0xccccccccu) >> 2);
  i = ((i & 0x55555555u) << 1) | ((i & 0xaaaaaaaau) >> 1);
  return float(i >> 8) * 0x1p-24f;
}
float radical_inverse3(uint32_t i) {
  double inv = 1.0 / 3.0, f = inv, r = 0.0;
  while (i > 0) {
    r += f * double(i % 3);
    i /= 3;
    f *= inv;
  }
  return float(r);
}

// Sample i of n, dimension `dim`, rotated by the pixel's Cranley-Patterson
// offset. Kept strictly inside (0, 1) so that mapped samples stay inside the
// light rectangle (and so inside the beam of its corners).
float sample(int i, int n, int dim, uint32_t seed) {
  const float shift = unit_float(hash32(seed ^ (0x9e3779b9u * uint32_t(dim + 1))));
  float u;
  switch (dim) {
    case 0:
      u = (float(i) + 0.5f) / float(n);
      break;
    case 1:
      u = radical_inverse2(uint32_t(i));
      break;
    default:
      u = radical_inverse3(uint32_t(i));
      break;
  }
  return std::clamp(frac(u + shift), 0x1p-20f, 1.f - 0x1p-20f);
}

// Orthonormal basis around a unit vector (Duff et al. 2017).
void basis(Vec3 n, Vec3* t, Vec3* b) {
  const float sign = std::copysign(1.f, n.z);
  const float a = -1.f / (sign + n.z);
  const float c = n.x * n.y * a;
  *t = {1.f + sign * n.x * n.x * a, sign * c, -sign * n.x};
  *b = {c, sign + n.y * n.y * a, -n.y};
}

bool finite_nonzero(Vec3 v) {
  return is_finite(v) && length(v) > 0.f;
}

}  // namespace

void validate(const EffectOptions& o) {
  if (o.shadow_rays < 1 || o.shadow_rays > 4096)
    throw Error("effects: shadow rays must be in 1..4096");
  if (o.ao_rays < 0 || o.ao_rays > 4096) throw Error("effects: AO rays must be in 0..4096");
  if (!std::isfinite(o.ao_radius)) throw Error("effects: AO radius must be finite");
  if (!(o.ao_cone_angle_deg >= 0.f && o.ao_cone_angle_deg < 90.f))
    throw Error("effects: AO cone angle must be in [0, 90) degrees");
  if (o.light != LightKind::Directional && !is_finite(o.light_position))
    throw Error("effects: light position must be finite");
  if (o.light == LightKind::Area) {
    if (!finite_nonzero(o.area_u) || !finite_nonzero(o.area_v) ||
        !(length(cross(o.area_u, o.area_v)) > 0.f))
      throw Error("effects: area light edges must be finite, non-zero and not parallel");
  }
  if (o.shadows == ShadowMode::Soft && o.light != LightKind::Area)
    throw Error("effects: soft shadows need an area light");
}

Vec3 offset_origin(const ShadingPoint& p) {
  return p.position + (p.normal * 2.f - p.view_dir) * p.voxel_size;
}

uint32_t pixel_seed(int x, int y, uint32_t seed) {
  return hash32(uint32_t(x) * 0x8da6b343u ^
                hash32(uint32_t(y) * 0xd8163841u ^ hash32(seed + 0x2545f491u)));
}

Vec3 direction_to_light(const EffectOptions& o, Vec3 light_dir, Vec3 p, float* distance) {
  if (o.light == LightKind::Directional) {
    *distance = INFINITY;
    return normalize(-light_dir);
  }
  const Vec3 d = o.light_position - p;
  *distance = length(d);
  return normalize(d);
}

float shadow_visibility(const Occluder& occ, TraceContext& ctx, const ShadingPoint& p,
                        const EffectOptions& o, Vec3 light_dir, uint32_t seed,
                        EffectCounters* counters) {
  const Vec3 origin = offset_origin(p);
  EffectCounters c;
  float visibility = 0.f;
  if (o.shadows == ShadowMode::Hard || o.light != LightKind::Area) {
    // One ray to the light (an area light's center for hard shadows).
    float dist;
    const Vec3 d = direction_to_light(o, light_dir, origin, &dist);
    if (dot(d, p.normal) > 0.f && dist > 0.f) {  // below the horizon: the surface itself blocks
      ++c.shadow_rays;
      visibility = occ.transmittance(Ray{origin, d, dist}, LodFootprint{}, ctx, nullptr);
    }
    if (counters) *counters += c;
    return visibility;
  }

  // ---- Soft shadows, rectangular area light (svdag §4) ----
  const int n = o.shadow_rays;
  const Vec3 corner[4] = {
      o.light_position + o.area_u + o.area_v, o.light_position - o.area_u + o.area_v,
      o.light_position - o.area_u - o.area_v, o.light_position + o.area_u - o.area_v};
  bool all_above = true, any_above = false;
  for (const Vec3& k : corner) {
    const bool above = dot(k - origin, p.normal) > 0.f;
    all_above &= above, any_above |= above;
  }
  if (!any_above) {  // the rectangle is convex: every sample is below the horizon
    if (counters) *counters += c;
    return 0.f;
  }
  ++c.beams;
  // Samples: stratified (rotated Hammersley) over [-1, 1]^2 of the rectangle.
  // Rays below the horizon count as occluded without a ray.
  auto sample_ray = [&](int i, Ray* ray) {
    const float a = 2.f * sample(i, n, 0, seed) - 1.f, b = 2.f * sample(i, n, 1, seed) - 1.f;
    const Vec3 target = o.light_position + o.area_u * a + o.area_v * b;
    const Vec3 d = target - origin;
    const float dist = length(d);
    if (!(dist > 0.f)) return false;
    *ray = Ray{origin, d / dist, dist};
    return dot(ray->dir, p.normal) > 0.f;
  };

  BeamStart start;  // invalid = no information
  if (o.shadow_beam == ShadowBeam::Conservative) {
    // The beam from the shading point over the whole light, traced
    // conservatively (esvo §6.2 coarse pass). Its region holds every voxel any
    // ray of the beam can hit, so clipping the shadow rays to it shortens them
    // from both ends (svdag §4: forward from the view sample and backward from
    // the light) without changing a single answer.
    BeamFrustum beam;
    beam.eye = origin;
    float min_cos = 1.f;
    bool ok = true;
    for (int k = 0; k < 4; ++k) {
      beam.edge[k] = normalize(corner[k] - origin);
      ok &= finite_nonzero(beam.edge[k]);
    }
    if (ok) {
      for (int i = 0; i < 4; ++i)
        for (int j = i + 1; j < 4; ++j)
          min_cos = std::min(min_cos, dot(beam.edge[i], beam.edge[j]));
      // Widest angle between two directions of the cone = between two corner
      // directions (the cone is their convex hull); 1e-4 relative + 1e-6 rad slack.
      beam.angular_width = std::acos(std::clamp(min_cos, -1.f, 1.f)) * 1.0001f + 1e-6f;
      occ.beam_start(beam, ctx, &start);
    }
    if (start.valid && start.empty) {
      ++c.beams_lit;
      int lit = 0;
      Ray ray;
      for (int i = 0; i < n; ++i) lit += sample_ray(i, &ray);
      if (counters) *counters += c;
      return float(lit) / float(n);
    }
  } else if (o.shadow_beam == ShadowBeam::Corners && all_above) {
    // The literal 4-ray beam: not conservative (see effects.hpp).
    bool any_blocked = false;
    for (int k = 0; k < 4 && !any_blocked; ++k) {
      const Vec3 d = corner[k] - origin;
      const float dist = length(d);
      ++c.shadow_rays;
      any_blocked =
          occ.transmittance(Ray{origin, d / dist, dist}, LodFootprint{}, ctx, nullptr) < 1.f;
    }
    if (!any_blocked) {
      ++c.beams_lit;
      if (counters) *counters += c;
      return 1.f;  // all corners above the horizon -> every sample is (convexity)
    }
  }
  // The sum of 0/1 transmittances is an exact small integer, so a surface's
  // visibility is the fraction of unoccluded rays, as counted.
  float lit = 0.f;
  for (int i = 0; i < n; ++i) {
    Ray ray;
    if (!sample_ray(i, &ray)) continue;
    ++c.shadow_rays;
    lit += occ.transmittance(ray, LodFootprint{}, ctx, start.valid ? &start : nullptr);
  }
  if (counters) *counters += c;
  return lit / float(n);
}

void shadow_visibility_batch(const Occluder& occ, TraceContext& ctx, const ShadingPoint* points,
                             int n, const EffectOptions& o, Vec3 light_dir, const uint32_t* seeds,
                             EffectCounters* counters, float* out) {
  if (!o.packets || (o.shadows != ShadowMode::Hard && o.light == LightKind::Area)) {
    for (int i = 0; i < n; ++i)
      out[i] = shadow_visibility(occ, ctx, points[i], o, light_dir, seeds[i], counters);
    return;
  }
  // shadow_visibility's one ray per point, all traced in one batch: the
  // batch's answers are the single rays' (Occluder::transmittance_batch).
  constexpr int kMax = 256;  // a tile's (render/surface_integrator.cpp kShadowGroup)
  Ray rays[kMax];
  int slot[kMax];
  float vis[kMax];
  EffectCounters c;
  for (int b = 0; b < n; b += kMax) {
    const int m = std::min(kMax, n - b);
    int k = 0;
    for (int i = 0; i < m; ++i) {
      const ShadingPoint& p = points[b + i];
      const Vec3 origin = offset_origin(p);
      float dist;
      const Vec3 d = direction_to_light(o, light_dir, origin, &dist);
      out[b + i] = 0.f;
      slot[i] = -1;
      if (dot(d, p.normal) > 0.f && dist > 0.f) {  // below the horizon: occluded, no ray
        slot[i] = k;
        rays[k++] = Ray{origin, d, dist};
      }
    }
    c.shadow_rays += uint64_t(k);
    occ.transmittance_batch(rays, size_t(k), LodFootprint{}, ctx, vis, 0, nullptr);
    for (int i = 0; i < m; ++i)
      if (slot[i] >= 0) out[b + i] = vis[slot[i]];
  }
  if (counters) *counters += c;
}

float ambient_occlusion(const Occluder& occ, TraceContext& ctx, const ShadingPoint& p,
                        const EffectOptions& o, float radius, uint32_t seed,
                        EffectCounters* counters) {
  const int n = o.ao_rays;
  if (n <= 0 || !(radius > 0.f)) return 1.f;
  const Vec3 origin = offset_origin(p);
  Vec3 t, b;
  basis(p.normal, &t, &b);
  // svdag §4: stop AO rays at nodes that subtend the cone angle from the ray
  // origin, i.e. whose side <= 2 tan(angle/2) * t (a coarser LOD farther
  // out: faster, darker than ground truth, exact near contact).
  LodFootprint lod;
  if (o.ao_cone_angle_deg > 0.f)
    lod.size_per_t = 2.f * std::tan(0.5f * o.ao_cone_angle_deg * 3.14159265358979f / 180.f);
  float open = 0.f;  // sum of transmittances (exact integers for a surface)
  // o.packets: the point's rays are generated first and traced together (on
  // the octree family: packets of one point's rays, which share their origin
  // and so the first nodes they read; docs/BENCHMARKS.md "Occlusion
  // packets"), then
  // summed in the same order, so `open` is the same float.
  constexpr int kMaxRays = 4096;  // validate(): ao_rays <= 4096
  thread_local Ray group[kMaxRays];
  thread_local float trans[kMaxRays];
  for (int i = 0; i < n; ++i) {
    // Cosine-weighted direction (Malley): uniform on the disc, lifted.
    const float u1 = sample(i, n, 0, seed), u2 = sample(i, n, 1, seed), u3 = sample(i, n, 2, seed);
    const float r = std::sqrt(u1), phi = 6.28318530717959f * u2;
    const float z = std::sqrt(std::max(0.f, 1.f - u1));
    const Vec3 d = normalize(t * (r * std::cos(phi)) + b * (r * std::sin(phi)) + p.normal * z);
    // Falloff in sampling (Laine & Karras 2010b): length R*sqrt(u) has
    // P(L > d) = 1 - (d/R)^2 = f(d), so a ray is occluded with probability f.
    const float len = radius * std::sqrt(u3);
    if (o.packets)
      group[i] = Ray{origin, d, len};
    else
      open += occ.transmittance(Ray{origin, d, len}, lod, ctx, nullptr);
  }
  if (o.packets) {
    occ.transmittance_batch(group, size_t(n), lod, ctx, trans, n, &p.normal);
    for (int i = 0; i < n; ++i) open += trans[i];
  }
  if (counters) counters->ao_rays += uint64_t(n);
  return open / float(n);
}

}  // namespace voxcast
