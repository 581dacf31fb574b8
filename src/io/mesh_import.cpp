// Mesh import through Assimp: every format it reads becomes one flat, indexed,
// validated voxcast::Mesh in world space.
//
// Conventions decided here (other modules rely on them):
//  * UVs: origin at the top-left of the texture, v pointing down (glTF/D3D
//    style), so that v maps directly onto Texture rows, which run top to
//    bottom. Assimp's default is OpenGL style (v up; it flips glTF's v on
//    import); aiProcess_FlipUVs turns every format into the top-left convention.
//  * Vertex colors: glTF defines COLOR_0 as linear and is taken as is. Every
//    other format (PLY, OBJ extensions, FBX, DAE, ...) in practice stores
//    display-referred 8-bit colors, so they are treated as sRGB and linearized.
//  * Material color factors (glTF baseColorFactor, OBJ Kd, ...) are linear.
//  * Textures stay sRGB bytes; Texture::sample linearizes.
//  * Non-finite or zero normals are recomputed (area-weighted from the faces);
//    non-finite UVs become (0,0) and non-finite colors white: those attributes
//    only shade, and a broken exporter should not make the geometry unusable.
//    Non-finite positions are an error: they would corrupt the voxel grid.
//  * Vertices no triangle uses are dropped, so bounds() and voxelization see
//    only surface geometry.
#include <assimp/material.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>
#include <assimp/texture.h>
#include <fcntl.h>
#include <fmt/format.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <assimp/DefaultLogger.hpp>
#include <assimp/Importer.hpp>
#include <assimp/LogStream.hpp>
#include <assimp/ProgressHandler.hpp>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <span>
#include <sstream>
#include <string>
#include <string_view>
#include <type_traits>

// stb_image from Debian's libstb-dev (/usr/include/stb), compiled into this
// file with internal linkage: libstb.so's exported stbi_* symbols would be
// interposed by the older stb copy that libdraco (pulled in by Assimp)
// exports too, and that copy never returned on some truncated files. Static
// functions cannot be interposed, so every call below is Debian's current
// stb (MeshImport.TruncatedTexturesAreRefusedQuickly).
#define STB_IMAGE_STATIC
#define STB_IMAGE_IMPLEMENTATION
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wunused-function"
#pragma GCC diagnostic ignored "-Wsign-compare"
#pragma GCC diagnostic ignored "-Wmissing-field-initializers"
#pragma GCC diagnostic ignored "-Wunused-but-set-variable"
#pragma GCC diagnostic ignored "-Wimplicit-fallthrough"
#include <stb_image.h>
#pragma GCC diagnostic pop

#include "voxcast/environment.hpp"
#include "voxcast/error.hpp"
#include "voxcast/image.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/mesh_height.hpp"
#include "voxcast/progress.hpp"
#include "voxcast/system.hpp"

namespace voxcast {

namespace {

namespace fs = std::filesystem;

// Error messages must stay on one line and short enough for a terminal.
std::string one_line(std::string_view s, size_t max_len = 200) {
  std::string out;
  bool space = false;
  for (char c : s) {
    if (c == '\n' || c == '\r' || c == '\t' || c == ' ') {
      space = !out.empty();
      continue;
    }
    if (space) out.push_back(' ');
    space = false;
    out.push_back(c);
  }
  if (out.size() > max_len) out = out.substr(0, max_len - 3) + "...";
  return out;
}

// Guards against decompression bombs: 2^28 texels is already 1 GiB of RGBA.
constexpr uint64_t kMaxTexels = uint64_t(1) << 28;

// ------------------------------------------------------------ image decode

// A texture that does not fit the memory budget, or whose file is not a
// regular file, stops the import (a resource error like any other budget
// refusal; a FIFO could block a later reader), unlike a missing or unreadable
// texture, which only costs the model its texture.
class FatalTextureError : public Error {
 public:
  using Error::Error;
};

// Peak bytes of decoding a w x h image to RGBA: stb_image's inflated stream
// (up to 4 bytes per texel plus a filter byte per row), its converted RGBA
// result and our copy of it in Texture::rgba; 3 x 4 bytes per texel bounds
// all three.
constexpr uint64_t kDecodeBytesPerTexel = 12;

// Refuses, before anything is allocated, a w x h texture whose decode peak
// does not fit what is left of the budget. `budget_left` 0: no budget.
void require_texture_budget(uint64_t w, uint64_t h, uint64_t bytes_per_texel, uint64_t budget_left,
                            uint64_t held, const std::string& what) {
  if (budget_left == 0) return;
  const uint64_t need = w * h * bytes_per_texel;
  if (need <= budget_left) return;
  throw FatalTextureError(fmt::format(
      "texture {}: {}x{} texels need {} MiB to decode, more than the {} MiB left of the memory "
      "budget{}; raise --memory-budget",
      what, w, h, (need + (1u << 20) - 1) >> 20, budget_left >> 20,
      held ? fmt::format(" ({} MiB held by earlier textures)", (held + (1u << 20) - 1) >> 20)
           : std::string()));
}

// Texture files (PNG, JPEG, TGA, BMP, PSD, GIF, HDR, PNM) are decoded by
// stb_image from Debian's libstb. The header is read first so that a
// decompression bomb, or an image too large for the budget, is refused
// before anything is allocated.
// A Radiance .hdr texture: stb_image's run-length decoder (Debian's 2.27
// too) loops forever on a truncated file (a run count read past the end is
// 0 and never advances), so .hdr goes through our own validated reader
// (environment.hpp's parse_hdr) and is mapped to 8 bits as stb_image maps
// HDR to LDR by default: 255 * x^(1 / 2.2) + 0.5, clamped; alpha 255.
Texture decode_hdr_texture(const uint8_t* data, size_t size, const std::string& what) {
  Image im;
  try {
    im = parse_hdr(std::span<const uint8_t>(data, size));
  } catch (const Error& e) {
    throw Error(fmt::format("texture {}: {}", what, one_line(e.what())));
  }
  Texture tex;
  tex.width = im.width;
  tex.height = im.height;
  tex.rgba.resize(size_t(im.width) * size_t(im.height) * 4);
  for (size_t i = 0; i < size_t(im.width) * size_t(im.height); ++i) {
    for (int c = 0; c < 3; ++c) {
      const float v =
          std::pow(std::max(0.f, im.pixels[3 * i + size_t(c)]), 1.f / 2.2f) * 255.f + 0.5f;
      tex.rgba[4 * i + size_t(c)] = uint8_t(std::clamp(v, 0.f, 255.f));
    }
    tex.rgba[4 * i + 3] = 255;
  }
  return tex;
}

Texture decode_image(const uint8_t* data, size_t size, const std::string& what,
                     uint64_t budget_left, uint64_t held) {
  if (size == 0 || size > size_t(INT32_MAX))
    throw Error(fmt::format("texture {}: empty or oversized image file", what));
  int w = 0, h = 0, comp = 0;
  if (!stbi_info_from_memory(data, int(size), &w, &h, &comp))
    throw Error(fmt::format("texture {}: unreadable image ({})", what,
                            one_line(stbi_failure_reason() ? stbi_failure_reason() : "unknown")));
  if (w <= 0 || h <= 0 || uint64_t(w) * uint64_t(h) > kMaxTexels)
    throw Error(fmt::format("texture {}: {}x{} texels is out of range", what, w, h));
  require_texture_budget(uint64_t(w), uint64_t(h), kDecodeBytesPerTexel, budget_left, held, what);
  if (stbi_is_hdr_from_memory(data, int(size))) return decode_hdr_texture(data, size, what);
  stbi_uc* pixels = stbi_load_from_memory(data, int(size), &w, &h, &comp, 4);
  if (!pixels)
    throw Error(fmt::format("texture {}: cannot decode ({})", what,
                            one_line(stbi_failure_reason() ? stbi_failure_reason() : "unknown")));
  Texture tex;
  tex.width = w;
  tex.height = h;
  tex.rgba.assign(pixels, pixels + size_t(w) * h * 4);
  stbi_image_free(pixels);
  return tex;
}

// ------------------------------------------------------------ scene walking

// Non-finite positions would corrupt the voxel grid. Checked on the file's
// data as imported (before JoinIdenticalVertices, which merges a NaN vertex
// with an arbitrary other one and so turns it into a "degenerate" triangle)
// and again after the node transforms are applied.
void require_finite_positions(const aiMesh& am, unsigned mesh_index, const std::string& name) {
  if (!am.mVertices) return;
  for (unsigned i = 0; i < am.mNumVertices; ++i) {
    const aiVector3D& p = am.mVertices[i];
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z))
      throw Error(fmt::format("{}: vertex {} of mesh {} has a non-finite coordinate ({}, {}, {})",
                              name, i, mesh_index, p.x, p.y, p.z));
  }
}

