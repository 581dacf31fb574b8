#pragma once
// The volume integrator (docs/ARCHITECTURE.md, "Integrators"): front-to-back
// emission-absorption compositing over a structure's VolumeQuery spans
// (gigavoxels §3.5), the sibling of the surface integrator of render.hpp.
//
// Optical model (Max 1995, as tests/support/volume_oracle.hpp): a medium of
// extinction sigma and color c crossed over a length dt changes the
// accumulated color C and transmittance T by
//     C += T (1 - exp(-sigma dt)) c,   T *= exp(-sigma dt),
// from C = 0, T = 1. Constant spans apply this once over their whole length
// (exact); brick spans are marched by steps of step_scale x the larger of
// the span's voxel size and the pixel cone at the span's entry, each step
// using the sample at its midpoint (the last step is cut at the span's end),
// the samples taken in chunks through VolumeQuery::sample_span. A ray stops early once its opacity
// 1 - T reaches `opacity_cutoff` (gigavoxels §3.5.1).
//
// The level handed to VolumeQuery::sample_span is the pixel cone's own level
// (gigavoxels §3.5.4): with footprint f(t) = lod.size_at_origin +
// lod.size_per_t t and a span of voxel size v at level L, the voxel size
// that matches the cone is reached at level L + log2(v / f(t)), clamped to
// [L - 1, L], so samples blend a brick with its parent's as the cone widens
// (quadrilinear filtering without steps at node boundaries); log2 f is
// interpolated linearly between the span's ends, where it is exact.
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "voxcast/integrator.hpp"
#include "voxcast/math.hpp"
#include "voxcast/volume_query.hpp"

namespace voxcast {

/// A piecewise-linear transfer function for scalar data: maps the value a
/// structure stores in VolumeSample::density (a scalar, typically in [0, 1])
/// to an extinction and a color. Points are sorted by value; below the first
/// and above the last point the end points hold.
class TransferFunction {
 public:
  struct Point {
    float value = 0.f;
    float density = 0.f;  // extinction per world unit
    Color color{1.f, 1.f, 1.f, 1.f};
  };
  TransferFunction() = default;
  /// Throws voxcast::Error unless the values are finite and strictly
  /// increasing and every density is finite and >= 0.
  explicit TransferFunction(std::vector<Point> points);
  bool empty() const { return points_.empty(); }
  const std::vector<Point>& points() const { return points_; }
  /// The classified medium for scalar `s` (its color's alpha is 1).
  VolumeSample operator()(float s) const;
  /// Parses "v:density:r,g,b;v:density:r,g,b;..." (the CLI's --transfer).
  static TransferFunction parse(const std::string& text);

 private:
  std::vector<Point> points_;
};

struct VolumeIntegratorOptions {
  /// Stop a ray once 1 - T >= this (gigavoxels §3.5.1); 1 disables it.
  float opacity_cutoff = 0.99f;
  /// Brick spans are marched in steps of step_scale x max(span's voxel size,
  /// pixel cone at the span's entry).
  float step_scale = 0.5f;
  /// The depth AOV holds the t at which the opacity first reaches this
  /// (+inf when it never does).
  float depth_opacity = 0.5f;
  /// Radiance behind the volume, composited as C + T x background.
  Color background{0.f, 0.f, 0.f, 1.f};
  /// Scalar data: when not empty, samples' density is a scalar classified by it.
  TransferFunction transfer;
  /// Blinn-Phong with gradient normals (central differences of the density
  /// at one voxel) on brick samples; constant spans are unlit (no gradient).
  bool shading = false;
  Vec3 light_dir{0.4f, 0.8f, 0.45f};  // towards the light (normalized on use)
  float ambient = 0.3f, diffuse = 0.7f, specular = 0.25f, shininess = 24.f;
  /// Shadows (gigavoxels §3.9): every lit sample (and constant span) asks
  /// the medium's transmittance towards light_dir along a light cone that
  /// starts as wide as the pixel cone there and widens by 2 light_radius per
  /// unit length (light_radius: tangent of the light's angular radius; 0 =
  /// hard shadows); its steps are shadow_step_scale x the cone's voxel. The
  /// light reaching a sample is ambient + (1 - ambient) x transmittance.
  /// shadow_footprint_scale scales the cone's starting width (and the
  /// offset it starts at, so a sample does not shadow itself): below 1 the
  /// cone reads finer levels than the pixel's (0: the finest level at the
  /// start, a ray).
  bool shadows = false;
  float light_radius = 0.f;
  float shadow_step_scale = 1.f;
  float shadow_footprint_scale = 1.f;
  /// Depth of field (gigavoxels §3.9): a lens of diameter dof_aperture
  /// (world units; 0 = pinhole) focused at distance dof_focus widens each
  /// ray's cone by dof_aperture |t - dof_focus| / dof_focus, so the LOD reads
  /// coarser (blurred) levels away from the focus plane.
  float dof_aperture = 0.f, dof_focus = 1.f;
};

/// Per-frame totals (summed over threads).
struct VolumeIntegratorStats {
  uint64_t rays = 0;
  uint64_t spans = 0;
  uint64_t samples = 0;             // brick steps composited (without gradients, shadows)
  uint64_t early_terminations = 0;  // rays stopped by opacity_cutoff
  uint64_t shadow_rays = 0;         // light cones traced (shadows)
  uint64_t shadow_samples = 0;      // brick steps of the light cones
};

/// One ray's result (what a pixel receives).
struct VolumeRayResult {
  Color color{0.f, 0.f, 0.f, 1.f};  // C + T background (r, g, b); a = opacity 1 - T
  float transmittance = 1.f;
  float depth = INFINITY;  // t at which the opacity reached depth_opacity
};

class VolumeIntegrator final : public Integrator {
 public:
  explicit VolumeIntegrator(VolumeIntegratorOptions options = {});
  const VolumeIntegratorOptions& options() const { return options_; }

  uint32_t aovs() const override { return kAovColor | kAovAlpha | kAovDepth; }
  /// Throws voxcast::Error when the structure has no volume query.
  void begin_frame(const Structure& structure, const FrameView& view, Film& film) override;
  void render_tile(const Structure& structure, const FrameView& view, const TileRect& tile,
                   TraceContext& ctx, Film& film) override;

  /// Integrates one ray through `query` (the per-pixel work of render_tile).
  VolumeRayResult integrate(const VolumeQuery& query, const Ray& ray, const LodFootprint& lod,
                            TraceContext& ctx, VolumeIntegratorStats* stats = nullptr) const;

  /// Totals of the last frame (since begin_frame).
  VolumeIntegratorStats stats() const;

 private:
  VolumeSample classify(VolumeSample s) const;
  /// Transmittance from p towards the light along the light cone.
  float light_transmittance(const VolumeQuery& query, Vec3 p, float foot, TraceContext& ctx,
                            uint64_t* samples) const;
  VolumeIntegratorOptions options_;
  Vec3 light_;
  struct Totals;
  std::shared_ptr<Totals> totals_;
};

}  // namespace voxcast
