// Embree 3 reference ray caster over the source triangles: the oracle for the
// voxel renderer's tests and the peer `voxcast bench` measures against.
#include "voxcast/embree_reference.hpp"

#include <embree3/rtcore.h>
#include <unistd.h>
#include <xmmintrin.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <sstream>
#include <string>
#include <type_traits>
#include <vector>

#include "render/bench_timing.hpp"
#include "render/tiling.hpp"
#include "voxcast/error.hpp"
#include "voxcast/render.hpp"

namespace voxcast {
namespace {

const char* embree_error_name(RTCError e) {
  switch (e) {
    case RTC_ERROR_NONE:
      return "none";
    case RTC_ERROR_UNKNOWN:
      return "unknown error";
    case RTC_ERROR_INVALID_ARGUMENT:
      return "invalid argument";
    case RTC_ERROR_INVALID_OPERATION:
      return "invalid operation";
    case RTC_ERROR_OUT_OF_MEMORY:
      return "out of memory";
    case RTC_ERROR_UNSUPPORTED_CPU:
      return "unsupported CPU";
    case RTC_ERROR_CANCELLED:
      return "cancelled";
  }
  return "unrecognized error";
}

void check(RTCDevice device, const char* what) {
  const RTCError e = rtcGetDeviceError(device);
  if (e != RTC_ERROR_NONE)
    throw Error(std::string("embree: ") + what + ": " + embree_error_name(e));
}

}  // namespace

struct EmbreeScene::Impl {
  RTCDevice device = nullptr;
  RTCScene scene = nullptr;
  std::atomic<int64_t> bytes{0};
  Mesh mesh;  // for shading: interpolated normals and surface colors
  ~Impl() {
    if (scene) rtcReleaseScene(scene);
    if (device) rtcReleaseDevice(device);
  }
};

EmbreeScene::EmbreeScene(const Mesh& mesh) : impl_(std::make_unique<Impl>()) {
  if (mesh.triangle_count() == 0) throw Error("embree: mesh has no triangles");
  if (mesh.positions.size() > UINT32_MAX) throw Error("embree: too many vertices");
  impl_->mesh = mesh;
  const auto t0 = std::chrono::steady_clock::now();
  impl_->device = rtcNewDevice(nullptr);
  if (!impl_->device) check(nullptr, "rtcNewDevice");
  rtcSetDeviceMemoryMonitorFunction(
      impl_->device,
      [](void* user, ssize_t bytes, bool) -> bool {
        static_cast<std::atomic<int64_t>*>(user)->fetch_add(int64_t(bytes),
                                                            std::memory_order_relaxed);
        return true;
      },
      &impl_->bytes);
  impl_->scene = rtcNewScene(impl_->device);
  check(impl_->device, "rtcNewScene");
  rtcSetSceneBuildQuality(impl_->scene, RTC_BUILD_QUALITY_HIGH);
  rtcSetSceneFlags(impl_->scene, RTC_SCENE_FLAG_NONE);  // robust mode off

  RTCGeometry geom = rtcNewGeometry(impl_->device, RTC_GEOMETRY_TYPE_TRIANGLE);
  check(impl_->device, "rtcNewGeometry");
  rtcSetGeometryBuildQuality(geom, RTC_BUILD_QUALITY_HIGH);
  // Embree-owned copies: its buffers are padded for its 16-byte vertex loads.
  auto* v = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0,
                                                        RTC_FORMAT_FLOAT3, 3 * sizeof(float),
                                                        mesh.positions.size()));
  auto* idx = static_cast<uint32_t*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0,
                                                             RTC_FORMAT_UINT3, 3 * sizeof(uint32_t),
                                                             mesh.triangle_count()));
  if (!v || !idx) {
    rtcReleaseGeometry(geom);
    check(impl_->device, "rtcSetNewGeometryBuffer");
    throw Error("embree: cannot allocate geometry buffers");
  }
  for (size_t i = 0; i < mesh.positions.size(); ++i) {
    v[3 * i + 0] = mesh.positions[i].x;
    v[3 * i + 1] = mesh.positions[i].y;
    v[3 * i + 2] = mesh.positions[i].z;
  }
  for (size_t i = 0; i < mesh.indices.size(); ++i) {
    if (mesh.indices[i] >= mesh.positions.size()) {
      rtcReleaseGeometry(geom);
      throw Error("embree: triangle index out of range");
    }
    idx[i] = mesh.indices[i];
  }
  rtcCommitGeometry(geom);
  rtcAttachGeometry(impl_->scene, geom);
  rtcReleaseGeometry(geom);
  rtcCommitScene(impl_->scene);
  check(impl_->device, "rtcCommitScene");
  build_seconds_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