class SceneConverter {
 public:
  // `texture_budget`: bytes the decoded textures may take (0 = no limit).
  SceneConverter(const aiScene& scene, const fs::path& path, uint64_t texture_budget,
                 bool height_textures)
      : scene_(scene),
        path_(path),
        name_(path.string()),
        texture_budget_(texture_budget),
        height_textures_(height_textures) {
    std::string ext = path.extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(),
                   [](unsigned char c) { return char(std::tolower(c)); });
    colors_are_linear_ = ext == ".gltf" || ext == ".glb";
  }

  const Image& height_map() const { return height_map_; }

  Mesh convert(MeshLoadStats& stats) {
    Mesh out = convert_meshes(stats);
    stats.warnings = warnings_;
    return out;
  }

  Mesh convert_meshes(MeshLoadStats& stats) {
    Mesh out;
    bool any_colors = false, any_uvs = false;
    for (unsigned m = 0; m < scene_.mNumMeshes; ++m) {
      const aiMesh* am = scene_.mMeshes[m];
      if (!am || !(am->mPrimitiveTypes & aiPrimitiveType_TRIANGLE)) continue;
      any_colors |= am->HasVertexColors(0);
      any_uvs |= am->HasTextureCoords(0);
    }
    for (unsigned m = 0; m < scene_.mNumMeshes; ++m) {
      const aiMesh* am = scene_.mMeshes[m];
      // SortByPType leaves each aiMesh with a single primitive type; points
      // and lines have no surface to voxelize.
      if (!am || !(am->mPrimitiveTypes & aiPrimitiveType_TRIANGLE)) continue;
      append_mesh(*am, m, any_colors, any_uvs, out, stats);
    }
    if (out.indices.empty()) {
      if (stats.input_triangles > 0)
        throw Error(
            fmt::format("{}: {}", name_, all_degenerate(stats.input_triangles, repeated_vertex_)));
      throw Error(fmt::format("{}: contains no triangles", name_));
    }
    compact_vertices(out);
    return out;
  }

 private:
  void append_mesh(const aiMesh& am, unsigned mesh_index, bool any_colors, bool any_uvs, Mesh& out,
                   MeshLoadStats& stats) {
    const size_t base = out.positions.size();
    const unsigned nv = am.mNumVertices;
    if (!am.mVertices && nv > 0)
      throw Error(fmt::format("{}: mesh {} has no vertex positions", name_, mesh_index));
    if (base + nv > size_t(UINT32_MAX))
      throw Error(fmt::format("{}: more than 2^32 vertices", name_));

    require_finite_positions(am, mesh_index, name_);
    for (unsigned i = 0; i < nv; ++i) {
      const aiVector3D& p = am.mVertices[i];
      out.positions.push_back(Vec3{p.x, p.y, p.z});
    }

    // Triangles first: normals are computed from the surviving ones.
    const uint32_t material = material_for(am);
    std::vector<uint32_t> tris;
    tris.reserve(size_t(am.mNumFaces) * 3);
    for (unsigned f = 0; f < am.mNumFaces; ++f) {
      const aiFace& face = am.mFaces[f];
      if (face.mNumIndices != 3) continue;  // stray point/line inside a mixed mesh
      ++stats.input_triangles;
      uint32_t a = face.mIndices[0], b = face.mIndices[1], c = face.mIndices[2];
      if (a >= nv || b >= nv || c >= nv)
        throw Error(fmt::format("{}: face {} of mesh {} references vertex {} but the mesh has {}",
                                name_, f, mesh_index, std::max({a, b, c}), nv));
      if (a == b || b == c || a == c) {
        ++stats.degenerate_dropped;
        ++repeated_vertex_;
        continue;
      }
      if (area2(am.mVertices[a], am.mVertices[b], am.mVertices[c]) == 0) {
        ++stats.degenerate_dropped;
        continue;
      }
      tris.insert(tris.end(), {a, b, c});
    }

    // Normals: keep the file's where they are usable, compute the rest.
    std::vector<Vec3> normals(nv);
    std::vector<bool> need(nv, true);
    if (am.HasNormals()) {
      for (unsigned i = 0; i < nv; ++i) {
        Vec3 n{am.mNormals[i].x, am.mNormals[i].y, am.mNormals[i].z};
        float len = length(n);
        if (std::isfinite(len) && len > 1e-12f) {
          normals[i] = n / len;
          need[i] = false;
        }
      }
    }
    if (std::find(need.begin(), need.end(), true) != need.end()) {
      stats.normals_computed = true;
      compute_normals(am, tris, need, normals);
    }
    out.normals.insert(out.normals.end(), normals.begin(), normals.end());

    if (any_colors) {
      for (unsigned i = 0; i < nv; ++i) {
        Color c{1, 1, 1, 1};
        if (am.HasVertexColors(0)) {
          const aiColor4D& s = am.mColors[0][i];
          c = {convert_color(s.r), convert_color(s.g), convert_color(s.b), clamp_unit(s.a, 1.0f)};
        }
        out.colors.push_back(c);
      }
    }
    if (any_uvs) {
      for (unsigned i = 0; i < nv; ++i) {
        Vec2 uv{0, 0};
        if (am.HasTextureCoords(0)) {
          const aiVector3D& t = am.mTextureCoords[0][i];
          if (std::isfinite(t.x) && std::isfinite(t.y)) uv = {t.x, t.y};
        }
        out.uvs.push_back(uv);
      }
    }

    for (uint32_t& i : tris) i += uint32_t(base);
    out.indices.insert(out.indices.end(), tris.begin(), tris.end());
    out.triangle_material.insert(out.triangle_material.end(), tris.size() / 3, material);
  }

  static double area2(const aiVector3D& a, const aiVector3D& b, const aiVector3D& c) {
    double e1[3] = {double(b.x) - a.x, double(b.y) - a.y, double(b.z) - a.z};
    double e2[3] = {double(c.x) - a.x, double(c.y) - a.y, double(c.z) - a.z};
    double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                   e1[0] * e2[1] - e1[1] * e2[0]};
    return std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
  }

  // Smooth, area-weighted vertex normals: the unnormalized cross product of a
  // face is proportional to its area, so summing it weights large faces more
  // and keeps tiny slivers from tilting the normal.
  static void compute_normals(const aiMesh& am, const std::vector<uint32_t>& tris,
                              const std::vector<bool>& need, std::vector<Vec3>& normals) {
    const unsigned nv = am.mNumVertices;
    std::vector<double> acc(size_t(nv) * 3, 0.0);
    std::vector<Vec3> fallback(nv, Vec3{0, 0, 0});
    for (size_t t = 0; t < tris.size(); t += 3) {
      const aiVector3D &a = am.mVertices[tris[t]], &b = am.mVertices[tris[t + 1]],
                       &c = am.mVertices[tris[t + 2]];
      double e1[3] = {double(b.x) - a.x, double(b.y) - a.y, double(b.z) - a.z};
      double e2[3] = {double(c.x) - a.x, double(c.y) - a.y, double(c.z) - a.z};
      double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                     e1[0] * e2[1] - e1[1] * e2[0]};
      double len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
      for (int k = 0; k < 3; ++k) {
        uint32_t v = tris[t + k];
        for (int d = 0; d < 3; ++d) acc[3 * size_t(v) + d] += n[d];
        if (length(fallback[v]) == 0 && len > 0)
          fallback[v] = Vec3{float(n[0] / len), float(n[1] / len), float(n[2] / len)};
      }
    }
    for (unsigned i = 0; i < nv; ++i) {
      if (!need[i]) continue;
      const double* s = &acc[3 * size_t(i)];
      double len = std::sqrt(s[0] * s[0] + s[1] * s[1] + s[2] * s[2]);
      if (len > 0 && std::isfinite(len)) {
        normals[i] = Vec3{float(s[0] / len), float(s[1] / len), float(s[2] / len)};
      } else if (length(fallback[i]) > 0) {
        // Opposite faces cancelled out (e.g. a double-sided sheet): any one face is right.
        normals[i] = fallback[i];
      } else {
        // Used by no surviving triangle; compact_vertices drops it. Still unit length.
        normals[i] = Vec3{0, 0, 1};
      }
    }
  }

  static float clamp_unit(float v, float fallback) {
    if (!std::isfinite(v)) return fallback;
    return std::clamp(v, 0.0f, 1.0f);
  }

  float convert_color(float v) const {
    float c = clamp_unit(v, 1.0f);
    return colors_are_linear_ ? c : srgb_to_linear(c);
  }

  // Materials are created on first use, so unused materials (and their possibly
  // missing textures) never matter. Assimp's placeholder material gets
  // voxcast's default color, or white under vertex colors, which would
  // otherwise be darkened by a gray nobody chose.
  uint32_t material_for(const aiMesh& am) {
    const unsigned mi = am.mMaterialIndex;
    const bool has_colors = am.HasVertexColors(0);
    const aiMaterial* mat = mi < scene_.mNumMaterials ? scene_.mMaterials[mi] : nullptr;
    bool placeholder = mat == nullptr;
    if (mat) {
      aiString name;
      if (mat->Get(AI_MATKEY_NAME, name) == AI_SUCCESS &&
          std::string_view(name.C_Str()) == AI_DEFAULT_MATERIAL_NAME)
        placeholder = true;
    }
    const uint64_t key = (uint64_t(mi) << 1) | uint64_t(placeholder && has_colors);
    auto it = material_map_.find(key);
    if (it != material_map_.end()) return it->second;

    Material m;
    if (placeholder) {
      if (has_colors) m.base_color = {1, 1, 1, 1};
    } else {
      aiColor4D c;
      bool found = mat->Get(AI_MATKEY_BASE_COLOR, c) == AI_SUCCESS;
      if (!found) {
        found = mat->Get(AI_MATKEY_COLOR_DIFFUSE, c) == AI_SUCCESS;
        // Diffuse colors are RGB; opacity lives in a separate key.
        float opacity = 1.0f;
        if (found && mat->Get(AI_MATKEY_OPACITY, opacity) == AI_SUCCESS)
          c.a = opacity;
        else
          c.a = 1.0f;
      }
      if (found)
        m.base_color = {clamp_unit(c.r, 0.8f), clamp_unit(c.g, 0.8f), clamp_unit(c.b, 0.8f),
                        clamp_unit(c.a, 1.0f)};
      m.texture = texture_for(*mat, {aiTextureType_BASE_COLOR, aiTextureType_DIFFUSE});
      if (height_textures_ && height_ < 0)
        height_ = texture_for(*mat, {aiTextureType_DISPLACEMENT, aiTextureType_HEIGHT});
    }
    uint32_t index = uint32_t(materials_.size());
    materials_.push_back(m);
    material_map_.emplace(key, index);
    return index;
  }

  /// The first texture of `types` the material names (loaded once per path).
  int texture_for(const aiMaterial& mat, std::initializer_list<aiTextureType> types) {
    aiString tex_path;
    bool found = false;
    for (aiTextureType type : types) {
      if (mat.GetTextureCount(type) > 0 && mat.GetTexture(type, 0, &tex_path) == AI_SUCCESS &&
          tex_path.length > 0) {
        found = true;
        break;
      }
    }
    if (!found) return -1;
    const std::string key = tex_path.C_Str();
    auto it = texture_map_.find(key);
    if (it != texture_map_.end()) return it->second;
    // A texture that cannot be used costs the model its texture, not the
    // whole import: real-world files often point at images that were not
    // shipped with them. The caller gets a warning.
    Texture tex;
    try {
      tex = load_texture(key);
    } catch (const FatalTextureError&) {
      throw;
    } catch (const Error& e) {
      warnings_.push_back(std::string(e.what()) + "; using the base color instead");
      texture_map_.emplace(key, -1);
      return -1;
    }
    int index = int(textures_.size());
    texture_bytes_ += tex.rgba.size();
    textures_.push_back(std::move(tex));
    texture_map_.emplace(key, index);
    return index;
  }

  Texture load_texture(const std::string& ref) {
    const std::string what = fmt::format("'{}' of {}", one_line(ref, 120), name_);
    // Embedded: "*N" references and, for FBX, textures matched by file name.
    if (const aiTexture* emb = scene_.GetEmbeddedTexture(ref.c_str()))
      return convert_embedded(*emb, what);
    if (!ref.empty() && ref[0] == '*')
      throw Error(fmt::format("texture {} refers to a missing embedded texture", what));

    fs::path dir = path_.parent_path();
    std::string slashed = ref;
    std::replace(slashed.begin(), slashed.end(), '\\', '/');  // Windows exporters
    std::vector<fs::path> candidates = {fs::path(ref), dir / ref, dir / slashed,
                                        dir / fs::path(slashed).filename()};
    for (const fs::path& c : candidates) {
      std::error_code ec;
      if (c.empty()) continue;
      struct stat st;
      if (::stat(c.c_str(), &st) != 0) continue;
      if (!S_ISREG(st.st_mode))
        throw FatalTextureError(fmt::format("texture {}: '{}' is {}, not a regular file", what,
                                            one_line(c.string(), 120),
                                            file_type_name(uint32_t(st.st_mode))));
      // The file's bytes are held while they are decoded.
      const uint64_t file_bytes = fs::file_size(c, ec);
      if (!ec && texture_budget_ && file_bytes > budget_left())
        throw FatalTextureError(fmt::format(
            "texture {}: the file is {} MiB, more than the {} MiB left of the memory budget; "
            "raise --memory-budget",
            what, (file_bytes + (1u << 20) - 1) >> 20, budget_left() >> 20));
      std::ifstream in(c, std::ios::binary);
      std::vector<uint8_t> bytes((std::istreambuf_iterator<char>(in)),
                                 std::istreambuf_iterator<char>());
      if (!in.good() && !in.eof())
        throw Error(fmt::format("texture {}: cannot read {}", what, c.string()));
      return decode_image(bytes.data(), bytes.size(), what, decode_budget(bytes.size()),
                          texture_bytes_);
    }
    throw Error(fmt::format("texture {} not found next to the model", what));
  }

  Texture convert_embedded(const aiTexture& t, const std::string& what) const {
    if (!t.pcData) throw Error(fmt::format("texture {}: embedded texture has no data", what));
    if (t.mHeight == 0)  // compressed file bytes (already in memory), mWidth is their size
      return decode_image(reinterpret_cast<const uint8_t*>(t.pcData), t.mWidth, what,
                          decode_budget(0), texture_bytes_);
    if (uint64_t(t.mWidth) * t.mHeight > kMaxTexels)
      throw Error(fmt::format("texture {}: embedded texture too large", what));
    // Only our RGBA copy is allocated here.
    if (texture_budget_)
      require_texture_budget(t.mWidth, t.mHeight, 4, budget_left(), texture_bytes_, what);
    Texture tex;
    tex.width = int(t.mWidth);
    tex.height = int(t.mHeight);
    tex.rgba.resize(size_t(t.mWidth) * t.mHeight * 4);
    for (size_t i = 0, n = size_t(t.mWidth) * t.mHeight; i < n; ++i) {
      const aiTexel& s = t.pcData[i];  // aiTexel is BGRA in memory
      tex.rgba[4 * i] = s.r;
      tex.rgba[4 * i + 1] = s.g;
      tex.rgba[4 * i + 2] = s.b;
      tex.rgba[4 * i + 3] = s.a;
    }
    return tex;
  }

  // Drops vertices that no kept triangle references (points/lines, removed
  // degenerates, unused file vertices), and moves materials and textures in.
  void compact_vertices(Mesh& m) {
    const size_t nv = m.positions.size();
    std::vector<uint32_t> remap(nv, UINT32_MAX);
    uint32_t next = 0;
    for (uint32_t& i : m.indices) {
      if (remap[i] == UINT32_MAX) remap[i] = next++;
      i = remap[i];
    }
    auto shrink = [&](auto& arr) {
      if (arr.empty()) return;
      std::remove_reference_t<decltype(arr)> out(next);
      for (size_t i = 0; i < nv; ++i)
        if (remap[i] != UINT32_MAX) out[remap[i]] = arr[i];
      arr.swap(out);
    };
    shrink(m.positions);
    shrink(m.normals);
    shrink(m.colors);
    shrink(m.uvs);
    m.materials = std::move(materials_);
    // The height map leaves the textures before they move into the mesh.
    if (height_ >= 0) {
      const Texture& t = textures_[size_t(height_)];
      height_map_ = Image(t.width, t.height, 1);
      for (size_t i = 0; i < height_map_.pixels.size(); ++i)
        height_map_.pixels[i] = float(t.rgba[4 * i]) / 255.f;
    }
    m.textures = std::move(textures_);
  }

  // Why every triangle went: "the only triangle has zero area", "all 5
  // triangles are degenerate (3 repeat a vertex, 2 have zero area)".
  static std::string all_degenerate(size_t total, size_t repeated) {
    const size_t flat = total - repeated;
    if (total == 1)
      return repeated ? "the only triangle is degenerate (it uses one vertex twice)"
                      : "the only triangle is degenerate (zero area: its corners are collinear)";
    if (repeated == total)
      return fmt::format("all {} triangles are degenerate (each uses one vertex twice)", total);
    if (repeated == 0)
      return fmt::format("all {} triangles are degenerate (zero area: their corners are collinear)",
                         total);
    return fmt::format("all {} triangles are degenerate ({} {} one vertex twice, {} {} zero area)",
                       total, repeated, repeated == 1 ? "uses" : "use", flat,
                       flat == 1 ? "has" : "have");
  }

  const aiScene& scene_;
  size_t repeated_vertex_ = 0;
  fs::path path_;
  std::string name_;
  bool colors_are_linear_ = false;
  std::map<uint64_t, uint32_t> material_map_;
  std::vector<Material> materials_;
  std::map<std::string, int> texture_map_;
  std::vector<std::string> warnings_;
  std::vector<Texture> textures_;
  uint64_t texture_budget_ = 0;   // 0: no limit
  bool height_textures_ = false;  // look for the materials' height maps too
  int height_ = -1;               // the first one found (index into textures_)
  Image height_map_{0, 0, 1};
  uint64_t texture_bytes_ = 0;  // held by textures_

  // What the budget leaves for the next texture (1 when it is used up, so
  // that 0 keeps meaning "no budget" to require_texture_budget).
  uint64_t budget_left() const {
    return texture_budget_ > texture_bytes_ ? texture_budget_ - texture_bytes_ : 1;
  }
  // The same while `file_bytes` of its encoded file are held too.
  uint64_t decode_budget(uint64_t file_bytes) const {
    if (texture_budget_ == 0) return 0;
    const uint64_t left = budget_left();
    return left > file_bytes ? left - file_bytes : 1;
  }
};

