// Volume scenes: several objects with their own transforms (gigavoxels_scene.hpp).
#include <algorithm>
#include <array>
#include <cmath>

#include "voxcast/error.hpp"
#include "voxcast/gigavoxels_scene.hpp"

namespace voxcast::giga {

// ---- Affine ----

Vec3 Affine::point(Vec3 p) const {
  Vec3 r;
  for (int i = 0; i < 3; ++i) r[i] = m[i][0] * p.x + m[i][1] * p.y + m[i][2] * p.z + m[i][3];
  return r;
}

Vec3 Affine::vector(Vec3 d) const {
  Vec3 r;
  for (int i = 0; i < 3; ++i) r[i] = m[i][0] * d.x + m[i][1] * d.y + m[i][2] * d.z;
  return r;
}

Affine Affine::operator*(const Affine& o) const {
  Affine r;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 4; ++j) {
      float s = j == 3 ? m[i][3] : 0.f;
      for (int k = 0; k < 3; ++k) s += m[i][k] * o.m[k][j];
      r.m[i][j] = s;
    }
  return r;
}

float Affine::determinant() const {
  return m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) -
         m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
         m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
}

Affine Affine::inverse() const {
  for (const auto& row : m)
    for (float v : row)
      if (!std::isfinite(v)) throw Error("volume scene: a transform has a non-finite entry");
  // Adjugate / determinant in double (a scene's scales may span decades).
  double a[3][3];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) a[i][j] = m[i][j];
  const double det = a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1]) -
                     a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0]) +
                     a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]);
  double scale = 0;
  for (const auto& row : a)
    for (double v : row) scale = std::max(scale, std::abs(v));
  if (!(std::abs(det) > 1e-12 * scale * scale * scale))
    throw Error("volume scene: a transform is singular (it flattens the object)");
  Affine r;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      // Cofactor (j, i) of a.
      const int r0 = (j + 1) % 3, r1 = (j + 2) % 3, c0 = (i + 1) % 3, c1 = (i + 2) % 3;
      r.m[i][j] = float((a[r0][c0] * a[r1][c1] - a[r0][c1] * a[r1][c0]) / det);
    }
  const Vec3 t = r.vector({m[0][3], m[1][3], m[2][3]});
  for (int i = 0; i < 3; ++i) r.m[i][3] = -t[i];
  return r;
}

Affine Affine::translate(Vec3 t) {
  Affine r;
  for (int i = 0; i < 3; ++i) r.m[i][3] = t[i];
  return r;
}

Affine Affine::scale(Vec3 s) {
  Affine r;
  for (int i = 0; i < 3; ++i) r.m[i][i] = s[i];
  return r;
}

Affine Affine::rotate(Vec3 axis, float degrees) {
  if (!(length(axis) > 0.f)) throw Error("volume scene: a rotation axis must not be zero");
  const Vec3 u = normalize(axis);
  const double a = double(degrees) * M_PI / 180.0, c = std::cos(a), s = std::sin(a), k = 1 - c;
  // Rodrigues' rotation matrix.
  const double x = u.x, y = u.y, z = u.z;
  const double rot[3][3] = {{c + x * x * k, x * y * k - z * s, x * z * k + y * s},
                            {y * x * k + z * s, c + y * y * k, y * z * k - x * s},
                            {z * x * k - y * s, z * y * k + x * s, c + z * z * k}};
  Affine r;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) r.m[i][j] = float(rot[i][j]);
  return r;
}

// ---- The scene ----

