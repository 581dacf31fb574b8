// The surface integrator over the frame loop (surface_integrator.hpp,
// render.hpp) against a straightforward reference: one pixel after the other
// on one thread, no tiles, batches, beams or frame loop, through the
// SurfaceQuery and the effect functions directly, shaded with the
// Blinn-Phong formula written out here. The images must agree byte for byte
// (the move of render() onto the integrator kept every output identical),
// and the counters must be those of the rays alone. Frames that do not count
// trace their primary rays as 4x4 pixel blocks through the packet caster
// (SurfaceOptions::caster): the same bytes again, for every kernel ISA this
// CPU runs, on ESVO (raw, compressed attributes, contours) and DAG.
#include <gtest/gtest.h>

#include <atomic>
#include <bit>
#include <cmath>
#include <cstring>
#include <memory>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include "render/shade_kernel.hpp"
#include "support/test_data.hpp"
#include "voxcast/dag.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/occlusion_packets.hpp"
#include "voxcast/packet_caster.hpp"
#include "voxcast/render.hpp"
#include "voxcast/surface_integrator.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast {
namespace {

struct Scenes {
  std::unique_ptr<esvo::EsvoStructure> esvo;
  std::unique_ptr<dag::DagStructure> dag;
  Aabb bounds;
};

const Scenes& scenes() {
  static const Scenes s = [] {
    Scenes out;
    const Mesh mesh = load_mesh(testing::test_mesh("spot.obj"));
    const GridTransform grid = GridTransform::fit(mesh.bounds(), 128);
    VoxelizeOptions vo;
    vo.attributes = true;
    const VoxelSet voxels = voxelize(mesh, grid, vo);
    out.esvo = std::make_unique<esvo::EsvoStructure>(
        std::make_shared<const esvo::EsvoOctree>(esvo::build_octree(voxels)));
    out.dag = std::make_unique<dag::DagStructure>(
        std::make_shared<const dag::SparseVoxelDag>(dag::build_dag(voxels)));
    out.bounds = mesh.bounds();
    return out;
  }();
  return s;
}

struct Reference {
  Image color, depth, normal, iterations, ao, shadow;
  uint64_t hits = 0;
  RayCounters counters;
};

// The reference loop. Effects through StructureOccluder with the options'
// explicit AO radius (the tests set one, so no default is involved).
Reference reference_render(const SurfaceQuery& q, const RenderOptions& o) {
  const int W = o.width, H = o.height;
  const CameraRays cam(o.camera, W, H);
  const LodFootprint lod{o.lod_pixels * cam.pixel_size(), o.lod_pixels * cam.pixel_angle()};
  const Vec3 to_light = normalize(-o.light_dir);
  const EffectOptions& fx = o.effects;
  const StructureOccluder occluder(q);
  Reference r;
  r.color = Image(W, H, 3), r.depth = Image(W, H, 1), r.normal = Image(W, H, 3);
  r.iterations = Image(W, H, 1), r.ao = Image(W, H, 1), r.shadow = Image(W, H, 1);
  TraceContext ctx;
  ctx.counting = true;
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const Ray ray = cam.ray(x, y);
      SurfaceHit hit;
      const uint64_t before = ctx.counters.iterations;
      const bool found = q.trace(ray, lod, ctx, &hit);
      *r.iterations.at(x, y) = float(ctx.counters.iterations - before);
      float* c = r.color.at(x, y);
      float* nn = r.normal.at(x, y);
      *r.ao.at(x, y) = *r.shadow.at(x, y) = 1.f;
      if (!found) {
        c[0] = o.background.r, c[1] = o.background.g, c[2] = o.background.b;
        *r.depth.at(x, y) = INFINITY;
        nn[0] = nn[1] = nn[2] = 0.5f;
        continue;
      }
      ++r.hits;
      Color col;
      Vec3 n;
      q.attributes(hit, ctx, &col, &n);
      if (dot(n, ray.dir) > 0.f) n = -n;
      Vec3 light = to_light;
      if (fx.light != LightKind::Directional) {
        float dist;
        light = direction_to_light(fx, o.light_dir, hit.position, &dist);
      }
      // Secondary rays are not part of the Table 6 counters.
      TraceContext secondary;
      const ShadingPoint sp{hit.position, n, ray.dir, hit.voxel_size};
      const uint32_t seed = pixel_seed(x, y, fx.seed);
      float visibility = 1.f, ao = 1.f;
      if (fx.shadows != ShadowMode::None)
        *r.shadow.at(x, y) = visibility =
            shadow_visibility(occluder, secondary, sp, fx, o.light_dir, seed, nullptr);
      if (fx.ao_rays > 0)
        *r.ao.at(x, y) = ao =
            ambient_occlusion(occluder, secondary, sp, fx, fx.ao_radius, seed, nullptr);
      const float diffuse = std::fmax(0.f, dot(n, light)) * visibility;
      const Vec3 half_vec = normalize(light - ray.dir);
      const float s1 = std::fmax(0.f, dot(n, half_vec));
      const float s2 = s1 * s1, s4 = s2 * s2, s8 = s4 * s4, s16 = s8 * s8;
      const float spec = s16 * s16 * visibility;
      const float k = 0.18f * ao + 0.82f * diffuse;
      c[0] = col.r * k + 0.12f * spec;
      c[1] = col.g * k + 0.12f * spec;
      c[2] = col.b * k + 0.12f * spec;
      *r.depth.at(x, y) = hit.t;
      nn[0] = n.x * 0.5f + 0.5f, nn[1] = n.y * 0.5f + 0.5f, nn[2] = n.z * 0.5f + 0.5f;
    }
  r.counters = ctx.counters;
  return r;
}

