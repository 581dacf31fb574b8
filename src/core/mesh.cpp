// Mesh member functions, Texture::sample and validate_mesh.
#include "voxcast/mesh.hpp"

#include <fmt/format.h>

#include <array>
#include <cmath>

#include "voxcast/error.hpp"
#include "voxcast/image.hpp"

namespace voxcast {

namespace {

// Textures hold sRGB bytes; 256 entries cover every possible texel value, so a
// table is both exact (same function as srgb_to_linear) and cheap per sample.
const std::array<float, 256>& srgb_byte_to_linear() {
  static const std::array<float, 256> table = [] {
    std::array<float, 256> t{};
    for (int i = 0; i < 256; ++i) t[i] = srgb_to_linear(float(i) / 255.0f);
    return t;
  }();
  return table;
}

// Positive modulo: wrap addressing must also work for negative texel indices.
inline int wrap(int i, int n) {
  int r = i % n;
  return r < 0 ? r + n : r;
}

// Reduces a texture coordinate to [0,1) before it is scaled to texels, so that
// huge or non-finite UVs can neither overflow the int conversion nor produce NaN.
inline float fract_or_zero(float t) {
  if (!std::isfinite(t)) return 0.0f;
  float f = t - std::floor(t);
  return f < 1.0f ? f : 0.0f;  // t - floor(t) can round up to 1 for tiny negative t
}

Vec3 face_normal(const Mesh& m, size_t t) {
  Vec3 a = m.positions[m.indices[3 * t]];
  Vec3 b = m.positions[m.indices[3 * t + 1]];
  Vec3 c = m.positions[m.indices[3 * t + 2]];
  // Double precision: slivers whose float cross product underflows to zero
  // still have a well-defined orientation.
  double e1[3] = {double(b.x) - a.x, double(b.y) - a.y, double(b.z) - a.z};
  double e2[3] = {double(c.x) - a.x, double(c.y) - a.y, double(c.z) - a.z};
  double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                 e1[0] * e2[1] - e1[1] * e2[0]};
  double len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
  if (!(len > 0) || !std::isfinite(len)) return {0, 0, 1};
  return {float(n[0] / len), float(n[1] / len), float(n[2] / len)};
}

}  // namespace

Color Texture::sample(Vec2 uv) const {
  if (width <= 0 || height <= 0 || rgba.size() < size_t(width) * size_t(height) * 4)
    return {1, 1, 1, 1};  // an absent texture must not change the color it multiplies
  const auto& lut = srgb_byte_to_linear();
  // UV origin is the top-left corner of the image (v grows downwards, as in
  // glTF), matching the top-to-bottom row order of `rgba`. Texel centers sit
  // at half-integer coordinates, hence the -0.5.
  float x = fract_or_zero(uv.x) * float(width) - 0.5f;
  float y = fract_or_zero(uv.y) * float(height) - 0.5f;
  float fx = std::floor(x), fy = std::floor(y);
  float tx = x - fx, ty = y - fy;
  int x0 = wrap(int(fx), width), x1 = wrap(int(fx) + 1, width);
  int y0 = wrap(int(fy), height), y1 = wrap(int(fy) + 1, height);
  auto texel = [&](int xi, int yi, int ch) {
    uint8_t v = rgba[(size_t(yi) * size_t(width) + size_t(xi)) * 4 + size_t(ch)];
    return ch == 3 ? float(v) / 255.0f : lut[v];  // alpha is linear already
  };
  float out[4];
  // Filtering happens after decoding to linear: averaging sRGB values would
  // darken edges between bright and dark texels.
  for (int ch = 0; ch < 4; ++ch) {
    float top = texel(x0, y0, ch) * (1 - tx) + texel(x1, y0, ch) * tx;
    float bot = texel(x0, y1, ch) * (1 - tx) + texel(x1, y1, ch) * tx;
    out[ch] = top * (1 - ty) + bot * ty;
  }
  return {out[0], out[1], out[2], out[3]};
}

Aabb Mesh::bounds() const {
  Aabb box;
  // Only referenced vertices count: a stray vertex must not grow the voxel grid.
  for (uint32_t i : indices)
    if (i < positions.size()) box.extend(positions[i]);
  return box;
}