EmbreeScene::~EmbreeScene() = default;

uint64_t EmbreeScene::memory_bytes() const {
  const int64_t b = impl_->bytes.load();
  return b > 0 ? uint64_t(b) : 0;
}

namespace {

inline void init_occlusion_ray(RTCRay& r, const Ray& ray) {
  r.org_x = ray.origin.x, r.org_y = ray.origin.y, r.org_z = ray.origin.z;
  r.dir_x = ray.dir.x, r.dir_y = ray.dir.y, r.dir_z = ray.dir.z;
  r.tnear = 0.f;
  r.tfar = ray.tmax;
  r.time = 0.f;
  r.mask = 0xFFFFFFFFu;
  r.id = 0;
  r.flags = 0;
}

inline void init_ray(RTCRayHit& rh, const Ray& ray) {
  init_occlusion_ray(rh.ray, ray);
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
}

}  // namespace

float EmbreeScene::intersect(const Ray& ray) const {
  return intersect_hit(ray).t;
}

EmbreeScene::Hit EmbreeScene::intersect_hit(const Ray& ray) const {
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  RTCRayHit rh;
  init_ray(rh, ray);
  rtcIntersect1(impl_->scene, &ctx, &rh);
  Hit h;
  if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return h;
  h.t = rh.ray.tfar;
  h.ng = {rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z};
  h.triangle = rh.hit.primID;
  h.u = rh.hit.u, h.v = rh.hit.v;
  return h;
}

bool EmbreeScene::occluded(const Ray& ray) const {
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  RTCRay r;
  init_occlusion_ray(r, ray);
  rtcOccluded1(impl_->scene, &ctx, &r);
  return r.tfar < 0.f;  // Embree sets tfar = -inf on occlusion
}

float EmbreeScene::transmittance(const Ray& ray, const LodFootprint& lod, TraceContext& ctx,
                                 const BeamStart* beam) const {
  (void)lod, (void)ctx, (void)beam;
  return occluded(ray) ? 0.f : 1.f;
}

namespace {
// Indexed by Mode (the enum's order).
struct ModeText {
  const char* name;
  const char* call;
};
constexpr ModeText kModeText[] = {{"x1", "rtcIntersect1"},
                                  {"x4", "rtcIntersect4 coherent, 2x2 pixels"},
                                  {"x8", "rtcIntersect8 coherent, 4x2 pixels"},
                                  {"x16", "rtcIntersect16 coherent, 4x4 pixels"},
                                  {"1M", "rtcIntersect1M coherent, one tile"}};
}  // namespace

const char* EmbreeScene::mode_name(Mode mode) {
  return kModeText[int(mode)].name;
}
const char* EmbreeScene::mode_call(Mode mode) {
  return kModeText[int(mode)].call;
}