bool same_bytes(const Image& a, const Image& b) {
  return a.width == b.width && a.height == b.height && a.channels == b.channels &&
         std::memcmp(a.pixels.data(), b.pixels.data(), a.pixels.size() * sizeof(float)) == 0;
}

std::vector<Isa> isas() {
  std::vector<Isa> v{Isa::Avx2};
  if (cpu_supports(Isa::Avx512)) v.push_back(Isa::Avx512);
  return v;
}

struct Variant {
  const char* name;
  float lod;
  int beam;
  bool effects;
  bool point_light;
};

class SurfaceIntegratorVsReference : public ::testing::TestWithParam<Variant> {};

TEST_P(SurfaceIntegratorVsReference, ImagesAndCountersAgreeByteForByte) {
  const Variant v = GetParam();
  const Scenes& s = scenes();
  RenderOptions o;
  o.width = 72, o.height = 54;
  o.tile_size = 16;  // partial tiles at the right and bottom borders
  o.camera = Camera::frame(s.bounds, o.width, o.height);
  o.lod_pixels = v.lod;
  o.beam = v.beam;
  o.want_depth = o.want_normal = true;
  o.collect_stats = true;
  if (v.effects) {
    o.effects.shadows = ShadowMode::Hard;
    o.effects.ao_rays = 6;
    o.effects.ao_radius = 0.1f * length(s.bounds.extent());
    o.effects.seed = 5;
  }
  if (v.point_light) {
    o.effects.light = LightKind::Point;
    o.effects.light_position = s.bounds.hi + s.bounds.extent() * 0.5f;
  }
  for (Structure* st :
       {static_cast<Structure*>(s.esvo.get()), static_cast<Structure*>(s.dag.get())}) {
    SCOPED_TRACE(st->name() + " " + v.name);
    const Reference ref = reference_render(*st->surface(), o);
    ASSERT_GT(ref.hits, uint64_t(o.width * o.height / 10)) << "the view shows too little";
    const RenderResult got = render(std::as_const(*st), o);  // one pass, serves nothing
    EXPECT_EQ(got.hits, ref.hits);
    EXPECT_TRUE(same_bytes(got.color, ref.color));
    EXPECT_TRUE(same_bytes(got.depth, ref.depth));
    EXPECT_TRUE(same_bytes(got.normal, ref.normal));
    // Iterations per pixel: the reference's rays start at the root, so they
    // equal only without the beam.
    if (v.beam == 0) {
      EXPECT_TRUE(same_bytes(got.iterations, ref.iterations));
    }
    if (v.effects) {
      EXPECT_TRUE(same_bytes(got.ao, ref.ao));
      EXPECT_TRUE(same_bytes(got.shadow, ref.shadow));
      EXPECT_GT(got.effect_counters.ao_rays, 0u);
    } else {
      EXPECT_TRUE(got.ao.pixels.empty());
      EXPECT_TRUE(got.shadow.pixels.empty());
    }
    // The counters are the primary rays' (with the beam they start at the
    // block's region: no more iterations than from the root); the coarse
    // pass is counted apart (added in, it would exceed the reference).
    if (v.beam == 0) {
      EXPECT_EQ(got.counters.iterations, ref.counters.iterations);
      EXPECT_EQ(got.counters.pushes, ref.counters.pushes);
      EXPECT_EQ(got.counters.descriptor_fetches, ref.counters.descriptor_fetches);
      EXPECT_EQ(got.coarse_counters.iterations, 0u);
      EXPECT_EQ(got.beams, 0u);
    } else {
      EXPECT_LE(got.counters.iterations, ref.counters.iterations);
      EXPECT_GT(got.coarse_counters.iterations, 0u);
      EXPECT_EQ(got.beams, uint64_t((o.width + v.beam - 1) / v.beam) *
                               uint64_t((o.height + v.beam - 1) / v.beam));
    }
    EXPECT_EQ(got.counters.attribute_bytes, ref.counters.attribute_bytes);
    double sum = 0;
    for (float it : got.iterations.pixels) sum += it;
    EXPECT_EQ(uint64_t(sum), got.counters.iterations);

    // Without counting, the primary rays go through the packet caster in
    // 4x4 blocks: the reference's bytes again, with every kernel ISA.
    for (const Isa isa : isas()) {
      SCOPED_TRACE(isa_name(isa));
      RenderOptions p = o;
      p.collect_stats = false;
      p.isa = isa;
      const RenderResult packets = render(std::as_const(*st), p);
      EXPECT_EQ(packets.hits, ref.hits);
      EXPECT_TRUE(same_bytes(packets.color, ref.color));
      EXPECT_TRUE(same_bytes(packets.depth, ref.depth));
      EXPECT_TRUE(same_bytes(packets.normal, ref.normal));
      if (v.effects) {
        EXPECT_TRUE(same_bytes(packets.ao, ref.ao));
        EXPECT_TRUE(same_bytes(packets.shadow, ref.shadow));
      }
    }

    // The mutable overload runs the full frame loop: the same image (a
    // static structure never asks for anything, so it is one pass).
    const RenderResult loop = render(*st, o);
    EXPECT_EQ(loop.passes, 1);
    EXPECT_TRUE(same_bytes(loop.color, got.color));
  }
}

