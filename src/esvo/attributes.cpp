// Attribute encoding of the raw color/normal attachment (esvo §5.4, Figure 7)
// and the per-hit attribute lookup EsvoOctree::attributes(), which dispatches
// on the attachment type to the raw lookup or the compressed decoder (§5.5,
// compress.cpp).
//
// Value layout (two 32-bit words per voxel):
//
//   word 0, color (ABGR, sRGB-encoded RGB, linear alpha):
//     | 31..24 A | 23..16 B | 15..8 G | 7..0 R |
//
//   word 1, cube-face normal:
//     | 31..29 face | 28..15 u (14 bits) | 14..0 v (15 bits) |
//     face = axis*2 + (major component negative ? 1 : 0), axis 0=x 1=y 2=z.
//     u = component (axis+1)%3 / |major|, v = component (axis+2)%3 / |major|,
//     both in [-1,1], quantized with rounding to [0, 2^14-1] / [0, 2^15-1].
//     The paper uses a similar cube-map style encoding (§5.4: 32 bits for the
//     normal); splitting 29 bits as 14+15 keeps the worst-case angular error
//     below ~7e-5 rad (half a quantization step on the face, see the tests).
#include <immintrin.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstring>

#include "esvo/compress.hpp"
#include "esvo/layout_internal.hpp"
#include "voxcast/esvo.hpp"

namespace voxcast::esvo {
namespace {

constexpr uint32_t kUMax = layout::NormalU::max;  // 2^14 - 1
constexpr uint32_t kVMax = layout::NormalV::max;  // 2^15 - 1

double linear_from_srgb(double c) {
  return c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4);
}

// Encoding one channel = round(srgb(c) * 255). Since srgb() is monotonic this
// is "the number of thresholds t_k = linear((k - 0.5)/255), k = 1..255, that
// are <= c": exact, and free of pow() per voxel, which matters when the
// builder encodes tens of millions of values. A 4096-bin table gives the code
// at each bin's lower edge; sRGB's steepest slope (12.92 near 0) means at
// most ~1 threshold per bin, so a short forward scan finishes the job.
constexpr int kBins = 4096;
struct SrgbTables {
  std::array<float, 257> threshold{};  // threshold[k] = lower bound of code k (k >= 1); [256] = inf
  std::array<float, 256> decode{};     // code -> linear
  std::array<uint8_t, kBins> start{};  // code of the value bin / kBins
  SrgbTables() {
    for (int k = 0; k < 256; ++k) {
      decode[k] = float(linear_from_srgb(k / 255.0));
      threshold[k] = k == 0 ? -INFINITY : float(linear_from_srgb((k - 0.5) / 255.0));
    }
    threshold[256] = INFINITY;
    int k = 0;
    for (int b = 0; b < kBins; ++b) {
      const float lo = float(b) / kBins;
      while (threshold[k + 1] <= lo) ++k;
      start[b] = uint8_t(k);
    }
  }
};
const SrgbTables& tables() {
  static const SrgbTables t;
  return t;
}

uint32_t encode_srgb8(float c) {
  if (!(c > 0.f)) return 0;  // also maps NaN to 0
  if (c >= 1.f) return 255;
  const SrgbTables& t = tables();
  uint32_t k = t.start[int(c * kBins)];
  while (t.threshold[k + 1] <= c) ++k;
  return k;
}

uint32_t encode_unorm8(float c) {
  if (!(c > 0.f)) return 0;
  if (c >= 1.f) return 255;
  return uint32_t(double(c) * 255.0 + 0.5);  // round half up (c > 0); no libm call
}

uint32_t quantize(float t, uint32_t max) {  // t in [-1, 1] -> [0, max], rounded
  const float q = (t + 1.f) * 0.5f * float(max);
  if (!(q > 0.f)) return 0;
  if (q >= float(max)) return max;
  return uint32_t(double(q) + 0.5);  // exact round half up for q >= 0, no libm call
}

}  // namespace

uint32_t encode_color_abgr(const Color& linear) {
  return layout::ColorR::put(encode_srgb8(linear.r)) | layout::ColorG::put(encode_srgb8(linear.g)) |
         layout::ColorB::put(encode_srgb8(linear.b)) | layout::ColorA::put(encode_unorm8(linear.a));
}

Color decode_color_abgr(uint32_t abgr) {
  const auto& d = tables().decode;
  return {d[layout::ColorR::get(abgr)], d[layout::ColorG::get(abgr)], d[layout::ColorB::get(abgr)],
          float(layout::ColorA::get(abgr)) * (1.f / 255.f)};
}

uint32_t encode_normal_cube(Vec3 n) {
  // Major axis with a fixed tie break (x before y before z) so that the code
  // is a pure function of the input.
  const float ax = std::fabs(n.x), ay = std::fabs(n.y), az = std::fabs(n.z);
  int axis = 0;
  float major = ax;
  if (ay > major) axis = 1, major = ay;
  if (az > major) axis = 2, major = az;
  if (!(major > 0.f) || !std::isfinite(major)) return encode_normal_cube({0, 0, 1});
  const bool negative = n[axis] < 0.f;
  const float u = n[(axis + 1) % 3] / major, v = n[(axis + 2) % 3] / major;
  const uint32_t face = uint32_t(axis * 2 + (negative ? 1 : 0));
  return layout::NormalFace::put(face) | layout::NormalU::put(quantize(u, kUMax)) |
         layout::NormalV::put(quantize(v, kVMax));
}