namespace {

// Embree's packet types and calls by width (4, 8 or 16), so that one
// template serves every packet mode; the pixel block is bw x bh.
template <int N>
struct Packet {
  static_assert(N == 4 || N == 8 || N == 16);
  using RayHit =
      std::conditional_t<N == 4, RTCRayHit4, std::conditional_t<N == 8, RTCRayHit8, RTCRayHit16>>;
  using RayT = std::conditional_t<N == 4, RTCRay4, std::conditional_t<N == 8, RTCRay8, RTCRay16>>;
  static constexpr int bw = N == 4 ? 2 : 4, bh = N / bw;
  static void intersect(const int* v, RTCScene s, RTCIntersectContext* c, RayHit* r) {
    if constexpr (N == 4)
      rtcIntersect4(v, s, c, r);
    else if constexpr (N == 8)
      rtcIntersect8(v, s, c, r);
    else
      rtcIntersect16(v, s, c, r);
  }
  static void occluded(const int* v, RTCScene s, RTCIntersectContext* c, RayT* r) {
    if constexpr (N == 4)
      rtcOccluded4(v, s, c, r);
    else if constexpr (N == 8)
      rtcOccluded8(v, s, c, r);
    else
      rtcOccluded16(v, s, c, r);
  }
};

template <class R>
inline void set_lane(R& r, int i, const Ray& ray) {
  r.org_x[i] = ray.origin.x, r.org_y[i] = ray.origin.y, r.org_z[i] = ray.origin.z;
  r.dir_x[i] = ray.dir.x, r.dir_y[i] = ray.dir.y, r.dir_z[i] = ray.dir.z;
  r.tnear[i] = 0.f;
  r.tfar[i] = ray.tmax;
  r.time[i] = 0.f;
  r.mask[i] = 0xFFFFFFFFu;
  r.id[i] = unsigned(i);
  r.flags[i] = 0;
}

// Embree asks for flush-to-zero and denormals-are-zero on every thread that
// traces ("severe performance impact" otherwise, its verbose output says).
// Set for the Embree work only and restored, so the voxel casters that run on
// the same TBB threads are measured in their own (default) mode.
class EmbreeFpMode {
 public:
  EmbreeFpMode() : saved_(_mm_getcsr()) { _mm_setcsr(saved_ | 0x8040u); }  // FTZ | DAZ
  ~EmbreeFpMode() { _mm_setcsr(saved_); }
  EmbreeFpMode(const EmbreeFpMode&) = delete;
  EmbreeFpMode& operator=(const EmbreeFpMode&) = delete;

 private:
  unsigned saved_;
};

// Per-hit output shared by every primary mode: depth, and with shading the
// interpolated normal and surface color through surface_phong().
struct PrimaryOut {
  EmbreeScene::DepthRender* out;
  const Mesh* mesh;  // null: trace only
  Vec3 to_light;
  void hit(int x, int y, float t, uint32_t prim, float u, float v, Vec3 dir) const {
    *out->depth.at(x, y) = t;
    if (!mesh) return;
    const Color c = surface_phong(mesh->surface_color(prim, u, v), mesh->surface_normal(prim, u, v),
                                  dir, to_light);
    float* o = out->color.at(x, y);
    o[0] = c.r, o[1] = c.g, o[2] = c.b;
  }
  /// A single ray's result (hit or miss); returns whether it hit.
  bool result(int x, int y, const RTCRayHit& rh) const {
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) {
      miss(x, y);
      return false;
    }
    hit(x, y, rh.ray.tfar, rh.hit.primID, rh.hit.u, rh.hit.v,
        {rh.ray.dir_x, rh.ray.dir_y, rh.ray.dir_z});
    return true;
  }
  void miss(int x, int y) const {
    *out->depth.at(x, y) = INFINITY;
    if (!mesh) return;
    // The voxel renderer's default background (RenderOptions::background).
    const Color bg = RenderOptions{}.background;
    float* o = out->color.at(x, y);
    o[0] = bg.r, o[1] = bg.g, o[2] = bg.b;
  }
};