// Assimp's OFF reader clamps out-of-range face indices to the last vertex
// (only logging it) and trusts the header's counts, spinning for tens of
// seconds on absurd ones. OFF is simple enough to check up front: ASCII,
// one vertex per line, then one face per line as "n i1 ... in".
void precheck_off(const fs::path& path, const std::string& name) {
  std::ifstream in(path, std::ios::binary);
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  size_t pos = 0;
  auto next_line = [&](std::string& line) {
    while (pos < text.size()) {
      size_t end = text.find('\n', pos);
      if (end == std::string::npos) end = text.size();
      line.assign(text, pos, end - pos);
      pos = end + 1;
      if (size_t hash = line.find('#'); hash != std::string::npos) line.resize(hash);
      if (line.find_first_not_of(" \t\r") != std::string::npos) return true;
    }
    return false;
  };
  std::string line;
  if (!next_line(line)) return;  // empty: Assimp reports it
  std::istringstream head(line);
  std::string magic;
  head >> magic;
  // Only the 3-D variants with one vertex per line are checked (ST/C/N only add
  // per-vertex values); nOFF/4OFF and anything else are left to Assimp.
  static const char* const kVariants[] = {"OFF",   "COFF",   "NOFF",   "CNOFF",
                                          "STOFF", "STCOFF", "STNOFF", "STCNOFF"};
  if (std::find(std::begin(kVariants), std::end(kVariants), magic) == std::end(kVariants)) return;
  // The counts follow the magic on the same line or on the next one.
  std::string rest;
  std::getline(head, rest);
  if (rest.find("BINARY") != std::string::npos) return;
  if (rest.find_first_not_of(" \t\r") == std::string::npos) {
    if (!next_line(line)) return;
    rest = line;
  }
  std::istringstream counts(rest);
  unsigned long long nv = 0, nf = 0;
  if (!(counts >> nv >> nf)) throw Error(fmt::format("{}: malformed OFF header", name));
  // Every vertex line needs at least 6 bytes ("0 0 0\n"), every face 8 ("3 0 1 2\n").
  if (nv > text.size() / 6 || nf > text.size() / 8 || nv * 6 + nf * 8 > text.size())
    throw Error(fmt::format(
        "{}: OFF header claims {} vertices and {} faces, more than the {}-byte file can hold", name,
        nv, nf, text.size()));
  for (unsigned long long v = 0; v < nv; ++v)
    if (!next_line(line))
      throw Error(fmt::format("{}: truncated OFF file (vertex {} of {} missing)", name, v, nv));
  for (unsigned long long f = 0; f < nf; ++f) {
    if (!next_line(line))
      throw Error(fmt::format("{}: truncated OFF file (face {} of {} missing)", name, f, nf));
    std::istringstream face(line);
    unsigned long long n = 0;
    if (!(face >> n)) throw Error(fmt::format("{}: malformed OFF face {}", name, f));
    for (unsigned long long k = 0; k < n; ++k) {
      long long idx = -1;
      if (!(face >> idx))
        throw Error(fmt::format("{}: OFF face {} has fewer than {} indices", name, f, n));
      if (idx < 0 || static_cast<unsigned long long>(idx) >= nv)
        throw Error(fmt::format("{}: OFF face {} references vertex {} but the file has {}", name, f,
                                idx, nv));
    }
  }
}

