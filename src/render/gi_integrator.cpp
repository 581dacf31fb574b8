// The GI integrator (include/voxcast/gi_integrator.hpp): the path loop of
// render/path_tracer.hpp on a structure's SurfaceQuery, accumulated over
// frames.
#include "voxcast/gi_integrator.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <string>

#include "render/const_view.hpp"
#include "render/path_tracer.hpp"
#include "voxcast/error.hpp"

namespace voxcast {
namespace {

/// The voxel side of path_tracer.hpp's Scene: hits, albedo and normals from
/// the SurfaceQuery, rays leaving a hit from offset_origin() (effects.hpp:
/// clear of the hit voxel's own surface).
struct VoxelScene {
  const SurfaceQuery& q;
  TraceContext& ctx;
  LodFootprint primary, secondary;

  bool intersect(const Ray& ray, int depth, detail::PathVertex* v) const {
    SurfaceHit hit;
    if (!q.trace(ray, depth == 0 ? primary : secondary, ctx, &hit)) return false;
    Color c;
    Vec3 n;
    q.attributes(hit, ctx, &c, &n);
    if (!(length(n) > 0.5f)) n = -ray.dir;
    v->t = hit.t;
    // An albedo above 1 would create energy; the attributes are colors in [0, 1].
    v->albedo = {std::clamp(c.r, 0.f, 1.f), std::clamp(c.g, 0.f, 1.f), std::clamp(c.b, 0.f, 1.f),
                 1.f};
    if (dot(n, ray.dir) <= 0.f) {
      v->normal = n;
      v->origin = offset_origin(ShadingPoint{hit.position, n, ray.dir, hit.voxel_size});
    } else {
      // A normal facing away from the ray: the back of a thin sheet (the
      // flip is right) or a voxel on an edge whose averaged normal leans to
      // the face the ray cannot see (the flip points into the solid, and
      // offset_origin would start the next rays inside it, where they never
      // escape). Scatter around the flipped normal, but start the rays two
      // voxel sides back along the arriving ray, which crossed only empty
      // space to get here (the voxel's diagonal is sqrt(3) sides): a wrong
      // normal then costs a re-hit of the surface, never a trapped path.
      v->normal = -n;
      v->origin = hit.position - ray.dir * std::min(2.f * hit.voxel_size, hit.t);
    }
    return true;
  }
  bool occluded(const Ray& ray, int depth) const {
    // Shadow rays of the primary hits at the finest level (crisp sun
    // shadows); later ones are as diffuse as the bounce that led there.
    return q.occluded(ray, depth == 0 ? LodFootprint{} : secondary, ctx);
  }
};

}  // namespace

void validate(const GiOptions& o) {
  if (o.spp < 1 || o.spp > 65536) throw Error("gi: samples per pixel must be in 1..65536");
  if (o.bounces < 0 || o.bounces > 1024) throw Error("gi: bounces must be in 0..1024");
  if (o.rr_start < 1) throw Error("gi: Russian roulette must start at bounce 1 or later");
  if (!(o.bounce_cone_deg >= 0.f && o.bounce_cone_deg < 90.f))
    throw Error("gi: bounce cone angle must be in [0, 90) degrees");
  if (o.sun) {
    const Vec3 d = o.sun_dir;
    if (!is_finite(d) || !(length(d) > 0.f)) throw Error("gi: sun direction must be non-zero");
    const Color& e = o.sun_irradiance;
    for (float c : {e.r, e.g, e.b})
      if (!(c >= 0.f) || !std::isfinite(c))
        throw Error("gi: sun irradiance must be finite and >= 0");
  }
}

GiIntegrator::GiIntegrator(const GiOptions& options) : options_(options) {
  validate(options_);
  if (options_.sun) options_.sun_dir = normalize(options_.sun_dir);
  if (!options_.environment) options_.environment = std::make_shared<const Environment>();
}

uint32_t GiIntegrator::aovs() const {
  uint32_t a = kAovColor;
  if (options_.want_depth) a |= kAovDepth;
  if (options_.want_normal) a |= kAovNormal;
  return a;
}

void GiIntegrator::set_spp(int spp) {
  GiOptions o = options_;
  o.spp = spp;
  validate(o);
  options_.spp = spp;
}

void GiIntegrator::reset() {
  samples_ = 0;
  base_.clear();
  sum_.clear();
}

void GiIntegrator::begin_frame(const Structure& structure, const FrameView& view, Film&) {
  query_ = structure.surface();
  if (query_ == nullptr)
    throw Error("gi: the " + structure.name() + " structure has no surface query");
  // Samples of another view must not be averaged in: a new size, camera or
  // LOD starts over (the viewer also calls reset() itself).
  const Camera& c = view.camera;
  auto same = [](Vec3 a, Vec3 b) { return a.x == b.x && a.y == b.y && a.z == b.z; };
  const bool same_view = view.width == width_ && view.height == height_ &&
                         view.lod_pixels == lod_pixels_ && same(c.eye, camera_.eye) &&
                         same(c.target, camera_.target) && same(c.up, camera_.up) &&
                         c.fovy_degrees == camera_.fovy_degrees &&
                         c.projection == camera_.projection && c.ortho_width == camera_.ortho_width;
  if (!same_view) reset();
  width_ = view.width, height_ = view.height;
  camera_ = c;
  lod_pixels_ = view.lod_pixels;
  const size_t n = size_t(width_) * size_t(height_);
  if (samples_ == 0) {
    base_.assign(n * 3, 0.0);
    depth_.assign(n, INFINITY);
    normal_.assign(n * 3, 0.5f);
  }
  sum_ = base_;
  cam_.emplace(view.camera, view.width, view.height);
  lod_ = view.lod();
  bounce_lod_ =
      LodFootprint{0.f, 2.f * std::tan(0.5f * options_.bounce_cone_deg * detail::kPathPi / 180.f)};
  stats_ = GiStats{};
}

void GiIntegrator::render_tile(const Structure&, const FrameView&, const TileRect& tile,
                               TraceContext& ctx, Film& film) {
  // With the counting path (FrameOptions::counting) ctx.counters sums the
  // caster work of every ray of the paths; GiStats counts the rays.
  const VoxelScene scene{*query_, ctx, lod_, bounce_lod_};
  const Environment& env = *options_.environment;
  const uint32_t s0 = samples_, s1 = samples_ + uint32_t(options_.spp);
  const float inv = 1.f / float(s1);
  detail::PathCounts counts;
  for (int y = tile.y0; y < tile.y1; ++y)
    for (int x = tile.x0; x < tile.x1; ++x) {
      const size_t p = size_t(y) * size_t(width_) + size_t(x);
      // From the sums before this frame: a tile rendered again in a later
      // pass of the same frame replaces its samples instead of adding twice.
      double acc[3] = {base_[3 * p], base_[3 * p + 1], base_[3 * p + 2]};
      for (uint32_t s = s0; s < s1; ++s) {
        detail::PathRng rng(x, y, options_.seed, s);
        const Ray ray = detail::jittered_ray(*cam_, x, y, rng);
        detail::PathVertex first;
        const Color c =
            detail::trace_path(scene, ray, options_, env, rng, &counts, s == 0 ? &first : nullptr);
        acc[0] += c.r, acc[1] += c.g, acc[2] += c.b;
        if (s == 0) {
          depth_[p] = first.t;
          const Vec3 n = std::isfinite(first.t) ? first.normal : Vec3{0, 0, 0};
          normal_[3 * p] = n.x * 0.5f + 0.5f;
          normal_[3 * p + 1] = n.y * 0.5f + 0.5f;
          normal_[3 * p + 2] = n.z * 0.5f + 0.5f;
        }
      }
      float* out = film.color.at(x, y);
      for (int k = 0; k < 3; ++k) {
        sum_[3 * p + k] = acc[k];
        out[k] = float(acc[k]) * inv;
      }
      if (options_.want_depth) *film.depth.at(x, y) = depth_[p];
      if (options_.want_normal) {
        float* o = film.normal.at(x, y);
        for (int k = 0; k < 3; ++k) o[k] = normal_[3 * p + k];
      }
    }
  const uint64_t pixels = uint64_t(tile.x1 - tile.x0) * uint64_t(tile.y1 - tile.y0);
  std::lock_guard<std::mutex> lock(stats_mutex_);
  stats_.samples += pixels * uint64_t(options_.spp);
  stats_.bounce_rays += counts.bounce_rays;
  stats_.shadow_rays += counts.shadow_rays;
}

void GiIntegrator::end_frame(const Structure&, const FrameView&, Film&) {
  base_.swap(sum_);
  samples_ += uint32_t(options_.spp);
  stats_.rays = stats_.samples + stats_.bounce_rays + stats_.shadow_rays;
}

GiResult render_gi(const Structure& structure, const Camera& camera, int width, int height,
                   float lod_pixels, const GiOptions& options) {
  detail::ConstView frame_structure(structure);
  GiIntegrator integrator(options);
  FrameView view;
  view.camera = camera;
  view.width = width, view.height = height;
  view.lod_pixels = lod_pixels;
  FrameOptions fo;
  fo.max_passes = 1;
  GiResult r;
  const FrameStats fs = render_frame(frame_structure, integrator, view, fo, &r.film);
  r.stats = integrator.stats();
  r.stats.seconds = fs.seconds;
  return r;
}

}  // namespace voxcast
