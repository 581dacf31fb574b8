#pragma once
// Several volume objects with their own transforms in one scene (issue 12
// item 6; gigavoxels §3.8 places instances of volumes in a scene by their
// transforms; docs/ARCHITECTURE.md "GigaVoxels scenes").
//
// A VolumeScene is one Structure and one VolumeQuery made of several: each
// object is a structure with a volume query (GigaVoxels with its own pools,
// a RecursiveVolume, any other) in its own local space, placed in the world
// by an affine map. Its march() walks every object the ray crosses in its
// local space and merges their spans front to back into one ascending,
// non-overlapping sequence: where a single object answers, its span passes
// through; where several overlap, the interval is cut at every span end and
// each piece is one span of the summed medium (extinctions add, colors mix
// weighted by extinction, the emission-absorption model of
// volume_integrator.hpp), exact when all parts are constant.
//
// Transform convention: the object's medium is carried by its map, optical
// depth included. The local ray is (M^-1 o, M^-1 d) with the same t, so a
// local extinction s (per local unit) is s |M^-1 d| per world unit along the
// ray: a scaled cloud looks the same, only larger; a stretched one is
// stretched. Each object's transfer function classifies its own scalar
// samples before the scaling (its densities are per local unit).
//
// Level of detail: the cone's footprint f (a world length across the ray)
// becomes f / sigma in the object's local space, sigma the largest world
// length, seen across the ray, of a local unit: the largest singular value
// of P_d A (A the map's linear part, P_d the projection onto the plane
// across the unit direction d). A local voxel v then projects to at most
// v sigma across the ray, so the descent stops where the voxel's projected
// size falls below the pixel's (gigavoxels §3.5) for any affine map, not
// only for rotations and uniform scales: a cloud stretched 8x along z seen
// from the side is read 3 levels finer than along z. Spans report
// voxel_size = v sigma (the projected size, which the integrator's level
// blend compares with f) and stretch = 1 / (k sigma), k = |A^-1 d|: the
// length along the ray of a local voxel over its projected size, which
// scales the integrator's steps.
//
// Requests: each object serves its own. The scene tags the requests an
// object pushed with the object's index (RequestSink::tag_keys, in the key's
// bits 48..63) and hands each object its own, untagged and still sorted, in
// end_pass. The objects' accessor caches (the requests a GigaVoxels pushed
// lately) live side by side in the trace context (AccessorCache slots).
#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "voxcast/math.hpp"
#include "voxcast/structure.hpp"
#include "voxcast/volume_integrator.hpp"
#include "voxcast/volume_query.hpp"

namespace voxcast::giga {

/// An affine map p -> A p + b (3x4, row-major: m[r][3] is b's component r).
struct Affine {
  float m[3][4] = {{1, 0, 0, 0}, {0, 1, 0, 0}, {0, 0, 1, 0}};
  Vec3 point(Vec3 p) const;
  Vec3 vector(Vec3 d) const;  // the linear part only
  /// this ∘ o: o first.
  Affine operator*(const Affine& o) const;
  float determinant() const;  // of the linear part
  /// Throws voxcast::Error for a singular or non-finite map.
  Affine inverse() const;
  static Affine translate(Vec3 t);
  static Affine scale(Vec3 s);
  /// Rotation by `degrees` about `axis` (right-handed; axis normalized here).
  static Affine rotate(Vec3 axis, float degrees);
};

struct SceneObject {
  /// The object in its local space; must have a volume query.
  std::shared_ptr<Structure> structure;
  /// Local to world.
  Affine transform;
  /// Scalar data: classifies the object's samples (empty: its densities as
  /// they are).
  TransferFunction transfer;
  std::string name;  // messages and statistics
};

/// At most this many objects (a composite span names its parts in a mask).
constexpr int kMaxSceneObjects = 32;

class VolumeScene final : public Structure, public VolumeQuery {
 public:
  /// Throws voxcast::Error for no object, too many, an object without a
  /// volume query or with a singular transform.
  explicit VolumeScene(std::vector<SceneObject> objects);
  std::string name() const override { return "volume scene"; }
  Aabb bounds() const override;  // of the objects' transformed bounds
  const VolumeQuery* volume() const override { return this; }
  void begin_frame(const FrameView& view) override;
  PassOutcome end_pass(std::span<const Request> requests) override;
  void end_frame() override;

  /// Spans of every object, merged (header). A span's node names its
  /// origin: bits 48..63 = object index + 1 and bits 0..47 the object's own
  /// node, or bits 48..63 = 0xFFFF and bits 0..31 the mask of the objects
  /// that overlap there (a composite span; it keeps the ray's footprint in
  /// value: density = size_at_origin, color.r = size_per_t, color.g = the
  /// footprint at its middle, which the integrator never reads for a
  /// sampled span).
  int march(const Ray& ray, float t_begin, const LodFootprint& lod, TraceContext& ctx,
            std::span<VolumeSpan> out) const override;
  /// The summed, classified medium at p: the span's object at `level`, or for
  /// a composite span every part at the span's footprint; without a span
  /// every object at its finest level. Densities of a sample without a ray
  /// scale by |det M^-1|^(1/3) (exact for rotations and uniform scales).
  VolumeSample sample(Vec3 p, float level, TraceContext& ctx,
                      const VolumeSpan* span = nullptr) const override;
  /// One object's span: its own sample_span in its local space; a composite:
  /// each part's spans over the piece, sampled at the levels the integrator
  /// would give them (volume_integrator.hpp), classified and summed.
  void sample_span(const Ray& ray, const VolumeSpan& span, const float* t, const float* level,
                   int n, TraceContext& ctx, VolumeSample* out) const override;

  const std::vector<SceneObject>& objects() const { return objects_; }

 private:
  struct Placed;
  /// The object's medium at a local sample, classified and scaled by k.
  VolumeSample classified(int object, VolumeSample s, float k) const;
  std::vector<SceneObject> objects_;
  std::vector<Affine> inverse_;
  std::vector<Aabb> local_bounds_;
  std::vector<float> point_scale_;  // |det M^-1|^(1/3)
  /// Per object: G = A A^T and its adjugate (6 entries each: xx yy zz xy xz
  /// yz), for sigma(d)^2, the larger eigenvalue of G restricted to the plane
  /// across d (header), and the largest singular value of A (the footprint
  /// of a point sample, which has no direction: every direction's sigma is
  /// at most this).
  std::vector<std::array<float, 6>> gram_, gram_adjugate_;
  std::vector<float> max_stretch_;
  float across_stretch(int object, Vec3 d) const;
};

}  // namespace voxcast::giga