// Assimp's PLY reader loops forever on some malformed headers (found by
// fuzz/fuzz_mesh: "element face 1" followed by a line that is no keyword and
// no end_header). The header grammar is small, so it is checked up front:
// known keywords only, known property types, element counts the file can hold,
// and an end_header within the first 64 KiB.
void precheck_ply(const fs::path& path, const std::string& name, bool ply_extension) {
  std::ifstream in(path, std::ios::binary);
  std::string head(65536, '\0');
  in.read(head.data(), std::streamsize(head.size()));
  head.resize(size_t(in.gcount()));
  // Assimp takes a file for PLY by its extension or by a leading "ply" token.
  const bool ply_magic = head.size() >= 3 &&
                         std::tolower(static_cast<unsigned char>(head[0])) == 'p' &&
                         std::tolower(static_cast<unsigned char>(head[1])) == 'l' &&
                         std::tolower(static_cast<unsigned char>(head[2])) == 'y';
  if (!ply_extension && !ply_magic) return;
  if (head.rfind("ply\n", 0) != 0 && head.rfind("ply\r\n", 0) != 0)
    throw Error(fmt::format("{}: malformed PLY header (the first line is not 'ply')", name));
  std::error_code ec;
  const uint64_t file_size = fs::file_size(path, ec);
  static const char* const kTypes[] = {"char",  "uchar",  "short",   "ushort", "int",   "uint",
                                       "float", "double", "int8",    "uint8",  "int16", "uint16",
                                       "int32", "uint32", "float32", "float64"};
  auto is_type = [&](const std::string& t) {
    return std::find(std::begin(kTypes), std::end(kTypes), t) != std::end(kTypes);
  };
  std::istringstream lines(head);
  std::string line;
  std::getline(lines, line);  // "ply"
  int line_no = 1;
  while (std::getline(lines, line)) {
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream words(line);
    std::string key;
    words >> key;
    if (key == "end_header") return;
    if (key == "comment" || key == "obj_info") continue;
    if (key == "format") {
      std::string fmt_name, version;
      if (!(words >> fmt_name >> version) ||
          (fmt_name != "ascii" && fmt_name != "binary_little_endian" &&
           fmt_name != "binary_big_endian"))
        throw Error(fmt::format("{}: malformed PLY header (line {}: bad format)", name, line_no));
    } else if (key == "element") {
      std::string elem;
      unsigned long long count = 0;
      if (!(words >> elem >> count))
        throw Error(fmt::format("{}: malformed PLY header (line {}: bad element)", name, line_no));
      if (count > file_size)
        throw Error(
            fmt::format("{}: PLY header claims {} {} elements, more than the {}-byte file can hold",
                        name, count, elem, file_size));
    } else if (key == "property") {
      std::string type, a, b, prop;
      words >> type;
      bool ok = false;
      if (type == "list")
        ok = bool(words >> a >> b >> prop) && is_type(a) && is_type(b);
      else
        ok = is_type(type) && bool(words >> prop);
      if (!ok)
        throw Error(fmt::format("{}: malformed PLY header (line {}: bad property)", name, line_no));
    } else {
      throw Error(
          fmt::format("{}: malformed PLY header (line {}: unknown keyword)", name, line_no));
    }
  }
  throw Error(fmt::format("{}: malformed PLY header (no end_header)", name));
}

