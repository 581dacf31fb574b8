#pragma once
// Embree 3 ray casts of the source mesh: the independent oracle for tests and
// the peer that `voxcast bench` measures against.
#include <cmath>
#include <cstdint>
#include <memory>

#include "voxcast/camera.hpp"
#include "voxcast/image.hpp"
#include "voxcast/math.hpp"
#include "voxcast/mesh.hpp"

namespace voxcast {

class EmbreeScene {
 public:
  /// Builds an Embree BVH (high quality) over the mesh; throws voxcast::Error.
  explicit EmbreeScene(const Mesh& mesh);
  ~EmbreeScene();
  EmbreeScene(const EmbreeScene&) = delete;
  EmbreeScene& operator=(const EmbreeScene&) = delete;

  /// rtcIntersect1: distance along the unit direction, +inf on a miss.
  float intersect(const Ray& ray) const;
  struct Hit {
    float t = INFINITY;  // distance along the unit direction, +inf on a miss
    Vec3 ng;             // Embree's geometric normal (RTCHit Ng): unnormalized, winding-oriented
    uint32_t triangle = UINT32_MAX;  // primitive index into the mesh's triangles
  };
  /// rtcIntersect1 with the hit triangle and its geometric normal.
  Hit intersect_hit(const Ray& ray) const;
  /// rtcOccluded1.
  bool occluded(const Ray& ray) const;

  enum class Mode { Single, Packet8 };
  struct DepthRender {
    Image depth;  // 1 channel, world distance, +inf on a miss
    uint64_t rays = 0, hits = 0;
    double seconds = 0;  // wall time of the ray loop (all threads)
  };
  /// Casts every primary ray of `camera` (same tiles and threads as the voxel renderer).
  DepthRender render_depth(const Camera& camera, int width, int height, Mode mode) const;

  double build_seconds() const { return build_seconds_; }
  /// Bytes Embree reports allocating for the scene (device memory monitor).
  uint64_t memory_bytes() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  double build_seconds_ = 0;
};

}  // namespace voxcast
