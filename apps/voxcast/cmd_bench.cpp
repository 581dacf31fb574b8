// voxcast bench MESH: the voxel ray casters against Embree on the same mesh,
// camera, image size, tiles and threads, measured in one run (issue 10, the
// fair benchmark): Embree in every primary mode (x1, 2x2/4x2/4x4 packets,
// stream), trace only and with the same shading, voxel casters at LOD 0 and
// --lod, occlusion rays generated once for every caster, and an instrumented
// single-threaded cycles-per-ray profile. docs/BENCHMARKS.md shows the output.

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <functional>
#include <iterator>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "bench_anyhit.hpp"
#include "bench_brickmap.hpp"
#include "bench_machine.hpp"
#include "camera_options.hpp"
#include "cli_io.hpp"
#include "commands.hpp"
#include "pipeline.hpp"
#include "render/beam.hpp"
#include "render/bench_timing.hpp"
#include "render/tiling.hpp"
#include "voxcast/effects.hpp"
#include "voxcast/embree_path.hpp"
#include "voxcast/embree_reference.hpp"
#include "voxcast/environment.hpp"
#include "voxcast/error.hpp"
#include "voxcast/format_registry.hpp"
#include "voxcast/gi_integrator.hpp"
#include "voxcast/packet_caster.hpp"
#include "voxcast/progress.hpp"
#include "voxcast/render.hpp"