// glTF keeps its geometry in buffers: external .bin files or, in a .glb, the
// BIN chunk. A missing or short buffer makes Assimp answer "No suitable
// reader found" or "byteLength exceeds size", which names neither the buffer
// nor the cause; checked here first, with both in the message.
std::string percent_decode(const std::string& uri) {
  std::string out;
  for (size_t i = 0; i < uri.size(); ++i) {
    if (uri[i] == '%' && i + 2 < uri.size() &&
        std::isxdigit(static_cast<unsigned char>(uri[i + 1])) &&
        std::isxdigit(static_cast<unsigned char>(uri[i + 2]))) {
      out.push_back(char(std::stoi(uri.substr(i + 1, 2), nullptr, 16)));
      i += 2;
    } else {
      out.push_back(uri[i]);
    }
  }
  return out;
}

void check_gltf_buffers(const nlohmann::json& doc, const fs::path& dir, const std::string& name,
                        int64_t bin_chunk_bytes) {
  if (!doc.is_object() || !doc.contains("buffers")) return;
  const nlohmann::json& buffers = doc["buffers"];  // glTF 2: array; glTF 1: object by id
  if (!buffers.is_array() && !buffers.is_object()) return;
  size_t index = 0;
  for (const auto& [key, buf] : buffers.items()) {
    const std::string id = buffers.is_array() ? std::to_string(index) : one_line(key, 60);
    ++index;
    if (!buf.is_object() || !buf.contains("byteLength") || !buf["byteLength"].is_number()) continue;
    const double declared = buf["byteLength"].get<double>();
    if (!buf.contains("uri")) {  // the GLB's BIN chunk
      if (bin_chunk_bytes >= 0 && declared > double(bin_chunk_bytes))
        throw Error(fmt::format(
            "{}: buffer {} declares {} bytes but the GLB's binary chunk holds {} (truncated file?)",
            name, id, declared, bin_chunk_bytes));
      continue;
    }
    if (!buf["uri"].is_string()) continue;
    const std::string uri = buf["uri"].get<std::string>();
    if (uri.rfind("data:", 0) == 0) continue;  // embedded base64: Assimp reports it
    const fs::path file = dir / percent_decode(uri);
    struct stat st;
    if (::stat(file.c_str(), &st) != 0)
      throw Error(fmt::format("{}: buffer {} refers to '{}', which is not next to the model", name,
                              id, one_line(uri, 120)));
    if (!S_ISREG(st.st_mode))
      throw Error(fmt::format("{}: buffer {} file '{}' is {}, not a regular file", name, id,
                              one_line(uri, 120), file_type_name(uint32_t(st.st_mode))));
    if (declared > double(st.st_size))
      throw Error(fmt::format(
          "{}: buffer '{}' holds {} bytes but the model declares {} (truncated, or from another "
          "version of the model?)",
          name, one_line(uri, 120), uint64_t(st.st_size), declared));
  }
}