// One tile in N-wide packets of bw x bh pixel blocks; lanes outside the tile
// are masked off (valid = 0) and carry a copy of a valid lane's ray.
template <int N>
uint64_t trace_tile_packets(RTCScene scene, const CameraRays& cam, const detail::Tile& tile,
                            const PrimaryOut& po) {
  using P = Packet<N>;
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
  uint64_t hits = 0;
  for (int by = tile.y0; by < tile.y1; by += P::bh)
    for (int bx = tile.x0; bx < tile.x1; bx += P::bw) {
      alignas(64) typename P::RayHit rh;
      alignas(64) int valid[N];
      for (int i = 0; i < N; ++i) {
        const int x = bx + i % P::bw, y = by + i / P::bw;
        valid[i] = x < tile.x1 && y < tile.y1 ? -1 : 0;
        set_lane(rh.ray, i, cam.ray(valid[i] ? x : bx, valid[i] ? y : by));
        rh.hit.geomID[i] = RTC_INVALID_GEOMETRY_ID;
        rh.hit.instID[0][i] = RTC_INVALID_GEOMETRY_ID;
      }
      P::intersect(valid, scene, &ctx, &rh);
      for (int i = 0; i < N; ++i) {
        if (!valid[i]) continue;
        const int x = bx + i % P::bw, y = by + i / P::bw;
        if (rh.hit.geomID[i] != RTC_INVALID_GEOMETRY_ID) {
          ++hits;
          po.hit(x, y, rh.ray.tfar[i], rh.hit.primID[i], rh.hit.u[i], rh.hit.v[i],
                 {rh.ray.dir_x[i], rh.ray.dir_y[i], rh.ray.dir_z[i]});
        } else {
          po.miss(x, y);
        }
      }
    }
  return hits;
}

template <int N>
void occlude_packets(RTCScene scene, const Ray* rays, size_t n, uint8_t* occ) {
  using P = Packet<N>;
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
  for (size_t b = 0; b < n; b += N) {
    alignas(64) typename P::RayT r;
    alignas(64) int valid[N];
    for (int i = 0; i < N; ++i) {
      valid[i] = b + size_t(i) < n ? -1 : 0;
      set_lane(r, i, rays[valid[i] ? b + size_t(i) : b]);
    }
    P::occluded(valid, scene, &ctx, &r);
    for (int i = 0; i < N && b + size_t(i) < n; ++i) occ[b + size_t(i)] = r.tfar[i] < 0.f;
  }
}

}  // namespace

EmbreeScene::DepthRender EmbreeScene::render_depth(const Camera& camera, int width, int height,
                                                   Mode mode) const {
  return render_impl(camera, width, height, mode, false, {});
}

EmbreeScene::DepthRender EmbreeScene::render_shaded(const Camera& camera, int width, int height,
                                                    Mode mode, Vec3 light_dir) const {
  return render_impl(camera, width, height, mode, true, light_dir);
}

