// The volume integrator of volume_integrator.hpp: front-to-back
// emission-absorption over VolumeQuery spans.
#include "voxcast/volume_integrator.hpp"

#if defined(__AVX2__)
#include <immintrin.h>
#endif

#include <array>
#include <atomic>
#include <charconv>
#include <cmath>
#include <cstddef>
#include <string_view>

#include "voxcast/error.hpp"

namespace voxcast {

// ---- Transfer function ----

TransferFunction::TransferFunction(std::vector<Point> points) : points_(std::move(points)) {
  for (size_t i = 0; i < points_.size(); ++i) {
    const Point& p = points_[i];
    if (!std::isfinite(p.value) || !std::isfinite(p.density) || p.density < 0.f)
      throw Error("transfer function: values and densities must be finite, densities >= 0");
    // Emitted radiance: finite and not negative (above 1 is an HDR emitter).
    for (const float c : {p.color.r, p.color.g, p.color.b})
      if (!(c >= 0.f) || !std::isfinite(c))
        throw Error("transfer function: colors must be finite and >= 0");
    if (i > 0 && !(p.value > points_[i - 1].value))
      throw Error("transfer function: values must be strictly increasing");
  }
}

VolumeSample TransferFunction::operator()(float s) const {
  if (points_.empty()) return {};
  auto out = [](const Point& p) { return VolumeSample{p.density, p.color}; };
  if (!(s > points_.front().value)) return out(points_.front());
  if (!(s < points_.back().value)) return out(points_.back());
  // First point above s (few points: a linear scan beats a search).
  size_t i = 1;
  while (points_[i].value <= s) ++i;
  const Point &a = points_[i - 1], &b = points_[i];
  const float f = (s - a.value) / (b.value - a.value), g = 1.f - f;
  return VolumeSample{g * a.density + f * b.density,
                      Color{g * a.color.r + f * b.color.r, g * a.color.g + f * b.color.g,
                            g * a.color.b + f * b.color.b, 1.f}};
}

namespace {

float parse_float(std::string_view s, const std::string& whole) {
  float v = 0.f;
  const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (ec != std::errc() || end != s.data() + s.size() || s.empty())
    throw Error("transfer function '" + whole + "': '" + std::string(s) + "' is not a number");
  return v;
}

std::vector<std::string_view> split(std::string_view s, char sep) {
  std::vector<std::string_view> parts;
  size_t start = 0;
  for (size_t i = 0; i <= s.size(); ++i)
    if (i == s.size() || s[i] == sep) parts.push_back(s.substr(start, i - start)), start = i + 1;
  return parts;
}

}  // namespace

TransferFunction TransferFunction::parse(const std::string& text) {
  std::vector<Point> points;
  for (std::string_view item : split(text, ';')) {
    const auto fields = split(item, ':');
    if (fields.size() != 3)
      throw Error("transfer function '" + text + "': expected value:density:r,g,b per point");
    const auto rgb = split(fields[2], ',');
    if (rgb.size() != 3)
      throw Error("transfer function '" + text + "': a color is three numbers r,g,b");
    Point p;
    p.value = parse_float(fields[0], text);
    p.density = parse_float(fields[1], text);
    p.color = {parse_float(rgb[0], text), parse_float(rgb[1], text), parse_float(rgb[2], text),
               1.f};
    points.push_back(p);
  }
  return TransferFunction(std::move(points));
}

// ---- Integrator ----

struct VolumeIntegrator::Totals {
  std::atomic<uint64_t> rays{0}, spans{0}, samples{0}, early{0}, shadow_rays{0}, shadow_samples{0};
};

VolumeIntegrator::VolumeIntegrator(VolumeIntegratorOptions options)
    : options_(std::move(options)), totals_(std::make_shared<Totals>()) {
  if (!(options_.step_scale > 0.f) || !std::isfinite(options_.step_scale))
    throw Error("volume integrator: step_scale must be a positive number");
  if (!(options_.opacity_cutoff > 0.f && options_.opacity_cutoff <= 1.f))
    throw Error("volume integrator: opacity_cutoff must be in (0, 1]");
  if (!(options_.depth_opacity > 0.f && options_.depth_opacity <= 1.f))
    throw Error("volume integrator: depth_opacity must be in (0, 1]");
  light_ = normalize(options_.light_dir);
  if (!(options_.dof_aperture >= 0.f) || !std::isfinite(options_.dof_aperture) ||
      (options_.dof_aperture > 0.f &&
       !(options_.dof_focus > 0.f && std::isfinite(options_.dof_focus))))
    throw Error("volume integrator: the lens aperture must be >= 0 and the focus distance > 0");
  if (!(options_.light_radius >= 0.f && options_.light_radius <= 1.f))
    throw Error("volume integrator: light_radius must be in [0, 1]");
  if (!(options_.shadow_step_scale > 0.f) || !std::isfinite(options_.shadow_step_scale))
    throw Error("volume integrator: shadow_step_scale must be a positive number");
  if (!(options_.shadow_footprint_scale >= 0.f && options_.shadow_footprint_scale <= 16.f))
    throw Error("volume integrator: shadow_footprint_scale must be in [0, 16]");
  if ((options_.shading || options_.shadows) && length(light_) == 0.f)
    throw Error("volume integrator: light_dir must not be zero");
}

void VolumeIntegrator::begin_frame(const Structure& structure, const FrameView&, Film&) {
  if (structure.volume() == nullptr)
    throw Error("volume render: structure '" + structure.name() + "' has no volume query");
  totals_->rays = 0, totals_->spans = 0, totals_->samples = 0, totals_->early = 0;
  totals_->shadow_rays = 0, totals_->shadow_samples = 0;
}

VolumeIntegratorStats VolumeIntegrator::stats() const {
  return {totals_->rays.load(),  totals_->spans.load(),       totals_->samples.load(),
          totals_->early.load(), totals_->shadow_rays.load(), totals_->shadow_samples.load()};
}

VolumeSample VolumeIntegrator::classify(VolumeSample s) const {
  return options_.transfer.empty() ? s : options_.transfer(s.density);
}

namespace {

/// The running front-to-back state of one ray.
struct Accumulator {
  // r, g, b (and a lane that sums w * alpha, never read): one 128-bit
  // multiply and add per piece under AVX2, the same products and sums.
  alignas(16) float c[4] = {0.f, 0.f, 0.f, 0.f};
  float T = 1.f;
  float depth = INFINITY;