// A referenced file that exists but is not a regular file: a FIFO blocks the
// reader that opens it until a writer appears (Assimp would hang), a device
// may never end. Missing files are left to the importer and the texture
// loader, which report them.
void require_regular_reference(const fs::path& file, const std::string& name, const char* what,
                               const std::string& ref) {
  struct stat st;
  if (::stat(file.c_str(), &st) == 0 && !S_ISREG(st.st_mode))
    throw Error(fmt::format("{}: {} '{}' is {}, not a regular file", name, what, one_line(ref, 120),
                            file_type_name(uint32_t(st.st_mode))));
}

// glTF images (the buffers: check_gltf_buffers).
void check_gltf_images(const nlohmann::json& doc, const fs::path& dir, const std::string& name) {
  if (!doc.is_object() || !doc.contains("images")) return;
  const nlohmann::json& images = doc["images"];  // glTF 2: array; glTF 1: object by id
  if (!images.is_array() && !images.is_object()) return;
  for (const auto& [key, image] : images.items()) {
    (void)key;
    if (!image.is_object() || !image.contains("uri") || !image["uri"].is_string()) continue;
    const std::string uri = image["uri"].get<std::string>();
    if (uri.rfind("data:", 0) == 0) continue;
    require_regular_reference(dir / percent_decode(uri), name, "image", uri);
  }
}