namespace {

constexpr int kObjectShift = 48;
constexpr uint64_t kLocalMask = (uint64_t(1) << kObjectShift) - 1;
constexpr uint64_t kCompositeTag = 0xFFFFu;

uint64_t object_tag(int object) {
  return uint64_t(object + 1) << kObjectShift;
}

/// Clips [*t0, *t1] to where o + d t lies in box b; false when empty.
bool clip_box(const Aabb& b, Vec3 o, Vec3 d, float* t0, float* t1) {
  for (int a = 0; a < 3; ++a) {
    if (d[a] == 0.f) {
      if (!(o[a] >= b.lo[a] && o[a] <= b.hi[a])) return false;
      continue;
    }
    float ta = (b.lo[a] - o[a]) / d[a], tb = (b.hi[a] - o[a]) / d[a];
    if (ta > tb) std::swap(ta, tb);
    *t0 = std::max(*t0, ta), *t1 = std::min(*t1, tb);
  }
  return *t1 > *t0;
}

/// The level the volume integrator hands sample_span for a span of level L
/// and voxel v under a footprint f (volume_integrator.hpp: L + log2(v / f)
/// clamped to [max(0, L - 1), L]).
float cone_level(const VolumeSpan& s, float foot) {
  const float L = float(s.level);
  if (!(foot > 0.f)) return L;
  return std::clamp(L + std::log2(s.voxel_size / foot), std::max(0.f, L - 1.f), L);
}

/// Extinction-weighted sums of a medium (colors mix by extinction).
struct Mix {
  float sigma = 0.f, c[3] = {0.f, 0.f, 0.f};
  void add(const VolumeSample& s) {
    if (!(s.density > 0.f)) return;
    sigma += s.density;
    c[0] += s.density * s.color.r, c[1] += s.density * s.color.g, c[2] += s.density * s.color.b;
  }
  VolumeSample sample() const {
    VolumeSample s;
    if (sigma > 0.f) {
      const float inv = 1.f / sigma;
      s = {sigma, {c[0] * inv, c[1] * inv, c[2] * inv, 1.f}};
    }
    return s;
  }
};

}  // namespace

/// An object along one ray: its local ray (same t), the world-to-local
/// length factor k = |M^-1 d| along the ray, the largest world length across
/// the ray of a local unit (sigma, header) and where the ray crosses its
/// bounds.
struct VolumeScene::Placed {
  int object = 0;
  Ray ray;
  float k = 1.f, sigma = 1.f;
  float ta = 0.f, tb = 0.f;
  /// The cone's footprint in local units (header: f / sigma).
  LodFootprint local_lod(const LodFootprint& lod) const {
    return {lod.size_at_origin / sigma, lod.size_per_t / sigma};
  }
  /// A local span in world terms: its size across the ray and its stretch.
  void to_world(VolumeSpan* s) const {
    s->voxel_size *= sigma;
    s->stretch /= k * sigma;
  }
};

float VolumeScene::across_stretch(int object, Vec3 d) const {
  // G restricted to the plane across d has trace tr(G) - d^T G d and
  // determinant d^T adj(G) d (|d| = 1); its larger eigenvalue is sigma^2.
  const std::array<float, 6>& g = gram_[size_t(object)];
  const std::array<float, 6>& a = gram_adjugate_[size_t(object)];
  const double x = d.x, y = d.y, z = d.z, n2 = x * x + y * y + z * z;
  auto form = [&](const std::array<float, 6>& m) {
    return (m[0] * x * x + m[1] * y * y + m[2] * z * z +
            2.0 * (m[3] * x * y + m[4] * x * z + m[5] * y * z)) /
           n2;
  };
  const double trace = double(g[0]) + g[1] + g[2] - form(g), det = form(a) / n2;
  const double half = 0.5 * trace;
  return float(std::sqrt(half + std::sqrt(std::max(0.0, half * half - det))));
}