namespace voxcast::cli {

namespace {
struct BenchArgs {
  std::string input, size = "1024x768", voxelization = "conservative", attributes = "raw";
  CameraArgs camera;
  uint32_t resolution = 2048;
  float lod = 1.f;
  int repeat = 5, threads = 0, beam = 8;
  int frustum = 16;         // block size of the tile frustum rows (0 = no such rows;
                            // 16 and up: the 16x16 tile's list for all its rays)
  double min_coverage = 0;  // > 0: zoom the automatic camera in (crops the model)
  bool verbose = false;
  bool contours = false;
  // --effects (svdag §4): shadow and AO occlusion rays
  bool effects = false;
  bool brickmap = false;
  int ao_rays = 64;
  float ao_radius = 0.f;
  int gi = 0, bounces = 8;  // --gi SPP: diffuse path tracing against Embree's
  std::string json;         // --json FILE: every figure
  std::string memory_budget;
};

// What bench holds at once, estimated before anything is built. Each voxel
// build is estimated as `build` does (estimate_build_bytes: its peak, which
// bounds the structure it leaves), each extra build also holds its own copy
// of the mesh. Embree's high-quality BVH (primitive references, spatial
// splits, nodes and the triangle copy): 384 bytes per triangle bounds it.
// Images: per pixel, the voxel render kept for the agreement figures
// (color, depth, normals: 28 B), Embree's depth render (4 B), and the frame
// being measured (up to 28 + 4 B of iteration counts), rounded up to 128 B.
constexpr uint64_t kEmbreeBytesPerTriangle = 384;
constexpr uint64_t kImageBytesPerPixel = 128;

struct BenchMemory {
  uint64_t mesh = 0;      // every mesh copy held for the whole run
  uint64_t primary = 0;   // the first structure's build (estimate_build_bytes)
  uint64_t embree = 0;    // Embree's BVH
  uint64_t contours = 0;  // the contour build and its own mesh copy
  uint64_t images = 0;    // the largest --size
  uint64_t others = 0;    // --effects: what the other structures hold once built
  uint64_t total() const { return mesh + primary + embree + contours + images + others; }
};

// One measured structure: a registered format whose structure has a surface
// query, built from the same mesh, grid and voxelization as the others.
struct Measured {
  std::string caster;  // "voxcast <format>": the rows' and the JSON's name
  const SceneFormat* format = nullptr;
  LoadedStructure structure;
  const SurfaceQuery* query = nullptr;
  const SurfacePackets* packets = nullptr;  // null: no packet rows
  bool tiles = false;                       // packets has a tile caster: tile rows
  uint64_t leaf_voxels = 0;
  double voxelize_seconds = 0, build_seconds = 0;
};

// The built scene as a Measured, or nothing when its structure has no
// surface query (a volume: nothing for these rays to hit).
std::optional<Measured> measured(const SceneFormat& format, BuiltScene&& built) {
  Measured m;
  m.caster = "voxcast " + format.name;
  m.format = &format;
  m.query = built.structure->surface();
  if (!m.query) return std::nullopt;
  m.packets = m.query->packets();
  if (m.packets) {
    // Whether it has a tile caster: a one-pixel trace_tile answers.
    const CameraRays probe(Camera{}, 1, 1);
    SurfaceHit hit;
    uint8_t found = 0;
    TraceContext ctx;
    m.tiles =
        m.packets->trace_tile(probe, 0, 0, 1, 1, LodFootprint{}, ctx, &hit, &found, active_isa());
  }
  m.structure = std::move(built.structure);
  m.leaf_voxels = built.leaf_voxels;
  m.voxelize_seconds = built.voxelize_seconds;
  m.build_seconds = built.octree_seconds;
  return m;
}

// Bytes a structure holds, by its format's count (SceneFormat::memory_bytes).
uint64_t memory_of(const Measured& m) {
  return m.format->memory_bytes ? m.format->memory_bytes(*m.structure) : 0;
}

// Occlusion rays of --effects, known once the shading points are: every
// shadow and AO ray (28 B) twice (as generated and sample-major), one answer
// byte per ray and caster row (at most 8), and the point itself.
uint64_t effects_bytes(uint64_t points, uint64_t ao_rays) {
  return points * ((1 + ao_rays) * (2 * sizeof(Ray) + 8) + sizeof(ShadingPoint) + 4);
}

void require_within_budget(uint64_t need, uint64_t budget, const std::string& what) {
  if (budget && need > budget)
    throw Error("bench: " + what + " need an estimated " + format_bytes(double(need)) +
                ", more than the " + format_bytes(double(budget)) +
                " memory budget; lower --resolution or --size, drop --contours/--effects, or "
                "raise --memory-budget");
}

// One timing harness for every caster, voxel or Embree. Each row has a
// frame() that runs one frame and returns the seconds of its timed loop only
// (setup and allocation outside). Every row gets a warm-up frame (pages its
// structure in, spins up the TBB workers), then `repeat` rounds run every
// row once each, in turn, so that a load change on the (shared) machine hits
// all casters alike; each row keeps its best frame.
struct Timed {
  double seconds = 1e30;
  uint64_t rays = 0, hits = 0;  // hits: primary hits, or occluded rays
  double mrays() const { return double(rays) / seconds * 1e-6; }
  double mhits() const { return double(hits) / seconds * 1e-6; }
};
// The bar advances between frames, outside every timed loop.
template <class Row>
void measure_interleaved(std::vector<Row>& rows, int repeat, const char* what) {
  Progress progress(what, uint64_t(rows.size()) * uint64_t(repeat + 1));
  for (Row& r : rows) {
    r.t = r.frame();  // warm-up
    r.t.seconds = 1e30;
    progress.advance();
  }
  for (int k = 0; k < repeat; ++k)
    for (Row& r : rows) {
      const Timed t = r.frame();
      if (t.seconds < r.t.seconds) r.t = t;
      progress.advance();
    }
}

Timed timed(const RenderResult& r) {
  return {r.seconds, r.rays, r.hits};
}
Timed timed(const EmbreeScene::DepthRender& r) {
  return {r.seconds, r.rays, r.hits};
}

// The pixel cone of render() (esvo §6.1): lod_pixels pixels per unit distance.
LodFootprint pixel_lod(const CameraRays& cam, float lod_pixels) {
  LodFootprint lod;
  lod.size_per_t = lod_pixels * cam.pixel_angle();
  return lod;
}

// One trace-only frame: the same tiles and threads as render(), depth
// written. trace_tile(tile, cam, lod) traces a tile's primary rays (generated
// in the loop, as render() does), writes their depth and returns its hits.
template <class TraceTile>
Timed depth_frame(const RenderOptions& ro, Image* depth, const TraceTile& trace_tile) {
  const CameraRays cam(ro.camera, ro.width, ro.height);
  const LodFootprint lod = pixel_lod(cam, ro.lod_pixels);
  *depth = Image(ro.width, ro.height, 1);
  std::atomic<uint64_t> hits{0};
  Timed t;
  t.rays = uint64_t(ro.width) * uint64_t(ro.height);
  t.seconds =
      detail::for_each_tile(ro.width, ro.height, ro.tile_size, [&](const detail::Tile& tile) {
        hits.fetch_add(trace_tile(tile, cam, lod), std::memory_order_relaxed);
      });
  t.hits = hits.load();
  return t;
}

// Trace only, the voxel side of the trace-only comparison: no attributes and
// no shading. Through the SurfaceQuery, as render() calls it (one virtual
// call per ray; the structure is any registered format's).
// beam > 0: per beam x beam block of the tile, the coarse pass (esvo §6.2)
// first, inside the timed loop, and the block's rays start from its region.
Timed trace_depth(const SurfaceQuery& s, const RenderOptions& ro, Image* depth, int beam = 0) {
  return depth_frame(
      ro, depth, [&](const detail::Tile& tile, const CameraRays& cam, const LodFootprint& lod) {
        uint64_t h = 0;
        TraceContext ctx;  // plain (non-counting), one per tile
        const int k = beam > 0 ? beam : std::max(tile.x1 - tile.x0, tile.y1 - tile.y0);
        for (int by = tile.y0; by < tile.y1; by += k)
          for (int bx = tile.x0; bx < tile.x1; bx += k) {
            const int bx1 = std::min(bx + k, tile.x1), by1 = std::min(by + k, tile.y1);
            BeamStart start;
            if (beam > 0) s.beam_start(detail::block_beam(cam, bx, by, bx1, by1, lod), ctx, &start);
            for (int y = by; y < by1; ++y)
              for (int x = bx; x < bx1; ++x) {
                SurfaceHit hit;
                const bool found =
                    s.trace(cam.ray(x, y), lod, ctx, &hit, beam > 0 ? &start : nullptr);
                h += found;
                *depth->at(x, y) = found ? hit.t : INFINITY;
              }
          }
        return h;
      });
}

// trace_depth through the structure's packet caster (SurfaceQuery::packets(),
// voxcast/packet_caster.hpp): each
// tile's rays generated in 4x4 block order and traced as one queue.
// beam > 0: the coarse pass (esvo §6.2) per beam x beam block first, inside
// the timed loop; each ray starts at its block's region, rays of empty
// blocks are not traced.
// frustum > 0 instead: the tile frustum pass (SurfaceQuery::frustum_start)
// per tile, then per frustum x frustum block within the tile's cubes, as
// render() does; a tile without cubes writes misses and traces nothing.
// (The shaded packet rows are render() itself, which traces the same way.)
Timed trace_depth_packets(const SurfaceQuery& s, const SurfacePackets& packets,
                          const RenderOptions& ro, int beam, Image* depth, int frustum = 0) {
  return depth_frame(
      ro, depth, [&](const detail::Tile& tile, const CameraRays& cam, const LodFootprint& lod) {
        thread_local detail::PacketTile pt;
        thread_local BeamStart tile_start;
        TraceContext ctx;
        if (frustum > 0) {
          const int octant =
              ray_octant(cam.ray((tile.x0 + tile.x1) / 2, (tile.y0 + tile.y1) / 2).dir);
          s.frustum_start(detail::block_beam(cam, tile.x0, tile.y0, tile.x1, tile.y1, lod), octant,
                          ctx, &tile_start);
          if (tile_start.valid && tile_start.empty) {
            for (int y = tile.y0; y < tile.y1; ++y)
              for (int x = tile.x0; x < tile.x1; ++x) *depth->at(x, y) = INFINITY;
            return uint64_t(0);
          }
        }
        pt.generate(cam, tile.x0, tile.y0, tile.x1, tile.y1);
        if (frustum > 0)
          pt.frustum_blocks(s, cam, lod, tile.x0, tile.y0, tile.x1, tile.y1, frustum, ctx,
                            tile_start);
        else if (beam > 0)
          pt.coarse_pass(
              tile.x0, tile.y0, tile.x1, tile.y1, beam, [&](int x0, int y0, BeamStart* start) {
                s.beam_start(detail::block_beam(cam, x0, y0, std::min(x0 + beam, tile.x1),
                                                std::min(y0 + beam, tile.y1), lod),
                             ctx, start);
              });
        packets.trace_packets(pt.rays.data(), pt.rays.size(), lod, ctx, pt.hits.data(),
                              pt.found.data(), active_isa(), pt.beam_list());
        uint64_t h = 0;
        for (size_t i = 0; i < pt.rays.size(); ++i) {
          h += pt.found[i];
          *depth->at(pt.x(i), pt.y(i)) = pt.found[i] ? pt.hits[i].t : INFINITY;
        }
        return h;
      });
}

// trace_depth through the structure's tile caster (SurfacePackets::trace_tile):
// one walk of the structure per 16x16 tile, rays generated inside it.
Timed trace_depth_tiles(const SurfacePackets& packets, const RenderOptions& ro, Image* depth) {
  return depth_frame(ro, depth,
                     [&](const detail::Tile& tile, const CameraRays& cam, const LodFootprint& lod) {
                       thread_local std::vector<SurfaceHit> hits;
                       thread_local std::vector<uint8_t> found;
                       const int w = tile.x1 - tile.x0, n = w * (tile.y1 - tile.y0);
                       hits.resize(size_t(n)), found.resize(size_t(n));
                       TraceContext ctx;
                       packets.trace_tile(cam, tile.x0, tile.y0, tile.x1, tile.y1, lod, ctx,
                                          hits.data(), found.data(), active_isa());
                       uint64_t h = 0;
                       for (int k = 0; k < n; ++k) {
                         h += found[size_t(k)];
                         *depth->at(tile.x0 + k % w, tile.y0 + k / w) =
                             found[size_t(k)] ? hits[size_t(k)].t : INFINITY;
                       }
                       return h;
                     });
}

// Any-hit answers for pre-generated rays, in the same chunks as
// EmbreeScene::occluded_all (finest level, as the effects trace): chunk(b, e,
// o) answers rays [b, e) into o[b, e).
template <class Chunk>
Timed occluded_frame(const std::vector<Ray>& rays, std::vector<uint8_t>* occ, const Chunk& chunk) {
  occ->assign(rays.size(), 0);
  uint8_t* o = occ->data();
  Timed t;
  t.rays = rays.size();
  t.seconds = detail::for_each_chunk(rays.size(), EmbreeScene::kOcclusionChunk,
                                     [&](size_t b, size_t e) { chunk(b, e, o); });
  for (uint8_t v : *occ) t.hits += v;
  return t;
}

// A voxel structure's occluded(), ray by ray.
Timed occluded_all(const SurfaceQuery& s, const std::vector<Ray>& rays, std::vector<uint8_t>* occ) {
  return occluded_frame(rays, occ, [&](size_t b, size_t e, uint8_t* o) {
    TraceContext ctx;
    for (size_t i = b; i < e; ++i) o[i] = s.occluded(rays[i], LodFootprint{}, ctx);
  });
}

// The same answers through trace() (SurfaceQuery's default transmittance):
// the baseline of a structure's own any-hit path.
Timed occluded_all_trace(const SurfaceQuery& s, const std::vector<Ray>& rays,
                         std::vector<uint8_t>* occ) {
  return occluded_frame(rays, occ, [&](size_t b, size_t e, uint8_t* o) {
    TraceContext ctx;
    SurfaceHit hit;
    for (size_t i = b; i < e; ++i) o[i] = s.trace(rays[i], LodFootprint{}, ctx, &hit);
  });
}

// The packet caster's occluded_packets: each chunk as one queue (runs of
// parallel rays, the shadow rays, by shared walks; AnyHitOptions::parallel).
Timed occluded_all_packets(const SurfacePackets& s, const std::vector<Ray>& rays,
                           std::vector<uint8_t>* occ) {
  return occluded_frame(rays, occ, [&](size_t b, size_t e, uint8_t* o) {
    TraceContext ctx;
    s.occluded_packets(rays.data() + b, e - b, LodFootprint{}, ctx, o + b, active_isa());
  });
}

// The deep start the any-hit rows use (the packet rows are the same kernel
// from the root).
constexpr DeepStart kBenchDeepStart = DeepStart::Packet;

// The any-hit packets' lane kernel (the packet rows have the parallel walks)
// with the rays started at `start`: each chunk as one call.
Timed occluded_all_anyhit(const AnyHitCaster& s, const std::vector<Ray>& rays, DeepStart start,
                          std::vector<uint8_t>* occ) {
  return occluded_frame(rays, occ, [&](size_t b, size_t e, uint8_t* o) {
    AnyHitOptions opt;
    opt.deep_start = start;
    opt.parallel = false;
    s(rays.data() + b, e - b, o + b, opt, nullptr);
  });
}

// The any-hit packets on point-major AO rays (k per point, rays[p k + j]),
// with or without the deep start, chunks of whole points. The answers go
// back to sample-major order (the other rows' order, occ[j np + p]) after
// the timed loop. *stats (may be null): what the deep start did.
Timed occluded_ao_groups(const AnyHitCaster& s, const std::vector<Ray>& rays,
                         const std::vector<Vec3>& normals, size_t k, bool deep, int cull_budget,
                         std::vector<uint8_t>* occ, AnyHitStats* stats) {
  const size_t np = normals.size();
  std::vector<uint8_t> point_major(rays.size(), 0);  // outside the timed loop
  std::atomic<uint64_t> points{0}, culled{0}, traced{0}, deep_rays{0}, depth{0};
  const size_t per_chunk = std::max<size_t>(1, EmbreeScene::kOcclusionChunk / k);
  Timed t;
  t.rays = rays.size();
  t.seconds = detail::for_each_chunk(np, per_chunk, [&](size_t b, size_t e) {
    AnyHitOptions opt;
    opt.group = int(k), opt.normals = normals.data() + b,
    opt.deep_start = deep ? kBenchDeepStart : DeepStart::Off;
    opt.cull_budget = cull_budget;
    AnyHitStats st;
    s(rays.data() + b * k, (e - b) * k, point_major.data() + b * k, opt, &st);
    points += st.points, culled += st.culled, traced += st.rays;
    deep_rays += st.deep_rays, depth += st.depth_sum;
  });
  occ->assign(rays.size(), 0);
  for (size_t p = 0; p < np; ++p)
    for (size_t j = 0; j < k; ++j) (*occ)[j * np + p] = point_major[p * k + j];
  for (uint8_t v : *occ) t.hits += v;
  if (stats != nullptr)
    *stats = {points.load(), culled.load(), traced.load(), deep_rays.load(), depth.load()};
  return t;
}

// Records the rays shadow_visibility() / ambient_occlusion() would trace
// (answering "open"), so that the occlusion rays are generated once, with
// the renderer's very sampling, and every caster gets the same array.
class RayRecorder final : public Occluder {
 public:
  float transmittance(const Ray& ray, const LodFootprint&, TraceContext&,
                      const BeamStart*) const override {
    rays.push_back(ray);
    return 1.f;
  }
  mutable std::vector<Ray> rays;
};

// Stage ticks of the instrumented single-threaded voxel pass: what render()
// does per pixel (ray generation, trace, attributes, shading without
// effects), with timestamp reads between the stages. packets (may be null:
// the scalar path): render()'s packet path, per 16x16 tile the rays
// generated in 4x4 block order and traced by one trace_packets call (ray
// generation and traversal read per tile), then the hits' attributes and
// shading.
// frustum > 0 (with packets): the tile frustum pass and the per-block lists
// first, counted as traversal.
EmbreeScene::StageTicks profile_voxels(const SurfaceQuery& s, const RenderOptions& ro,
                                       const SurfacePackets* packets, int frustum = 0,
                                       bool tile = false) {
  const CameraRays cam(ro.camera, ro.width, ro.height);
  const LodFootprint lod = pixel_lod(cam, ro.lod_pixels);
  const Vec3 to_light = normalize(-ro.light_dir);
  const uint64_t overhead = detail::tick_overhead();
  auto since = [overhead](uint64_t a, uint64_t b) {
    return b - a > overhead ? b - a - overhead : 0;
  };
  EmbreeScene::StageTicks st;
  Image color(ro.width, ro.height, 3);
  TraceContext ctx;
  // Attributes and shading of one hit, from t0 = the tick after its trace.
  auto shade = [&](const SurfaceHit& hit, Vec3 dir, int x, int y, uint64_t t0) {
    Color c;
    Vec3 n;
    s.attributes(hit, ctx, &c, &n);
    const uint64_t t1 = detail::ticks();
    const Color sh = surface_phong(c, n, dir, to_light);
    float* o = color.at(x, y);
    o[0] = sh.r, o[1] = sh.g, o[2] = sh.b;
    const uint64_t t2 = detail::ticks();
    st.attributes += since(t0, t1);
    st.shading += since(t1, t2);
  };
  if (packets && tile) {
    // The tile caster: its ray set-up is inside trace_tile, so it counts as
    // traversal here (the "ray generation" column stays 0).
    const int T = 16;
    std::vector<SurfaceHit> hits(size_t(T * T));
    std::vector<uint8_t> found(size_t(T * T));
    for (int ty = 0; ty < ro.height; ty += T)
      for (int tx = 0; tx < ro.width; tx += T) {
        const int tx1 = std::min(tx + T, ro.width), ty1 = std::min(ty + T, ro.height);
        const uint64_t t1 = detail::ticks();
        packets->trace_tile(cam, tx, ty, tx1, ty1, lod, ctx, hits.data(), found.data(),
                            active_isa());
        const uint64_t t2 = detail::ticks();
        st.traversal += since(t1, t2);
        const int w = tx1 - tx;
        for (int k = 0; k < w * (ty1 - ty); ++k) {
          if (!found[size_t(k)]) continue;
          const Vec3 dir = cam.direction(tx + k % w, ty + k / w);  // the view vector, untimed
          shade(hits[size_t(k)], dir, tx + k % w, ty + k / w, detail::ticks());
        }
      }
  } else if (packets) {
    const int T = 16;
    detail::PacketTile pt;
    BeamStart tile_start;
    for (int ty = 0; ty < ro.height; ty += T)
      for (int tx = 0; tx < ro.width; tx += T) {
        const int tx1 = std::min(tx + T, ro.width), ty1 = std::min(ty + T, ro.height);
        const uint64_t t0 = detail::ticks();
        pt.generate(cam, tx, ty, tx1, ty1);
        const uint64_t t1 = detail::ticks();
        if (frustum > 0) {
          s.frustum_start(detail::block_beam(cam, tx, ty, tx1, ty1, lod),
                          ray_octant(cam.ray((tx + tx1) / 2, (ty + ty1) / 2).dir), ctx,
                          &tile_start);
          pt.frustum_blocks(s, cam, lod, tx, ty, tx1, ty1, frustum, ctx, tile_start);
        }
        packets->trace_packets(pt.rays.data(), pt.rays.size(), lod, ctx, pt.hits.data(),
                               pt.found.data(), active_isa(), pt.beam_list());
        const uint64_t t2 = detail::ticks();
        st.ray_generation += since(t0, t1);
        st.traversal += since(t1, t2);
        for (size_t i = 0; i < pt.rays.size(); ++i)
          if (pt.found[i]) shade(pt.hits[i], pt.rays[i].dir, pt.x(i), pt.y(i), detail::ticks());
      }
  } else {
    for (int y = 0; y < ro.height; ++y)
      for (int x = 0; x < ro.width; ++x) {
        const uint64_t t0 = detail::ticks();
        const Ray ray = cam.ray(x, y);
        const uint64_t t1 = detail::ticks();
        SurfaceHit hit;
        const bool found = s.trace(ray, lod, ctx, &hit);
        const uint64_t t2 = detail::ticks();
        st.ray_generation += since(t0, t1);
        st.traversal += since(t1, t2);
        if (found) shade(hit, ray.dir, x, y, t2);
      }
  }
  st.rays = uint64_t(ro.width) * uint64_t(ro.height);
  return st;
}

double coverage(const Image& depth) {
  size_t hits = 0;
  for (float d : depth.pixels) hits += std::isfinite(d);
  return double(hits) / double(depth.pixels.size());
}
}  // namespace

Runner add_bench(CLI::App& app) {
  auto args = std::make_shared<BenchArgs>();
  CLI::App* cmd = app.add_subcommand(
      "bench", "Build a mesh as voxels and as an Embree BVH, ray cast both, compare Mrays/s");
  cmd->add_option("MESH", args->input, "Input mesh")->required();
  cmd->add_option("--resolution", args->resolution, "Voxels per axis (power of two)")
      ->capture_default_str()
      ->check(not_negative());
  cmd->add_option("--size", args->size,
                  "Image size WxH, or a comma-separated list of sizes measured one after another")
      ->capture_default_str();
  add_camera_options(cmd, args->camera);
  cmd->add_option("--min-coverage", args->min_coverage,
                  "Zoom the automatic camera in until this share of the pixels hits the mesh "
                  "(0 = off; crops the model; older BENCHMARKS rows used 0.3)")
      ->capture_default_str();
  cmd->add_option("--lod", args->lod, "Voxel LOD in pixels (0 = finest level)")
      ->capture_default_str();
  cmd->add_option("--voxelization", args->voxelization, "conservative | 6-separating")
      ->capture_default_str();
  cmd->add_option("--attributes", args->attributes, "raw | compressed")->capture_default_str();
  cmd->add_option("--repeat", args->repeat, "Timed frames per ray caster (best is reported)")
      ->capture_default_str();
  cmd->add_option("--beam", args->beam,
                  "Beam block size for the second voxcast run (4 or 8; 0 = skip that run)")
      ->capture_default_str();
  cmd->add_option("--frustum", args->frustum,
                  "Block size of the 'packet+frustum' rows (tile frustum pass, per-block cube "
                  "lists the packets start from; 2..64, 16 or more: the 16x16 tile's list; 0 = "
                  "no such rows)")
      ->capture_default_str();
  cmd->add_option("--threads", args->threads, "Worker threads (0 = all cores)");
  cmd->add_flag("-v,--verbose", args->verbose, "Print timings per stage");
  cmd->add_flag(
      "--contours", args->contours,
      "Also build the same voxels with contours (esvo section 5.2) and measure them, with "
      "and without the beam (the shape of esvo Table 4)");
  cmd->add_flag(
      "--effects", args->effects,
      "Also measure every other registered structure of the same voxels (the DAG, the "
      "brickmap world), and shadow and AO rays (svdag section 4), generated once, on every "
      "structure and Embree rtcOccluded1/8/16/1M");
  cmd->add_flag("--brickmap", args->brickmap,
                "Also measure the brickmap world of the same voxels (van Wingerden 2015), without "
                "--effects");
  cmd->add_option("--ao-rays", args->ao_rays, "AO rays per hit pixel for --effects")
      ->capture_default_str();
  cmd->add_option("--ao-radius", args->ao_radius,
                  "AO ray length for --effects (0 = 5% of the mesh bounds diagonal)")
      ->capture_default_str();
  cmd->add_option("--gi", args->gi,
                  "Also time diffuse GI with this many samples per pixel (render --gi, under "
                  "the procedural sky and its sun) against the Embree path tracer of the mesh "
                  "with the same sampling code (0 = off)")
      ->capture_default_str();
  cmd->add_option("--bounces", args->bounces, "With --gi: diffuse bounces at most")
      ->capture_default_str();
  cmd->add_option("--json", args->json, "Also write every figure as JSON to this file");
  cmd->add_option("--memory-budget", args->memory_budget,
                  "Bytes every structure, image and ray array held at once may take (512M, 8G, "
                  "...; default 90% of available memory); checked before anything is built");
  return [args]() {
    ThreadLimit limit(args->threads);
    std::vector<std::pair<int, int>> sizes;
    {
      std::stringstream list(args->size);
      std::string one;
      while (std::getline(list, one, ',')) {
        int w = 0, h = 0;
        parse_size(one, &w, &h);
        sizes.emplace_back(w, h);
      }
      if (sizes.empty()) throw UsageError("--size: no size given");
    }
    require_power_of_two("--resolution", args->resolution, 1, uint64_t(1) << 20);
    require_range("--lod", args->lod, 0, 1e6);
    require_range("--repeat", args->repeat, 1, 1000);
    require_range("--gi", args->gi, 0, 65536);
    require_range("--bounces", args->bounces, 0, 1024);
    if (args->beam != 0 && args->beam != 4 && args->beam != 8)
      throw UsageError("--beam must be 0, 4 or 8");
    if (args->frustum != 0 && (args->frustum < 2 || args->frustum > 64))
      throw UsageError("--frustum must be 0 (off) or a block size in 2..64");
    require_range("--min-coverage", args->min_coverage, 0, 0.95);
    require_range("--ao-rays", args->ao_rays, 1, 4096);
    require_range("--ao-radius", args->ao_radius, 0, 1e30);
    check_camera_options(args->camera, 64, 64);
    require_regular_input(args->input, "mesh");

    const uint64_t budget = effective_budget(
        args->memory_budget.empty() ? 0 : parse_memory_budget(args->memory_budget));

    BuildSettings s;
    s.mesh_path = args->input;
    s.resolution = args->resolution;
    s.mode = parse_voxelization(args->voxelization);
    s.compress_attributes = parse_compressed_attributes(args->attributes);
    s.verbose = args->verbose;
    s.memory_budget = budget;
    // The registered formats, in registration order: the first is measured
    // always (its hits are the shading points of --effects, its bounds frame
    // the camera), the others with --effects.
    const std::vector<SceneFormat>& formats = format_registry().formats();
    if (formats.empty()) throw Error("bench: no scene format is registered");
    const SceneFormat& first = formats.front();
    if (args->contours && !first.contours)
      throw UsageError("--contours: format " + first.name + " stores no contours");
    s.format = first.name;
    MeshLoadStats mesh_stats;
    Mesh mesh = load_build_mesh(s.mesh_path, budget, &mesh_stats, s.verbose);
    // The grid every build fits to the mesh (build_scene's).
    const GridTransform grid = build_grid(s, mesh.bounds());
    // Every structure bench holds at once, against the budget, before the
    // first build: the first structure, Embree's BVH, the contour build, the
    // images.
    BenchMemory held;
    {
      const uint64_t build = estimate_build_bytes(mesh, grid), one_mesh = mesh_bytes(mesh);
      // The first build's mesh, and the copy later builds start from.
      held.mesh = one_mesh * (args->contours || args->effects || args->brickmap ? 2 : 1);
      held.primary = build;
      held.embree = uint64_t(mesh.triangle_count()) * kEmbreeBytesPerTriangle;
      if (args->contours) held.contours = build + one_mesh;
      for (const auto& [w, h] : sizes)
        held.images = std::max(held.images, uint64_t(w) * uint64_t(h) * kImageBytesPerPixel);
      std::string parts = "the mesh, the " + first.name + " structure, Embree's BVH";
      if (args->contours) parts += ", the contour octree";
      parts += " and the images";
      require_within_budget(held.total(), budget, parts);
    }
    const Mesh mesh_copy = (args->contours || args->effects || args->brickmap) ? mesh : Mesh();
    BuiltScene built = build_scene(s, std::move(mesh), mesh_stats);
    const size_t triangles = built.mesh.triangle_count();
    std::optional<Measured> primary_or = measured(first, std::move(built));
    if (!primary_or)
      throw Error("bench: format " + first.name + " has no surface query to cast rays at");
    // Every measured structure; [0] is the first format's. Reserved: the rows
    // below keep references to the elements.
    std::vector<Measured> structures;
    structures.reserve(formats.size());
    structures.push_back(std::move(*primary_or));
    const Measured& main_structure = structures.front();
    const Aabb occupied = first.occupied(*main_structure.structure);
    EmbreeScene embree(built.mesh);
    std::optional<Measured> contoured;
    // What is left for a later build (0 would mean "no budget").
    auto left_after = [&](uint64_t bytes) { return budget > bytes ? budget - bytes : 1; };
    if (args->contours) {
      BuildSettings cs = s;
      cs.contours = true;
      // (build_scene counts its own copy of the mesh.)
      cs.memory_budget = left_after(held.mesh + held.primary + held.embree + held.images);
      contoured = measured(first, build_scene(cs, mesh_copy, mesh_stats));
    }
    // With --effects: every other registered format of the same voxels
    // (svdag §4: the DAG), same mesh, grid and voxelization.
    // With --brickmap alone: the brickmap world only (van Wingerden 2015).
    for (size_t i = 1; i < formats.size(); ++i)
      if (formats[i].builds() &&  // not a file type of its own (slice files)
          (args->effects || (args->brickmap && formats[i].name == "brickmap"))) {
        BuildSettings ds = s;
        ds.format = formats[i].name;
        ds.verbose = false;
        // Out of core within what the others leave when in core would not
        // fit (build_scene counts its own copy of the mesh).
        ds.memory_budget = left_after(held.total());
        // Held afterwards: at most its in-core estimate (the same grid as
        // the first's) or the budget it was given.
        held.others += std::min(held.primary, ds.memory_budget);
        if (std::optional<Measured> m =
                measured(formats[i], build_scene(ds, mesh_copy, mesh_stats)))
          structures.push_back(std::move(*m));
      }

    // Machine and command line first: every figure below depends on them.
    const std::string isa = EmbreeScene::probe_isa();
    const std::string cpu = cpu_description(), load = load_average(), cmdline = command_line();
    print_bench_header();
    std::printf("embree      %s\n", isa.c_str());
    nlohmann::json json_runs = nlohmann::json::array();
    for (size_t size_index = 0; size_index < sizes.size(); ++size_index) {
      const int width = sizes[size_index].first, height = sizes[size_index].second;
      // The same framing as `render` of a scene of these voxels: the occupied
      // voxel bounds the scene loader computes.
      bool derived_camera = false;
      Camera camera = resolve_camera(args->camera, occupied, width, height, &derived_camera);
      if (derived_camera && args->min_coverage > 0) {
        // Misses flatter every ray caster: optionally zoom in until the mesh
        // covers enough pixels (this crops the model).
        for (int i = 0; i < 12; ++i) {
          double c =
              coverage(embree.render_depth(camera, width, height, EmbreeScene::Mode::Single).depth);
          if (c >= args->min_coverage) break;
          if (camera.projection == Projection::Orthographic)
            camera.ortho_width *= 0.85f;
          else
            camera.fovy_degrees *= 0.85f;
        }
      }

      RenderOptions ro;
      ro.width = width;
      ro.height = height;
      ro.camera = camera;
      ro.lod_pixels = args->lod;
      ro.want_depth = true;

      const int threads = args->threads ? args->threads : int(std::thread::hardware_concurrency());
      const double rays = double(width) * height;
      nlohmann::json run;
      run["image"] = {{"width", width}, {"height", height}};
      run["camera"] = camera.to_string();

      // ---- Primary rays: Embree in every mode, then the voxel casters. ----
      struct PrimaryRow {
        std::string caster, call;
        float lod;  // < 0: not a voxel caster
        bool shaded;
        std::function<Timed()> frame;
        Timed t;
      };
      std::vector<PrimaryRow> primary;
      EmbreeScene::DepthRender e1;  // rtcIntersect1 depth: coverage and agreement
      for (const EmbreeScene::Mode m : EmbreeScene::kModes) {
        const std::string name = std::string("embree ") + EmbreeScene::mode_name(m);
        primary.push_back({name,
                           EmbreeScene::mode_call(m),
                           -1.f,
                           false,
                           [&, m] {
                             auto r = embree.render_depth(camera, width, height, m);
                             if (m == EmbreeScene::Mode::Single) e1 = std::move(r);
                             return timed(m == EmbreeScene::Mode::Single ? e1 : r);
                           },
                           {}});
        primary.push_back(
            {name,
             std::string(EmbreeScene::mode_call(m)) + ", normals + Phong",
             -1.f,
             true,
             [&, m] { return timed(embree.render_shaded(camera, width, height, m, ro.light_dir)); },
             {}});
      }
      // LOD 0 (finest level) and --lod: trace only and render() (attributes + shading).
      std::vector<float> lods{0.f};
      if (args->lod != 0.f) lods.push_back(args->lod);
      RenderResult vox_result;  // at --lod, for the agreement line
      // Trace-only and render() rows of one voxel structure at every LOD
      // (packet rows where it offers a packet caster).
      auto add_voxel_rows = [&](const Measured& m) {
        const std::string& caster = m.caster;
        const SurfaceQuery& q = *m.query;
        const SurfacePackets* p = m.packets;
        for (float lod : lods) {
          RenderOptions rl = ro;
          rl.lod_pixels = lod;
          primary.push_back({caster,
                             "trace, depth only",
                             lod,
                             false,
                             [&q, rl] {
                               Image depth;
                               return trace_depth(q, rl, &depth);
                             },
                             {}});
          if (args->beam)
            primary.push_back({caster + "+beam",
                               "trace, beam " + std::to_string(args->beam) + "x" +
                                   std::to_string(args->beam) +
                                   " (coarse pass included), depth only",
                               lod,
                               false,
                               [&q, rl, k = args->beam] {
                                 Image depth;
                                 return trace_depth(q, rl, &depth, k);
                               },
                               {}});
          if (p) {
            primary.push_back({caster + " packet",
                               std::string("trace_packets ") + isa_name(active_isa()) + " x" +
                                   std::to_string(packet_width(active_isa())) + ", depth only",
                               lod,
                               false,
                               [&q, p, rl] {
                                 Image depth;
                                 return trace_depth_packets(q, *p, rl, 0, &depth);
                               },
                               {}});
            // The tile caster, where the structure has one.
            if (m.tiles) {
              primary.push_back(
                  {caster + " tile",
                   std::string("trace_tile ") + isa_name(active_isa()) + ", depth only",
                   lod,
                   false,
                   [p, rl] {
                     Image depth;
                     return trace_depth_tiles(*p, rl, &depth);
                   },
                   {}});
              primary.push_back({caster + " tile",
                                 std::string("render(), tile caster ") + isa_name(active_isa()) +
                                     ": attributes + Phong",
                                 lod,
                                 true,
                                 [&m, rl] {
                                   RenderOptions rp = rl;
                                   rp.caster = Caster::Tile;
                                   return timed(render(*m.structure, rp));
                                 },
                                 {}});
            }
            // render() as it runs by default: primary rays as 4x4 pixel
            // blocks through the packet caster, then attributes and shading.
            primary.push_back({caster + " packet",
                               std::string("render(), packet primary rays ") +
                                   isa_name(active_isa()) + ": attributes + Phong",
                               lod,
                               true,
                               [&m, rl] {
                                 RenderOptions rp = rl;
                                 rp.caster = Caster::Packet;
                                 return timed(render(*m.structure, rp));
                               },
                               {}});
            if (args->beam)
              primary.push_back({caster + " packet+beam",
                                 std::string("trace_packets, beam ") + std::to_string(args->beam) +
                                     "x" + std::to_string(args->beam) +
                                     " (coarse pass included), depth only",
                                 lod,
                                 false,
                                 [&q, p, rl, k = args->beam] {
                                   Image depth;
                                   return trace_depth_packets(q, *p, rl, k, &depth);
                                 },
                                 {}});
            if (args->frustum) {
              const std::string k = std::to_string(args->frustum);
              // Blocks of the tile's size or more: the tile's list serves them.
              const std::string lists = args->frustum >= RenderOptions{}.tile_size
                                            ? "the tile's list"
                                            : k + "x" + k + " block lists";
              primary.push_back(
                  {caster + " packet+frustum",
                   "trace_packets, tile frustum pass + " + lists + " (passes included), depth only",
                   lod,
                   false,
                   [&q, p, rl, k = args->frustum] {
                     Image depth;
                     return trace_depth_packets(q, *p, rl, 0, &depth, k);
                   },
                   {}});
              primary.push_back({caster + " packet+frustum",
                                 "render(), packet primary rays from the tile frustum pass + " +
                                     lists + ": attributes + Phong",
                                 lod,
                                 true,
                                 [&m, rl, k = args->frustum] {
                                   RenderOptions rp = rl;
                                   rp.caster = Caster::Packet;
                                   rp.frustum = k;
                                   return timed(render(*m.structure, rp));
                                 },
                                 {}});
            }
          }
          RenderOptions rs = rl;
          rs.caster = Caster::Scalar;
          primary.push_back({caster,
                             "render(), scalar primary rays: attributes + Phong",
                             lod,
                             true,
                             [&, rs, keep = &m == &main_structure && lod == args->lod] {
                               if (!keep) return timed(render(*m.structure, rs));
                               vox_result = render(*m.structure, rs);
                               return timed(vox_result);
                             },
                             {}});
        }
      };
      add_voxel_rows(main_structure);
      // The existing variants at --lod, rendered (attributes + shading).
      RenderOptions ro_beam = ro;
      ro_beam.beam = args->beam;
      if (args->beam)
        primary.push_back({main_structure.caster + "+beam",
                           "render(), beam " + std::to_string(args->beam) + "x" +
                               std::to_string(args->beam) + " (coarse pass included)",
                           args->lod,
                           true,
                           [&] { return timed(render(*main_structure.structure, ro_beam)); },
                           {}});
      if (contoured) {
        primary.push_back({"voxcast contours",
                           "render()",
                           args->lod,
                           true,
                           [&] { return timed(render(*contoured->structure, ro)); },
                           {}});
        if (args->beam)
          primary.push_back({"voxcast contours+beam",
                             "render(), beam",
                             args->lod,
                             true,
                             [&] { return timed(render(*contoured->structure, ro_beam)); },
                             {}});
      }
      // With --effects: the other structures of the same voxels (svdag §4),
      // same camera, rendered with a beam of 8x8 as well.
      RenderOptions other_beam = ro;
      other_beam.beam = 8;
      const size_t measured_here = size_index == 0 ? structures.size() : 1;
      for (size_t i = 1; i < measured_here; ++i) {
        const Measured& m = structures[i];
        add_voxel_rows(m);
        primary.push_back({m.caster + "+beam",
                           "render(), beam 8x8",
                           args->lod,
                           true,
                           [&] { return timed(render(*m.structure, other_beam)); },
                           {}});
      }
      measure_interleaved(primary, args->repeat, "bench primary rays");
      const double cov = double(primary[0].t.hits) / rays;
      // Ratios against the fastest Embree mode of the same comparison.
      double fastest[2] = {0, 0};
      std::string fastest_name[2];
      for (const PrimaryRow& r : primary)
        if (r.lod < 0 && r.t.mrays() > fastest[r.shaded])
          fastest[r.shaded] = r.t.mrays(), fastest_name[r.shaded] = r.caster;

      // How well the voxels reproduce the mesh in this very frame.
      size_t agree = 0, both = 0, close = 0;
      double tol = 2.0 * std::sqrt(3.0) * grid.voxel_size;
      for (size_t i = 0; i < vox_result.depth.pixels.size(); ++i) {
        float dv = vox_result.depth.pixels[i], de = e1.depth.pixels[i];
        agree += std::isfinite(dv) == std::isfinite(de);
        if (std::isfinite(dv) && std::isfinite(de)) {
          ++both;
          close += std::fabs(dv - de) <= tol;
        }
      }
      const uint64_t memory = memory_of(main_structure);
      std::printf("mesh        %s: %zu triangles\n", printable(args->input).c_str(), triangles);
      std::printf("camera      %s\n", camera.to_string().c_str());
      std::printf("image       %dx%d, %.1f%% of pixels hit the mesh, %d threads, best of %d\n",
                  width, height, 100.0 * cov, threads, args->repeat);
      std::printf("voxels      %u^3 %s, %llu leaf voxels, lod %.2g px\n", grid.resolution,
                  voxelization_name(s.mode), (unsigned long long)main_structure.leaf_voxels,
                  args->lod);
      std::printf("agreement   hit/miss %.3f%%, depth within 2 leaf voxel diagonals %.3f%%\n",
                  100.0 * double(agree) / rays, both ? 100.0 * double(close) / double(both) : 0.0);
      std::printf("build       voxcast %.2f s (voxelize %.2f s + %s %.2f s), embree %.2f s\n",
                  main_structure.voxelize_seconds + main_structure.build_seconds,
                  main_structure.voxelize_seconds, first.name.c_str(), main_structure.build_seconds,
                  embree.build_seconds());
      std::printf("memory      voxcast %s (%.2f B/leaf voxel), embree %s\n",
                  format_bytes(double(memory)).c_str(),
                  double(memory) / double(main_structure.leaf_voxels),
                  format_bytes(double(embree.memory_bytes())).c_str());
      for (int shaded = 0; shaded < 2; ++shaded) {
        std::printf("\n%s (ratio: Mrays/s over %s, the fastest Embree mode here)\n",
                    shaded ? "trace + the same shading" : "trace only (depth written)",
                    fastest_name[shaded].c_str());
        std::printf("  %-22s %4s %9s %9s %7s  %s\n", "caster", "lod", "Mrays/s", "Mhits/s", "ratio",
                    "how");
        for (const PrimaryRow& r : primary) {
          if (r.shaded != bool(shaded)) continue;
          char lod[16] = "-";
          if (r.lod >= 0) std::snprintf(lod, sizeof lod, "%g", double(r.lod));
          std::printf("  %-22s %4s %9.2f %9.2f %7.3f  %s\n", r.caster.c_str(), lod, r.t.mrays(),
                      r.t.mhits(), r.t.mrays() / fastest[shaded], r.call.c_str());
        }
      }
      std::printf("\n");
      // The one-line summary (bench/*.sh read these lines): voxcast render()
      // at --lod against Embree trace only, as before, now with every mode.
      auto find = [&](const std::string& caster, bool shaded, float lod) -> const Timed* {
        for (const PrimaryRow& r : primary)
          if (r.caster == caster && r.shaded == shaded && (r.lod < 0 || r.lod == lod)) return &r.t;
        return nullptr;
      };
      // render() as it runs by default (packet primary rays where the
      // structure has them).
      const Timed* main_packet = find(main_structure.caster + " packet", true, args->lod);
      const double m_vox =
          (main_packet ? main_packet : find(main_structure.caster, true, args->lod))->mrays();
      std::printf("voxcast     %8.2f Mrays/s\n", m_vox);
      double best_voxcast = m_vox;
      if (const Timed* t = find(main_structure.caster + "+beam", true, args->lod)) {
        std::printf("voxcast+beam%8.2f Mrays/s (beam %dx%d, coarse pass included)\n", t->mrays(),
                    args->beam, args->beam);
        best_voxcast = std::max(best_voxcast, t->mrays());
      }
      if (const Timed* t = find(main_structure.caster + " tile", true, args->lod)) {
        std::printf("voxcast tile%8.2f Mrays/s (render(), tile caster)\n", t->mrays());
        best_voxcast = std::max(best_voxcast, t->mrays());
      }
      if (const Timed* t = find("voxcast contours", true, args->lod)) {
        std::printf("contours    %8.2f Mrays/s (build %.2f s, %s)\n", t->mrays(),
                    contoured->voxelize_seconds + contoured->build_seconds,
                    format_bytes(double(memory_of(*contoured))).c_str());
        best_voxcast = std::max(best_voxcast, t->mrays());
      }
      if (const Timed* t = find("voxcast contours+beam", true, args->lod)) {
        std::printf("contours+beam%7.2f Mrays/s (beam %dx%d)\n", t->mrays(), args->beam,
                    args->beam);
        best_voxcast = std::max(best_voxcast, t->mrays());
      }
      for (const EmbreeScene::Mode m : EmbreeScene::kModes) {
        const std::string name = std::string("embree ") + EmbreeScene::mode_name(m);
        std::printf("%-12s%8.2f Mrays/s (%s)\n", name.c_str(), find(name, false, 0)->mrays(),
                    EmbreeScene::mode_call(m));
      }
      for (size_t i = 1; i < measured_here; ++i)
        std::printf("primary %s %8.2f Mrays/s, with beam 8x8 %.2f Mrays/s (%s in memory)\n",
                    structures[i].format->name.c_str(),
                    find(structures[i].caster, true, args->lod)->mrays(),
                    find(structures[i].caster + "+beam", true, args->lod)->mrays(),
                    format_bytes(double(memory_of(structures[i]))).c_str());
      std::printf("ratio voxcast/embree: %.3f\n", best_voxcast / fastest[0]);
      if (size_index == 0)
        for (size_t i = 1; i < structures.size(); ++i) {
          print_brickmap_edit_rows(*structures[i].structure,
                                   CameraRays(camera, width, height).ray(width / 2, height / 2));
          nlohmann::json decode;
          print_brickmap_decode_row(*structures[i].structure, args->repeat, &decode);
          if (!decode.is_null()) run["brickmap_chunk_decode"] = decode;
        }

      run["coverage"] = cov;
      run["agreement"] = {{"hit_miss", double(agree) / rays},
                          {"depth_within_2_diagonals", both ? double(close) / double(both) : 0.0}};
      run["fastest_embree"] = {{"trace", fastest_name[0]}, {"shaded", fastest_name[1]}};
      for (const PrimaryRow& r : primary)
        run["primary"].push_back({{"caster", r.caster},
                                  {"how", r.call},
                                  {"lod", r.lod >= 0 ? nlohmann::json(r.lod) : nlohmann::json()},
                                  {"shaded", r.shaded},
                                  {"seconds", r.t.seconds},
                                  {"rays", r.t.rays},
                                  {"hits", r.t.hits},
                                  {"mrays_per_s", r.t.mrays()},
                                  {"mhits_per_s", r.t.mhits()},
                                  {"ratio", r.t.mrays() / fastest[r.shaded]}});

      // ---- Cycles per ray: one instrumented single-threaded pass each. ----
      {
        const double hz = detail::tsc_hz();
        struct ProfileRow {
          std::string caster;
          float lod;
          EmbreeScene::StageTicks st;
        };
        std::vector<ProfileRow> prof;
        // Timestamps count wall time: a pass that another process preempted
        // reads high. The pass with the lowest total of a few (after a warm-up
        // pass) is the one least disturbed.
        const int passes = std::min(args->repeat, 3);
        auto least_disturbed = [&](const auto& pass) {
          pass();  // warm-up
          EmbreeScene::StageTicks best = pass();
          for (int k = 1; k < passes; ++k) {
            const EmbreeScene::StageTicks st = pass();
            if (st.total() < best.total()) best = st;
          }
          return best;
        };
        prof.push_back({"embree x1", -1.f, least_disturbed([&] {
                          return embree.profile_single(camera, width, height, ro.light_dir);
                        })});
        for (float lod : lods) {
          RenderOptions rl = ro;
          rl.lod_pixels = lod;
          for (size_t i = 0; i < measured_here; ++i) {
            prof.push_back({structures[i].caster, lod, least_disturbed([&] {
                              return profile_voxels(*structures[i].query, rl, nullptr);
                            })});
            if (structures[i].packets)
              prof.push_back({structures[i].caster + " packet", lod, least_disturbed([&] {
                                return profile_voxels(*structures[i].query, rl,
                                                      structures[i].packets);
                              })});
            if (structures[i].tiles)
              prof.push_back({structures[i].caster + " tile", lod, least_disturbed([&] {
                                return profile_voxels(*structures[i].query, rl,
                                                      structures[i].packets, 0, true);
                              })});
            if (structures[i].packets && args->frustum)
              prof.push_back({structures[i].caster + " frustum", lod, least_disturbed([&] {
                                return profile_voxels(*structures[i].query, rl,
                                                      structures[i].packets, args->frustum);
                              })});
          }
        }
        std::printf(
            "cycles per ray (TSC ticks at %.2f GHz, 1 thread, instrumented pass; per primary ray,\n"
            "attributes and shading only on hits)\n",
            hz * 1e-9);
        std::printf("  %-14s %4s %9s %9s %10s %8s %8s\n", "caster", "lod", "ray gen", "traversal",
                    "attributes", "shading", "total");
        for (const ProfileRow& p : prof) {
          const double n = double(std::max<uint64_t>(p.st.rays, 1));
          const double total = double(p.st.total()) / n;
          char lod[16] = "-";
          if (p.lod >= 0) std::snprintf(lod, sizeof lod, "%g", double(p.lod));
          std::printf("  %-14s %4s %9.1f %9.1f %10.1f %8.1f %8.1f\n", p.caster.c_str(), lod,
                      double(p.st.ray_generation) / n, double(p.st.traversal) / n,
                      double(p.st.attributes) / n, double(p.st.shading) / n, total);
          run["cycles_per_ray"].push_back(
              {{"caster", p.caster},
               {"lod", p.lod >= 0 ? nlohmann::json(p.lod) : nlohmann::json()},
               {"ray_generation", double(p.st.ray_generation) / n},
               {"traversal", double(p.st.traversal) / n},
               {"attributes", double(p.st.attributes) / n},
               {"shading", double(p.st.shading) / n},
               {"total", total}});
        }
        run["tsc_hz"] = hz;
        std::printf("\n");
      }

      if (args->effects && size_index == 0) {
        // Shading points: the first structure's primary hits of this frame (finest level,
        // voxel normals), offset once (effects.hpp). Their shadow and AO rays
        // are generated once, here, and every caster traces the same arrays.
        // Pixels in 4x4 block order (block_order): the shadow rays of a block
        // are neighbours in the arrays, so a 16-ray packet, voxcast's or
        // Embree's, holds the parallel shadow rays of one pixel block.
        const CameraRays cam(camera, width, height);
        std::vector<ShadingPoint> points;
        std::vector<uint32_t> seeds;
        std::vector<uint32_t> pixel_order;
        block_order(0, 0, width, height, &pixel_order);
        TraceContext ctx;
        for (const uint32_t xy : pixel_order) {
          const int x = int(xy & 0xFFFF), y = int(xy >> 16);
          const Ray ray = cam.ray(x, y);
          SurfaceHit hit;
          if (!main_structure.query->trace(ray, LodFootprint{}, ctx, &hit)) continue;
          Color c;
          Vec3 n;
          main_structure.query->attributes(hit, ctx, &c, &n);
          if (dot(n, ray.dir) > 0.f) n = -n;
          points.push_back({hit.position, n, ray.dir, hit.voxel_size});
          seeds.push_back(pixel_seed(x, y, 0));
        }
        // The rays are recorded next: check them against what the structures
        // and images leave of the budget.
        require_within_budget(
            held.total() + effects_bytes(points.size(), uint64_t(args->ao_rays)), budget,
            "the structures and the " + std::to_string(points.size()) + " shading points' " +
                std::to_string(args->ao_rays + 1) + " occlusion rays each");
        EffectOptions shadow_fx;
        shadow_fx.shadows = ShadowMode::Hard;
        EffectOptions ao_fx;
        ao_fx.ao_rays = args->ao_rays;
        ao_fx.ao_radius =
            args->ao_radius > 0 ? args->ao_radius : 0.05f * length(built.mesh.bounds().extent());
        RayRecorder shadow_rec, ao_rec;
        bool ao_uniform = true;
        for (size_t i = 0; i < points.size(); ++i) {
          shadow_visibility(shadow_rec, ctx, points[i], shadow_fx, ro.light_dir, seeds[i], nullptr);
          const size_t before = ao_rec.rays.size();
          ambient_occlusion(ao_rec, ctx, points[i], ao_fx, ao_fx.ao_radius, seeds[i], nullptr);
          ao_uniform &= ao_rec.rays.size() - before == size_t(args->ao_rays);
        }
        // AO rays sample-major (ray k of consecutive points next to each
        // other), so a packet holds the same sample of neighbouring pixels.
        std::vector<Vec3> ao_normals;  // one per point: the AO hemisphere's
        for (const ShadingPoint& p : points) ao_normals.push_back(p.normal);
        std::vector<Ray> ao_rays = ao_rec.rays;
        if (ao_uniform) {
          const size_t np = points.size(), k = size_t(args->ao_rays);
          for (size_t p = 0; p < np; ++p)
            for (size_t j = 0; j < k; ++j) ao_rays[j * np + p] = ao_rec.rays[p * k + j];
        }
        std::printf(
            "occlusion   %zu shading points (%s primary hits, offset 2 voxels along the normal "
            "+ "
            "1 back); %zu shadow rays (directional), %zu AO rays (%d per point, radius %g), "
            "generated once\n",
            points.size(), first.name.c_str(), shadow_rec.rays.size(), ao_rays.size(),
            args->ao_rays, double(ao_fx.ao_radius));
        struct OccRow {
          std::string caster, how;
          bool embree;
          std::function<Timed()> frame;
          Timed t;
          std::vector<uint8_t> answers;
        };
        nlohmann::json occ_json;
        for (int kind = 0; kind < 2; ++kind) {
          const std::vector<Ray>& rs = kind == 0 ? shadow_rec.rays : ao_rays;
          const char* kind_name = kind == 0 ? "shadow" : "ao";
          // Every row answers into its own array (frames capture the row's
          // index: the vector may move while rows are added).
          std::vector<OccRow> rows;
          // Each structure's scalar any-hit rows, then its packet rows.
          std::vector<size_t> scalar_row(structures.size()), packet_row(structures.size(), 0);
          for (size_t k = 0; k < structures.size(); ++k) {
            scalar_row[k] = rows.size();
            rows.push_back({structures[k].caster,
                            "any hit (transmittance)",
                            false,
                            [&, k, i = rows.size()] {
                              return occluded_all(*structures[k].query, rs, &rows[i].answers);
                            },
                            {},
                            {}});
          }
          // The brickmap world's any-hit path (issue 11) against trace(),
          // same rays, interleaved with the rows above.
          std::vector<std::pair<size_t, size_t>> trace_rows;  // (row, structure)
          for (size_t k = 0; k < structures.size(); ++k) {
            if (structures[k].format->name != "brickmap") continue;
            trace_rows.push_back({rows.size(), k});
            rows.push_back({structures[k].caster + " trace",
                            "first hit (trace), the any-hit path's baseline",
                            false,
                            [&, k, i = rows.size()] {
                              return occluded_all_trace(*structures[k].query, rs, &rows[i].answers);
                            },
                            {},
                            {}});
          }
          const std::string occ_how = std::string("occluded_packets ") + isa_name(active_isa()) +
                                      " x" + std::to_string(packet_width(active_isa())) +
                                      (kind == 0 ? ", octrees: parallel walks" : "");
          for (size_t k = 0; k < structures.size(); ++k) {
            if (!structures[k].packets) continue;
            packet_row[k] = rows.size();
            rows.push_back({structures[k].caster + " packet",
                            occ_how,
                            false,
                            [&, k, i = rows.size()] {
                              return occluded_all_packets(*structures[k].packets, rs,
                                                          &rows[i].answers);
                            },
                            {},
                            {}});
          }
          // The any-hit packets (issue 10 item 5), same arrays, started deep
          // (the packet rows above are the same kernel from the root); then
          // for AO the same rays point-major, 16 (8) rays of one point per
          // packet, from the root, with the deep start, and deep start + a
          // ball / hemisphere cull of up to 24 node fetches per point
          // (AnyHitOptions::cull_budget). anyhit_rows: (row, structure).
          const std::string any_how = std::string("occluded_anyhit ") + isa_name(active_isa()) +
                                      " x" + std::to_string(packet_width(active_isa()));
          std::vector<std::pair<size_t, size_t>> anyhit_rows;
          std::vector<AnyHitStats> deep_stats(structures.size());
          const bool ao_groups = kind == 1 && ao_uniform;
          for (size_t k = 0; k < structures.size(); ++k) {
            const AnyHitCaster anyhit = anyhit_caster(*structures[k].structure);
            if (!anyhit) continue;
            anyhit_rows.push_back({rows.size(), k});
            rows.push_back({structures[k].caster + " anyhit",
                            any_how + ", deep start, lanes only",
                            false,
                            [&, anyhit, i = rows.size()] {
                              return occluded_all_anyhit(anyhit, rs, kBenchDeepStart,
                                                         &rows[i].answers);
                            },
                            {},
                            {}});
            if (kind == 0) {  // the packet rows' rays without the parallel walks
              anyhit_rows.push_back({rows.size(), k});
              rows.push_back({structures[k].caster + " lanes",
                              any_how + ", root start, lanes only",
                              false,
                              [&, anyhit, i = rows.size()] {
                                return occluded_all_anyhit(anyhit, rs, DeepStart::Off,
                                                           &rows[i].answers);
                              },
                              {},
                              {}});
            }
            if (!ao_groups) continue;
            for (const int variant : {0, 1, 2}) {
              static const char* const names[] = {" ao point", " ao deep", " ao deep+cull"};
              static const char* const hows[] = {", point-major, root start",
                                                 ", point-major, deep start",
                                                 ", point-major, deep start, cull budget 24"};
              anyhit_rows.push_back({rows.size(), k});
              rows.push_back({structures[k].caster + names[variant],
                              any_how + hows[variant],
                              false,
                              [&, anyhit, variant, k, i = rows.size()] {
                                AnyHitStats* stats = variant == 2 ? &deep_stats[k] : nullptr;
                                return occluded_ao_groups(
                                    anyhit, ao_rec.rays, ao_normals, size_t(args->ao_rays),
                                    variant > 0, variant == 2 ? 24 : 0, &rows[i].answers, stats);
                              },
                              {},
                              {}});
            }
          }
          const size_t embree_x1 = rows.size();  // the first of kOcclusionModes
          for (const EmbreeScene::Mode m : EmbreeScene::kOcclusionModes) {
            static const char* const calls[] = {"rtcOccluded1", "", "rtcOccluded8 coherent",
                                                "rtcOccluded16 coherent", "rtcOccluded1M coherent"};
            rows.push_back({std::string("embree ") + EmbreeScene::mode_name(m),
                            calls[int(m)],
                            true,
                            [&, m, i = rows.size()] {
                              Timed t;
                              t.rays = rs.size();
                              t.seconds = embree.occluded_all(rs, m, &rows[i].answers);
                              for (uint8_t v : rows[i].answers) t.hits += v;
                              return t;
                            },
                            {},
                            {}});
          }
          // AO has ~16x the rays of the shadows: fewer rounds.
          measure_interleaved(rows, kind == 0 ? args->repeat : std::min(args->repeat, 3),
                              "bench secondary rays");
          double fastest_occ = 0;
          std::string fastest_occ_name;
          for (const OccRow& r : rows)
            if (r.embree && r.t.mrays() > fastest_occ)
              fastest_occ = r.t.mrays(), fastest_occ_name = r.caster;
          std::printf("%s rays (ratio over %s; 'same' = answers equal to embree x1)\n", kind_name,
                      fastest_occ_name.c_str());
          std::printf("  %-14s %9s %9s %7s %9s  %s\n", "caster", "Mrays/s", "occluded", "ratio",
                      "same", "how");
          const std::vector<uint8_t>& ref = rows[embree_x1].answers;
          nlohmann::json kj;
          for (const OccRow& r : rows) {
            size_t same = 0;
            for (size_t i = 0; i < ref.size(); ++i) same += r.answers[i] == ref[i];
            const double nr = double(std::max<size_t>(rs.size(), 1));
            std::printf("  %-14s %9.2f %8.2f%% %7.3f %8.3f%%  %s\n", r.caster.c_str(), r.t.mrays(),
                        100.0 * double(r.t.hits) / nr, r.t.mrays() / fastest_occ,
                        100.0 * double(same) / nr, r.how.c_str());
            kj.push_back({{"caster", r.caster},
                          {"how", r.how},
                          {"seconds", r.t.seconds},
                          {"rays", r.t.rays},
                          {"occluded", r.t.hits},
                          {"same_as_embree_x1", same},
                          {"mrays_per_s", r.t.mrays()},
                          {"ratio", r.t.mrays() / fastest_occ}});
          }
          // Rays on which every structure answers alike, and on which every
          // packet caster answers as its structure's scalar caster.
          size_t agree = 0, packet_same = 0;
          std::string names;
          for (const Measured& m : structures)
            names += (names.empty() ? "" : " == ") + m.format->name;
          for (size_t i = 0; i < rs.size(); ++i) {
            bool all = true, packets = true;
            for (size_t k = 0; k < structures.size(); ++k) {
              all &= rows[scalar_row[k]].answers[i] == rows[scalar_row[0]].answers[i];
              if (structures[k].packets)
                packets &= rows[packet_row[k]].answers[i] == rows[scalar_row[k]].answers[i];
            }
            agree += all;
            packet_same += packets;
          }
          // Rays on which each (row, structure) answers as the structure's
          // scalar caster: the any-hit packet rows, the brickmap trace rows.
          const auto same_as_scalar = [&](const std::vector<std::pair<size_t, size_t>>& pairs) {
            size_t n = 0;
            for (size_t i = 0; i < rs.size(); ++i) {
              bool same = true;
              for (const auto& [row, k] : pairs)
                same &= rows[row].answers[i] == rows[scalar_row[k]].answers[i];
              n += same;
            }
            return n;
          };
          const size_t anyhit_same = same_as_scalar(anyhit_rows);
          const size_t trace_same = same_as_scalar(trace_rows);
          const double nrs = double(std::max<size_t>(rs.size(), 1));
          std::printf(
              "  %s on %.3f%% of the rays, packet == scalar on %.3f%%, any-hit packets == scalar "
              "on %.3f%%\n",
              names.c_str(), 100.0 * double(agree) / nrs, 100.0 * double(packet_same) / nrs,
              100.0 * double(anyhit_same) / nrs);
          if (!trace_rows.empty())
            std::printf("  brickmap any hit == trace on %.3f%%\n",
                        100.0 * double(trace_same) / nrs);
          nlohmann::json deep_json;
          if (ao_groups) {
            for (size_t k = 0; k < structures.size(); ++k) {
              if (!anyhit_caster(*structures[k].structure)) continue;
              const AnyHitStats& d = deep_stats[k];
              const std::string& fname = structures[k].format->name;
              std::printf(
                  "  %s deep start + cull: %llu of %llu points answered by the cull alone; of "
                  "the %llu rays traced, %llu started deep, %.2f levels down on average\n",
                  fname.c_str(), (unsigned long long)d.culled, (unsigned long long)d.points,
                  (unsigned long long)d.rays, (unsigned long long)d.deep_rays,
                  d.rays ? double(d.depth_sum) / double(d.rays) : 0.0);
              deep_json[fname] = {{"points", d.points},
                                  {"culled", d.culled},
                                  {"rays", d.rays},
                                  {"deep_rays", d.deep_rays},
                                  {"depth_sum", d.depth_sum}};
            }
          }
          std::printf("\n");
          occ_json[kind_name] = {{"rays", rs.size()},
                                 {"fastest_embree", fastest_occ_name},
                                 {"structures_agree", agree},
                                 {"packet_equals_scalar", packet_same},
                                 {"anyhit_equals_scalar", anyhit_same},
                                 {"brickmap_anyhit_equals_trace", trace_same},
                                 {"deep_start", deep_json},
                                 {"casters", kj}};
        }
        occ_json["points"] = points.size();
        occ_json["ao_rays_per_point"] = args->ao_rays;
        occ_json["ao_radius"] = ao_fx.ao_radius;
        run["occlusion"] = occ_json;
      }
      // ---- --gi SPP: diffuse path tracing (README "Global illumination"):
      // the GI integrator on every measured structure against the Embree
      // path tracer of the mesh, same samples, bounces, sky, sun and random
      // streams (embree_path.hpp: equal work up to the geometry). Timed
      // fields here: rays = camera samples, hits = all rays traced.
      if (args->gi > 0) {
        GiOptions gi;
        gi.spp = args->gi;
        gi.bounces = args->bounces;
        gi.sun = true;
        gi.environment = std::make_shared<const Environment>(procedural_sky(256, 128, gi.sun_dir));
        struct GiRow {
          std::string caster;
          std::function<Timed()> frame;
          Timed t;
        };
        std::vector<GiRow> gi_rows;
        gi_rows.push_back({"embree (mesh)",
                           [&] {
                             const EmbreePathResult e =
                                 embree_path_trace(embree, built.mesh, camera, width, height, gi);
                             return Timed{e.stats.seconds, e.stats.samples, e.stats.rays};
                           },
                           {}});
        for (size_t i = 0; i < measured_here; ++i) {
          const Measured& m = structures[i];
          gi_rows.push_back({m.caster,
                             [&] {
                               const GiResult g =
                                   render_gi(*m.structure, camera, width, height, args->lod, gi);
                               return Timed{g.stats.seconds, g.stats.samples, g.stats.rays};
                             },
                             {}});
        }
        measure_interleaved(gi_rows, args->repeat, "bench gi");
        const double embree_rate = gi_rows[0].t.mrays();
        std::printf(
            "diffuse GI, %d spp, %d bounces at most, procedural sky and sun (ratio: "
            "samples/s over the Embree path tracer)\n",
            args->gi, args->bounces);
        std::printf("  %-22s %11s %9s %7s\n", "renderer", "Msamples/s", "Mrays/s", "ratio");
        nlohmann::json gj = nlohmann::json::array();
        for (const GiRow& r : gi_rows) {
          std::printf("  %-22s %11.3f %9.3f %7.3f\n", r.caster.c_str(), r.t.mrays(), r.t.mhits(),
                      r.t.mrays() / embree_rate);
          gj.push_back({{"renderer", r.caster},
                        {"seconds", r.t.seconds},
                        {"samples", r.t.rays},
                        {"rays", r.t.hits},
                        {"ratio", r.t.mrays() / embree_rate}});
        }
        std::printf("\n");
        run["gi"] = {{"spp", args->gi}, {"bounces", args->bounces}, {"renderers", gj}};
      }
      json_runs.push_back(run);
    }  // sizes
    if (!args->json.empty()) {
      const nlohmann::json j = {
          {"command", cmdline},
          {"machine",
           {{"cpu", cpu},
            {"logical_cpus", std::thread::hardware_concurrency()},
            {"loadavg", load},
            {"embree_isa", isa},
            {"threads", args->threads ? args->threads : int(std::thread::hardware_concurrency())}}},
          {"mesh", args->input},
          {"triangles", triangles},
          {"resolution", grid.resolution},
          {"repeat", args->repeat},
          {"runs", json_runs}};
      std::ofstream out(args->json);
      out << j.dump(2) << "\n";
      if (!out) throw Error("bench: cannot write --json file " + printable(args->json));
    }
    return 0;
  };
}

}  // namespace voxcast::cli