// OBJ: Assimp opens every "mtllib" file with a blocking read. It takes the
// rest of the line as one name; each whitespace-separated word is checked
// too (other readers split the list).
void precheck_obj(const fs::path& path, const std::string& name) {
  std::ifstream in(path, std::ios::binary);
  std::string line;
  while (std::getline(in, line)) {
    const size_t start = line.find_first_not_of(" \t");
    if (start == std::string::npos || line.compare(start, 6, "mtllib") != 0) continue;
    std::string rest = line.substr(start + 6);
    if (!rest.empty() && rest[0] != ' ' && rest[0] != '\t') continue;  // e.g. "mtllibx"
    const size_t first = rest.find_first_not_of(" \t");
    const size_t last = rest.find_last_not_of(" \t\r");
    if (first == std::string::npos) continue;
    rest = rest.substr(first, last - first + 1);
    std::vector<std::string> names{rest};
    std::istringstream words(rest);
    for (std::string w; words >> w;)
      if (w != rest) names.push_back(w);
    for (const std::string& n : names)
      require_regular_reference(path.parent_path() / n, name, "material library", n);
  }
}

void precheck_gltf(const fs::path& path, const std::string& name, bool binary) {
  std::ifstream in(path, std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  nlohmann::json doc;
  int64_t bin_chunk = -1;
  auto u32 = [&](size_t at) {
    uint32_t v = 0;
    std::memcpy(&v, bytes.data() + at, 4);
    return v;
  };
  // Assimp's glTF importers read a binary file whatever its extension.
  binary = binary || bytes.compare(0, 4, "glTF") == 0;
  if (binary) {
    // Header: magic "glTF", version, total length; glTF 2 then has chunks
    // of {length, type, data}: JSON first, then optionally BIN.
    if (bytes.size() < 12 || bytes.compare(0, 4, "glTF") != 0) return;
    if (u32(8) > bytes.size())
      throw Error(
          fmt::format("{}: the GLB header declares {} bytes but the file has {} (truncated)", name,
                      u32(8), bytes.size()));
    if (bytes.size() < 20) return;
    // Assimp allocates a chunk's declared length before reading it (a 1 KB
    // file declaring a 4 GB JSON chunk costs 4 GB; found by fuzz_mesh):
    // every declared length must fit in the file. glTF 1 binary: the
    // content (JSON) length at offset 12; glTF 2: the chunks' lengths.
    auto chunk_fits = [&](const char* what, uint64_t at, uint64_t length) {
      if (at + length > bytes.size())
        throw Error(fmt::format(
            "{}: the GLB's {} declares {} bytes but the file has {} after its header (truncated "
            "or damaged)",
            name, what, length, bytes.size() > at ? bytes.size() - at : 0));
    };
    if (u32(4) == 1) chunk_fits("JSON content", 20, u32(12));
    if (u32(4) != 2) return;
    const uint64_t json_len = u32(12);
    if (u32(16) != 0x4E4F534Au) return;
    chunk_fits("JSON chunk", 20, json_len);
    const uint64_t bin_at = 20 + ((json_len + 3) & ~uint64_t(3));
    if (bin_at + 8 <= bytes.size() && u32(size_t(bin_at) + 4) == 0x004E4942u) {
      chunk_fits("binary chunk", bin_at + 8, u32(size_t(bin_at)));
      bin_chunk = int64_t(u32(size_t(bin_at)));
    }
    doc = nlohmann::json::parse(bytes.begin() + 20, bytes.begin() + 20 + int64_t(json_len), nullptr,
                                false);
  } else {
    doc = nlohmann::json::parse(bytes, nullptr, false);
  }
  if (doc.is_discarded()) return;  // not JSON: Assimp's message says where
  check_gltf_buffers(doc, path.parent_path(), name, bin_chunk);
  check_gltf_images(doc, path.parent_path(), name);
}

// Assimp reports through its DefaultLogger (silent unless one is created),
// and a few importers print to stdout/stderr directly (e.g. OpenGEX's DDL
// parser). During an import both are captured: the log, because some
// warnings mean lost geometry (ImportLog::dropped_geometry), the streams so
// that nothing stray reaches the user's terminal. Both are process-wide, so
// imports run one at a time.
class ImportLog : public Assimp::LogStream {
 public:
  void write(const char* message) override {
    std::string line = one_line(message, 300);
    // Drop the "Warn,  T0: " severity and thread tag.
    if (const size_t tag = line.find(": "); tag != std::string::npos && tag < 20)
      line.erase(0, tag + 2);
    lines.push_back(std::move(line));
  }
  // Importers that drop faces or vertices with out-of-range indices and only
  // warn about it; a model silently missing faces is worse than an error.
  const std::string* dropped_geometry() const {
    static const char* const kDropped[] = {
        "out-of-range indices",        "vertex index is out of range",
        "vertex index out of range",   "polygon index is out of range",
        "Face has an invalid index",   "Position index out of range",
        "face index is out of range",  "Failure evaluating face record",
        "IRRMESH: Index out of range", "Coordinate idx is out of range",
        "GLTF: Invalid index",         "not compatible with the TRIANGLES mode"};
    for (const std::string& l : lines)
      for (const char* k : kDropped)
        if (l.find(k) != std::string::npos) return &l;
    return nullptr;
  }
  std::vector<std::string> lines;
};

class QuietImport {
 public:
  QuietImport() : lock_(mutex()) {
    if (Assimp::DefaultLogger::isNullLogger()) {
      Assimp::DefaultLogger::create("", Assimp::Logger::NORMAL, 0);
      created_ = true;
    }
    Assimp::DefaultLogger::get()->attachStream(&log_, kSeverity);
    std::fflush(stdout);
    std::fflush(stderr);
    capture_ = std::tmpfile();
    for (int k = 0; k < 2 && capture_; ++k) {
      saved_[k] = ::dup(k + 1);
      if (saved_[k] >= 0) ::dup2(::fileno(capture_), k + 1);
    }
  }
  ~QuietImport() {
    std::fflush(stdout);
    std::fflush(stderr);
    for (int k = 0; k < 2; ++k)
      if (saved_[k] >= 0) {
        ::dup2(saved_[k], k + 1);
        ::close(saved_[k]);
      }
    if (capture_) std::fclose(capture_);
    Assimp::DefaultLogger::get()->detachStream(&log_, kSeverity);
    if (created_) Assimp::DefaultLogger::kill();
  }
  QuietImport(const QuietImport&) = delete;
  QuietImport& operator=(const QuietImport&) = delete;
  const ImportLog& log() const { return log_; }
  /// The real stderr while it is captured (-1 if it could not be saved):
  /// where a progress bar goes.
  int terminal_fd() const { return saved_[1]; }

 private:
  static std::mutex& mutex() {
    static std::mutex m;
    return m;
  }
  static constexpr unsigned kSeverity = Assimp::Logger::Warn | Assimp::Logger::Err;
  std::lock_guard<std::mutex> lock_;
  ImportLog log_;
  bool created_ = false;
  std::FILE* capture_ = nullptr;
  int saved_[2] = {-1, -1};
};

// Assimp's progress reports (file read, then post-processing) onto a bar
// drawn on the real stderr, which QuietImport has captured meanwhile.
class ImportProgress : public Assimp::ProgressHandler {
 public:
  // Phase weights: shares of the import's time, measured on the bunny OBJ
  // (2 cores): Assimp's read 0.7 s, post-processing and our conversion
  // together under 0.2 s.
  ImportProgress(const std::string& name, int terminal_fd)
      : progress_("load " + fs::path(name).filename().string(),
                  {{"read", 0.8}, {"post-process", 0.15}, {"convert", 0.05}}, sink(terminal_fd)) {}
  bool Update(float) override { return true; }
  void UpdateFileRead(int step, int steps) override { report(0, step, steps); }
  void UpdatePostProcess(int step, int steps) override { report(1, step, steps); }
  Progress& progress() { return progress_; }

 private:
  static ProgressSink sink(int fd) {
    ProgressSink s = ProgressSink::terminal();
    s.tty = fd >= 0 && !Progress::quiet() && ::isatty(fd);
    s.write = [fd](const std::string& text) {
      if (::write(fd, text.data(), text.size()) < 0) return;  // a progress bar may be lost
    };
    return s;
  }
  void report(size_t phase, int step, int steps) {
    if (steps <= 0) return;
    if (phase != phase_) progress_.start_phase(phase, uint64_t(steps)), phase_ = phase;
    progress_.set_done(uint64_t(std::clamp(step, 0, steps)));
  }
  Progress progress_;
  size_t phase_ = size_t(-1);
};

}  // namespace

