#pragma once
// Displacement mapping (Laine & Karras 2010, §7.4): triangles displaced by
// a height map along their interpolated vertex normals, voxelized without
// tessellating them.
//
// The displaced surface of triangle t at barycentric b (w = 1-u-v at vertex
// 0, as Mesh::surface_color) is
//     D(b) = P(b) + N(b) * scale * h(T(b)),
// P the interpolated position, N the linearly interpolated vertex normals
// (not renormalized, so that D is affine in b for a fixed height), T the
// interpolated texture coordinates and h the map's bilinear height in [0,1]
// (DisplacementMap::sample: texel centers at (i + 0.5) / width, wrap-around,
// like Texture::sample). A mesh without texture coordinates is displaced by
// h(0,0) everywhere.
//
// voxelize_displaced() treats each triangle as a displacement primitive (the
// triangle and its footprint in map space) and splits it into four as long
// as its displaced bound is not below a voxel a side: the bound of a piece
// is the box around its corners displaced by the least and the largest
// height of its footprint, which the min/max mip-map gives conservatively
// for footprints of a texel or more (the power-of-two squares of texels
// covering it) and exactly below (a bilinear patch has its extremes on the
// corners of its cells). Pieces whose bound misses the grid are culled. A
// piece below a voxel marks every voxel its bound touches (at most two per
// axis), so the result has no holes: every point of the displaced surface is
// inside a marked voxel, and every marked voxel is within one voxel (per
// axis) of a voxel the surface passes through.
#include <cstdint>
#include <vector>

#include "voxcast/image.hpp"
#include "voxcast/math.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast {

/// A height map in [0,1] with min/max mip-maps.
class DisplacementMap {
 public:
  DisplacementMap() = default;
  /// Heights from `image`'s first channel (a grayscale PNG as read_png reads
  /// it: [0,1] without color conversion). Throws voxcast::Error for an empty
  /// image or a value outside [0,1] (NaN included).
  explicit DisplacementMap(const Image& image);
  int width() const { return width_; }
  int height() const { return height_; }
  float texel(int x, int y) const { return levels_[0].lo[size_t(y) * size_t(width_) + size_t(x)]; }
  /// Bilinear, wrap-around (texel centers at (i + 0.5) / width).
  float sample(Vec2 uv) const;
  /// Conservative least and largest height over the map-space rectangle
  /// [u0,u1] x [v0,v1] (exact below a texel, from the mip-maps above).
  void range(double u0, double v0, double u1, double v1, float* lo, float* hi) const;

 private:
  struct Level {
    int w = 0, h = 0;
    std::vector<float> lo, hi;  // per cell: min/max of the texels it covers
  };
  void texel_range(int64_t x0, int64_t y0, int64_t x1, int64_t y1, float* lo, float* hi) const;
  int width_ = 0, height_ = 0;
  std::vector<Level> levels_;
};

struct DisplacementStats {
  uint64_t pieces = 0;   // displacement primitives visited (after splits)
  uint64_t culled = 0;   // of those, outside the grid
  uint64_t emitted = 0;  // voxel marks before merging
};

/// The box around every displaced triangle (what GridTransform::fit needs).
Aabb displaced_bounds(const Mesh& mesh, const DisplacementMap& map, float scale);

/// The voxels of the displaced mesh (see the top of this header), with the
/// mesh's colors and the displaced surface's normals, area-weighted like
/// voxelize(). Deterministic whatever the thread count. `options.mode` is
/// ignored (the marks are conservative).
VoxelSet voxelize_displaced(const Mesh& mesh, const DisplacementMap& map, float scale,
                            const GridTransform& grid, const VoxelizeOptions& options,
                            DisplacementStats* stats = nullptr);

}  // namespace voxcast