VolumeScene::VolumeScene(std::vector<SceneObject> objects) : objects_(std::move(objects)) {
  if (objects_.empty()) throw Error("volume scene: no object");
  if (objects_.size() > size_t(kMaxSceneObjects))
    throw Error("volume scene: at most " + std::to_string(kMaxSceneObjects) + " objects");
  for (const SceneObject& o : objects_) {
    if (!o.structure || !o.structure->volume())
      throw Error("volume scene: object '" + o.name + "' has no volume");
    inverse_.push_back(o.transform.inverse());
    local_bounds_.push_back(o.structure->bounds());
    point_scale_.push_back(std::cbrt(std::abs(inverse_.back().determinant())));
    // G = A A^T (symmetric), its adjugate, and its largest eigenvalue by
    // power iteration (G is positive definite: A is not singular).
    double A[3][3], G[3][3];
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) A[i][j] = o.transform.m[i][j];
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j)
        G[i][j] = A[i][0] * A[j][0] + A[i][1] * A[j][1] + A[i][2] * A[j][2];
    auto cof = [&](int i, int j) {
      const int r0 = (i + 1) % 3, r1 = (i + 2) % 3, c0 = (j + 1) % 3, c1 = (j + 2) % 3;
      return G[r0][c0] * G[r1][c1] - G[r0][c1] * G[r1][c0];
    };
    gram_.push_back({float(G[0][0]), float(G[1][1]), float(G[2][2]), float(G[0][1]), float(G[0][2]),
                     float(G[1][2])});
    gram_adjugate_.push_back({float(cof(0, 0)), float(cof(1, 1)), float(cof(2, 2)),
                              float(cof(0, 1)), float(cof(0, 2)), float(cof(1, 2))});
    double v[3] = {1.0, 0.7548776662, 0.5698402910}, lambda = 0;  // not an eigenvector of a
                                                                  // diagonal G
    for (int it = 0; it < 200; ++it) {
      double w[3];
      for (int i = 0; i < 3; ++i) w[i] = G[i][0] * v[0] + G[i][1] * v[1] + G[i][2] * v[2];
      const double len = std::sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
      lambda = len / std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
      for (int i = 0; i < 3; ++i) v[i] = w[i] / len;
    }
    max_stretch_.push_back(float(std::sqrt(lambda)));
  }
}

Aabb VolumeScene::bounds() const {
  Aabb b;
  for (size_t i = 0; i < objects_.size(); ++i) {
    const Aabb& l = local_bounds_[i];
    for (int c = 0; c < 8; ++c)
      b.extend(objects_[i].transform.point(
          {c & 1 ? l.hi.x : l.lo.x, c & 2 ? l.hi.y : l.lo.y, c & 4 ? l.hi.z : l.lo.z}));
  }
  return b;
}

void VolumeScene::begin_frame(const FrameView& view) {
  for (SceneObject& o : objects_) o.structure->begin_frame(view);
}

void VolumeScene::end_frame() {
  for (SceneObject& o : objects_) o.structure->end_frame();
}

PassOutcome VolumeScene::end_pass(std::span<const Request> requests) {
  // Requests arrive sorted by (kind, key): each object's, untagged, stay sorted.
  std::vector<std::vector<Request>> mine(objects_.size());
  for (const Request& r : requests) {
    const uint64_t tag = r.key >> kObjectShift;
    if (tag == 0 || tag > objects_.size()) continue;
    Request own = r;
    own.key &= kLocalMask;
    mine[size_t(tag - 1)].push_back(own);
  }
  PassOutcome out;
  for (size_t i = 0; i < objects_.size(); ++i) {
    const PassOutcome o = objects_[i].structure->end_pass(mine[i]);
    out.changed = out.changed || o.changed;
    out.served += o.served, out.pending += o.pending;
  }
  return out;
}

VolumeSample VolumeScene::classified(int object, VolumeSample s, float k) const {
  const TransferFunction& tf = objects_[size_t(object)].transfer;
  if (!tf.empty()) s = tf(s.density);
  s.density *= k;
  return s;
}