Vec3 decode_normal_cube(uint32_t code) {
  uint32_t face = layout::NormalFace::get(code);
  if (face > 5) face = 4;  // not produced by the encoder; keep decode total (+z)
  const int axis = int(face >> 1);
  const float u = float(layout::NormalU::get(code)) * (2.f / float(kUMax)) - 1.f;
  const float v = float(layout::NormalV::get(code)) * (2.f / float(kVMax)) - 1.f;
  Vec3 r;
  r[axis] = (face & 1) ? -1.f : 1.f;
  r[(axis + 1) % 3] = u;
  r[(axis + 2) % 3] = v;
  return r / std::sqrt(1.f + u * u + v * v);
}

void decode_normal_cubes(const uint32_t* codes, size_t n, Vec3* out) {
  // decode_normal_cube in 8 lanes (the baseline ISA's AVX2): every lane
  // does its operations in the same order (-ffp-contract=off; sqrt and
  // division are correctly rounded in vector lanes as in scalar ones), and
  // the major component, u and v land where decode_normal_cube's r[axis],
  // r[(axis + 1) % 3] and r[(axis + 2) % 3] do.
  using V = float __attribute__((vector_size(32)));
  using U = uint32_t __attribute__((vector_size(32)));
  using S = int32_t __attribute__((vector_size(32)));
  size_t i = 0;
  for (; i + 8 <= n; i += 8) {
    U code;
    std::memcpy(&code, codes + i, sizeof code);
    U face = code >> layout::NormalFace::lo;
    face = (S)(face > 5u) != 0 ? U{} + 4u : face;  // as decode_normal_cube
    const U axis = face >> 1;
    const V u =
        __builtin_convertvector((S)((code >> layout::NormalU::lo) & layout::NormalU::max), V) *
            (2.f / float(kUMax)) -
        1.f;
    const V v =
        __builtin_convertvector((S)((code >> layout::NormalV::lo) & layout::NormalV::max), V) *
            (2.f / float(kVMax)) -
        1.f;
    const V len = (V)_mm256_sqrt_ps((__m256)(1.f + u * u + v * v));
    const V major = ((face & 1u) != 0u ? V{} - 1.f : V{} + 1.f) / len;
    const V nu = u / len, nv = v / len;
    const V x = axis == 0u ? major : (axis == 1u ? nv : nu);
    const V y = axis == 0u ? nu : (axis == 1u ? major : nv);
    const V z = axis == 0u ? nv : (axis == 1u ? nu : major);
    for (int k = 0; k < 8; ++k) out[i + size_t(k)] = {x[k], y[k], z[k]};
  }
  for (; i < n; ++i) out[i] = decode_normal_cube(codes[i]);
}

namespace {

/// Where the attributes of the children of the descriptor at parent_slot
/// live: page header -> info section -> color/normal attachment (esvo §5.4,
/// Figure 8), and the slot's index in its block. Only valid after
/// validate() or build_octree(). (The page header and info section are
/// per-block metadata that stays cached.)
struct AttributeSlot {
  size_t attach;  // first word of the attachment
  size_t rel;     // the slot within its block
  uint32_t type;  // kAttachRawColorNormal or kAttachCompressedColorNormal
};
/// The part of an AttributeSlot that all slots of a page share (their
/// block's attachment), found through the page header and info section.
struct PageAttachment {
  size_t attach;       // first word of the attachment
  size_t block_first;  // first word of the block
  uint32_t type;
  AttributeSlot slot(uint32_t parent_slot) const {
    return {attach, size_t(parent_slot) - block_first / 2, type};
  }
};
PageAttachment page_attachment(const uint32_t* w, uint32_t parent_slot) {
  const size_t page = size_t(parent_slot & ~(kPageSlots - 1)) * 2;
  const size_t info = size_t(int64_t(page) + int32_t(w[page]));
  PageAttachment p;
  p.block_first = size_t(int64_t(info) + int32_t(w[info + 1]));
  p.type = 0;
  p.attach = detail::find_color_attachment(w, info, &p.type);
  return p;
}
AttributeSlot attribute_slot(const uint32_t* w, uint32_t parent_slot) {
  return page_attachment(w, parent_slot).slot(parent_slot);
}
/// §5.5: compression block rel >> 1 holds the slot's children at
/// (rel & 1) * 8 + child.
const uint32_t* compressed_block(const uint32_t* w, const AttributeSlot& a) {
  return w + a.attach + 2 + detail::kCompressedBlockWords * (a.rel >> 1);
}
/// Raw (§5.4, Figure 7): the slot's lookup entry, then child's value.
const uint32_t* raw_entry(const uint32_t* w, const AttributeSlot& a) {
  return w + a.attach + 2 + a.rel;
}
const uint32_t* raw_value(const uint32_t* w, const AttributeSlot& a, uint32_t entry, int child) {
  const uint32_t slot_count = w[a.attach];
  const uint32_t index =
      layout::ValuePointer::get(entry) +
      uint32_t(std::popcount(layout::AttributeMask::get(entry) & ((1u << child) - 1)));
  return w + a.attach + 2 + slot_count + size_t(index) * 2;
}
void prefetch_line(const void* p) {
  _mm_prefetch(static_cast<const char*>(p), _MM_HINT_T0);
}

}  // namespace