INSTANTIATE_TEST_SUITE_P(Variants, SurfaceIntegratorVsReference,
                         ::testing::Values(Variant{"finest", 0.f, 0, false, false},
                                           Variant{"lod1_beam4", 1.f, 4, false, false},
                                           Variant{"effects", 0.f, 0, true, false},
                                           Variant{"effects_beam8", 1.f, 8, true, false},
                                           Variant{"point_light", 0.f, 0, true, true}),
                         [](const auto& info) { return std::string(info.param.name); });

// A structure's queries, forwarded, with the primary rays counted by the
// path they took: shows which caster the integrator used.
class CountingQuery final : public Structure, public SurfaceQuery, public SurfacePackets {
 public:
  explicit CountingQuery(const Structure& s) : s_(s), q_(*s.surface()) {}
  std::string name() const override { return "counting " + s_.name(); }
  Aabb bounds() const override { return s_.bounds(); }
  const SurfaceQuery* surface() const override { return this; }
  bool trace(const Ray& ray, const LodFootprint& lod, TraceContext& ctx, SurfaceHit* hit,
             const BeamStart* beam) const override {
    scalar_rays.fetch_add(1, std::memory_order_relaxed);
    return q_.trace(ray, lod, ctx, hit, beam);
  }
  float transmittance(const Ray& ray, const LodFootprint& lod, TraceContext& ctx,
                      const BeamStart* beam) const override {
    return q_.transmittance(ray, lod, ctx, beam);
  }
  void transmittance_batch(const Ray* rays, size_t n, const LodFootprint& lod, TraceContext& ctx,
                           float* out, int group, const Vec3* normals) const override {
    uint64_t was = largest_batch.load();
    while (n > was && !largest_batch.compare_exchange_weak(was, n)) {
    }
    q_.transmittance_batch(rays, n, lod, ctx, out, group, normals);
  }
  void attributes(const SurfaceHit& hit, TraceContext& ctx, Color* color,
                  Vec3* normal) const override {
    q_.attributes(hit, ctx, color, normal);
  }
  void beam_start(const BeamFrustum& beam, TraceContext& ctx, BeamStart* start) const override {
    q_.beam_start(beam, ctx, start);
  }
  const SurfacePackets* packets() const override { return q_.packets() ? this : nullptr; }
  void trace_packets(const Ray* rays, size_t n, const LodFootprint& lod, TraceContext& ctx,
                     SurfaceHit* hits, uint8_t* found, Isa isa,
                     const BeamStart* const* beams) const override {
    packet_rays.fetch_add(n, std::memory_order_relaxed);
    q_.packets()->trace_packets(rays, n, lod, ctx, hits, found, isa, beams);
  }
  void occluded_packets(const Ray* rays, size_t n, const LodFootprint& lod, TraceContext& ctx,
                        uint8_t* occluded, Isa isa) const override {
    q_.packets()->occluded_packets(rays, n, lod, ctx, occluded, isa);
  }
  bool trace_tile(const CameraRays& cam, int x0, int y0, int x1, int y1, const LodFootprint& lod,
                  TraceContext& ctx, SurfaceHit* hits, uint8_t* found, Isa isa) const override {
    const bool tiled = q_.packets()->trace_tile(cam, x0, y0, x1, y1, lod, ctx, hits, found, isa);
    if (tiled) tile_rays.fetch_add(uint64_t(x1 - x0) * uint64_t(y1 - y0));
    return tiled;
  }
  mutable std::atomic<uint64_t> scalar_rays{0}, packet_rays{0}, tile_rays{0};
  mutable std::atomic<uint64_t> largest_batch{0};  // of transmittance_batch