Color Mesh::surface_color(size_t t, float u, float v) const {
  Color c{1, 1, 1, 1};
  if (t >= triangle_count()) return Material{}.base_color;
  float w = 1.0f - u - v;
  uint32_t i0 = indices[3 * t], i1 = indices[3 * t + 1], i2 = indices[3 * t + 2];
  const Material* mat = nullptr;
  if (t < triangle_material.size() && triangle_material[t] < materials.size())
    mat = &materials[triangle_material[t]];
  if (mat) {
    c = mat->base_color;
    if (mat->texture >= 0 && size_t(mat->texture) < textures.size() &&
        uvs.size() == positions.size()) {
      Vec2 a = uvs[i0], b = uvs[i1], d = uvs[i2];
      Vec2 uv{w * a.x + u * b.x + v * d.x, w * a.y + u * b.y + v * d.y};
      Color tex = textures[size_t(mat->texture)].sample(uv);
      c = {c.r * tex.r, c.g * tex.g, c.b * tex.b, c.a * tex.a};
    }
  } else if (colors.size() != positions.size()) {
    // Neither a material nor vertex colors: the documented default material color.
    return Material{}.base_color;
  }
  if (colors.size() == positions.size()) {
    const Color &a = colors[i0], &b = colors[i1], &d = colors[i2];
    c.r *= w * a.r + u * b.r + v * d.r;
    c.g *= w * a.g + u * b.g + v * d.g;
    c.b *= w * a.b + u * b.b + v * d.b;
    c.a *= w * a.a + u * b.a + v * d.a;
  }
  return c;
}

Vec3 Mesh::surface_normal(size_t t, float u, float v) const {
  if (t >= triangle_count()) return {0, 0, 1};
  if (normals.size() == positions.size()) {
    float w = 1.0f - u - v;
    Vec3 n = normals[indices[3 * t]] * w + normals[indices[3 * t + 1]] * u +
             normals[indices[3 * t + 2]] * v;
    float len = length(n);
    // Opposing vertex normals (e.g. a thin fold) can cancel; the face normal is
    // then the only meaningful direction left.
    if (len > 1e-6f && std::isfinite(len)) return n / len;
  }
  return face_normal(*this, t);
}

void validate_mesh(const Mesh& m) {
  const size_t nv = m.positions.size();
  if (nv > size_t(UINT32_MAX))
    throw Error(fmt::format("mesh has {} vertices, more than 32-bit indices can address", nv));
  if (m.indices.size() % 3 != 0)
    throw Error(fmt::format("mesh index count {} is not a multiple of 3", m.indices.size()));
  auto check_size = [&](size_t n, const char* what) {
    if (n != 0 && n != nv) throw Error(fmt::format("mesh has {} {} for {} vertices", n, what, nv));
  };
  check_size(m.normals.size(), "normals");
  check_size(m.colors.size(), "colors");
  check_size(m.uvs.size(), "uvs");
  for (size_t i = 0; i < m.indices.size(); ++i)
    if (m.indices[i] >= nv)
      throw Error(fmt::format("triangle {} references vertex {} but the mesh has {} vertices",
                              i / 3, m.indices[i], nv));
  for (size_t i = 0; i < nv; ++i)
    if (!is_finite(m.positions[i]))
      throw Error(fmt::format("vertex {} has a non-finite coordinate", i));
  for (size_t i = 0; i < m.normals.size(); ++i) {
    float len = length(m.normals[i]);
    // Tolerance covers float rounding of normalize(); anything further off was
    // never normalized.
    if (!std::isfinite(len) || std::fabs(len - 1.0f) > 1e-3f)
      throw Error(fmt::format("normal {} is not unit length (length {})", i, len));
  }
  for (size_t i = 0; i < m.colors.size(); ++i) {
    const Color& c = m.colors[i];
    if (!std::isfinite(c.r) || !std::isfinite(c.g) || !std::isfinite(c.b) || !std::isfinite(c.a))
      throw Error(fmt::format("vertex color {} is not finite", i));
  }
  for (size_t i = 0; i < m.uvs.size(); ++i)
    if (!std::isfinite(m.uvs[i].x) || !std::isfinite(m.uvs[i].y))
      throw Error(fmt::format("texture coordinate {} is not finite", i));
  if (!m.triangle_material.empty()) {
    if (m.triangle_material.size() != m.triangle_count())
      throw Error(fmt::format("mesh has {} triangle materials for {} triangles",
                              m.triangle_material.size(), m.triangle_count()));
    for (size_t t = 0; t < m.triangle_material.size(); ++t)
      if (m.triangle_material[t] >= m.materials.size())
        throw Error(fmt::format("triangle {} uses material {} but the mesh has {} materials", t,
                                m.triangle_material[t], m.materials.size()));
  }
  for (size_t i = 0; i < m.materials.size(); ++i) {
    int tex = m.materials[i].texture;
    if (tex < -1 || (tex >= 0 && size_t(tex) >= m.textures.size()))
      throw Error(fmt::format("material {} uses texture {} but the mesh has {} textures", i, tex,
                              m.textures.size()));
  }
  for (size_t i = 0; i < m.textures.size(); ++i) {
    const Texture& t = m.textures[i];
    if (t.width <= 0 || t.height <= 0 || t.rgba.size() != size_t(t.width) * size_t(t.height) * 4)
      throw Error(fmt::format("texture {} is {}x{} but holds {} bytes", i, t.width, t.height,
                              t.rgba.size()));
  }
}

}  // namespace voxcast
