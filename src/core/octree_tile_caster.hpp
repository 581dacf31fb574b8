#pragma once
// The tile caster of the octree family (issue 10, primary rays): all camera
// rays of a tile traced by one front-to-back walk of the tree, each node
// tested against the tile's rays at once, instead of each ray walking the
// tree by itself.
//
// Why. A camera ray that walks the tree alone (cast_octree, or one lane of
// the packet kernel) pays ~20-30 loop iterations from the root to a LOD-1
// pixel stop, and its neighbours pay the same iterations again for the same
// nodes. Here a node is fetched once per tile; its children are tested
// against the rays of the tile that are inside it (a row of the tile per
// vector register); a ray that hits is taken out of every later test, so
// whatever lies behind the visible surface is culled by whole subtrees; and
// a ray that misses everything costs nothing below the first node it leaves.
//
// Order. All rays of a perspective camera start at the eye, so for every ray
// the children of a node come in the order of the eye's side of the node's
// three center planes: a ray crosses each plane at most once, from the eye's
// side to the other, so the set of planes crossed only grows along the ray.
// Visiting children by decreasing "eye-side" index (bit a set = the eye's
// half on axis a) therefore meets every ray's cubes in its own order, and the
// walk is depth first, so a ray's first hit is the first hit the walk finds
// for it. An orthographic camera's rays are parallel: the direction's octant
// gives the same order.
//
// Why the hits are those of cast_octree bit for bit. Its comment "Why a start
// region gives bit-identical hits" characterizes the loop: with t(c) =
// fma(c, coef, -bias) the rounded crossing of grid plane c, the loop places a
// ray in cube C iff tau = max(start', t of C's entry planes) < t of C's exit
// planes and tau <= the parent's span end, where start' and the span end are
// the root's span narrowed by the contour slabs of C's ancestors; at C it
// stops at a LOD stop (exit t * size_coef + size_bias >= side) at tau, else
// narrows [tau, min(end, exit t)] by C's own contour and, if that span is not
// empty, hits C at its start if C is a leaf or descends with that span. The
// walk evaluates exactly these conditions per ray with the same fma on the
// same plane coordinates (mirrored per ray as MirroredRay does: 3 - c, exact)
// and the same contour_span, so each ray finds the cube, t and stop that
// cast_octree returns; the epilogue is OctreeWorld::trace's.
//
// Without contours the span start and end are the root's, whatever lies
// above C, so a cube that cannot be a LOD stop for any ray (its farthest
// point is nearer than the distance where its side meets the footprint) and
// is not a leaf needs no per-ray test: the walk hands its children the rays
// whose pixels the cube's projected box covers (a superset), and the exact
// test happens where a ray may stop. With contours every level is tested,
// since an ancestor's slab narrows the span.
//
// Split like the packet caster (core/octree_packet_caster.hpp): the set-up
// and epilogue here with the baseline flags, the walk in
// core/octree_tile_kernel.hpp compiled once per ISA.
#include <algorithm>
#include <cstdint>
#include <type_traits>
#include <vector>

#include "core/octree_caster.hpp"
#include "core/octree_ray.hpp"
#include "voxcast/camera.hpp"
#include "voxcast/isa.hpp"
#include "voxcast/math.hpp"
#include "voxcast/packet_caster.hpp"
#include "voxcast/structure.hpp"