 private:
  const Structure& s_;
  const SurfaceQuery& q_;
};

// The structures of the packet comparison: spot at 128^3 with attributes.
struct PacketScenes {
  std::unique_ptr<esvo::EsvoStructure> raw, compressed, contours;
  std::unique_ptr<dag::DagStructure> dag;
  Aabb bounds;
};

const PacketScenes& packet_scenes() {
  static const PacketScenes s = [] {
    PacketScenes out;
    const Mesh mesh = load_mesh(testing::test_mesh("spot.obj"));
    const GridTransform grid = GridTransform::fit(mesh.bounds(), 128);
    VoxelizeOptions vo;
    vo.attributes = true;
    const VoxelSet voxels = voxelize(mesh, grid, vo);
    auto esvo_of = [](esvo::EsvoOctree o) {
      return std::make_unique<esvo::EsvoStructure>(
          std::make_shared<const esvo::EsvoOctree>(std::move(o)));
    };
    out.raw = esvo_of(esvo::build_octree(voxels));
    esvo::BuildOptions compressed;
    compressed.attributes = esvo::AttributeFormat::Compressed;
    out.compressed = esvo_of(esvo::build_octree(voxels, compressed));
    esvo::BuildOptions contours;
    contours.contours = true;
    out.contours = esvo_of(esvo::build_octree(voxels, mesh, contours));
    out.dag = std::make_unique<dag::DagStructure>(
        std::make_shared<const dag::SparseVoxelDag>(dag::build_dag(voxels)));
    out.bounds = mesh.bounds();
    return out;
  }();
  return s;
}

