// The tile frustum pass (issue 10 item 4; src/core/tile_frustum.hpp) and the
// packets that start from its cube lists (src/core/frustum_packets.hpp),
// against the scalar caster started at the root with no beam (itself tested
// against the dense-grid DDA oracle): per 16x16 tile the tile's list, per
// 4x4 block the finer list within it, as render() makes them; every hit
// field bit-identical, for the ESVO (raw, compressed attributes, contours)
// and the DAG, at LOD 0 and coarser footprints, with perspective and
// orthographic cameras whose tiles are fully empty, partly empty, cut by the
// image edge and straddle the camera axis (rays of two mirroring octants in
// one block), and rays that run exactly along grid planes (grazing). A direct
// check of the lists' conservativeness: every voxel the scalar caster hits
// lies inside a listed cube of its block. And render() with --frustum gives
// the bytes of render() without it.
#include <gtest/gtest.h>

#include <bit>
#include <cstdint>
#include <cstdio>
#include <deque>
#include <memory>
#include <string>
#include <vector>

#include "render/beam.hpp"
#include "support/esvo_testing.hpp"
#include "support/packet_testing.hpp"
#include "support/test_data.hpp"
#include "voxcast/camera.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/film.hpp"
#include "voxcast/integrator.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/packet_caster.hpp"
#include "voxcast/render.hpp"
#include "voxcast/surface_integrator.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast {
namespace {

using testing::same_hit;

struct Scenes {
  std::unique_ptr<esvo::EsvoStructure> esvo, esvo_compressed, esvo_contours;
  std::unique_ptr<dag::DagStructure> dag;
};

const Scenes& scenes() {
  static const Scenes s = [] {
    Scenes s;
    const Mesh mesh = load_mesh(testing::test_mesh("spot.obj"));
    const GridTransform grid = GridTransform::fit(mesh.bounds(), 256);
    const VoxelSet v = voxelize(mesh, grid, {});
    s.esvo = std::make_unique<esvo::EsvoStructure>(
        std::make_shared<const esvo::EsvoOctree>(esvo::build_octree(v)));
    esvo::BuildOptions compressed;
    compressed.attributes = esvo::AttributeFormat::Compressed;
    s.esvo_compressed = std::make_unique<esvo::EsvoStructure>(
        std::make_shared<const esvo::EsvoOctree>(esvo::build_octree(v, compressed)));
    esvo::BuildOptions contours;
    contours.contours = true;
    s.esvo_contours = std::make_unique<esvo::EsvoStructure>(
        std::make_shared<const esvo::EsvoOctree>(esvo::build_octree(v, mesh, contours)));
    s.dag = std::make_unique<dag::DagStructure>(
        std::make_shared<const dag::SparseVoxelDag>(dag::build_dag(v)));
    return s;
  }();
  return s;
}

// A frame's rays in render()'s order (16x16 tiles, 4x4 blocks) with the
// starts render() gives them: the tile's list where the tile pass found no
// cube, else the block's list made within the tile's.
struct FrustumFrame {
  std::vector<Ray> rays;
  std::vector<const BeamStart*> beams;
  std::deque<BeamStart> starts;  // stable addresses
  size_t tiles = 0, empty_tiles = 0, blocks = 0, empty_blocks = 0, listed_blocks = 0;
  size_t nodes = 0, deep_nodes = 0;  // list entries; below the root's children
};

template <class S>
FrustumFrame frustum_frame(const S& s, const CameraRays& cr, const LodFootprint& lod) {
  constexpr int T = 16, K = 4;
  FrustumFrame f;
  TraceContext ctx;
  auto octant = [&](int x0, int y0, int x1, int y1) {
    return ray_octant(cr.ray((x0 + x1) / 2, (y0 + y1) / 2).dir);
  };
  for (int ty = 0; ty < cr.height; ty += T)
    for (int tx = 0; tx < cr.width; tx += T) {
      const int tx1 = std::min(tx + T, cr.width), ty1 = std::min(ty + T, cr.height);
      BeamStart& tile = f.starts.emplace_back();
      s.frustum_start(detail::block_beam(cr, tx, ty, tx1, ty1, lod), octant(tx, ty, tx1, ty1), ctx,
                      &tile);
      ++f.tiles;
      const bool empty_tile = tile.valid && tile.empty;
      f.empty_tiles += empty_tile;
      std::vector<const BeamStart*> block_start;
      const int bw = (tx1 - tx + K - 1) / K, bh = (ty1 - ty + K - 1) / K;
      for (int j = 0; j < bh; ++j)
        for (int i = 0; i < bw; ++i) {
          if (empty_tile) {
            block_start.push_back(&tile);
            continue;
          }
          const int x0 = tx + i * K, y0 = ty + j * K;
          const int x1 = std::min(x0 + K, tx1), y1 = std::min(y0 + K, ty1);
          BeamStart& b = f.starts.emplace_back();
          s.frustum_start(detail::block_beam(cr, x0, y0, x1, y1, lod), octant(x0, y0, x1, y1), ctx,
                          &b, &tile);
          ++f.blocks;
          f.empty_blocks += b.valid && b.empty;
          f.listed_blocks += b.valid && !b.empty && b.octant >= 0;
          f.nodes += b.nodes.size();
          for (const FrustumNode& n : b.nodes) f.deep_nodes += n.scale < 22;
          block_start.push_back(&b);
        }
      std::vector<uint32_t> order;
      block_order(tx, ty, tx1 - tx, ty1 - ty, &order);
      for (const uint32_t xy : order) {
        const int x = int(xy & 0xFFFF), y = int(xy >> 16);
        f.rays.push_back(cr.ray(x, y));
        f.beams.push_back(block_start[size_t((y - ty) / K * bw + (x - tx) / K)]);
      }
    }
  return f;
}

const GridTransform& grid_of(const esvo::EsvoStructure& s) {
  return s.octree().grid;
}
const GridTransform& grid_of(const dag::DagStructure& s) {
  return s.dag().grid;
}

// Whether octree-space point p lies inside a listed cube of `b`.
bool in_list(const BeamStart& b, Vec3 p) {
  for (const FrustumNode& n : b.nodes)
    if (p.x >= n.lo[0] && p.x <= n.lo[0] + n.side && p.y >= n.lo[1] && p.y <= n.lo[1] + n.side &&
        p.z >= n.lo[2] && p.z <= n.lo[2] + n.side)
      return true;
  return false;
}

// trace_packets with the frame's starts == trace() from the root, every
// field; the scalar trace() with the same starts (their regions) too; every
// scalar hit inside its block's list. Returns the hits.
template <class S>
size_t expect_same(const S& s, const FrustumFrame& f, const GridTransform& grid,
                   const LodFootprint& lod, const std::string& what) {
  const size_t n = f.rays.size();
  std::vector<SurfaceHit> want(n), got(n);
  std::vector<uint8_t> want_found(n), found(n);
  TraceContext ctx;
  size_t hits = 0, outside = 0, region_bad = 0;
  const double side = grid.side();
  for (size_t i = 0; i < n; ++i) {
    want_found[i] = s.trace(f.rays[i], lod, ctx, &want[i]);
    hits += want_found[i];
    SurfaceHit h;
    const bool with_region = s.trace(f.rays[i], lod, ctx, &h, f.beams[i]);
    region_bad += with_region != bool(want_found[i]) || (with_region && !same_hit(h, want[i]));
    const BeamStart& b = *f.beams[i];
    if (want_found[i] && b.valid && b.octant == ray_octant(f.rays[i].dir)) {
      const Vec3 p = (want[i].position - grid.origin) * float(1.0 / side) + Vec3{1, 1, 1};
      outside += !in_list(b, p);
    }
  }
  EXPECT_EQ(region_bad, 0u) << what << ": trace() with the list's region";
  EXPECT_EQ(outside, 0u) << what << ": scalar hits outside their block's list";
  for (const Isa isa : testing::packet_isas()) {
    std::fill(found.begin(), found.end(), uint8_t(7));
    trace_packets(s, f.rays.data(), n, lod, got.data(), found.data(), isa, f.beams.data());
    size_t bad = 0;
    for (size_t i = 0; i < n; ++i) {
      const bool ok = found[i] == want_found[i] && (!found[i] || same_hit(got[i], want[i]));
      if (!ok && ++bad <= 5)
        ADD_FAILURE() << what << " " << isa_name(isa) << " ray " << i << ": found " << int(found[i])
                      << " want " << int(want_found[i]) << ", t " << got[i].t << " want "
                      << want[i].t << ", level " << got[i].level << " want " << want[i].level
                      << ", ref " << got[i].voxel_ref << " want " << want[i].voxel_ref;
    }
    EXPECT_EQ(bad, 0u) << what << " " << isa_name(isa);
  }
  return hits;
}

template <class S>
void check_views(const S& s, const char* name) {
  constexpr int w = 96, h = 72;  // 72 = 4.5 tiles: the last row of tiles is cut
  const Aabb b = s.bounds();
  struct View {
    const char* what;
    Camera cam;
  };
  const View views[] = {
      {"framed", Camera::frame(b, w, h)},  // empty corner tiles
      {"close", Camera::orbit(b, w, h, 30.f, 20.f, 0.6f * length(b.extent()))},
      {"axis", Camera::orbit(b, w, h, 0.f, 0.f)},  // x, y signs flip mid-image
      {"ortho", Camera::orbit(b, w, h, 90.f, 0.f, 0.f, Projection::Orthographic)},
      {"ortho tilted", Camera::orbit(b, w, h, 200.f, -30.f, 0.f, Projection::Orthographic)},
  };
  size_t empty_tiles = 0, partial = 0, listed = 0, deep = 0;
  for (const View& v : views) {
    const CameraRays cr(v.cam, w, h);
    for (const float lod_pixels : {0.f, 1.f, 3.f}) {
      LodFootprint lod;
      lod.size_per_t = lod_pixels * cr.pixel_angle();
      lod.size_at_origin = lod_pixels * cr.pixel_size();
      const FrustumFrame f = frustum_frame(s, cr, lod);
      const std::string what =
          std::string(name) + " " + v.what + " lod " + std::to_string(int(lod_pixels));
      const size_t hits = expect_same(s, f, grid_of(s), lod, what);
      EXPECT_GT(hits, 0u) << what;
      empty_tiles += f.empty_tiles;
      partial += f.empty_blocks;
      listed += f.listed_blocks;
      deep += f.deep_nodes;
    }
  }
  // The views exercise every case: tiles without a cube, empty blocks inside
  // occupied tiles, and lists whose cubes lie deep in the tree.
  EXPECT_GT(empty_tiles, 0u) << name;
  EXPECT_GT(partial, 0u) << name;
  EXPECT_GT(listed, 0u) << name;
  EXPECT_GT(deep, 0u) << name;
}

TEST(TileFrustum, EsvoPacketsFromListsEqualTheScalarCaster) {
  check_views(*scenes().esvo, "esvo");
}

TEST(TileFrustum, EsvoCompressedPacketsFromListsEqualTheScalarCaster) {
  check_views(*scenes().esvo_compressed, "esvo compressed");
}

TEST(TileFrustum, EsvoContoursPacketsFromListsEqualTheScalarCaster) {
  check_views(*scenes().esvo_contours, "esvo contours");
}

TEST(TileFrustum, DagPacketsFromListsEqualTheScalarCaster) {
  check_views(*scenes().dag, "dag");
}

// Grazing rays: on the unit grid (world = octree space - 1), an
// orthographic camera whose rays pass through pixel corners runs every ray
// exactly along two grid planes of the 32^3 voxels (and the lists' cube
// faces), where the loop's tie rules decide; then slightly tilted.
TEST(TileFrustum, GrazingRaysAlongGridPlanes) {
  const VoxelSet v = testing::make_random_voxels(5, 3000, 5);
  ASSERT_TRUE(v.grid.origin.x == 0 && v.grid.origin.y == 0 && v.grid.origin.z == 0);
  ASSERT_EQ(v.grid.side(), 1.0);
  const esvo::EsvoStructure e(std::make_shared<const esvo::EsvoOctree>(esvo::build_octree(v)));
  const dag::DagStructure d(std::make_shared<const dag::SparseVoxelDag>(dag::build_dag(v)));
  constexpr int w = 64, h = 64;
  Camera straight;
  straight.eye = {0.5f, 0.5f, 3.f};
  straight.target = {0.5f, 0.5f, 0.f};
  straight.projection = Projection::Orthographic;
  straight.ortho_width = 1.f;
  Camera tilted = straight;
  tilted.target = {0.5f, 0.5001f, 0.f};
  Camera corner;  // perspective from a grid vertex along a diagonal plane
  corner.eye = {-0.5f, 0.5f, -0.5f};
  corner.target = {0.5f, 0.5f, 0.5f};
  for (const Camera& cam : {straight, tilted, corner}) {
    const CameraRays cr(cam, w, h, Vec2{0.f, 0.f});  // rays through pixel corners
    for (const float lod_pixels : {0.f, 2.f}) {
      LodFootprint lod;
      lod.size_per_t = lod_pixels * cr.pixel_angle();
      lod.size_at_origin = lod_pixels * cr.pixel_size();
      const std::string what =
          std::string(cam.projection == Projection::Orthographic ? "ortho" : "perspective") +
          " lod " + std::to_string(int(lod_pixels));
      const FrustumFrame fe = frustum_frame(e, cr, lod);
      EXPECT_GT(expect_same(e, fe, v.grid, lod, "esvo grazing " + what), 0u);
      const FrustumFrame fd = frustum_frame(d, cr, lod);
      EXPECT_GT(expect_same(d, fd, v.grid, lod, "dag grazing " + what), 0u);
    }
  }
}

// render() / voxcast render --frustum: the same bytes as without the pass
// and as the scalar path, on every ISA, with tiles the pass resolves alone.
TEST(TileFrustum, RenderImagesByteIdentical) {
  const Scenes& sc = scenes();
  const Structure* structures[] = {sc.esvo.get(), sc.esvo_contours.get(), sc.dag.get()};
  for (const Structure* st : structures) {
    for (const Projection proj : {Projection::Perspective, Projection::Orthographic}) {
      for (const float lod_pixels : {0.f, 1.f}) {
        RenderOptions ro;
        ro.width = 120, ro.height = 90;
        ro.camera = Camera::frame(st->bounds(), ro.width, ro.height, proj);
        ro.lod_pixels = lod_pixels;
        ro.want_depth = ro.want_normal = true;
        ro.caster = Caster::Scalar;
        const RenderResult want = render(*st, ro);
        ro.caster = Caster::Packet;
        for (const Isa isa : testing::packet_isas()) {
          ro.isa = isa;
          for (const int k : {4, 8, 16}) {  // 16: the whole tile's list
            ro.frustum = k;
            const RenderResult got = render(*st, ro);
            const std::string what = st->name() + " k " + std::to_string(k) + " " + isa_name(isa) +
                                     " lod " + std::to_string(int(lod_pixels));
            EXPECT_EQ(got.hits, want.hits) << what;
            EXPECT_TRUE(got.color.pixels == want.color.pixels) << what;
            EXPECT_TRUE(got.depth.pixels == want.depth.pixels) << what;
            EXPECT_TRUE(got.normal.pixels == want.normal.pixels) << what;
          }
        }
      }
    }
  }
}

TEST(TileFrustum, SurfaceIntegratorResolvesEmptyTilesAlone) {
  esvo::EsvoStructure& s = *scenes().esvo;
  SurfaceOptions so;
  so.frustum = 4;
  SurfaceIntegrator integrator(so);
  FrameView view;
  view.width = 128, view.height = 96;
  view.camera = Camera::frame(s.bounds(), view.width, view.height);
  FrameOptions fo;
  fo.tile_size = 16;
  Film film;
  render_frame(s, integrator, view, fo, &film);
  EXPECT_GT(integrator.stats().empty_tiles, 0u);
  EXPECT_LT(integrator.stats().empty_tiles, uint64_t((128 / 16) * (96 / 16)));
  SurfaceOptions bad;
  bad.frustum = 1;
  EXPECT_THROW(SurfaceIntegrator{bad}, Error);
}

}  // namespace
}  // namespace voxcast