EmbreeScene::DepthRender EmbreeScene::render_impl(const Camera& camera, int width, int height,
                                                  Mode mode, bool shade, Vec3 light_dir) const {
  if (width <= 0 || height <= 0 || width > 65536 || height > 65536)
    throw Error("embree: image size must be in 1..65536");
  const CameraRays cam(camera, width, height);
  DepthRender out;
  out.depth = Image(width, height, 1);
  if (shade) out.color = Image(width, height, 3);
  Vec3 to_light = normalize(-light_dir);
  if (shade && (!is_finite(to_light) || length(to_light) == 0.f)) to_light = {0, 1, 0};
  const PrimaryOut po{&out, shade ? &impl_->mesh : nullptr, to_light};
  std::atomic<uint64_t> total_hits{0};
  RTCScene scene = impl_->scene;
  // Same tiles and threads as render() (RenderOptions::tile_size default).
  const int tile_size = RenderOptions{}.tile_size;
  out.seconds = detail::for_each_tile(width, height, tile_size, [&](const detail::Tile& tile) {
    const EmbreeFpMode fp;
    uint64_t hits = 0;
    switch (mode) {
      case Mode::Single: {
        RTCIntersectContext ctx;
        rtcInitIntersectContext(&ctx);
        for (int y = tile.y0; y < tile.y1; ++y)
          for (int x = tile.x0; x < tile.x1; ++x) {
            RTCRayHit rh;
            init_ray(rh, cam.ray(x, y));
            rtcIntersect1(scene, &ctx, &rh);
            hits += po.result(x, y, rh);
          }
        break;
      }
      case Mode::Packet4:
        hits = trace_tile_packets<4>(scene, cam, tile, po);
        break;
      case Mode::Packet8:
        hits = trace_tile_packets<8>(scene, cam, tile, po);
        break;
      case Mode::Packet16:
        hits = trace_tile_packets<16>(scene, cam, tile, po);
        break;
      case Mode::Stream: {
        // All rays of the tile in one rtcIntersect1M call (row-major).
        thread_local std::vector<RTCRayHit> rays;
        const int tw = tile.x1 - tile.x0, n = tw * (tile.y1 - tile.y0);
        rays.resize(size_t(n));
        for (int i = 0; i < n; ++i)
          init_ray(rays[size_t(i)], cam.ray(tile.x0 + i % tw, tile.y0 + i / tw));
        RTCIntersectContext ctx;
        rtcInitIntersectContext(&ctx);
        ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
        rtcIntersect1M(scene, &ctx, rays.data(), unsigned(n), sizeof(RTCRayHit));
        for (int i = 0; i < n; ++i) {
          hits += po.result(tile.x0 + i % tw, tile.y0 + i / tw, rays[size_t(i)]);
        }
        break;
      }
    }
    total_hits.fetch_add(hits, std::memory_order_relaxed);
  });
  check(impl_->device, "rtcIntersect");
  out.rays = uint64_t(width) * uint64_t(height);
  out.hits = total_hits.load();
  return out;
}

double EmbreeScene::occluded_all(const std::vector<Ray>& rays, Mode mode,
                                 std::vector<uint8_t>* occluded) const {
  if (mode == Mode::Packet4) throw Error("embree: occluded_all has no 4-wide mode");
  occluded->assign(rays.size(), 0);
  RTCScene scene = impl_->scene;
  uint8_t* occ = occluded->data();
  const double seconds =
      detail::for_each_chunk(rays.size(), kOcclusionChunk, [&](size_t b, size_t e) {
        const EmbreeFpMode fp;
        switch (mode) {
          case Mode::Single: {
            RTCIntersectContext ctx;
            rtcInitIntersectContext(&ctx);
            for (size_t i = b; i < e; ++i) {
              RTCRay r;
              init_occlusion_ray(r, rays[i]);
              rtcOccluded1(scene, &ctx, &r);
              occ[i] = r.tfar < 0.f;  // Embree sets tfar = -inf on occlusion
            }
            break;
          }
          case Mode::Packet8:
            occlude_packets<8>(scene, rays.data() + b, e - b, occ + b);
            break;
          case Mode::Packet16:
            occlude_packets<16>(scene, rays.data() + b, e - b, occ + b);
            break;
          case Mode::Stream: {
            thread_local std::vector<RTCRay> buf;
            buf.resize(e - b);
            for (size_t i = b; i < e; ++i) init_occlusion_ray(buf[i - b], rays[i]);
            RTCIntersectContext ctx;
            rtcInitIntersectContext(&ctx);
            ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
            rtcOccluded1M(scene, &ctx, buf.data(), unsigned(e - b), sizeof(RTCRay));
            for (size_t i = b; i < e; ++i) occ[i] = buf[i - b].tfar < 0.f;
            break;
          }
          case Mode::Packet4:
            break;
        }
      });
  check(impl_->device, "rtcOccluded");
  return seconds;
}