struct PacketVariant {
  const char* name;
  float lod;
  int beam;
};

class SurfaceIntegratorPackets : public ::testing::TestWithParam<PacketVariant> {};

// Packet primary rays against scalar ones through the same integrator: every
// AOV byte for byte, on two views (one orthographic), and the packet path
// really taken (every pixel's ray handed to trace_packets, none to trace()).
TEST_P(SurfaceIntegratorPackets, ImagesByteIdenticalToScalar) {
  const PacketVariant v = GetParam();
  const PacketScenes& s = packet_scenes();
  RenderOptions o;
  o.width = 70, o.height = 46;  // 4x4 blocks and 16x16 tiles cut at the borders
  o.tile_size = 16;
  o.lod_pixels = v.lod;
  o.beam = v.beam;
  o.want_depth = o.want_normal = true;
  o.filter = true;  // the filter radius of every hit, then the blur
  const std::pair<const char*, const Structure*> structures[] = {
      {"esvo raw", s.raw.get()},
      {"esvo compressed", s.compressed.get()},
      {"esvo contours", s.contours.get()},
      {"dag", s.dag.get()}};
  for (const Camera& cam :
       {Camera::orbit(s.bounds, o.width, o.height, 30.f, -20.f),
        Camera::orbit(s.bounds, o.width, o.height, 120.f, 10.f, 0.f, Projection::Orthographic)}) {
    o.camera = cam;
    for (const auto& [name, st] : structures) {
      SCOPED_TRACE(std::string(name) + " " + v.name);
      ASSERT_NE(st->surface()->packets(), nullptr);
      RenderOptions scalar = o;
      scalar.caster = Caster::Scalar;
      const CountingQuery sq(*st);
      const RenderResult ref = render(sq, scalar);
      EXPECT_EQ(sq.packet_rays.load(), 0u);
      EXPECT_EQ(sq.scalar_rays.load(), uint64_t(o.width * o.height));
      ASSERT_GT(ref.hits, uint64_t(o.width * o.height / 10)) << "the view shows too little";
      for (const Isa isa : isas()) {
        SCOPED_TRACE(isa_name(isa));
        RenderOptions p = o;
        p.isa = isa;
        const CountingQuery pq(*st);
        const RenderResult got = render(pq, p);
        EXPECT_EQ(pq.scalar_rays.load(), 0u);
        EXPECT_EQ(pq.packet_rays.load(), uint64_t(o.width * o.height));
        EXPECT_EQ(got.hits, ref.hits);
        EXPECT_TRUE(same_bytes(got.color, ref.color));
        EXPECT_TRUE(same_bytes(got.depth, ref.depth));
        EXPECT_TRUE(same_bytes(got.normal, ref.normal));
        // The tile caster (beam and frustum do not apply to it).
        p.caster = Caster::Tile;
        const CountingQuery tq(*st);
        const RenderResult tiled = render(tq, p);
        EXPECT_EQ(tq.scalar_rays.load() + tq.packet_rays.load(), 0u);
        EXPECT_EQ(tq.tile_rays.load(), uint64_t(o.width * o.height));
        EXPECT_EQ(tiled.hits, ref.hits);
        EXPECT_TRUE(same_bytes(tiled.color, ref.color));
        EXPECT_TRUE(same_bytes(tiled.depth, ref.depth));
        EXPECT_TRUE(same_bytes(tiled.normal, ref.normal));
      }
    }
  }
}