Mesh load_mesh(const std::filesystem::path& path, MeshLoadStats* stats_out,
               uint64_t texture_budget) {
  return load_mesh(path, nullptr, stats_out, texture_budget);
}

Mesh load_mesh(const std::filesystem::path& path, Image* height_map, MeshLoadStats* stats_out,
               uint64_t texture_budget) {
  const std::string name = path.string();
  std::error_code ec;
  if (!fs::exists(path, ec)) throw Error(fmt::format("{}: file not found", name));
  if (!fs::is_regular_file(path, ec)) throw Error(fmt::format("{}: not a regular file", name));
  if (fs::file_size(path, ec) == 0) throw Error(fmt::format("{}: file is empty", name));

  {
    std::string ext = path.extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(),
                   [](unsigned char c) { return char(std::tolower(c)); });
    if (ext == ".off") precheck_off(path, name);
    precheck_ply(path, name, ext == ".ply");
    if (ext == ".gltf" || ext == ".glb") precheck_gltf(path, name, ext == ".glb");
    if (ext == ".obj") precheck_obj(path, name);
  }

  Assimp::Importer importer;
  // Points and lines are removed by SortByPType instead of reaching us.
  importer.SetPropertyInteger(AI_CONFIG_PP_SBP_REMOVE,
                              aiPrimitiveType_POINT | aiPrimitiveType_LINE);
  // Two steps: the file as read (ValidateDataStructure rejects out-of-range
  // indices before JoinIdenticalVertices would index with them), checked for
  // non-finite positions; then the rest. No GenNormals: we compute missing
  // normals ourselves, area-weighted, and only where missing.
  const unsigned read_flags = aiProcess_ValidateDataStructure;
  const unsigned post_flags = aiProcess_Triangulate | aiProcess_JoinIdenticalVertices |
                              aiProcess_SortByPType | aiProcess_PreTransformVertices |
                              aiProcess_FlipUVs;
  QuietImport quiet;
  // Owned here: Assimp deletes its handler in ~Importer, but not one that
  // SetProgressHandler(nullptr) replaced.
  ImportProgress progress(name, quiet.terminal_fd());
  importer.SetProgressHandler(&progress);
  struct DetachProgress {
    Assimp::Importer& importer;
    ~DetachProgress() { importer.SetProgressHandler(nullptr); }
  } detach{importer};
  const aiScene* scene = nullptr;
  try {
    scene = importer.ReadFile(path.string(), read_flags);
    if (scene) {
      for (unsigned m = 0; m < scene->mNumMeshes; ++m)
        if (scene->mMeshes && scene->mMeshes[m])
          require_finite_positions(*scene->mMeshes[m], m, name);
      scene = importer.ApplyPostProcessing(post_flags);
    }
  } catch (const Error&) {
    throw;
  } catch (const std::bad_alloc&) {
    throw Error(fmt::format("{}: out of memory while importing (corrupt element counts?)", name));
  } catch (const std::exception& e) {
    throw Error(fmt::format("{}: cannot import: {}", name, one_line(e.what())));
  }
  if (const std::string* dropped = quiet.log().dropped_geometry())
    throw Error(fmt::format(
        "{}: the file references vertices that do not exist ({}); damaged file?", name, *dropped));
  if (!scene) {
    std::string err = one_line(importer.GetErrorString());
    if (err.find("No suitable reader found") != std::string::npos) {
      const std::string ext = path.extension().string();
      if (!ext.empty() && importer.IsExtensionSupported(ext.c_str()))
        throw Error(fmt::format(
            "{}: not a valid {} file (Assimp's {} importer did not accept its contents; "
            "damaged, truncated, or missing a file it references?)",
            name, one_line(ext.substr(1), 20), one_line(ext.substr(1), 20)));
      throw Error(fmt::format(
          "{}: unknown mesh format{} (voxcast reads what Assimp reads: OBJ, PLY, OFF, STL, "
          "glTF/GLB, FBX, DAE, 3DS, ...)",
          name, ext.empty() ? std::string() : " '" + one_line(ext, 20) + "'"));
    }
    throw Error(fmt::format("{}: cannot import: {}", name, err.empty() ? "unknown error" : err));
  }
  if (scene->mNumMeshes == 0 || !scene->mMeshes)
    throw Error(fmt::format("{}: contains no triangles", name));

  MeshLoadStats stats;
  progress.progress().start_phase(2, 1);
  SceneConverter converter(*scene, path, texture_budget, height_map != nullptr);
  Mesh mesh = converter.convert(stats);
  if (height_map != nullptr) *height_map = converter.height_map();
  progress.progress().finish();
  try {
    validate_mesh(mesh);
  } catch (const Error& e) {
    // A violation here is an importer bug or a file we misread; name the file.
    throw Error(fmt::format("{}: {}", name, e.what()));
  }
  if (stats_out) *stats_out = stats;
  return mesh;
}

}  // namespace voxcast
