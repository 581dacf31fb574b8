// Brickmap ray casting (§3.3, §4.1): a 3-D DDA (Amanatides & Woo 1987) per
// level, occupancy layer -> brickgrid -> brick mask, in grid units (voxel
// (x, y, z) = [x, x+1] x [y, y+1] x [z, z+1]; t is the world distance, as the
// grid map p -> (p - origin) / voxel_size scales the direction with it).
//
// Consistency between levels: the t of a plane is always computed as
// (plane - o) * inv_d from the same float plane coordinate, whichever level
// asks, and every level breaks ties between axes the same way (argmin3), so
// when a finer walk leaves its parent cell through a plane, the parent's walk
// steps through exactly that plane at exactly that t. A finer walk starts in
// the cell holding the entry point, clamped into its parent (rounding of the
// entry point can only move it across a plane within float slack of it: a
// near tie in the oracle's sense, tests/support/dda_oracle.hpp).
#include <algorithm>
#include <array>
#include <bit>
#include <cmath>

#include "voxcast/brickmap.hpp"
#include "voxcast/esvo.hpp"

namespace voxcast::brickmap {
namespace {

constexpr int kOccSide = kBrickSide << kOccupancyLog2;  // voxels per occupancy cell

// Fixed tie break (x, then y, then z) shared by every level.
inline int argmin3(const float v[3]) {
  return v[0] <= v[1] ? (v[0] <= v[2] ? 0 : 2) : (v[1] <= v[2] ? 1 : 2);
}

struct GridRay {
  float o[3], d[3], inv[3];
  int step[3];  // +1 / -1: the side the ray moves to (the sign bit for a zero component)
  int up[3];    // 1 if step > 0: the exit plane of cell c is c + up
};

// The ray in grid units; false for non-finite input. Direction components
// below 2^-23 of the largest are replaced by +-2^-23 of it (sign kept, also
// for -0): such a ray cannot cross that axis's next plane inside a grid of
// fewer than 2^23 voxels, so it stays on the side its sign picks, and the
// arithmetic below stays finite.
bool to_grid(const GridTransform& g, const Ray& ray, GridRay* r) {
  if (!is_finite(ray.origin) || !is_finite(ray.dir)) return false;
  const double inv_vs = 1.0 / g.voxel_size;
  float big = 0.f;
  for (int a = 0; a < 3; ++a) {
    r->o[a] = float((double(ray.origin[a]) - g.origin[a]) * inv_vs);
    r->d[a] = float(double(ray.dir[a]) * inv_vs);
    big = std::fmax(big, std::fabs(r->d[a]));
  }
  if (!(big > 0.f) || !std::isfinite(big)) return false;
  const float tiny = big * 0x1p-23f;
  for (int a = 0; a < 3; ++a) {
    if (std::fabs(r->d[a]) < tiny) r->d[a] = std::copysign(tiny, r->d[a]);
    r->inv[a] = 1.f / r->d[a];
    r->step[a] = std::signbit(r->d[a]) ? -1 : 1;
    r->up[a] = r->step[a] > 0;
  }
  return true;
}

inline float plane_t(const GridRay& r, int a, float coord) {
  return (coord - r.o[a]) * r.inv[a];
}

// Cell of side `side` (grid units) holding o + d t, ties towards the side the
// ray moves to, clamped to [lo[a], hi[a]].
inline void start_cell(const GridRay& r, float t, float side, const int lo[3], const int hi[3],
                       int c[3]) {
  const float inv_side = 1.f / side;  // a power of two: exact
  for (int a = 0; a < 3; ++a) {
    const float p = (r.o[a] + r.d[a] * t) * inv_side;
    const float f = r.up[a] ? std::floor(p) : std::ceil(p) - 1.f;
    const float clamped = std::fmin(std::fmax(f, float(lo[a])), float(hi[a]));
    c[a] = int(clamped);
  }
}

struct Found {
  float t;
  int face;   // entered face (axis * 2 + (outward normal negative ? 1 : 0))
  int level;  // 0 = voxel, 1 = brick (LOD)
  int c[3];   // voxel or brickgrid cell coordinates
  uint64_t ref;
};

inline int face_of(const GridRay& r, int axis) {
  return axis * 2 + (r.up[axis] ? 1 : 0);
}

// The walk; true with `f` filled on a hit within [0, tmax].
template <bool kCount>
bool walk(const World& w, const GridRay& r, float tmax, const LodFootprint& lod, TraceContext& ctx,
          Found* f) {
  const GridTransform& g = w.grid();
  const float n = float(g.resolution);
  // Clip to the grid box [0, N]^3.
  float t0 = 0.f, t1 = tmax;
  int face = -1;
  for (int a = 0; a < 3; ++a) {
    const float ta = plane_t(r, a, r.up[a] ? 0.f : n), tb = plane_t(r, a, r.up[a] ? n : 0.f);
    if (ta > t0) t0 = ta, face = face_of(r, a);
    t1 = std::fmin(t1, tb);
  }
  if (!(t0 <= t1)) return false;
  if (face < 0) {
    // The ray starts inside the box: the face the ray looks at.
    const float ad[3] = {-std::fabs(r.d[0]), -std::fabs(r.d[1]), -std::fabs(r.d[2])};
    face = face_of(r, argmin3(ad));
  }
  const std::array<uint32_t, 3>& dims = w.dims();
  const std::array<uint32_t, 3>& odims = w.occupancy_dims();
  const uint32_t* cells = w.cells().data();
  const uint64_t* occ = w.occupancy_words().data();
  const Brick* bricks = w.bricks().data();
  const bool brick_lod = g.levels >= kBrickLog2;
  const float brick_world = float(g.voxel_size * kBrickSide);
  const int n_vox = int(g.resolution);

  float t = t0;
  const int olo[3] = {0, 0, 0};
  const int ohi[3] = {int(odims[0]) - 1, int(odims[1]) - 1, int(odims[2]) - 1};
  int oc[3];
  start_cell(r, t, float(kOccSide), olo, ohi, oc);
  // Exit planes of the current cell per level; a step recomputes only the
  // stepped axis's (the same expression, so the levels stay consistent).
  float on[3];
  for (int a = 0; a < 3; ++a) on[a] = plane_t(r, a, float((oc[a] + r.up[a]) * kOccSide));
  for (;;) {
    if constexpr (kCount) ++ctx.counters.iterations;
    const uint64_t ob =
        uint64_t(oc[0]) +
        uint64_t(odims[0]) * (uint64_t(oc[1]) + uint64_t(odims[1]) * uint64_t(oc[2]));
    if ((occ[ob >> 6] >> (ob & 63)) & 1) {
      if constexpr (kCount) ++ctx.counters.pushes;
      int blo[3], bhi[3], bc[3];
      for (int a = 0; a < 3; ++a) {
        blo[a] = oc[a] << kOccupancyLog2;
        bhi[a] = std::min(int(dims[a]), blo[a] + (1 << kOccupancyLog2)) - 1;
      }
      start_cell(r, t, float(kBrickSide), blo, bhi, bc);
      float bn[3];
      for (int a = 0; a < 3; ++a) bn[a] = plane_t(r, a, float((bc[a] + r.up[a]) * kBrickSide));
      const int64_t stride[3] = {r.step[0], r.step[1] * int64_t(dims[0]),
                                 r.step[2] * int64_t(dims[0]) * int64_t(dims[1])};
      uint64_t ci = w.cell_index(uint32_t(bc[0]), uint32_t(bc[1]), uint32_t(bc[2]));
      for (;;) {
        if constexpr (kCount) ++ctx.counters.iterations;
        const uint32_t cell = cells[ci];
        if (cell != 0) {
          const float exit = bn[argmin3(bn)];
          const bool lod_stop =
              brick_lod && brick_world <= lod.size_at_origin + lod.size_per_t * exit;
          const uint32_t state = cell_state(cell);
          if (state != kStateResident || lod_stop) {
            uint32_t abgr;
            if (state == kStateResident) {
              abgr = bricks[cell_brick(cell)].lod;
            } else {
              abgr = cell_lod_abgr(cell);
              // §3.2.1: the brick is needed (unless the LOD color is what
              // the footprint asks for anyway); nearer is more urgent.
              if (!lod_stop)
                ctx.requests.push(BrickmapStructure::kRequestBrick, ci, 1.f / (1.f + t));
            }
            *f = {t, face, 1, {bc[0], bc[1], bc[2]}, uint64_t(1) << 63 | abgr};
            return true;
          }
          // The brick's voxels (the inner loop: no allocation, one mask
          // word test and one plane per step).
          if constexpr (kCount) ++ctx.counters.pushes;
          const Brick& brick = bricks[cell_brick(cell)];
          int vlo[3], vhi[3], vc[3];
          for (int a = 0; a < 3; ++a) {
            vlo[a] = bc[a] << kBrickLog2;
            vhi[a] = std::min(n_vox, vlo[a] + kBrickSide) - 1;
          }
          start_cell(r, t, 1.f, vlo, vhi, vc);
          float vn[3];
          for (int a = 0; a < 3; ++a) vn[a] = plane_t(r, a, float(vc[a] + r.up[a]));
          for (;;) {
            if constexpr (kCount) ++ctx.counters.iterations, ++ctx.counters.intersects;
            const uint32_t bit = voxel_bit(uint32_t(vc[0] & 7), uint32_t(vc[1] & 7), 0);
            if ((brick.mask[vc[2] & 7] >> bit) & 1) {
              *f = {t,
                    face,
                    0,
                    {vc[0], vc[1], vc[2]},
                    uint64_t(cell_brick(cell)) << 9 |
                        voxel_bit(uint32_t(vc[0] & 7), uint32_t(vc[1] & 7), uint32_t(vc[2] & 7))};
              return true;
            }
            const int ax = argmin3(vn);
            t = vn[ax];
            face = face_of(r, ax);
            vc[ax] += r.step[ax];
            if (unsigned(vc[ax] - vlo[ax]) > unsigned(vhi[ax] - vlo[ax])) break;
            if (t > t1) return false;
            vn[ax] = plane_t(r, ax, float(vc[ax] + r.up[ax]));
          }
        }
        const int ax = argmin3(bn);
        t = bn[ax];
        face = face_of(r, ax);
        bc[ax] += r.step[ax];
        if (bc[ax] < blo[ax] || bc[ax] > bhi[ax]) break;
        if (t > t1) return false;
        ci = uint64_t(int64_t(ci) + stride[ax]);
        bn[ax] = plane_t(r, ax, float((bc[ax] + r.up[ax]) * kBrickSide));
      }
    }
    const int ax = argmin3(on);
    t = on[ax];
    face = face_of(r, ax);
    oc[ax] += r.step[ax];
    if (oc[ax] < 0 || oc[ax] > ohi[ax]) return false;
    if (t > t1) return false;
    on[ax] = plane_t(r, ax, float((oc[ax] + r.up[ax]) * kOccSide));
  }
}

Vec3 face_normal(int face) {
  Vec3 n{0, 0, 0};
  n[face >> 1] = (face & 1) ? -1.f : 1.f;
  return n;
}

}  // namespace

BrickmapStructure::BrickmapStructure(std::shared_ptr<const World> world)
    : world_(std::move(world)) {}

Aabb BrickmapStructure::bounds() const {
  const GridTransform& g = world_->grid();
  Aabb b;
  b.lo = g.origin;
  const float side = float(g.side());
  b.hi = g.origin + Vec3{side, side, side};
  return b;
}

bool BrickmapStructure::trace(const Ray& ray, const LodFootprint& lod, TraceContext& ctx,
                              SurfaceHit* hit, const BeamStart* beam) const {
  (void)beam;  // no beam optimization: every ray starts at the grid
  GridRay r;
  if (!to_grid(world_->grid(), ray, &r)) return false;
  Found f;
  const bool found = ctx.counting ? walk<true>(*world_, r, ray.tmax, lod, ctx, &f)
                                  : walk<false>(*world_, r, ray.tmax, lod, ctx, &f);
  if (!found) return false;
  const GridTransform& g = world_->grid();
  // Side in voxels; a grid smaller than one brick (N < 8) is its own brick.
  const int cube = f.level == 0 ? 1 : std::min(kBrickSide, int(g.resolution));
  const double side = double(cube) * g.voxel_size;
  hit->t = f.t;
  hit->voxel_size = float(side);
  hit->voxel_ref = f.ref;
  hit->child = uint32_t(f.face);
  hit->level = f.level == 0 ? g.levels : std::max(0, g.levels - kBrickLog2);
  const Vec3 p = ray.origin + ray.dir * f.t;
  for (int a = 0; a < 3; ++a) {
    // Clamped into the cube [lo, hi) as the floats inside it (when the cube
    // holds any float at all), so that the position names the hit voxel.
    const double lo = double(g.origin[a]) + double(f.c[a]) * side;
    const double hi = double(g.origin[a]) + std::min(double(f.c[a] + 1) * side, g.side());
    float lo_f = float(lo), hi_f = float(hi);
    if (double(lo_f) < lo) lo_f = std::nextafter(lo_f, INFINITY);
    if (double(hi_f) >= hi) hi_f = std::nextafter(hi_f, -INFINITY);
    hit->position[a] = std::fmax(std::fmin(p[a], hi_f), lo_f);
  }
  return true;
}

void BrickmapStructure::attributes(const SurfaceHit& hit, TraceContext& ctx, Color* color,
                                   Vec3* normal) const {
  const Vec3 face = face_normal(int(hit.child % 6));
  if (hit.voxel_ref >> 63) {
    if (color) *color = esvo::decode_color_abgr(uint32_t(hit.voxel_ref));
    if (normal) *normal = face;
    return;
  }
  const World& w = *world_;
  const Brick& b = w.brick(uint32_t(hit.voxel_ref >> 9));
  const uint32_t index = b.color + uint32_t(rank_below(b, uint32_t(hit.voxel_ref & 511)));
  if (color) *color = esvo::decode_color_abgr(w.colors()[index]);
  if (normal) *normal = w.has_normals() ? esvo::decode_normal_cube(w.normals()[index]) : face;
  if (ctx.counting) ctx.counters.attribute_bytes += sizeof(Brick) + (w.has_normals() ? 8 : 4);
}

namespace {

// VoxelStructure over the SurfaceQuery (brickmap.hpp: make_voxel_structure).
class VoxelAdapter final : public VoxelStructure {
 public:
  explicit VoxelAdapter(std::shared_ptr<const World> world) : s_(std::move(world)) {}
  Aabb bounds() const override { return s_.bounds(); }
  std::string name() const override { return s_.name(); }
  bool trace(const Ray& ray, const LodFootprint& lod, SurfaceHit* hit) const override {
    TraceContext ctx;
    return s_.trace(ray, lod, ctx, hit);
  }
  bool trace_hinted(const Ray& ray, const LodFootprint& lod, const TraceHints& hints,
                    SurfaceHit* hit) const override {
    TraceContext ctx;
    ctx.counting = hints.counters != nullptr;
    const bool found = s_.trace(ray, lod, ctx, hit);
    if (hints.counters) *hints.counters += ctx.counters;
    return found;
  }
  const World& world() const { return s_.world(); }
  void attributes(const SurfaceHit& hit, Color* color, Vec3* normal) const override {
    TraceContext ctx;
    s_.attributes(hit, ctx, color, normal);
  }
  void attributes_counted(const SurfaceHit& hit, Color* color, Vec3* normal,
                          RayCounters* counters) const override {
    TraceContext ctx;
    ctx.counting = counters != nullptr;
    s_.attributes(hit, ctx, color, normal);
    if (counters) *counters += ctx.counters;
  }

 private:
  BrickmapStructure s_;
};

}  // namespace

std::unique_ptr<VoxelStructure> make_voxel_structure(std::shared_ptr<const World> world) {
  return std::make_unique<VoxelAdapter>(std::move(world));
}

}  // namespace voxcast::brickmap

namespace voxcast::brickmap {
const World* adapted_world(const VoxelStructure& structure) {
  const auto* a = dynamic_cast<const VoxelAdapter*>(&structure);
  return a ? &a->world() : nullptr;
}
}  // namespace voxcast::brickmap