// Hard shadows (directional and point light) and AO through the tile and
// packet casters against one ray at a time (scalar caster, effects packets
// off): every AOV byte for byte; with a directional light the tile's shadow
// rays reach the structure as one batch of more than kParallelRun rays, the
// runs its parallel walks take (voxcast/occlusion_packets.hpp).
TEST(SurfaceIntegratorPackets, EffectsByteIdenticalToOneRayAtATime) {
  const PacketScenes& s = packet_scenes();
  RenderOptions o;
  o.width = 70, o.height = 46;
  o.tile_size = 16;
  o.lod_pixels = 1.f;
  o.want_depth = o.want_normal = true;
  o.camera = Camera::orbit(s.bounds, o.width, o.height, 30.f, -20.f);
  o.effects.shadows = ShadowMode::Hard;
  o.effects.ao_rays = 4;
  const std::pair<const char*, const Structure*> structures[] = {
      {"esvo raw", s.raw.get()}, {"esvo contours", s.contours.get()}, {"dag", s.dag.get()}};
  for (const LightKind light : {LightKind::Directional, LightKind::Point}) {
    o.effects.light = light;
    o.effects.light_position = s.bounds.center() + s.bounds.extent() * 1.2f;
    for (const auto& [name, st] : structures) {
      SCOPED_TRACE(std::string(name) + (light == LightKind::Point ? " point" : " directional"));
      RenderOptions one = o;
      one.caster = Caster::Scalar;
      one.effects.packets = false;
      const RenderResult ref = render(*st, one);
      size_t shadowed = 0;
      for (float v : ref.shadow.pixels) shadowed += v == 0.f;
      ASSERT_GT(shadowed, 20u) << "the view shows too little shadow";
      for (const Caster caster : {Caster::Packet, Caster::Tile}) {
        for (const Isa isa : isas()) {
          SCOPED_TRACE(std::string(caster_name(caster)) + " " + isa_name(isa));
          RenderOptions p = o;
          p.caster = caster;
          p.isa = isa;
          const CountingQuery q(*st);
          const RenderResult got = render(q, p);
          EXPECT_TRUE(same_bytes(got.color, ref.color));
          EXPECT_TRUE(same_bytes(got.depth, ref.depth));
          EXPECT_TRUE(same_bytes(got.shadow, ref.shadow));
          EXPECT_TRUE(same_bytes(got.ao, ref.ao));
          EXPECT_EQ(got.effect_counters.shadow_rays, ref.effect_counters.shadow_rays);
          if (light == LightKind::Directional) {
            EXPECT_GT(q.largest_batch.load(), uint64_t(kParallelRun));
          }
        }
      }
    }
  }
}

INSTANTIATE_TEST_SUITE_P(Variants, SurfaceIntegratorPackets,
                         ::testing::Values(PacketVariant{"lod0", 0.f, 0},
                                           PacketVariant{"lod1", 1.f, 0},
                                           PacketVariant{"lod0_beam8", 0.f, 8},
                                           PacketVariant{"lod1_beam8", 1.f, 8},
                                           PacketVariant{"lod1_beam6", 1.f, 6}),
                         [](const auto& info) { return std::string(info.param.name); });