int VolumeScene::march(const Ray& ray, float t_begin, const LodFootprint& lod, TraceContext& ctx,
                       std::span<VolumeSpan> out) const {
  if (out.empty()) return 0;
  const float t_start = std::max(0.f, t_begin);
  std::array<Placed, kMaxSceneObjects> placed;
  int count = 0;
  for (size_t i = 0; i < objects_.size(); ++i) {
    Placed p;
    p.object = int(i);
    p.ray = {inverse_[i].point(ray.origin), inverse_[i].vector(ray.dir), ray.tmax};
    p.k = length(p.ray.dir);
    p.sigma = across_stretch(int(i), ray.dir);
    p.ta = t_start, p.tb = ray.tmax;
    if (clip_box(local_bounds_[i], p.ray.origin, p.ray.dir, &p.ta, &p.tb))
      placed[size_t(count++)] = p;
  }
  std::sort(placed.begin(), placed.begin() + count, [](const Placed& a, const Placed& b) {
    return a.ta != b.ta ? a.ta < b.ta : a.object < b.object;
  });

  // A part's spans from t, its requests tagged; spans in world terms.
  auto march_part = [&](const Placed& p, float t, std::span<VolumeSpan> buf) {
    const size_t before = ctx.requests.size();
    const int m =
        objects_[size_t(p.object)].structure->volume()->march(p.ray, t, p.local_lod(lod), ctx, buf);
    ctx.requests.tag_keys(before, object_tag(p.object));
    for (int j = 0; j < m; ++j) {
      VolumeSpan& s = buf[size_t(j)];
      p.to_world(&s);
      if (s.constant) s.value = classified(p.object, s.value, p.k);
      s.node = object_tag(p.object) | (s.node & kLocalMask);
    }
    return m;
  };

  int n = 0;
  int first = 0;  // placed[first..] may still have spans past t
  float t = t_start;
  while (n < int(out.size()) && first < count) {
    // The cluster of objects whose intervals overlap (transitively) from t.
    while (first < count && !(placed[size_t(first)].tb > t)) ++first;
    if (first == count) break;
    int last = first + 1;
    float end = placed[size_t(first)].tb;
    while (last < count && placed[size_t(last)].ta < end)
      end = std::max(end, placed[size_t(last)].tb), ++last;
    int live = 0;
    for (int i = first; i < last; ++i) live += placed[size_t(i)].tb > t;
    const float from = std::max(t, placed[size_t(first)].ta);
    if (live == 1) {
      // One object: its spans pass through.
      const Placed& p = placed[size_t(first)];
      const int m = march_part(p, from, out.subspan(size_t(n)));
      n += m;
      if (n == int(out.size())) return n;
      t = end, first = last;
      continue;
    }
    // Overlapping objects: each part's next spans, merged up to the first
    // place where one part's buffer ends (the horizon).
    constexpr int kPartSpans = 16;
    struct Part {
      const Placed* placed;
      std::array<VolumeSpan, kPartSpans> spans;
      int count = 0, at = 0;
    };
    std::array<Part, kMaxSceneObjects> parts;
    int part_count = 0;
    float horizon = end;
    for (int i = first; i < last; ++i) {
      const Placed& p = placed[size_t(i)];
      if (!(p.tb > t)) continue;
      Part& q = parts[size_t(part_count++)];
      q.placed = &p;
      q.count = march_part(p, from, q.spans);
      if (q.count == kPartSpans) horizon = std::min(horizon, q.spans[kPartSpans - 1].t1);
    }
    if (!(horizon > from)) break;  // no part advanced (a span never ends where it starts)
    float u = from;
    while (u < horizon) {
      float v = horizon;
      for (int i = 0; i < part_count; ++i) {
        Part& q = parts[size_t(i)];
        while (q.at < q.count && !(q.spans[size_t(q.at)].t1 > u)) ++q.at;
        if (q.at == q.count) continue;
        const VolumeSpan& s = q.spans[size_t(q.at)];
        v = std::min(v, s.t0 > u ? s.t0 : s.t1);
      }
      // The parts that answer over [u, v].
      int active = 0, single = -1;
      bool all_constant = true;
      uint32_t mask = 0;
      Mix mix;
      float along = INFINITY, stretch = 1.f;  // the shortest voxel along the ray
      for (int i = 0; i < part_count; ++i) {
        const Part& q = parts[size_t(i)];
        if (q.at == q.count || q.spans[size_t(q.at)].t0 > u) continue;
        const VolumeSpan& s = q.spans[size_t(q.at)];
        ++active, single = i;
        mask |= 1u << q.placed->object;
        along = std::min(along, s.voxel_size * s.stretch);
        stretch = std::min(stretch, s.stretch);
        if (s.constant)
          mix.add(s.value);
        else
          all_constant = false;
      }
      if (active > 0 && v > u) {
        VolumeSpan s;
        if (active == 1) {
          s = parts[size_t(single)].spans[size_t(parts[size_t(single)].at)];
        } else {
          s.node = (kCompositeTag << kObjectShift) | mask;
          // Steps no longer than any part's voxel along the ray, nor than
          // the footprint times the most squashed part's stretch.
          s.level = 0, s.voxel_size = along / stretch, s.stretch = stretch;
          s.constant = all_constant;
          if (all_constant) {
            s.value = mix.sample();
          } else {
            const float mid = 0.5f * (u + v);
            s.value.density = lod.size_at_origin, s.value.color.r = lod.size_per_t;
            s.value.color.g = lod.size_at_origin + lod.size_per_t * mid;
          }
        }
        s.t0 = u, s.t1 = v;
        if (!(s.constant && !(s.value.density > 0.f))) out[size_t(n++)] = s;
        if (n == int(out.size())) return n;
      }
      u = v;
    }
    t = horizon;
    if (!(horizon < end)) first = last;
  }
  return n;
}

