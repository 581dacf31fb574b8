#pragma once
// Triangle meshes as imported from disk (Assimp), in world coordinates.
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "voxcast/math.hpp"

namespace voxcast {

/// An 8-bit RGBA texture (sRGB-encoded as stored in the file), rows top to bottom.
struct Texture {
  int width = 0, height = 0;
  std::vector<uint8_t> rgba;  // width * height * 4
  /// Bilinear lookup with wrap-around addressing; returns linear-space color.
  Color sample(Vec2 uv) const;
};

/// A material as far as voxcast needs it: a base color factor and an
/// optional base-color texture (index into Mesh::textures, -1 = none).
struct Material {
  Color base_color{0.8f, 0.8f, 0.8f, 1.0f};  // linear
  int texture = -1;
};

/// Indexed triangle mesh. All per-vertex arrays are either empty or have
/// positions.size() entries. `triangle_material` is empty or has one entry
/// per triangle.
struct Mesh {
  std::vector<Vec3> positions;
  std::vector<Vec3> normals;      // unit length; always present after load_mesh
  std::vector<Color> colors;      // linear vertex colors, optional
  std::vector<Vec2> uvs;          // optional, only meaningful with a textured material;
                                  // origin at the texture's top-left, v down (glTF convention)
  std::vector<uint32_t> indices;  // 3 per triangle
  std::vector<uint32_t> triangle_material;
  std::vector<Material> materials;
  std::vector<Texture> textures;

  size_t triangle_count() const { return indices.size() / 3; }
  Aabb bounds() const;
  /// Color of the surface at barycentric (u, v) of triangle t (w = 1-u-v at
  /// vertex 0): texture * base color * vertex color, whichever exist.
  Color surface_color(size_t t, float u, float v) const;
  /// Interpolated shading normal at barycentric (u, v) of triangle t.
  Vec3 surface_normal(size_t t, float u, float v) const;
};

struct MeshLoadStats {
  size_t input_triangles = 0;     // after triangulation
  size_t degenerate_dropped = 0;  // zero-area or repeated-index triangles
  bool normals_computed = false;  // the file had no normals
  /// Problems that did not stop the import (e.g. a texture file that is
  /// missing or unreadable: the material falls back to its base color).
  std::vector<std::string> warnings;
};

/// Loads any format Assimp reads (OBJ+MTL, PLY, OFF, STL, glTF/GLB, FBX, DAE, ...),
/// triangulated and flattened into world space (node transforms applied).
/// Throws voxcast::Error with a one-line message for a missing/unreadable
/// file, a file without triangles, NaN/Inf coordinates or out-of-range indices.
/// Degenerate triangles are dropped and counted in `stats`.
/// `texture_budget` (bytes, 0 = none) bounds what decoding the textures may
/// allocate: each image's size is read from its header and a texture whose
/// decode would exceed what is left of the budget is refused with
/// voxcast::Error before it is decoded (an unreadable or missing texture
/// only drops the texture, with a warning in `stats`).
Mesh load_mesh(const std::filesystem::path& path, MeshLoadStats* stats = nullptr,
               uint64_t texture_budget = 0);

/// Checks the invariants listed on Mesh (sizes, index ranges, finite values);
/// throws voxcast::Error naming the first violation. load_mesh calls it; call it
/// yourself on meshes you build in code.
void validate_mesh(const Mesh& mesh);

}  // namespace voxcast