// The batched Blinn-Phong kernels against the scalar formula as the
// integrator wrote it before (std::fmax, normalize()), bit for bit, on
// random unit vectors and on the edge cases of its selects: a normal facing
// away, a half vector of zero or underflowing length (light == dir), NaN
// and -0 dot products, zero visibility and AO.
TEST(ShadeKernel, EveryIsaEqualsTheScalarFormula) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> uni(-1.f, 1.f);
  auto unit = [&] {
    Vec3 v;
    do v = {uni(rng), uni(rng), uni(rng)};
    while (dot(v, v) < 1e-3f || dot(v, v) > 1.f);
    return normalize(v);
  };
  const float nan = std::nanf("");
  for (const Isa isa : isas()) {
    SCOPED_TRACE(isa_name(isa));
    const detail::ShadeKernel kernel = detail::shade_kernel(isa);
    for (int round = 0; round < 64; ++round) {
      detail::ShadeBatch b;
      Vec3 n[detail::kShadeLanes], d[detail::kShadeLanes], l[detail::kShadeLanes];
      for (int i = 0; i < detail::kShadeLanes; ++i) {
        n[i] = unit(), d[i] = unit(), l[i] = unit();
        switch ((round * detail::kShadeLanes + i) % 9) {
          case 0:
            l[i] = d[i];
            break;  // half vector of length 0
          case 1:
            l[i] = d[i] + Vec3{1e-30f, 0.f, 0.f};
            break;  // underflowing length
          case 2:
            n[i] = {nan, 0.f, 0.f};
            break;  // NaN dot products
          case 3:
            n[i] = {0.f, -0.f, 0.f}, l[i] = {1.f, 0.f, 0.f};
            break;  // -0 and +0
          case 4:
            n[i] = -l[i];
            break;  // facing away from the light
          default:
            break;
        }
        b.cr[i] = uni(rng) * 0.5f + 0.5f, b.cg[i] = uni(rng) * 0.5f + 0.5f,
        b.cb[i] = uni(rng) * 0.5f + 0.5f;
        b.nx[i] = n[i].x, b.ny[i] = n[i].y, b.nz[i] = n[i].z;
        b.dx[i] = d[i].x, b.dy[i] = d[i].y, b.dz[i] = d[i].z;
        b.lx[i] = l[i].x, b.ly[i] = l[i].y, b.lz[i] = l[i].z;
        b.visibility[i] = i % 5 == 0 ? 0.f : uni(rng) * 0.5f + 0.5f;
        b.ao[i] = i % 7 == 0 ? 0.f : uni(rng) * 0.5f + 0.5f;
      }
      b.count = detail::kShadeLanes;
      kernel(&b);
      for (int i = 0; i < detail::kShadeLanes; ++i) {
        const float diffuse = std::fmax(0.f, dot(n[i], l[i])) * b.visibility[i];
        float spec = std::fmax(0.f, dot(n[i], normalize(l[i] - d[i])));
        spec *= spec, spec *= spec, spec *= spec, spec *= spec, spec *= spec;
        spec *= b.visibility[i];
        const float k = 0.18f * b.ao[i] + 0.82f * diffuse;
        EXPECT_EQ(std::bit_cast<uint32_t>(b.r[i]),
                  std::bit_cast<uint32_t>(b.cr[i] * k + 0.12f * spec))
            << round << " " << i;
        EXPECT_EQ(std::bit_cast<uint32_t>(b.g[i]),
                  std::bit_cast<uint32_t>(b.cg[i] * k + 0.12f * spec));
        EXPECT_EQ(std::bit_cast<uint32_t>(b.b[i]),
                  std::bit_cast<uint32_t>(b.cb[i] * k + 0.12f * spec));
      }
    }
  }
}

// A structure without a surface query cannot be rendered by the surface
// integrator: a clear error, before any tile runs.
class VolumeOnly final : public Structure {
 public:
  std::string name() const override { return "volume-only"; }
  Aabb bounds() const override { return Aabb{{0, 0, 0}, {1, 1, 1}}; }
};

TEST(SurfaceIntegrator, StructureWithoutSurfaceQueryIsAnError) {
  const VolumeOnly v;
  RenderOptions o;
  o.width = 8, o.height = 8;
  try {
    render(v, o);
    FAIL() << "rendered a structure without a surface query";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("volume-only structure has no surface query"),
              std::string::npos)
        << e.what();
  }
}

}  // namespace
}  // namespace voxcast