void VolumeScene::sample_span(const Ray& ray, const VolumeSpan& span, const float* t,
                              const float* level, int n, TraceContext& ctx,
                              VolumeSample* out) const {
  const uint64_t tag = span.node >> kObjectShift;
  if (tag >= 1 && tag <= objects_.size()) {
    // One object's span: sampled in its local space.
    const int i = int(tag - 1);
    const Ray local{inverse_[size_t(i)].point(ray.origin), inverse_[size_t(i)].vector(ray.dir),
                    ray.tmax};
    const float k = length(local.dir), sigma = across_stretch(i, ray.dir);
    VolumeSpan own = span;
    own.node = span.node & kLocalMask;
    own.voxel_size = span.voxel_size / sigma, own.stretch = span.stretch * k * sigma;
    const size_t before = ctx.requests.size();
    objects_[size_t(i)].structure->volume()->sample_span(local, own, t, level, n, ctx, out);
    ctx.requests.tag_keys(before, object_tag(i));
    for (int j = 0; j < n; ++j) out[j] = classified(i, out[j], k);
    return;
  }
  // A composite: every part's spans over the piece, at the integrator's levels.
  constexpr int kMax = 16;  // the integrator's chunk; larger n is taken in pieces
  if (n > kMax) {
    for (int j0 = 0; j0 < n; j0 += kMax)
      sample_span(ray, span, t + j0, level + j0, std::min(kMax, n - j0), ctx, out + j0);
    return;
  }
  const LodFootprint lod{span.value.density, span.value.color.r};
  std::array<Mix, kMax> mix;
  for (size_t i = 0; i < objects_.size(); ++i) {
    if (!(uint32_t(span.node) >> i & 1u)) continue;
    Placed p;
    p.object = int(i);
    p.ray = {inverse_[i].point(ray.origin), inverse_[i].vector(ray.dir), span.t1};
    p.k = length(p.ray.dir);
    p.sigma = across_stretch(int(i), ray.dir);
    const VolumeQuery& q = *objects_[i].structure->volume();
    std::array<VolumeSpan, 8> parts;
    float from = span.t0;
    int j = 0;  // samples before t[j] are done
    while (j < n) {
      const size_t before = ctx.requests.size();
      const int m = q.march(p.ray, from, p.local_lod(lod), ctx, parts);
      for (int s = 0; s < m && j < n; ++s) {
        const VolumeSpan& ps = parts[size_t(s)];
        while (j < n && t[j] < ps.t0) ++j;  // in a gap of this part: empty
        int e = j;
        while (e < n && t[e] <= ps.t1) ++e;
        if (e == j) continue;
        VolumeSample vs[kMax];
        if (ps.constant) {
          for (int x = j; x < e; ++x) vs[x - j] = ps.value;
        } else {
          float lv[kMax];
          for (int x = j; x < e; ++x)
            lv[x - j] = cone_level(ps, (lod.size_at_origin + lod.size_per_t * t[x]) / p.sigma);
          q.sample_span(p.ray, ps, t + j, lv, e - j, ctx, vs);
        }
        for (int x = j; x < e; ++x) mix[size_t(x)].add(classified(int(i), vs[x - j], p.k));
        j = e;
      }
      ctx.requests.tag_keys(before, object_tag(int(i)));
      if (m < int(parts.size()) || !(parts[size_t(m) - 1].t1 > from)) break;
      from = parts[size_t(m) - 1].t1;
    }
  }
  (void)level;
  for (int j = 0; j < n; ++j) out[j] = mix[size_t(j)].sample();
}