namespace voxcast::detail {

/// A kernel call covers at most kTileRows x kTileCols pixels (16 x 16; the
/// AVX2 kernel walks the left and right 8 columns as two calls).
inline constexpr int kTileRows = 16;
inline constexpr int kTileCols = 16;

/// The rays of one tile in octree space, one row of the tile per array row
/// (or up to 256 rays of one direction, 16 a row: parallel_rays() below).
/// Every value is the one cast_octree computes for the ray (MirroredRay,
/// enter_root).
struct alignas(64) TileRays {
  float cx[kTileRows][kTileCols], cy[kTileRows][kTileCols], cz[kTileRows][kTileCols];
  // -bias: t(c) = fma(c, coef, nb)
  float nbx[kTileRows][kTileCols], nby[kTileRows][kTileCols], nbz[kTileRows][kTileCols];
  // Unmirrored directions after avoid_tiny_components (contour slabs).
  float dx[kTileRows][kTileCols], dy[kTileRows][kTileCols], dz[kTileRows][kTileCols];
  // The ray in the octree frame before avoid_tiny_components (the epilogue's
  // hit_to_world): origin p and direction u.
  float px[kTileRows][kTileCols], py[kTileRows][kTileCols], pz[kTileRows][kTileCols];
  float ux[kTileRows][kTileCols], uy[kTileRows][kTileCols], uz[kTileRows][kTileCols];
  // The root span of enter_root (no region).
  float t_min[kTileRows][kTileCols], t_max[kTileRows][kTileCols];
  // Bit l of row r: the ray's direction is positive on the axis (mirrored).
  uint32_t mirror_x[kTileRows], mirror_y[kTileRows], mirror_z[kTileRows];
  uint32_t live[kTileRows];  // rays that enter the root cube
  int rows = 0, cols = 0;
  // The walk's child order (file comment): perspective = order by the eye's
  // side (eye, octree space), else by the octant of `forward` (below).
  bool perspective = true;
  Vec3 eye{0, 0, 0};
  // A cube's rows and columns (perspective; TileWalk::cull): the camera
  // basis, and pixel (x0 + i, y0 + j)'s ray through X/Z = u0 + i du,
  // Y/Z = v0 + j dv in the camera frame (X right, Y up, Z forward).
  Vec3 right{1, 0, 0}, up{0, 1, 0}, forward{0, 0, 1};
  float abs_right = 0, abs_up = 0, abs_forward = 0;  // |x| + |y| + |z| of each
  float u0 = 0, du = 0, v0 = 0, dv = 0;
  float world_side = 1;  // world units per octree unit (t is in world units)
};

/// What stopped a ray: the cube and its node (the same fields as OctreeCast;
/// `index` = P::hit_index for a policy with a payload, else 0).
struct TileHit {
  uint32_t node;  // the hit cube's parent
  int8_t child;   // the hit cube's slot in node
  int8_t scale;
  uint8_t stop;  // CastStop
  float pos[3];  // unmirrored min corner
  uint64_t index;
};

/// The kernel's output: per pixel t and the index of its TileHit (-1: miss).
struct alignas(64) TileOut {
  float t[kTileRows][kTileCols];
  int32_t hit[kTileRows][kTileCols];
  std::vector<TileHit> hits;
};

/// Walks `rays`' columns [col0, col0 + N) (N = the kernel's lanes) through
/// `nodes` with LOD terms as cast_octree's; writes those columns of *out and
/// appends to out->hits. any_hit (occlusion): only out->hit is written, 0
/// for a ray that stops somewhere (no TileHit, no t), -1 for the others.
template <class P>
using TileKernel = void (*)(const P& nodes, const TileRays& rays, int col0, float size_coef,
                            float size_bias, bool any_hit, TileOut* out);

template <class P>
struct TileKernels {
  TileKernel<P> avx2, avx512;
};

/// The fields of *r that hold for the whole tile at (x0, y0) of `cam`: the
/// walk's order and the cull's camera frame.
inline void tile_camera(const CameraRays& cam, const OctreeFrame& frame, int x0, int y0,
                        TileRays* r) {
  r->perspective = !cam.ortho;
  r->eye = frame.point(cam.eye);
  r->world_side = frame.side;
  r->right = cam.right, r->up = cam.true_up, r->forward = cam.forward;
  auto abs_sum = [](Vec3 v) { return std::fabs(v.x) + std::fabs(v.y) + std::fabs(v.z); };
  r->abs_right = abs_sum(cam.right), r->abs_up = abs_sum(cam.true_up);
  r->abs_forward = abs_sum(cam.forward);
  // CameraRays::perspective_direction: forward + right sx tan aspect + up sy tan.
  const float sx_scale = cam.tan_half * cam.aspect, sy_scale = cam.tan_half;
  r->u0 = cam.screen_x(float(x0) + cam.sample.x) * sx_scale;
  r->du = 2.f / float(cam.width) * sx_scale;
  r->v0 = cam.screen_y(float(y0) + cam.sample.y) * sy_scale;
  r->dv = -2.f / float(cam.height) * sy_scale;
}

/// Fills *r with the rays of pixels [x0, x1) x [y0, y1) (at most 16 x 16)
/// of `cam` in the octree frame `frame`, a row of 8 or 16 pixels at a time
/// (src/core/tile_setup_*.cpp; the same floats as the scalar set-up).
void tile_rays_avx2(const CameraRays& cam, const OctreeFrame& frame, int x0, int y0, int x1, int y1,
                    TileRays* r);
void tile_rays_avx512(const CameraRays& cam, const OctreeFrame& frame, int x0, int y0, int x1,
                      int y1, TileRays* r);

/// trace() of every pixel of [x0, x1) x [y0, y1) of `cam` (any size; split
/// into 16 x 16 kernel calls): hits[(y - y0) w + x - x0] and found likewise,
/// bit-identical to OctreeWorld::trace(cam.ray(x, y), lod, ...) without a
/// beam. `world`: the structure's OctreeWorld<P>.
template <class P, class World>
void structure_trace_tile(const World& world, Isa isa, const TileKernels<P>& kernels,
                          const CameraRays& cam, int x0, int y0, int x1, int y1,
                          const LodFootprint& lod, SurfaceHit* hits, uint8_t* found) {
  using Index = typename P::Index;
  thread_local TileRays rays;
  thread_local TileOut out;
  const TileKernel<P> kernel = isa == Isa::Avx512 ? kernels.avx512 : kernels.avx2;
  const int lanes = packet_width(isa);
  const P nodes(world.source);
  const OctreeFrame& frame = world.frame;
  const float coef = frame.length(lod.size_per_t), bias = frame.length(lod.size_at_origin);
  const int w = x1 - x0;
  for (int ty = y0; ty < y1; ty += kTileRows)
    for (int tx = x0; tx < x1; tx += kTileCols) {
      const int tx1 = std::min(tx + kTileCols, x1), ty1 = std::min(ty + kTileRows, y1);
      (isa == Isa::Avx512 ? tile_rays_avx512 : tile_rays_avx2)(cam, frame, tx, ty, tx1, ty1, &rays);
      out.hits.clear();
      for (int col0 = 0; col0 < rays.cols; col0 += lanes)
        kernel(nodes, rays, col0, coef, bias, false, &out);
      for (int j = 0; j < rays.rows; ++j)
        for (int i = 0; i < rays.cols; ++i) {
          const size_t k = size_t(ty - y0 + j) * size_t(w) + size_t(tx - x0 + i);
          const int32_t h = out.hit[j][i];
          found[k] = h >= 0;
          if (h < 0) continue;
          const TileHit& th = out.hits[size_t(h)];
          const Vec3 p{rays.px[j][i], rays.py[j][i], rays.pz[j][i]};
          const Vec3 d{rays.ux[j][i], rays.uy[j][i], rays.uz[j][i]};
          OctreeCast<Index> r;
          r.hit = true;
          r.stop = CastStop(th.stop);
          r.t = out.t[j][i];
          r.pos = {th.pos[0], th.pos[1], th.pos[2]};
          r.node = th.node;
          r.child = th.child;
          r.scale = th.scale;
          if constexpr (!std::is_same_v<Index, NoIndex>) r.index = Index(th.index);
          if constexpr (P::kEnteredFace) {
            // entered_face of the ray's MirroredRay from the values the
            // tile keeps (coefficients, negated biases, mirror bits, the
            // direction after avoid_tiny_components): the same floats
            // without a MirroredRay's three divisions per hit.
            const int octant =
                7 ^ int((rays.mirror_x[j] >> i & 1u) | (rays.mirror_y[j] >> i & 1u) << 1 |
                        (rays.mirror_z[j] >> i & 1u) << 2);
            // unmirror() is its own inverse: the mirrored min corner.
            r.face = entered_face({rays.cx[j][i], rays.cy[j][i], rays.cz[j][i]},
                                  {rays.nbx[j][i], rays.nby[j][i], rays.nbz[j][i]},
                                  {rays.dx[j][i], rays.dy[j][i], rays.dz[j][i]},
                                  unmirror(octant, r.pos, r.scale), r.scale);
          }
          frame.hit_to_world(p, d, r.t, r.pos, r.scale, &hits[k]);
          P::name_hit(world.source, r, &hits[k]);
        }
    }
}

// Parallel rays (issue 10 item 5: the shadow rays of a directional light).
// Rays that share one direction meet the children of every node in the order
// of that direction's octant, whatever their origins, as an orthographic
// camera's rays do ("Order" above); so the tile walk, in that order and
// without the camera's cull, traces them together: up to 256 rays a walk, 16
// a row (in the pixel-block order of the callers, a row is the shadow rays
// of one 4 x 4 block). Each ray's set-up is cast_octree's own (frame,
// avoid_tiny_components, MirroredRay, enter_root with its tmax), and the
// walk places every ray in exactly the cubes the loop places it in
// ("Why the hits are those of cast_octree"), so a ray placed in some stop
// (a leaf, or a LOD stop) is one the loop stops on as well, and one placed
// in none is one the loop lets through: the answers are occluded()'s bit for
// bit. The any-hit walk ends a ray at the first stop it meets.

/// Rays a parallel walk takes at most.
inline constexpr int kParallelWalk = kTileRows * kTileCols;

/// Fills *r with rays[0, n), n <= kParallelWalk, that share one direction
/// (bitwise): ray i in row i / 16, column i % 16 (not p and u: only the
/// first-hit epilogue reads them); a ray whose origin or
/// direction is not finite, or that misses the root cube within its tmax, is
/// not live (cast_octree answers it without a step).
inline void parallel_rays(const OctreeFrame& frame, const Ray* rays, int n, TileRays* r) {
  r->rows = (n + kTileCols - 1) / kTileCols;
  r->cols = n < kTileCols ? n : kTileCols;
  r->perspective = false;
  r->world_side = frame.side;
  const Vec3 d = frame.direction(rays[0].dir);
  const Vec3 dt = avoid_tiny_components(d);
  r->forward = dt;  // the walk's order: the octant of the loop's direction
  const bool finite_d = is_finite(d);
  for (int j = 0; j < r->rows; ++j) {
    uint32_t mx = 0, my = 0, mz = 0, live = 0;
    for (int i = 0; i < kTileCols; ++i) {
      const int k = j * kTileCols + i;
      const Vec3 p = k < n ? frame.point(rays[k].origin) : Vec3{1.5f, 1.5f, 1.5f};
      const MirroredRay m(p, dt);
      CastEntry e{};
      const bool ok = k < n && finite_d && is_finite(p) && enter_root(m, rays[k].tmax, nullptr, &e);
      r->cx[j][i] = m.tx_coef, r->cy[j][i] = m.ty_coef, r->cz[j][i] = m.tz_coef;
      r->nbx[j][i] = -m.tx_bias, r->nby[j][i] = -m.ty_bias, r->nbz[j][i] = -m.tz_bias;
      r->dx[j][i] = dt.x, r->dy[j][i] = dt.y, r->dz[j][i] = dt.z;
      r->t_min[j][i] = ok ? e.t_min : 0.f, r->t_max[j][i] = ok ? e.t_max : -1.f;
      mx |= uint32_t(dt.x > 0.f) << i, my |= uint32_t(dt.y > 0.f) << i;
      mz |= uint32_t(dt.z > 0.f) << i, live |= uint32_t(ok) << i;
    }
    r->mirror_x[j] = mx, r->mirror_y[j] = my, r->mirror_z[j] = mz, r->live[j] = live;
  }
}

/// occluded[i] = occluded(rays[i], lod) for i < n, rays that share one
/// direction (bitwise), by parallel walks of up to kParallelWalk rays.
/// `world`: the structure's OctreeWorld<P> (in-core, below 2^31 words).
template <class P, class World>
void structure_occluded_parallel(const World& world, Isa isa, const TileKernels<P>& kernels,
                                 const Ray* rays, size_t n, const LodFootprint& lod,
                                 uint8_t* occluded) {
  thread_local TileRays tile;
  thread_local TileOut out;
  const TileKernel<P> kernel = isa == Isa::Avx512 ? kernels.avx512 : kernels.avx2;
  const int lanes = packet_width(isa);
  const P nodes(world.source);
  const float coef = world.frame.length(lod.size_per_t);
  const float bias = world.frame.length(lod.size_at_origin);
  for (size_t b = 0; b < n; b += size_t(kParallelWalk)) {
    const int m = int(std::min(size_t(kParallelWalk), n - b));
    parallel_rays(world.frame, rays + b, m, &tile);
    for (int col0 = 0; col0 < tile.cols; col0 += lanes)
      kernel(nodes, tile, col0, coef, bias, true, &out);
    for (int i = 0; i < m; ++i)
      occluded[b + size_t(i)] = out.hit[i / kTileCols][i % kTileCols] >= 0;
  }
}

}  // namespace voxcast::detail