EmbreeScene::StageTicks EmbreeScene::profile_single(const Camera& camera, int width, int height,
                                                    Vec3 light_dir) const {
  const CameraRays cam(camera, width, height);
  Vec3 to_light = normalize(-light_dir);
  if (!is_finite(to_light) || length(to_light) == 0.f) to_light = {0, 1, 0};
  const uint64_t overhead = detail::tick_overhead();
  auto since = [overhead](uint64_t a, uint64_t b) {
    return b - a > overhead ? b - a - overhead : 0;
  };
  StageTicks st;
  const EmbreeFpMode fp;
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  Image color(width, height, 3);
  for (int y = 0; y < height; ++y)
    for (int x = 0; x < width; ++x) {
      const uint64_t t0 = detail::ticks();
      RTCRayHit rh;
      init_ray(rh, cam.ray(x, y));
      const uint64_t t1 = detail::ticks();
      rtcIntersect1(impl_->scene, &ctx, &rh);
      const uint64_t t2 = detail::ticks();
      st.ray_generation += since(t0, t1);
      st.traversal += since(t1, t2);
      if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) continue;
      const Color c = impl_->mesh.surface_color(rh.hit.primID, rh.hit.u, rh.hit.v);
      const Vec3 n = impl_->mesh.surface_normal(rh.hit.primID, rh.hit.u, rh.hit.v);
      const uint64_t t3 = detail::ticks();
      const Color s = surface_phong(c, n, {rh.ray.dir_x, rh.ray.dir_y, rh.ray.dir_z}, to_light);
      float* o = color.at(x, y);
      o[0] = s.r, o[1] = s.g, o[2] = s.b;
      const uint64_t t4 = detail::ticks();
      st.attributes += since(t2, t3);
      st.shading += since(t3, t4);
    }
  st.rays = uint64_t(width) * uint64_t(height);
  return st;
}

std::string EmbreeScene::probe_isa() {
  // Embree prints its configuration (CPU features, ISA, targets) to stdout
  // when a device is created with verbose=1; capture it in a temporary file.
  std::fflush(stdout);
  std::cout.flush();
  std::FILE* tmp = std::tmpfile();
  if (!tmp) return "unknown (no temporary file)";
  const int saved = dup(1);
  dup2(fileno(tmp), 1);
  RTCDevice d = rtcNewDevice("verbose=1");
  std::fflush(stdout);
  std::cout.flush();
  dup2(saved, 1);
  close(saved);
  if (d) rtcReleaseDevice(d);
  std::rewind(tmp);
  std::string text;
  char buf[4096];
  size_t got;
  while ((got = std::fread(buf, 1, sizeof buf, tmp)) > 0) text.append(buf, got);
  std::fclose(tmp);
  // Embree runs the best target that is both supported by the CPU and
  // compiled in: "Targets : ... (supported)" and "... (compile time enabled)".
  std::istringstream lines(text);
  std::string line, supported, compiled;
  while (std::getline(lines, line)) {
    size_t at = line.find("(supported)");
    if (at != std::string::npos) {
      const size_t colon = line.find(':');
      if (colon != std::string::npos && colon < at)
        supported = line.substr(colon + 1, at - colon - 1);
    }
    at = line.find("(compile time enabled)");
    if (at != std::string::npos) compiled = line.substr(0, at);
  }
  auto tokens = [](const std::string& t) {
    std::vector<std::string> v;
    std::istringstream in(t);
    for (std::string w; in >> w;) v.push_back(w);
    return v;
  };
  const std::vector<std::string> sup = tokens(supported), comp = tokens(compiled);
  std::string selected;
  for (const std::string& c : comp)
    if (std::find(sup.begin(), sup.end(), c) != sup.end()) selected = c;  // ascending order
  if (selected.empty()) return "unknown (Embree printed no target lines)";
  std::string out = selected + " (compiled in:";
  for (const std::string& c : comp) out += " " + c;
  return out + ")";
}

}  // namespace voxcast