  /// One piece of constant medium from t over length dt (the closed form of
  /// the header). `threshold`: the opacity the depth AOV records.
  void add(float t, float dt, float sigma, const Color& color, float threshold) {
    if (!(sigma > 0.f) || !(dt > 0.f)) return;
    const float a = std::exp(-sigma * dt);
    const float w = T * (1.f - a);
#if defined(__AVX2__)
    static_assert(sizeof(Color) == 16 && offsetof(Color, b) == 8);
    _mm_store_ps(c, _mm_add_ps(_mm_load_ps(c), _mm_mul_ps(_mm_set1_ps(w), _mm_loadu_ps(&color.r))));
#else
    c[0] += w * color.r, c[1] += w * color.g, c[2] += w * color.b;
#endif
    const float before = T;
    T *= a;
    if (std::isinf(depth) && 1.f - T >= threshold) {
      // Inside the piece T(x) = before exp(-sigma x) reaches 1 - threshold at
      // x = ln(before / (1 - threshold)) / sigma (x = 0 if it already had).
      const float rest = 1.f - threshold;
      const float x = rest > 0.f ? std::log(before / rest) / sigma : dt;
      depth = t + std::clamp(x, 0.f, dt);
    }
  }
};

}  // namespace

namespace {

/// N elements of T left uninitialized (T's default member initializers
/// skipped): the span and sample buffers below are written before they are
/// read, and zeroing them (a `rep stos` of 768 bytes per ray and 320 per
/// brick span) showed in the warm frames' profile.
template <class T, size_t N>
struct Scratch {
  union {
    T v[N];
  };
  Scratch() {}
  T& operator[](size_t i) { return v[i]; }
  const T& operator[](size_t i) const { return v[i]; }
  std::span<T> all() { return std::span<T>(v, N); }
  static constexpr size_t size() { return N; }
};

/// Walks one brick span of `ray` in steps, calling take(a, b, t, level,
/// sample) for each step [a, b] with its midpoint t until take returns false
/// (returns false then). Steps are step_scale x the larger of the span's
/// voxel and the cone at its entry (the LOD's own resolution: where the cone
/// is wider than the voxel, samples blend toward the parent's coarser brick,
/// which needs no denser steps), times the span's stretch (a voxel's length
/// along the ray over its size across it, volume_query.hpp). Samples come in chunks through
/// VolumeQuery::sample_span (the span's bricks resolved once per chunk);
/// nothing is allocated.
template <class Take>
bool walk_brick(const VolumeQuery& query, const Ray& ray, const LodFootprint& lod,
                const VolumeSpan& s, float step_scale, TraceContext& ctx, Take&& take) {
  const float foot0 = lod.size_at_origin + lod.size_per_t * s.t0;
  const float dt = step_scale * std::max(s.voxel_size, foot0) * s.stretch;
  const float steps = std::ceil((s.t1 - s.t0) / dt);
  // The cone's level L + log2(v / f(t)), clamped to [L - 1, L]: log2 of the
  // footprint (linear in t) is interpolated between the span's ends, where
  // it is exact (a span is one node: f changes by a small fraction across
  // it, and the interpolation stays continuous from span to span).
  const float foot1 = lod.size_at_origin + lod.size_per_t * s.t1;
  const float L = float(s.level), lo = std::max(0.f, L - 1.f);
  const bool cone = foot0 > 0.f && foot1 > 0.f;
  const float lv0 = cone ? L + std::log2(s.voxel_size / foot0) : L;
  const float lv1 = cone ? L + std::log2(s.voxel_size / foot1) : L;
  const float slope = s.t1 > s.t0 ? (lv1 - lv0) / (s.t1 - s.t0) : 0.f;
  constexpr int kChunk = 16;
  float tk[kChunk], lk[kChunk];
  Scratch<VolumeSample, kChunk> vk;
  for (float k0 = 0.f; k0 < steps; k0 += float(kChunk)) {
    const int m = int(std::min(float(kChunk), steps - k0));
    for (int j = 0; j < m; ++j) {
      const float a = s.t0 + (k0 + float(j)) * dt, b = std::min(s.t1, a + dt);
      tk[j] = 0.5f * (a + b);
      lk[j] = std::clamp(lv0 + slope * (tk[j] - s.t0), lo, L);
    }
    query.sample_span(ray, s, tk, lk, m, ctx, vk.v);
    for (int j = 0; j < m; ++j) {
      const float a = s.t0 + (k0 + float(j)) * dt, b = std::min(s.t1, a + dt);
      if (!take(a, b, tk[j], lk[j], vk[j])) return false;
    }
  }
  return true;
}

}  // namespace

float VolumeIntegrator::light_transmittance(const VolumeQuery& query, Vec3 p, float foot,
                                            TraceContext& ctx, uint64_t* samples) const {
  const VolumeIntegratorOptions& o = options_;
  // The light cone: as wide as the primary ray's footprint where it starts,
  // widening by the light's angular size (0: a hard shadow at the
  // footprint's resolution). A wider cone reads coarser levels and takes
  // longer steps: soft shadows cost less than hard ones.
  const Ray ray{p, light_, INFINITY};
  const LodFootprint lod{foot, 2.f * o.light_radius};
  const float stop = 1.f - o.opacity_cutoff;
  // Start one footprint away, so that the sample does not shadow itself.
  float T = 1.f, t_begin = foot;
  Scratch<VolumeSpan, 16> spans;
  for (;;) {
    const int n = query.march(ray, t_begin, lod, ctx, spans.all());
    for (int i = 0; i < n; ++i) {
      const VolumeSpan& s = spans[size_t(i)];
      if (s.constant) {
        T *= std::exp(-classify(s.value).density * (s.t1 - s.t0));
      } else {
        walk_brick(query, ray, lod, s, o.shadow_step_scale, ctx,
                   [&](float a, float b, float, float, const VolumeSample& v) {
                     ++*samples;
                     T *= std::exp(-classify(v).density * (b - a));
                     return T > stop;
                   });
      }
      if (!(T > stop)) return 0.f;
    }
    if (n < int(spans.size())) return T;
    const float next = spans[size_t(n) - 1].t1;
    if (!(next > t_begin)) return T;
    t_begin = next;
  }
}

VolumeRayResult VolumeIntegrator::integrate(const VolumeQuery& query, const Ray& ray,
                                            const LodFootprint& lod, TraceContext& ctx,
                                            VolumeIntegratorStats* stats) const {
  const VolumeIntegratorOptions& o = options_;
  Accumulator acc;
  Scratch<VolumeSpan, 16> spans;
  bool done = false;
  uint64_t span_count = 0, sample_count = 0, shadow_count = 0, shadow_samples = 0;
  const Vec3 view = -ray.dir;
  const Vec3 half = normalize(light_ + view);

  // The shading factor at p from the density gradient (one voxel apart).
  auto lighting = [&](Vec3 p, float level, float h, const VolumeSpan& span) {
    const Vec3 axes[3] = {{h, 0, 0}, {0, h, 0}, {0, 0, h}};
    Vec3 g;
    for (int a = 0; a < 3; ++a)
      g[a] = query.sample(p + axes[a], level, ctx, &span).density -
             query.sample(p - axes[a], level, ctx, &span).density;
    const float len = length(g);
    if (!(len > 0.f)) return 1.f;     // homogeneous: no direction to light
    const Vec3 n = g * (-1.f / len);  // out of the denser side
    const float diff = std::max(0.f, dot(n, light_));
    const float spec = diff > 0.f ? std::pow(std::max(0.f, dot(n, half)), o.shininess) : 0.f;
    return o.ambient + o.diffuse * diff + o.specular * spec;
  };
  // The light's transmittance at a sample (one light cone).
  auto light_T = [&](const Ray& r, float t, float foot) {
    ++shadow_count;
    return light_transmittance(query, r.origin + r.dir * t, foot * o.shadow_footprint_scale, ctx,
                               &shadow_samples);
  };

  // Depth of field (gigavoxels §3.9): the lens cone adds
  // aperture |t - focus| / focus to the pixel cone, which is linear in t on
  // each side of the focus plane: the ray is marched in two segments, each
  // with its own linear footprint, through the same mip-mapped traversal.
  struct Segment {
    Ray ray;
    LodFootprint lod;
    float t_begin;
  };
  Segment segments[2];
  int segment_count = 1;
  segments[0] = {ray, lod, 0.f};
  if (o.dof_aperture > 0.f) {
    const float A = o.dof_aperture, F = o.dof_focus;
    segments[0].lod = {lod.size_at_origin + A, lod.size_per_t - A / F};
    segments[0].ray.tmax = std::min(ray.tmax, F);
    if (ray.tmax > F)
      segments[1] = {ray, {lod.size_at_origin - A, lod.size_per_t + A / F}, F}, segment_count = 2;
  }

  for (int g = 0; g < segment_count && !done; ++g) {
    const Ray& sray = segments[g].ray;
    const LodFootprint& slod = segments[g].lod;
    float t_begin = segments[g].t_begin;
    while (!done) {
      const int n = query.march(sray, t_begin, slod, ctx, spans.all());
      for (int i = 0; i < n && !done; ++i) {
        const VolumeSpan& s = spans[size_t(i)];
        ++span_count;
        if (s.constant) {
          VolumeSample v = classify(s.value);
          if (o.shadows && v.density > 0.f) {
            const float m = 0.5f * (s.t0 + s.t1);
            const float T =
                light_T(sray, m, std::max(s.voxel_size, slod.size_at_origin + slod.size_per_t * m));
            const float f = o.ambient + (1.f - o.ambient) * T;
            v.color.r *= f, v.color.g *= f, v.color.b *= f;
          }
          acc.add(s.t0, s.t1 - s.t0, v.density, v.color, o.depth_opacity);
        } else {
          walk_brick(query, sray, slod, s, o.step_scale, ctx,
                     [&](float a, float b, float t, float level, const VolumeSample& raw) {
                       VolumeSample v = classify(raw);
                       ++sample_count;
                       if (v.density > 0.f && (o.shading || o.shadows)) {
                         float f = 1.f;
                         if (o.shading)
                           f = lighting(sray.origin + sray.dir * t, level, s.voxel_size, s);
                         if (o.shadows) {
                           // Shadows dim the direct light; the ambient term stays.
                           const float T = light_T(
                               sray, t,
                               std::max(s.voxel_size, slod.size_at_origin + slod.size_per_t * t));
                           f = o.ambient + ((o.shading ? f : 1.f) - o.ambient) * T;
                         }
                         v.color.r *= f, v.color.g *= f, v.color.b *= f;
                       }
                       acc.add(a, b - a, v.density, v.color, o.depth_opacity);
                       return 1.f - acc.T < o.opacity_cutoff;
                     });
        }
        if (1.f - acc.T >= o.opacity_cutoff) {
          done = true;
          if (stats) ++stats->early_terminations;
        }
      }
      if (done || n < int(spans.size())) break;
      const float next = spans[size_t(n) - 1].t1;
      if (!(next > t_begin)) break;  // a query that does not advance would loop forever
      t_begin = next;
    }
  }
  if (stats) {
    ++stats->rays, stats->spans += span_count, stats->samples += sample_count;
    stats->shadow_rays += shadow_count, stats->shadow_samples += shadow_samples;
  }

  VolumeRayResult r;
  r.transmittance = acc.T;
  r.color = {acc.c[0] + acc.T * o.background.r, acc.c[1] + acc.T * o.background.g,
             acc.c[2] + acc.T * o.background.b, 1.f - acc.T};
  r.depth = acc.depth;
  return r;
}

void VolumeIntegrator::render_tile(const Structure& structure, const FrameView& view,
                                   const TileRect& tile, TraceContext& ctx, Film& film) {
  const VolumeQuery* query = structure.volume();
  // A structure may keep per-context state in the accessor cache, such as
  // the requests it pushed lately so as not to push duplicates (GigaVoxels).
  // The frame loop tells which tiles asked for data by whether they pushed,
  // so nothing may be remembered from one tile to the next.
  ctx.cache.reset();
  const CameraRays cam = view.rays();
  const LodFootprint lod = view.lod();
  VolumeIntegratorStats local;
  for (int y = tile.y0; y < tile.y1; ++y)
    for (int x = tile.x0; x < tile.x1; ++x) {
      const VolumeRayResult r = integrate(*query, cam.ray(x, y), lod, ctx, &local);
      if (film.has(kAovColor)) {
        float* c = film.color.at(x, y);
        c[0] = r.color.r, c[1] = r.color.g, c[2] = r.color.b;
      }
      if (film.has(kAovAlpha)) *film.alpha.at(x, y) = r.color.a;
      if (film.has(kAovDepth)) *film.depth.at(x, y) = r.depth;
    }
  totals_->rays += local.rays, totals_->spans += local.spans;
  totals_->samples += local.samples, totals_->early += local.early_terminations;
  totals_->shadow_rays += local.shadow_rays, totals_->shadow_samples += local.shadow_samples;
}

}  // namespace voxcast