VolumeSample VolumeScene::sample(Vec3 p, float level, TraceContext& ctx,
                                 const VolumeSpan* span) const {
  const uint64_t tag = span ? span->node >> kObjectShift : 0;
  if (tag >= 1 && tag <= objects_.size()) {
    const int i = int(tag - 1);
    VolumeSpan own = *span;
    own.node = span->node & kLocalMask;
    own.voxel_size = span->voxel_size * point_scale_[size_t(i)];
    const size_t before = ctx.requests.size();
    const VolumeSample s = objects_[size_t(i)].structure->volume()->sample(
        inverse_[size_t(i)].point(p), level, ctx, &own);
    ctx.requests.tag_keys(before, object_tag(i));
    return classified(i, s, point_scale_[size_t(i)]);
  }
  // Every object (a composite's parts) at the footprint: the node holding p
  // found by a march of a short local ray through it.
  const float foot = span ? span->value.color.g : 0.f;
  const uint32_t mask = span ? uint32_t(span->node) : ~0u;
  Mix mix;
  for (size_t i = 0; i < objects_.size(); ++i) {
    if (!(mask >> i & 1u)) continue;
    const Vec3 q = inverse_[i].point(p);
    const Aabb& b = local_bounds_[i];
    if (!(q.x >= b.lo.x && q.y >= b.lo.y && q.z >= b.lo.z && q.x <= b.hi.x && q.y <= b.hi.y &&
          q.z <= b.hi.z))
      continue;
    // No direction at a point: the footprint shrinks by the largest stretch
    // of any direction (every sigma(d) is at most it).
    const float k = point_scale_[i], local_foot = foot / max_stretch_[i];
    const VolumeQuery& vq = *objects_[i].structure->volume();
    const float h = 1e-4f * std::max(b.extent().x, std::max(b.extent().y, b.extent().z));
    const Ray r{q - Vec3{h, 0, 0}, {1, 0, 0}, 2 * h};
    std::array<VolumeSpan, 4> found;
    const size_t before = ctx.requests.size();
    const int m = vq.march(r, 0.f, {local_foot, 0.f}, ctx, found);
    VolumeSample s;
    for (int j = 0; j < m; ++j) {
      const VolumeSpan& f = found[size_t(j)];
      if (!(f.t0 <= h && f.t1 >= h)) continue;
      s = f.constant ? f.value : vq.sample(q, cone_level(f, local_foot), ctx, &f);
      break;
    }
    ctx.requests.tag_keys(before, object_tag(int(i)));
    mix.add(classified(int(i), s, k));
  }
  (void)level;
  return mix.sample();
}

}  // namespace voxcast::giga
