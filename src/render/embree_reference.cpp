// Embree 3 reference ray caster over the source triangles: the oracle for the
// voxel renderer's tests and the peer `voxcast bench` measures against.
#include "voxcast/embree_reference.hpp"

#include <embree3/rtcore.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <string>

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
  ~Impl() {
    if (scene) rtcReleaseScene(scene);
    if (device) rtcReleaseDevice(device);
  }
};

EmbreeScene::EmbreeScene(const Mesh& mesh) : impl_(std::make_unique<Impl>()) {
  if (mesh.triangle_count() == 0) throw Error("embree: mesh has no triangles");
  if (mesh.positions.size() > UINT32_MAX) throw Error("embree: too many vertices");
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

inline void init_ray(RTCRayHit& rh, const Ray& ray) {
  rh.ray.org_x = ray.origin.x, rh.ray.org_y = ray.origin.y, rh.ray.org_z = ray.origin.z;
  rh.ray.dir_x = ray.dir.x, rh.ray.dir_y = ray.dir.y, rh.ray.dir_z = ray.dir.z;
  rh.ray.tnear = 0.f;
  rh.ray.tfar = ray.tmax;
  rh.ray.time = 0.f;
  rh.ray.mask = 0xFFFFFFFFu;
  rh.ray.id = 0;
  rh.ray.flags = 0;
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
  return h;
}

bool EmbreeScene::occluded(const Ray& ray) const {
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  RTCRay r;
  r.org_x = ray.origin.x, r.org_y = ray.origin.y, r.org_z = ray.origin.z;
  r.dir_x = ray.dir.x, r.dir_y = ray.dir.y, r.dir_z = ray.dir.z;
  r.tnear = 0.f;
  r.tfar = ray.tmax;
  r.time = 0.f;
  r.mask = 0xFFFFFFFFu;
  r.id = 0;
  r.flags = 0;
  rtcOccluded1(impl_->scene, &ctx, &r);
  return r.tfar < 0.f;  // Embree sets tfar = -inf on occlusion
}

EmbreeScene::DepthRender EmbreeScene::render_depth(const Camera& camera, int width, int height,
                                                   Mode mode) const {
  if (width <= 0 || height <= 0 || width > 65536 || height > 65536)
    throw Error("embree: image size must be in 1..65536");
  const CameraRays cam(camera, width, height);
  DepthRender out;
  out.depth = Image(width, height, 1);
  std::atomic<uint64_t> total_hits{0};
  RTCScene scene = impl_->scene;
  // Same tiles and threads as render() (RenderOptions::tile_size default).
  const int tile_size = RenderOptions{}.tile_size;
  out.seconds = detail::for_each_tile(width, height, tile_size, [&](const detail::Tile& tile) {
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    uint64_t hits = 0;
    if (mode == Mode::Single) {
      for (int y = tile.y0; y < tile.y1; ++y)
        for (int x = tile.x0; x < tile.x1; ++x) {
          RTCRayHit rh;
          init_ray(rh, cam.ray(x, y));
          rtcIntersect1(scene, &ctx, &rh);
          const bool h = rh.hit.geomID != RTC_INVALID_GEOMETRY_ID;
          hits += h;
          *out.depth.at(x, y) = h ? rh.ray.tfar : INFINITY;
        }
    } else {
      // Packets of 8 consecutive pixels of a row (coherent primary rays).
      ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
      for (int y = tile.y0; y < tile.y1; ++y)
        for (int x0 = tile.x0; x0 < tile.x1; x0 += 8) {
          alignas(32) RTCRayHit8 rh;
          alignas(32) int valid[8];
          for (int i = 0; i < 8; ++i) {
            const int x = x0 + i;
            valid[i] = x < tile.x1 ? -1 : 0;
            const Vec3 d = cam.direction(valid[i] ? x : x0, y);
            const Vec3 o = cam.origin(valid[i] ? x : x0, y);  // the eye unless orthographic
            rh.ray.org_x[i] = o.x, rh.ray.org_y[i] = o.y, rh.ray.org_z[i] = o.z;
            rh.ray.dir_x[i] = d.x, rh.ray.dir_y[i] = d.y, rh.ray.dir_z[i] = d.z;
            rh.ray.tnear[i] = 0.f;
            rh.ray.tfar[i] = INFINITY;
            rh.ray.time[i] = 0.f;
            rh.ray.mask[i] = 0xFFFFFFFFu;
            rh.ray.id[i] = unsigned(i);
            rh.ray.flags[i] = 0;
            rh.hit.geomID[i] = RTC_INVALID_GEOMETRY_ID;
            rh.hit.instID[0][i] = RTC_INVALID_GEOMETRY_ID;
          }
          rtcIntersect8(valid, scene, &ctx, &rh);
          for (int i = 0; i < 8 && x0 + i < tile.x1; ++i) {
            const bool h = rh.hit.geomID[i] != RTC_INVALID_GEOMETRY_ID;
            hits += h;
            *out.depth.at(x0 + i, y) = h ? rh.ray.tfar[i] : INFINITY;
          }
        }
    }
    total_hits.fetch_add(hits, std::memory_order_relaxed);
  });
  check(impl_->device, "rtcIntersect");
  out.rays = uint64_t(width) * uint64_t(height);
  out.hits = total_hits.load();
  return out;
}

}  // namespace voxcast