void EsvoOctree::attributes(uint32_t parent_slot, int child, Color* color, Vec3* normal) const {
  const uint32_t* w = words.data();
  const AttributeSlot a = attribute_slot(w, parent_slot);
  if (a.type == kAttachCompressedColorNormal) {
    decode_compressed_slot(compressed_block(w, a), int(a.rel & 1) * 8 + child, color, normal);
    return;
  }
  const uint32_t* value = raw_value(w, a, *raw_entry(w, a), child);
  if (color) *color = decode_color_abgr(value[0]);
  if (normal) *normal = decode_normal_cube(value[1]);
}

void EsvoOctree::attributes(const uint32_t* parent_slots, const uint8_t* children, size_t n,
                            Color* colors, Vec3* normals) const {
  const uint32_t* w = words.data();
  constexpr size_t kChunk = 64;
  const uint32_t* values[kChunk];  // null: a compressed block's slot
  uint32_t codes[kChunk];
  for (size_t i0 = 0; i0 < n; i0 += kChunk) {
    const size_t m = std::min(kChunk, n - i0);
    // Every value located and its read started before any is used; the
    // page chain once per page (a group's hits share few pages).
    PageAttachment page{};
    uint32_t page_id = 0;
    for (size_t i = 0; i < m; ++i) {
      const uint32_t slot = parent_slots[i0 + i];
      if (i == 0 || (slot & ~(kPageSlots - 1)) != page_id)
        page = page_attachment(w, slot), page_id = slot & ~(kPageSlots - 1);
      const AttributeSlot a = page.slot(slot);
      values[i] = nullptr;
      if (a.type == kAttachCompressedColorNormal) continue;
      values[i] = raw_value(w, a, *raw_entry(w, a), children[i0 + i]);
      prefetch_line(values[i]);
    }
    for (size_t i = 0; i < m; ++i) {
      codes[i] = 0;
      if (values[i] == nullptr) continue;
      colors[i0 + i] = decode_color_abgr(values[i][0]);
      codes[i] = values[i][1];
    }
    decode_normal_cubes(codes, m, normals + i0);
    for (size_t i = 0; i < m; ++i)  // compressed (§5.5): slot by slot
      if (values[i] == nullptr)
        attributes(parent_slots[i0 + i], children[i0 + i], &colors[i0 + i], &normals[i0 + i]);
  }
}

void EsvoOctree::prefetch_attribute_entry(uint32_t parent_slot) const {
  const uint32_t* w = words.data();
  const AttributeSlot a = attribute_slot(w, parent_slot);
  if (a.type == kAttachCompressedColorNormal) {
    const uint32_t* block = compressed_block(w, a);  // may straddle two lines
    prefetch_line(block);
    prefetch_line(block + detail::kCompressedBlockWords - 1);
  } else {
    prefetch_line(raw_entry(w, a));
  }
}

void EsvoOctree::prefetch_attribute_value(uint32_t parent_slot, int child) const {
  const uint32_t* w = words.data();
  const AttributeSlot a = attribute_slot(w, parent_slot);
  if (a.type == kAttachCompressedColorNormal) return;       // the entry step fetched the block
  prefetch_line(raw_value(w, a, *raw_entry(w, a), child));  // 8 bytes, 8-byte aligned
}

AttributeFormat EsvoOctree::attribute_format() const {
  // Bounds-checked (also called on unvalidated octrees, e.g. when saving):
  // block 0's page header -> info section -> attachment table; anything out
  // of range reads as Raw, and validate() reports the actual problem.
  const uint64_t size = words.size();
  if (size < 2) return AttributeFormat::Raw;
  const int64_t info = int32_t(words[0]);
  if (info <= 0 || uint64_t(info) + detail::kInfoAttachTable > size) return AttributeFormat::Raw;
  const uint64_t count = words[size_t(info) + detail::kInfoAttachCountWord];
  for (uint64_t a = 0; a < count && uint64_t(info) + detail::kInfoAttachTable + 2 * a < size; ++a) {
    const uint32_t type = words[size_t(uint64_t(info) + detail::kInfoAttachTable + 2 * a)];
    if (type == kAttachCompressedColorNormal) return AttributeFormat::Compressed;
    if (type == kAttachRawColorNormal) return AttributeFormat::Raw;
  }
  return AttributeFormat::Raw;
}

}  // namespace voxcast::esvo
