// GigaVoxels pools, volume query and cache management (gigavoxels.hpp).
#include "voxcast/gigavoxels.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>
#include <tbb/parallel_scan.h>

#include "unit_cube.hpp"

#if defined(__AVX2__) && defined(__FMA__)
#include <immintrin.h>
#endif

#include <algorithm>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <map>
#include <new>

#include "core/prefetch.hpp"
#include "voxcast/error.hpp"
#include "voxcast/integrator.hpp"
#include "voxcast/system.hpp"

namespace voxcast::giga {
namespace {

constexpr uint32_t kNoNode = 0xFFFFFFFFu;
// Bytes per element: a tile's 8 nodes x 2 words + stamp, code, depth,
// parent, usage entry; a brick's voxels + stamp, owner, usage entry.
constexpr uint64_t kTileBytes = 8 * 8 + 4 + 4 + 1 + 4 + 4;
// (An 8-bit pool adds its BrickSteps8.)
constexpr uint64_t brick_bytes(int bits) {
  return uint64_t(kBrickVoxels) * pool_voxel_bytes(bits) + 12 +
         (bits == 8 ? sizeof(BrickSteps8) : 0);
}
constexpr uint32_t kMaxPoolElements = uint32_t(1) << 26;
static_assert(kMaxPoolElements - 1 <= NodeChildTile::max);

/// 2^e, exactly (ldexp's value without its call: it sat in the descent's
/// hot loop). e in [-126, 127].
inline float pow2f(int e) {
  return std::bit_cast<float>(uint32_t(127 + e) << 23);
}

/// The brick pool's memory, uninitialized (rays read only bricks the
/// producer wrote). A warm frame's samples hop between hundreds of bricks
/// per ray (a brick and its parent at every step) spread over a pool of up
/// to gigabytes: with 4 KiB pages nearly every brick access misses the
/// TLB, and the profile's hottest instructions were the brick loads. The
/// pool is aligned to 2 MiB and advised as huge pages (Linux transparent
/// huge pages in "madvise" mode): one TLB entry then covers 44 bricks of
/// 46 KB. Like a DAG's words, on unless VOXCAST_HUGE_PAGES=0 (system.hpp
/// HugePages::kHot). Elsewhere (or when refused) ordinary pages, the same
/// bytes.
unsigned char* allocate_brick_pool(size_t pool_bytes) {
  constexpr size_t kHuge = size_t(2) << 20;
  const size_t bytes = (pool_bytes + kHuge - 1) / kHuge * kHuge;
  void* p = std::aligned_alloc(kHuge, bytes);
  if (p == nullptr) throw std::bad_alloc();
  advise_huge_pages(p, bytes, HugePages::kHot);  // advice only: refused leaves 4 KiB pages
  return static_cast<unsigned char*>(p);
}

/// binary16 of x, rounded to nearest even, saturated at +-65504 (NaN: 0).
/// Integer arithmetic only: the same bits on every machine and ISA.
uint16_t to_half(float x) {
  const uint32_t bits = std::bit_cast<uint32_t>(x);
  const uint16_t sign = uint16_t((bits >> 16) & 0x8000u);
  const uint32_t mag = bits & 0x7FFFFFFFu;
  if (mag > 0x7F800000u) return 0;                          // NaN
  if (mag >= 0x477FF000u) return uint16_t(sign | 0x7BFFu);  // rounds above 65504
  if (mag < 0x38800000u) {
    // Below 2^-14: a subnormal half, in units of 2^-24. The float is
    // sig 2^(exp - 150), i.e. sig 2^(exp - 126) units: one rounding right
    // shift of the 24-bit significand.
    const int exp = int(mag >> 23);
    if (exp < 102) return sign;  // below 2^-25: rounds to 0
    const uint32_t sig = (mag & 0x7FFFFFu) | 0x800000u;
    const int shift = 126 - exp;  // 14..24: sig >> shift = units of 2^-24
    const uint32_t q = sig >> shift, rem = sig & ((1u << shift) - 1u), half = 1u << (shift - 1);
    return uint16_t(sign | (q + (rem > half || (rem == half && (q & 1u)))));
  }
  // Normal: rebias the exponent (127 - 15), keep 10 of the 23 mantissa bits
  // and round; a carry out of the mantissa correctly bumps the exponent.
  const uint32_t q = (mag - 0x38000000u) >> 13, rem = mag & 0x1FFFu;
  return uint16_t(sign | (q + (rem > 0x1000u || (rem == 0x1000u && (q & 1u)))));
}

/// The float of binary16 h (exact).
float from_half(uint16_t h) {
  const uint32_t sign = uint32_t(h & 0x8000u) << 16, e = (h >> 10) & 0x1Fu, m = h & 0x3FFu;
  if (e == 0) {
    const float v = float(m) * 0x1p-24f;  // subnormal (or zero): exact
    return sign ? -v : v;
  }
  if (e == 31) return std::bit_cast<float>(sign | 0x7F800000u | (m << 13));
  return std::bit_cast<float>(sign | ((e + 112u) << 23) | (m << 13));
}

/// Pool scale of level L: the side of its voxel in unit-cube lengths,
/// 2^-L / M (PoolVoxel), and its inverse.
constexpr int kLog2BrickSide = std::countr_zero(unsigned(kBrickSide));
static_assert((1 << kLog2BrickSide) == kBrickSide, "M is a power of two");
inline float voxel_side(int level) {
  return pow2f(-level - kLog2BrickSide);
}
inline float inv_voxel_side(int level) {
  return pow2f(level + kLog2BrickSide);
}

/// A producer's brick into the pool (PoolVoxel).
void encode_brick(const BrickVoxel* in, int level, PoolVoxel* out) {
  const float v = voxel_side(level);
  for (int i = 0; i < kBrickVoxels; ++i)
    out[i] = {to_half(in[i].density * v), to_half(in[i].r * v), to_half(in[i].g * v),
              to_half(in[i].b * v)};
}

/// A producer's brick into an 8-bit pool (PoolVoxel8): each channel's
/// largest value over the brick (capped where PoolVoxel's halves saturate,
/// 65504 per voxel side; NaN and negatives count as 0) sets its step.
void encode_brick8(const BrickVoxel* in, int level, PoolVoxel8* out, BrickSteps8* steps) {
  const float cap = 65504.f * inv_voxel_side(level);
  auto channel = [](const BrickVoxel& v, int c) {
    return c == 0 ? v.density : c == 1 ? v.r : c == 2 ? v.g : v.b;
  };
  float top[4] = {0.f, 0.f, 0.f, 0.f};
  for (int i = 0; i < kBrickVoxels; ++i)
    for (int c = 0; c < 4; ++c) top[c] = std::max(top[c], std::min(channel(in[i], c), cap));
  float inv[4];
  for (int c = 0; c < 4; ++c) {
    steps->step[c] = top[c] / 255.f;
    inv[c] = top[c] > 0.f ? 255.f / top[c] : 0.f;
  }
  for (int i = 0; i < kBrickVoxels; ++i) {
    uint8_t q[4];
    for (int c = 0; c < 4; ++c) {
      const float x = channel(in[i], c) * inv[c];  // NaN and <= 0 -> 0, beyond the cap -> 255
      q[c] = x > 0.f ? uint8_t(std::min(255.f, std::nearbyint(x))) : uint8_t(0);
    }
    out[i] = {q[0], q[1], q[2], q[3]};
  }
}

inline size_t stored_index(int i, int j, int k) {
  return size_t(i) + size_t(kBrickStored) * (size_t(j) + size_t(kBrickStored) * size_t(k));
}

/// Child bit along one axis (the paper's int(2x), x in [0, 1]) and the
/// coordinate within that child (2x - int(2x)).
inline uint32_t child_bit(float* x) {
  const float x2 = 2.f * *x;
  const uint32_t b = x2 >= 1.f ? 1u : 0u;
  *x = std::clamp(x2 - float(b), 0.f, 1.f);
  return b;
}

/// Trilinear lookup of a brick at stored coordinates u (stored voxel i is
/// centered at u = i + 0.5; u is clamped into the stored grid). acc receives
/// (density, r*density, g*density, b*density), the premultiplied layout of
/// BrickVoxel, times `scale` (the level's inv_voxel_side: a power of two,
/// exact). With F16C and AVX2: voxels i and i + 1 are adjacent (x fastest),
/// so one 128-bit load holds both x neighbours of a (j, k) row and one
/// vcvtph2ps makes them 8 floats; four loads and four lerps replace 32
/// scalar loads and their weights.
/// The lookup's first voxel along one axis and the weight of the next:
/// u clamped into the stored grid, its integer part (at most M, so that
/// i + 1 stays stored) and the fraction.
inline int cell_weight(float u, float* f) {
  const float c = std::clamp(u, 0.f, float(kBrickSide + 1));
  const int i = std::min(int(c), kBrickSide);
  *f = c - float(i);
  return i;
}

/// A pool voxel's size in bytes: PoolVoxel (16 bits per channel) or
/// PoolVoxel8 (8).
template <int Bits>
constexpr size_t kVoxelBytes = pool_voxel_bytes(Bits);

/// Channel ch of the pool voxel at v, undecoded-scale (half or q).
template <int Bits>
inline float pool_channel(const unsigned char* v, int ch) {
  if constexpr (Bits == 8) {
    return float(v[ch]);
  } else {
    uint16_t h;
    std::memcpy(&h, v + 2 * ch, sizeof h);
    return from_half(h);
  }
}

/// trilinear() from the lookup's first voxel v (a pointer into a brick of
/// Bits-bit voxels) and the weights f; `scale` multiplies each channel
/// (16-bit: the level's inv_voxel_side; 8-bit: the brick's steps).
template <int Bits>
inline void trilinear_at(const unsigned char* v, const float f[3], const float scale[4],
                         float acc[4]);

template <int Bits>
inline void trilinear(const unsigned char* b, const float u[3], const float scale[4],
                      float acc[4]) {
  int i0[3];
  float f[3];
  for (int a = 0; a < 3; ++a) i0[a] = cell_weight(u[a], &f[a]);
  trilinear_at<Bits>(b + stored_index(i0[0], i0[1], i0[2]) * kVoxelBytes<Bits>, f, scale, acc);
}

#if defined(__AVX2__) && defined(__FMA__) && defined(__F16C__)
/// trilinear_at()'s result in a register (what it stores into acc). One
/// row load holds both x neighbours (8 channels): 16 bytes of halves
/// through vcvtph2ps, or 8 bytes of unorm8 widened to floats.
template <int Bits>
inline __m128 trilinear_v(const unsigned char* v, const float f[3], __m128 scale) {
  constexpr size_t kRow = kBrickStored * kVoxelBytes<Bits>, kSlice = kRow * kBrickStored;
  auto row = [v](size_t at) {
    if constexpr (Bits == 8)
      return _mm256_cvtepi32_ps(
          _mm256_cvtepu8_epi32(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(v + at))));
    else
      return _mm256_cvtph_ps(_mm_loadu_si128(reinterpret_cast<const __m128i*>(v + at)));
  };
  const __m256 r00 = row(0), r10 = row(kRow), r01 = row(kSlice), r11 = row(kRow + kSlice);
  const __m256 fy = _mm256_set1_ps(f[1]), fz = _mm256_set1_ps(f[2]);
  // lerp(a, b, w) = a + w (b - a)
  const __m256 y0 = _mm256_fmadd_ps(fy, _mm256_sub_ps(r10, r00), r00);
  const __m256 y1 = _mm256_fmadd_ps(fy, _mm256_sub_ps(r11, r01), r01);
  const __m256 z = _mm256_fmadd_ps(fz, _mm256_sub_ps(y1, y0), y0);
  const __m128 x0 = _mm256_castps256_ps128(z), x1 = _mm256_extractf128_ps(z, 1);
  return _mm_mul_ps(_mm_fmadd_ps(_mm_set1_ps(f[0]), _mm_sub_ps(x1, x0), x0), scale);
}
#endif

template <int Bits>
inline void trilinear_at(const unsigned char* v, const float f[3], const float scale[4],
                         float acc[4]) {
#if defined(__AVX2__) && defined(__FMA__) && defined(__F16C__)
  _mm_storeu_ps(acc, trilinear_v<Bits>(v, f, _mm_loadu_ps(scale)));
#else
  constexpr size_t kB = kVoxelBytes<Bits>;
  constexpr size_t kRow = kBrickStored * kB, kSlice = kRow * kBrickStored;
  const unsigned char* c[8] = {
      v,          v + kB,          v + kRow,          v + kRow + kB,
      v + kSlice, v + kSlice + kB, v + kRow + kSlice, v + kRow + kSlice + kB};
  for (int ch = 0; ch < 4; ++ch) {
    float w[8];
    for (int n = 0; n < 8; ++n) w[n] = pool_channel<Bits>(c[n], ch);
    const float y0 = w[0] + f[0] * (w[1] - w[0]), y1 = w[2] + f[0] * (w[3] - w[2]);
    const float y2 = w[4] + f[0] * (w[5] - w[4]), y3 = w[6] + f[0] * (w[7] - w[6]);
    const float z0 = y0 + f[1] * (y1 - y0), z1 = y2 + f[1] * (y3 - y2);
    acc[ch] = (z0 + f[2] * (z1 - z0)) * scale[ch];
  }
#endif
}

/// A premultiplied lookup as a sample: density scaled to world units, color
/// divided by the density.
inline VolumeSample unpremultiply(const float acc[4], float density_scale) {
  VolumeSample out;
  out.density = acc[0] * density_scale;
  if (acc[0] > 0.f) {
    const float inv = 1.f / acc[0];
    out.color = {acc[1] * inv, acc[2] * inv, acc[3] * inv, 1.f};
  }
  return out;
}

/// unpremultiply() written into *out: with AVX2 the color as one 128-bit
/// multiply and store (the same products lane by lane) instead of the
/// scalar fields GCC packed through general registers.
#if defined(__AVX2__)
inline void unpremultiply_into(__m128 acc, float density_scale, VolumeSample* out) {
  static_assert(offsetof(VolumeSample, color) == 4 && sizeof(Color) == 16);
  const float a0 = _mm_cvtss_f32(acc);
  out->density = a0 * density_scale;
  // Without a branch (an empty sample is unpredictable along a ray): the
  // products are kept where a0 > 0 and zeroed elsewhere, as the scalar
  // code's test does (1 / a0 is not used there).
  const __m128 a = _mm_set1_ps(a0);
  const __m128 c0 = _mm_mul_ps(acc, _mm_div_ps(_mm_set1_ps(1.f), a));
  __m128 c = _mm_and_ps(_mm_cmpgt_ps(a, _mm_setzero_ps()), c0);
  // (acc1, acc2, acc3) * inv, then alpha 1.
  c = _mm_blend_ps(_mm_shuffle_ps(c, c, _MM_SHUFFLE(0, 3, 2, 1)), _mm_set1_ps(1.f), 8);
  _mm_storeu_ps(&out->color.r, c);
}
#endif

inline void unpremultiply_into(const float acc[4], float density_scale, VolumeSample* out) {
#if defined(__AVX2__)
  unpremultiply_into(_mm_loadu_ps(acc), density_scale, out);
#else
  *out = unpremultiply(acc, density_scale);
#endif
}

float request_priority(int level) {
  return float(kMaxLevel - level);
}

/// The requests this context pushed lately, in its accessor cache: a ray
/// asks for the same node at every sample and every neighbouring ray asks
/// again, which would fill the fixed-capacity buffer with duplicates and
/// make what survives depend on the thread schedule. Direct-mapped on the
/// node index. The volume integrator resets the cache at every tile (the
/// frame loop must see each asking tile push), the frame loop at every pass.
struct RecentRequests {
  static constexpr int kSlots = 31;  // 248 bytes: fits AccessorCache::kBytes
  uint64_t entry[kSlots];            // node * 2 + kind, + 1 (0 = empty)
};
static_assert(sizeof(RecentRequests) <= AccessorCache::kBytes);

void push_request(TraceContext& ctx, const void* owner, uint32_t kind, uint32_t node, int level) {
  RecentRequests& recent = ctx.cache.get<RecentRequests>(owner);
  const uint64_t tag = (uint64_t(node) << 1 | kind) + 1;
  uint64_t& slot = recent.entry[tag % RecentRequests::kSlots];
  if (slot == tag) return;
  slot = tag;
  ctx.requests.push(kind, node, request_priority(level));
}

/// Order-preserving compaction of a usage list (§3.6.2, Figures 3.17-3.18):
/// the elements not stamped `now` keep their order at the front, the ones
/// used in this pass keep theirs at the back. A TBB parallel scan computes
/// each unused element's destination (the used ones follow from it).
/// Returns the number of unused elements.
size_t lru_compact(std::vector<uint32_t>* usage, const std::vector<uint32_t>& stamps, uint32_t now,
                   std::vector<uint32_t>* scratch) {
  const size_t n = usage->size();
  const std::vector<uint32_t>& u = *usage;
  const size_t unused = tbb::parallel_reduce(
      tbb::blocked_range<size_t>(0, n, 4096), size_t(0),
      [&](const tbb::blocked_range<size_t>& r, size_t acc) {
        for (size_t i = r.begin(); i != r.end(); ++i) acc += stamps[u[i]] != now;
        return acc;
      },
      std::plus<size_t>());
  scratch->resize(n);
  uint32_t* out = scratch->data();
  tbb::parallel_scan(
      tbb::blocked_range<size_t>(0, n, 4096), size_t(0),
      [&](const tbb::blocked_range<size_t>& r, size_t before, bool is_final) {
        for (size_t i = r.begin(); i != r.end(); ++i) {
          const bool is_unused = stamps[u[i]] != now;
          // `before` = unused elements before i; used ones before i = i - before.
          if (is_final) out[is_unused ? before : unused + (i - before)] = u[i];
          before += is_unused;
        }
        return before;
      },
      std::plus<size_t>());
  usage->swap(*scratch);
  return unused;
}

}  // namespace

void GigaVoxels::PoolFree::operator()(unsigned char* p) const noexcept {
  std::free(p);
}

float stored_value(int level, float value) {
  return from_half(to_half(value * voxel_side(level))) * inv_voxel_side(level);
}

uint32_t GigaVoxels::stamp(uint32_t frame, uint32_t pass) {
  return (((frame & 0x7FFFFFu) << 8) | std::min(pass, 255u)) + 1u;
}

// ---- Producer ----

Produced Producer::produce(const NodeRegion& r, std::span<BrickVoxel> out) const {
  if (out.size() < size_t(kBrickVoxels)) throw Error("producer: brick buffer too small");
  Produced p;
  VolumeSample c;
  if (constant_below(r, &c)) {
    p.constant = p.terminal = true, p.value = c;
    return p;
  }
  const int64_t x0 = int64_t(r.x) * kBrickSide - 1, y0 = int64_t(r.y) * kBrickSide - 1,
                z0 = int64_t(r.z) * kBrickSide - 1;
  bool same = true;
  VolumeSample first;
  for (int k = 0; k < kBrickStored; ++k)
    for (int j = 0; j < kBrickStored; ++j)
      for (int i = 0; i < kBrickStored; ++i) {
        const VolumeSample v = voxel(r.level, x0 + i, y0 + j, z0 + k);
        const size_t at = stored_index(i, j, k);
        out[at] = {v.density, v.color.r * v.density, v.color.g * v.density, v.color.b * v.density};
        if (at == 0)
          first = v;
        else if (v.density != first.density ||
                 (v.density != 0.f && (v.color.r != first.color.r || v.color.g != first.color.g ||
                                       v.color.b != first.color.b)))
          same = false;
      }
  if (same) {
    p.constant = true;
    p.value = first.density == 0.f ? VolumeSample{} : first;
  }
  p.terminal = r.level >= max_level();
  return p;
}

// ---- Construction ----

GigaVoxels::GigaVoxels(std::shared_ptr<const Producer> producer, GigaOptions options)
    : producer_(std::move(producer)), options_(options) {
  if (!producer_) throw Error("gigavoxels: no producer");
  if (producer_->max_level() < 0 || producer_->max_level() > kMaxLevel)
    throw Error("gigavoxels: producer levels must be in 0.." + std::to_string(kMaxLevel));
  max_level_ = producer_->max_level();
  if (!(options_.size > 0.f) || !std::isfinite(options_.size) || !is_finite(options_.origin))
    throw Error("gigavoxels: the volume's size must be a positive number");
  if (options_.max_data_per_pass == 0) throw Error("gigavoxels: max_data_per_pass must be > 0");
  if (options_.brick_bits != 8 && options_.brick_bits != 16)
    throw Error("gigavoxels: brick bits must be 8 or 16, not " +
                std::to_string(options_.brick_bits));
  voxel_bytes_ = pool_voxel_bytes(options_.brick_bits);
  const uint64_t per_brick = brick_bytes(options_.brick_bits);
  uint64_t tiles = options_.tiles, bricks = options_.bricks;
  if (tiles == 0 || bricks == 0) {
    const uint64_t n = options_.budget_bytes / (kTileBytes + per_brick);
    tiles = n, bricks = n;
  }
  if (tiles < 2 || bricks < 1)
    throw Error("gigavoxels: the memory budget holds no brick (at least " +
                std::to_string(2 * kTileBytes + per_brick) + " bytes)");
  tiles = std::min<uint64_t>(tiles, kMaxPoolElements);
  bricks = std::min<uint64_t>(bricks, kMaxPoolElements);
  inv_size_ = 1.f / options_.size;
  for (int l = 0; l <= kMaxLevel; ++l) voxel_world_[l] = options_.size / float(kBrickSide << l);

  child_.assign(size_t(tiles) * 8, 0);
  data_.assign(size_t(tiles) * 8, 0);
  tile_stamp_.assign(size_t(tiles), 0);
  tile_code_.assign(size_t(tiles), 0);
  tile_depth_.assign(size_t(tiles), 0);
  tile_parent_.assign(size_t(tiles), kNoNode);
  tile_usage_.resize(size_t(tiles) - 1);
  for (uint32_t t = 1; t < tiles; ++t) tile_usage_[t - 1] = t;
  bricks_.reset(allocate_brick_pool(size_t(bricks) * kBrickVoxels * voxel_bytes_));
  if (options_.brick_bits == 8) brick_steps_.resize(size_t(bricks));
  brick_stamp_.assign(size_t(bricks), 0);
  brick_owner_.assign(size_t(bricks), kNoNode);
  brick_usage_.resize(size_t(bricks));
  for (uint32_t b = 0; b < bricks; ++b) brick_usage_[b] = b;
}

Aabb GigaVoxels::bounds() const {
  const Vec3 s{options_.size, options_.size, options_.size};
  return {options_.origin, options_.origin + s};
}

uint64_t GigaVoxels::node_pool_bytes() const {
  return uint64_t(tile_capacity()) * kTileBytes;
}

uint64_t GigaVoxels::brick_pool_bytes() const {
  return uint64_t(brick_capacity()) * brick_bytes(brick_bits());
}

NodeRegion GigaVoxels::region_of(uint32_t node) const {
  const uint32_t tile = node >> 3, c = node & 7u;
  if (tile == 0) return {};
  const uint32_t code = tile_code_[tile];
  return {int(tile_depth_[tile]), 2 * LocX::get(code) + (c & 1u),
          2 * LocY::get(code) + ((c >> 1) & 1u), 2 * LocZ::get(code) + (c >> 2)};
}

// Every ray writes the same value: a relaxed store, no read-modify-write,
// and only when the stamp differs. Rays touch the same tiles and bricks
// over and over (every descent passes the upper tiles, every span stamps
// its bricks); an unconditional store would dirty the line each time and,
// with two threads, bounce it between their caches, where a load of an
// already-stamped line stays shared.
void GigaVoxels::touch_tile(uint32_t tile, uint32_t s) const {
  std::atomic_ref<uint32_t> stamp(tile_stamp_[tile]);
  if (stamp.load(std::memory_order_relaxed) != s) stamp.store(s, std::memory_order_relaxed);
}
void GigaVoxels::touch_brick(uint32_t brick, uint32_t s) const {
  std::atomic_ref<uint32_t> stamp(brick_stamp_[brick]);
  if (stamp.load(std::memory_order_relaxed) != s) stamp.store(s, std::memory_order_relaxed);
}

void GigaVoxels::begin_frame(const FrameView& view) {
  frame_ = view.frame, pass_ = 0;
  passes_.clear();
}

// ---- Volume query ----

int GigaVoxels::march(const Ray& ray, float t_begin, const LodFootprint& lod, TraceContext& ctx,
                      std::span<VolumeSpan> out) const {
  if (out.empty()) return 0;
  // The ray in unit-cube coordinates (t stays the world t).
  const Vec3 o = (ray.origin - options_.origin) * inv_size_, d = ray.dir * inv_size_;
  float t0 = std::max(0.f, t_begin), t1 = ray.tmax;
  if (!detail::clip_unit_cube(o, d, &t0, &t1)) return 0;
  const uint32_t s = stamp(ctx.frame, ctx.pass);
  const int max_level = max_level_;
  // Each node is located from a point slightly past its entry, so that the
  // descent never picks the node the ray just left (progress is at least eps).
  const float eps =
      std::max(1e-3f * voxel_world(max_level), 4.f * std::numeric_limits<float>::epsilon() * t1);
  float inv_d[3];
  for (int a = 0; a < 3; ++a) inv_d[a] = d[a] != 0.f ? 1.f / d[a] : 0.f;
  // The path of the last descent (an accessor in NanoVDB's sense, local to
  // this call): path[l] is its node at level l, with[l] the deepest node with
  // data among path[0..l] (kNoNode: none) and cell its deepest cell. The
  // next node along the ray shares the ancestors whose cell holds the new
  // point: the descent resumes from the deepest of them instead of the root.
  uint32_t path[kMaxLevel + 1], with[kMaxLevel + 1], cell[3] = {0, 0, 0};
  int depth = 0;
  path[0] = 0;
  int n = 0;
  uint32_t fallback = kNoNode;  // the located node's deepest ancestor with data
  int fallback_level = 0;
  // The footprint never shrinks along the ray (no depth-of-field segment
  // before its focus): a condition of the empty-sibling jump below.
  const bool grows = lod.size_per_t >= 0.f;
  // All 8 nodes of tile t hold empty constants (no span, no request).
  auto empty_tile = [this](uint32_t t) {
    for (uint32_t n = t * 8; n < t * 8 + 8; ++n) {
      const uint32_t dw = data_[n];
      if (NodeDataKind::get(dw) != kDataConstant ||
          constants_[NodeDataPayload::get(dw)].density > 0.f)
        return false;
    }
    return true;
  };
  // Exit of the box [cell, cell + 1] / 2^level of the node `up` levels above
  // the path's node at `level` (cell >> up at level - up).
  auto box_exit = [&](int level, int up) {
    const float scale = pow2f(up - level);
    float te = t1;
    for (int a = 0; a < 3; ++a) {
      const uint32_t c = cell[a] >> up;
      if (d[a] > 0.f) te = std::min(te, (float(c + 1) * scale - o[a]) * inv_d[a]);
      if (d[a] < 0.f) te = std::min(te, (float(c) * scale - o[a]) * inv_d[a]);
    }
    return te;
  };
  auto locate = [&](float, const float* x, float foot) {
    // Descent by point location (§3.5.3): the child at level l + 1 is bit 0
    // of the cell floor(x 2^(l+1)), the paper's c + int(2x) unrolled.
    auto cell_at = [x](int a, int l) {
      return std::min(uint32_t(x[a] * pow2f(l)), (uint32_t(1) << l) - 1);
    };
    // Resume at the deepest common ancestor whose ancestors all still stand
    // above the cone's level (the footprint grows along the ray, so a level
    // where the descent stopped before may be where it stops now).
    int level = 0;
    if (depth > 0) {
      uint32_t diff = 0;
      for (int a = 0; a < 3; ++a) diff |= cell_at(a, depth) ^ cell[a];
      level = depth - int(std::bit_width(diff));
      while (level > 0 && voxel_world(level - 1) <= foot) --level;
      for (int a = 0; a < 3; ++a) cell[a] >>= (depth - level);
    }
    uint32_t node = path[level];
    fallback = level > 0 ? with[level - 1] : kNoNode;
    bool asked = false;
    for (;;) {
      const uint32_t kind = NodeDataKind::get(data_[node]);
      if (kind != kDataNone) fallback = node;
      path[level] = node, with[level] = fallback;
      const uint32_t cw = child_[node];
      if (voxel_world(level) <= foot || NodeTerminal::test(cw) || level >= max_level) break;
      const uint32_t tile = NodeChildTile::get(cw);
      if (tile == 0) {
        // §3.6.4: a node without data asks for data first (the producer may
        // find it constant or terminal); one with data asks to be subdivided.
        push_request(ctx, this, kind == kDataNone ? kRequestData : kRequestSubdivide, node, level);
        asked = true;
        break;
      }
      touch_tile(tile, s);
      // Empty below down to a level at least as fine as the cone's, and the
      // cone still finer than this node's voxel at the box's exit (the
      // footprint only grows): every descent inside the box would stop
      // between level + 1 and D on an empty constant, emit nothing and ask
      // for nothing, so the whole box is crossed at once. The exit is the
      // same plane the last of those descents would leave by.
      const int below = int(NodeEmptyBelow::get(cw));
      if (grows && below > level && voxel_world(below) <= foot) {
        const float te = box_exit(level, 0);
        if (lod.size_at_origin + lod.size_per_t * te < voxel_world(level)) {
          depth = level, fallback = kNoNode;  // emit() writes nothing
          return te;
        }
      }
      uint32_t c = 0;
      for (int a = 0; a < 3; ++a) {
        cell[a] = cell_at(a, level + 1);
        c |= (cell[a] & 1u) << a;
      }
      node = tile * 8 + c, ++level;
    }
    depth = level;
    fallback_level = 0;
    if (fallback != kNoNode)
      while (path[fallback_level] != fallback) ++fallback_level;
    if (fallback != node && !asked) push_request(ctx, this, kRequestData, node, level);
    // Empty space at the cone's level (most nodes a ray meets in a cloud's
    // surroundings): when the node and its 7 siblings are all empty
    // constants and the cone stays between the parent's voxel and theirs
    // until the parent's exit, every sibling the ray would visit next stops
    // at this level (the footprint only grows), emits nothing and asks for
    // nothing, so the walk jumps to the parent's exit at once: the same
    // spans for one locate instead of up to four (§3.5.1 skips empty space
    // by the octree's constant nodes; this skips where the octree keeps
    // empty leaves the producer could not prove empty at the coarser level).
    int exit_level = level;
    if (!asked && fallback == node && level > 0 && grows && voxel_world(level) <= foot &&
        empty_tile(node >> 3))
      exit_level = level - 1;
    // Exit of the parent's box (cell / 2)...
    float te = box_exit(level, level - exit_level);
    // ...and only if the cone does not reach the parent's voxel before it.
    if (exit_level < level && !(lod.size_at_origin + lod.size_per_t * te < voxel_world(exit_level)))
      te = box_exit(level, 0);
    return te;
  };
  auto emit = [&](float t, float te) {
    if (fallback != kNoNode) {
      const uint32_t dw = data_[fallback];
      VolumeSpan span;
      span.t0 = t, span.t1 = te, span.node = fallback, span.level = fallback_level;
      span.voxel_size = voxel_world(fallback_level);
      if (NodeDataKind::get(dw) == kDataConstant) {
        const VolumeSample& v = constants_[NodeDataPayload::get(dw)];
        span.constant = true;
        span.value = {v.density * inv_size_, v.color};
        if (v.density > 0.f) out[size_t(n++)] = span;  // empty space yields no span
      } else {
        touch_brick(NodeDataPayload::get(dw), s);
        out[size_t(n++)] = span;
      }
    }
    return n < int(out.size());
  };
  detail::walk_cells(o, d, t0, t1, eps, lod.size_at_origin, lod.size_per_t, locate, emit);
  return n;
}

VolumeSample GigaVoxels::node_value(uint32_t node, int level, const uint32_t cell[3], Vec3 q,
                                    TraceContext& ctx) const {
  const uint32_t dw = data_[node];
  const uint32_t kind = NodeDataKind::get(dw), payload = NodeDataPayload::get(dw);
  if (kind == kDataConstant) {
    const VolumeSample& v = constants_[payload];
    return {v.density * inv_size_, v.color};
  }
  touch_brick(payload, stamp(ctx.frame, ctx.pass));
  // Stored voxel i is centered at (i - 0.5) / M of the node.
  const float scale = pow2f(level);
  float u[3];
  for (int a = 0; a < 3; ++a) u[a] = (q[a] * scale - float(cell[a])) * float(kBrickSide) + 0.5f;
  float acc[4];
  if (brick_bits() == 8) {
    trilinear<8>(brick_data(payload), u, brick_steps_[payload].step, acc);
  } else {
    const float s = inv_voxel_side(level), scale[4] = {s, s, s, s};
    trilinear<16>(brick_data(payload), u, scale, acc);
  }
  return unpremultiply(acc, inv_size_);
}

VolumeSample GigaVoxels::sample(Vec3 p, float level, TraceContext& ctx,
                                const VolumeSpan* span) const {
  const Vec3 q = (p - options_.origin) * inv_size_;
  for (int a = 0; a < 3; ++a)
    if (!(q[a] >= 0.f && q[a] <= 1.f)) return {};
  const int max_level = max_level_;
  const float lv = std::clamp(level, 0.f, float(max_level));
  const int lo = int(std::floor(lv));
  const float f = lv - float(lo);
  const int want = f > 0.f ? lo + 1 : lo;  // the finer of the two levels

  // The nodes at levels `want` and want - 1 containing q: from the span's
  // node when it is the right one (no descent), else by descending.
  uint32_t fine = kNoNode, coarse = kNoNode;
  uint32_t fine_cell[3] = {0, 0, 0}, coarse_cell[3] = {0, 0, 0};
  int fine_level = 0, coarse_level = 0;
  if (span != nullptr && !span->constant && span->level == want && span->node != 0 &&
      span->node < child_.size()) {
    const uint32_t node = uint32_t(span->node);
    const NodeRegion r = region_of(node);
    const float scale = pow2f(r.level), margin = 0.5f / float(kBrickSide);
    const uint32_t rc[3] = {r.x, r.y, r.z};
    bool inside = NodeDataKind::get(data_[node]) != kDataNone;
    for (int a = 0; a < 3 && inside; ++a) {
      const float u = q[a] * scale - float(rc[a]);
      inside = u >= -margin && u <= 1.f + margin;
    }
    if (inside) {
      fine = node, fine_level = r.level;
      std::copy(rc, rc + 3, fine_cell);
      const uint32_t parent = tile_parent_[node >> 3];
      const NodeRegion pr = region_of(parent);
      coarse = parent, coarse_level = pr.level;
      coarse_cell[0] = pr.x, coarse_cell[1] = pr.y, coarse_cell[2] = pr.z;
    }
  }
  if (fine == kNoNode) {
    // Descend to `want`, remembering the deepest node with data and the
    // node one level above it (§3.5.4 keeps the last visited nodes).
    uint32_t node = 0, cell[3] = {0, 0, 0}, prev = kNoNode, prev_cell[3] = {0, 0, 0};
    float x[3] = {q.x, q.y, q.z};
    const uint32_t s = stamp(ctx.frame, ctx.pass);
    for (int l = 0;; ++l) {
      if (NodeDataKind::get(data_[node]) != kDataNone) {
        fine = node, fine_level = l;
        std::copy(cell, cell + 3, fine_cell);
        coarse = prev, coarse_level = l - 1;
        std::copy(prev_cell, prev_cell + 3, coarse_cell);
      }
      const uint32_t tile = NodeChildTile::get(child_[node]);
      if (l == want || tile == 0) break;
      touch_tile(tile, s);
      prev = node;
      std::copy(cell, cell + 3, prev_cell);
      uint32_t c = 0;
      for (int a = 0; a < 3; ++a) {
        const uint32_t b = child_bit(&x[a]);
        c |= b << a, cell[a] = 2 * cell[a] + b;
      }
      node = tile * 8 + c;
    }
    if (fine == kNoNode) return {};
  }
  const VolumeSample v1 = node_value(fine, fine_level, fine_cell, q, ctx);
  // Quadrilinear (§3.5.4, Listing 3.1): blend with the parent's brick when
  // the wanted level lies between them; a coarser answer stands alone.
  if (fine_level != want || f == 0.f || coarse == kNoNode) return v1;
  if (NodeDataKind::get(data_[coarse]) == kDataNone) {
    push_request(ctx, this, kRequestData, coarse, coarse_level);
    return v1;
  }
  const VolumeSample v0 = node_value(coarse, coarse_level, coarse_cell, q, ctx);
  // Blend extinction and extinction-weighted color (premultiplied, as in the bricks).
  const float d = (1.f - f) * v0.density + f * v1.density;
  VolumeSample out;
  out.density = d;
  if (d > 0.f) {
    const float w0 = (1.f - f) * v0.density / d, w1 = f * v1.density / d;
    out.color = {w0 * v0.color.r + w1 * v1.color.r, w0 * v0.color.g + w1 * v1.color.g,
                 w0 * v0.color.b + w1 * v1.color.b, 1.f};
  }
  return out;
}

void GigaVoxels::sample_span(const Ray& ray, const VolumeSpan& span, const float* t,
                             const float* level, int n, TraceContext& ctx,
                             VolumeSample* out) const {
  const uint32_t node = uint32_t(span.node);
  if (span.constant || span.node >= child_.size() || (node < 8 && node != 0) ||
      NodeDataKind::get(data_[node]) != kDataBrick) {
    VolumeQuery::sample_span(ray, span, t, level, n, ctx, out);
    return;
  }
  const uint32_t s = stamp(ctx.frame, ctx.pass);
  // One level's lookup along the ray as an affine map of t: stored
  // coordinate u_a(t) = A_a + B_a t (node_value's mapping with q = o + d t).
  struct Lookup {
    const unsigned char* brick = nullptr;  // null: constant `value`
    float value[4] = {0, 0, 0, 0};         // premultiplied, unit-cube density
    float A[3], B[3];
    float scale[4];  // per channel: inv_voxel_side of the level, or the brick's steps
  };
  const bool eight = brick_bits() == 8;
  const size_t vb = voxel_bytes_;
  const Vec3 o = (ray.origin - options_.origin) * inv_size_, d = ray.dir * inv_size_;
  auto prepare = [&](uint32_t nd, const NodeRegion& r, Lookup* lk) {
    const uint32_t dw = data_[nd];
    if (NodeDataKind::get(dw) == kDataConstant) {
      const VolumeSample& v = constants_[NodeDataPayload::get(dw)];
      lk->value[0] = v.density, lk->value[1] = v.color.r * v.density;
      lk->value[2] = v.color.g * v.density, lk->value[3] = v.color.b * v.density;
      return;
    }
    const uint32_t b = NodeDataPayload::get(dw);
    touch_brick(b, s);
    lk->brick = brick_data(b);
    if (eight)
      std::copy(brick_steps_[b].step, brick_steps_[b].step + 4, lk->scale);
    else
      std::fill(lk->scale, lk->scale + 4, inv_voxel_side(r.level));
    const float scale = pow2f(r.level) * float(kBrickSide);
    const uint32_t cell[3] = {r.x, r.y, r.z};
    for (int a = 0; a < 3; ++a) {
      lk->A[a] = o[a] * scale - float(cell[a]) * float(kBrickSide) + 0.5f;
      lk->B[a] = d[a] * scale;
    }
  };
  // A chunk's lookups of one level in two loops: first every point's
  // first voxel and weights (independent, branch-free arithmetic the
  // compiler vectorizes across points), then the loads and lerps; the
  // same operations on the same values as trilinear() per point.
  constexpr int kMaxPoints = 64;
  struct Cells {
    int32_t at[kMaxPoints];  // stored_index of the first voxel
    float f[3][kMaxPoints];  // weights of the next voxel along x, y, z
  };
  auto cells = [&](const Lookup& lk, const float* tp, int m, Cells* c) {
    if (lk.brick == nullptr) return;
#if defined(__AVX2__)
    // Eight points per step: cell_weight()'s operations lane by lane
    // (u = A + B t unfused, clamp as std::clamp orders it, truncation, the
    // integer part capped at M), the same values as the scalar loop below.
    const __m256 zero = _mm256_setzero_ps(), top = _mm256_set1_ps(float(kBrickSide + 1));
    const __m256i cap = _mm256_set1_epi32(kBrickSide),
                  lanes = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    for (int k = 0; k < m; k += 8) {
      const __m256i live = _mm256_cmpgt_epi32(_mm256_set1_epi32(m - k), lanes);
      const __m256 tk = _mm256_maskload_ps(tp + k, live);
      __m256i idx[3];
      for (int a = 0; a < 3; ++a) {
        const __m256 u =
            _mm256_add_ps(_mm256_set1_ps(lk.A[a]), _mm256_mul_ps(_mm256_set1_ps(lk.B[a]), tk));
        const __m256 cl = _mm256_min_ps(top, _mm256_max_ps(zero, u));
        idx[a] = _mm256_min_epi32(_mm256_cvttps_epi32(cl), cap);
        _mm256_storeu_ps(c->f[a] + k, _mm256_sub_ps(cl, _mm256_cvtepi32_ps(idx[a])));
      }
      const __m256i row = _mm256_set1_epi32(kBrickStored);
      const __m256i at = _mm256_add_epi32(
          idx[0],
          _mm256_mullo_epi32(row, _mm256_add_epi32(idx[1], _mm256_mullo_epi32(row, idx[2]))));
      _mm256_storeu_si256(reinterpret_cast<__m256i*>(c->at + k), at);
    }
#else
    for (int k = 0; k < m; ++k) {
      const float tk = tp[k];
      const int i = cell_weight(lk.A[0] + lk.B[0] * tk, &c->f[0][k]);
      const int j = cell_weight(lk.A[1] + lk.B[1] * tk, &c->f[1][k]);
      const int l = cell_weight(lk.A[2] + lk.B[2] * tk, &c->f[2][k]);
      c->at[k] = i + kBrickStored * (j + kBrickStored * l);
    }
#endif
  };
  auto prefetch = [vb](const Lookup& lk, const Cells& c, int m) {
#if defined(__AVX2__)
    if (lk.brick == nullptr) return;
    const size_t row = kBrickStored * vb, slice = row * kBrickStored;
    for (int k = 0; k < m; ++k) {
      const unsigned char* v = lk.brick + size_t(c.at[k]) * vb;
      for (size_t at : {size_t(0), row, slice, row + slice})
        ::voxcast::detail::prefetch_line(v + at);  // an asm hint GCC keeps
    }
#else
    (void)lk, (void)c, (void)m, (void)vb;
#endif
  };
  auto lookup = [eight](const Lookup& lk, const Cells& c, int k, float acc[4]) {
    if (lk.brick == nullptr) {
      std::copy(lk.value, lk.value + 4, acc);
      return;
    }
    const float f[3] = {c.f[0][k], c.f[1][k], c.f[2][k]};
    if (eight)
      trilinear_at<8>(lk.brick + size_t(c.at[k]) * kVoxelBytes<8>, f, lk.scale, acc);
    else
      trilinear_at<16>(lk.brick + size_t(c.at[k]) * kVoxelBytes<16>, f, lk.scale, acc);
  };
  // Weight of the fine level per point: level L - 1 + w blends the parent
  // (1 - w) with the node (w), as sample()'s quadrilinear filter. Only the
  // bricks some point reads are stamped as used (an unread parent stays
  // recyclable).
  // The node's region, and its parent's (the same cell halved, one level up).
  const NodeRegion region = region_of(node);
  const NodeRegion parent_region{region.level - 1, region.x >> 1, region.y >> 1, region.z >> 1};
  const int L = region.level;
  const float max_level = float(max_level_);
  float w[kMaxPoints];
  Cells fine_cells, coarse_cells;
  for (int k0 = 0; k0 < n; k0 += kMaxPoints) {
    const int m = std::min(kMaxPoints, n - k0);
    bool any_coarse = false, any_fine = false;
#if defined(__AVX2__)
    {
      // Eight points per step: std::clamp's max then min lane by lane
      // (max(lo, v) is lo > v ? lo : v, min(hi, v) is hi < v ? hi : v:
      // std::max(v, lo) and std::min(v, hi)), the same weights as the
      // scalar loop below; the lanes past m only pad w.
      const __m256 zero = _mm256_setzero_ps(), one = _mm256_set1_ps(1.f),
                   top = _mm256_set1_ps(max_level), below = _mm256_set1_ps(float(L - 1));
      const __m256i lanes = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
      __m256 coarse_lanes = zero, fine_lanes = zero;
      for (int k = 0; k < m; k += 8) {
        const __m256i live = _mm256_cmpgt_epi32(_mm256_set1_epi32(m - k), lanes);
        const __m256 lv =
            _mm256_min_ps(top, _mm256_max_ps(zero, _mm256_maskload_ps(level + k0 + k, live)));
        const __m256 wk =
            node != 0 ? _mm256_min_ps(one, _mm256_max_ps(zero, _mm256_sub_ps(lv, below))) : one;
        _mm256_storeu_ps(w + k, wk);
        const __m256 on = _mm256_castsi256_ps(live);
        coarse_lanes =
            _mm256_or_ps(coarse_lanes, _mm256_and_ps(on, _mm256_cmp_ps(wk, one, _CMP_LT_OQ)));
        fine_lanes =
            _mm256_or_ps(fine_lanes, _mm256_and_ps(on, _mm256_cmp_ps(wk, zero, _CMP_GT_OQ)));
      }
      any_coarse = _mm256_movemask_ps(coarse_lanes) != 0;
      any_fine = _mm256_movemask_ps(fine_lanes) != 0;
    }
#else
    for (int k = 0; k < m; ++k) {
      const float lv = std::clamp(level[k0 + k], 0.f, max_level);
      w[k] = node != 0 ? std::clamp(lv - float(L - 1), 0.f, 1.f) : 1.f;
      any_coarse |= w[k]<1.f, any_fine |= w[k]> 0.f;
    }
#endif
    Lookup fine, coarse;
    if (any_coarse) {
      const uint32_t parent = tile_parent_[node >> 3];
      if (NodeDataKind::get(data_[parent]) == kDataNone) {
        // Blends toward the parent wait for its data (sample() does the same).
        push_request(ctx, this, kRequestData, parent, L - 1);
        for (int k = 0; k < m; ++k) w[k] = 1.f;
        any_fine = true;
      } else {
        prepare(parent, parent_region, &coarse);
      }
    }
    if (any_fine) prepare(node, region, &fine), cells(fine, t + k0, m, &fine_cells);
    if (any_coarse) cells(coarse, t + k0, m, &coarse_cells);
    // Every row the chunk's lookups will read, requested at once: a warm
    // frame visits most resident bricks (hundreds of MB, beyond the caches)
    // and the profile's hottest instructions were the first loads of each
    // lookup waiting for memory; issued together the misses overlap.
    prefetch(fine, fine_cells, m);
    prefetch(coarse, coarse_cells, m);
#if defined(__AVX2__) && defined(__FMA__) && defined(__F16C__)
    // The same lookups and blend in registers: lookup()'s lanes, and
    // acc + w (a1 - acc) unfused, as the loop below.
    // The loop once per voxel format (a branch per lookup would sit in the
    // hot loop).
    auto blend = [&](auto bits) {
      constexpr int kBits = decltype(bits)::value;
      auto lookup_v = [](const Lookup& lk, const Cells& c, int k) {
        if (lk.brick == nullptr) return _mm_loadu_ps(lk.value);
        const float f[3] = {c.f[0][k], c.f[1][k], c.f[2][k]};
        return trilinear_v<kBits>(lk.brick + size_t(c.at[k]) * kVoxelBytes<kBits>, f,
                                  _mm_loadu_ps(lk.scale));
      };
      for (int k = 0; k < m; ++k) {
        __m128 acc;
        if (w[k] == 1.f) {
          acc = lookup_v(fine, fine_cells, k);
        } else if (w[k] == 0.f) {
          acc = lookup_v(coarse, coarse_cells, k);
        } else {
          const __m128 a1 = lookup_v(fine, fine_cells, k);
          acc = lookup_v(coarse, coarse_cells, k);
          acc = _mm_add_ps(acc, _mm_mul_ps(_mm_set1_ps(w[k]), _mm_sub_ps(a1, acc)));
        }
        unpremultiply_into(acc, inv_size_, &out[k0 + k]);
      }
    };
    if (eight)
      blend(std::integral_constant<int, 8>());
    else
      blend(std::integral_constant<int, 16>());
    (void)lookup;
#else
    for (int k = 0; k < m; ++k) {
      float acc[4];
      if (w[k] == 1.f) {
        lookup(fine, fine_cells, k, acc);
      } else if (w[k] == 0.f) {
        lookup(coarse, coarse_cells, k, acc);
      } else {
        float a1[4];
        lookup(fine, fine_cells, k, a1);
        lookup(coarse, coarse_cells, k, acc);
        for (int c = 0; c < 4; ++c) acc[c] += w[k] * (a1[c] - acc[c]);
      }
      unpremultiply_into(acc, inv_size_, &out[k0 + k]);
    }
#endif
  }
}

// ---- Serving requests (§3.6) ----

std::vector<uint32_t> GigaVoxels::tiles_by_depth() const {
  // Counting sort on the depth (at most kMaxLevel): tile order within a depth.
  size_t start[kMaxLevel + 2] = {};
  for (uint32_t t = 1; t < tile_parent_.size(); ++t)
    if (tile_parent_[t] != kNoNode) ++start[tile_depth_[t] + 1];
  for (int l = 0; l <= kMaxLevel; ++l) start[l + 1] += start[l];
  std::vector<uint32_t> order(start[kMaxLevel + 1]);
  for (uint32_t t = 1; t < tile_parent_.size(); ++t)
    if (tile_parent_[t] != kNoNode) order[start[tile_depth_[t]]++] = t;
  return order;
}

void GigaVoxels::stamp_empty_below(const std::vector<uint32_t>& order, uint32_t now) {
  // Shallowest first, so that a stamp propagates down the whole subtree.
  for (uint32_t t : order) {
    const uint32_t parent = tile_parent_[t], pt = parent >> 3;
    if (NodeEmptyBelow::get(child_[parent]) != 0 && (pt == 0 || tile_stamp_[pt] == now))
      tile_stamp_[t] = now;
  }
}

void GigaVoxels::update_empty_below(const std::vector<uint32_t>& order) {
  const int max_level = max_level_;
  for (uint32_t& w : child_) w = NodeEmptyBelow::set(w, 0);
  // Deepest first: a tile's nodes have their own summaries when the tile's
  // parent takes the smallest of them.
  for (auto it = order.rbegin(); it != order.rend(); ++it) {
    const uint32_t t = *it;
    const int level = tile_depth_[t];
    int deepest = kMaxLevel;  // how far all 8 nodes stay empty
    for (uint32_t node = t * 8; node < t * 8 + 8 && deepest >= level; ++node) {
      const uint32_t dw = data_[node], cw = child_[node];
      if (NodeDataKind::get(dw) != kDataConstant ||
          constants_[NodeDataPayload::get(dw)].density > 0.f) {
        deepest = -1;  // not empty: the parent has no summary
      } else if (!NodeTerminal::test(cw) && level < max_level) {
        // Empty here; below, as far as its own summary reaches (a node
        // without children: only its own level, the descent would ask).
        deepest = std::min(deepest, std::max(level, int(NodeEmptyBelow::get(cw))));
      }
    }
    if (deepest >= level) {
      uint32_t& pw = child_[tile_parent_[t]];
      pw = NodeEmptyBelow::set(pw, uint32_t(deepest));
    }
  }
}

PassOutcome GigaVoxels::end_pass(std::span<const Request> requests) {
  const uint32_t now = stamp(frame_, pass_);
  GigaPassStats st;
  std::vector<uint32_t> scratch;
  stamp_empty_below(tiles_by_depth(), now);
  // LRU: used elements to the back, order kept (§3.6.2).
  const size_t free_tiles = lru_compact(&tile_usage_, tile_stamp_, now, &scratch);
  const size_t free_bricks = lru_compact(&brick_usage_, brick_stamp_, now, &scratch);
  st.tiles_used = tile_usage_.size() - free_tiles;
  st.bricks_used = brick_usage_.size() - free_bricks;

  // Valid requests, most urgent (coarsest) first (§3.6.1: top-down refinement).
  const int max_level = max_level_;
  std::vector<Request> data, subdivide;
  for (const Request& r : requests) {
    if (r.key >= child_.size()) continue;
    const uint32_t node = uint32_t(r.key), tile = node >> 3;
    if (tile == 0 ? node != 0 : tile_parent_[tile] == kNoNode) continue;
    const uint32_t kind = NodeDataKind::get(data_[node]);
    if (r.kind == kRequestData && kind == kDataNone) data.push_back(r);
    if (r.kind == kRequestSubdivide && kind != kDataNone && NodeChildTile::get(child_[node]) == 0 &&
        !NodeTerminal::test(child_[node]) && region_of(node).level < max_level)
      subdivide.push_back(r);
  }
  auto urgent_first = [](const Request& a, const Request& b) {
    return a.priority != b.priority ? a.priority > b.priority : a.key < b.key;
  };
  std::sort(data.begin(), data.end(), urgent_first);
  std::sort(subdivide.begin(), subdivide.end(), urgent_first);
  st.data_requests = data.size(), st.subdivide_requests = subdivide.size();
  if (data.size() > options_.max_data_per_pass) {
    st.pending += data.size() - options_.max_data_per_pass;
    data.resize(options_.max_data_per_pass);
  }

  // The producer fills bricks on worker threads and decides constant vs brick (§3.6.7).
  std::vector<BrickVoxel> produced_voxels(data.size() * size_t(kBrickVoxels));
  std::vector<Produced> produced(data.size());
  tbb::parallel_for(
      tbb::blocked_range<size_t>(0, data.size(), 1), [&](const tbb::blocked_range<size_t>& r) {
        for (size_t i = r.begin(); i != r.end(); ++i)
          produced[i] =
              producer_->produce(region_of(uint32_t(data[i].key)),
                                 std::span(&produced_voxels[i * kBrickVoxels], kBrickVoxels));
      });
  size_t bricks_needed = 0;
  for (const Produced& p : produced) bricks_needed += !p.constant;
  const size_t new_bricks = std::min(bricks_needed, free_bricks);
  const size_t new_tiles = std::min(subdivide.size(), free_tiles);
  st.pending += (bricks_needed - new_bricks) + (subdivide.size() - new_tiles);

  // Two-step invalidation (§3.6.2, Figure 3.19). Step 1: zero the timestamps
  // of what is recycled: the front of each usage list, and with a recycled
  // tile its whole subtree (descendants of a tile unused in this pass are
  // unused too) and the subtree's bricks.
  std::vector<uint32_t> freed_tiles;
  std::vector<uint8_t> is_freed(new_tiles > 0 ? tile_parent_.size() : 0, 0);
  for (size_t i = 0; i < new_tiles; ++i) {
    const uint32_t t = tile_usage_[i];
    if (tile_parent_[t] != kNoNode) ++st.recycled_tiles;
    if (!is_freed[t]) freed_tiles.push_back(t), is_freed[t] = 1;
  }
  for (size_t i = 0; i < freed_tiles.size(); ++i) {
    const uint32_t t = freed_tiles[i];
    tile_stamp_[t] = 0;
    if (tile_parent_[t] == kNoNode) continue;
    for (uint32_t c = 0; c < 8; ++c) {
      const uint32_t node = t * 8 + c;
      if (NodeDataKind::get(data_[node]) == kDataBrick) {
        const uint32_t b = NodeDataPayload::get(data_[node]);
        brick_stamp_[b] = 0, brick_owner_[b] = kNoNode;
      }
      const uint32_t ct = NodeChildTile::get(child_[node]);
      if (ct != 0 && !is_freed[ct]) freed_tiles.push_back(ct), is_freed[ct] = 1;
    }
  }
  for (size_t i = 0; i < new_bricks; ++i) {
    const uint32_t b = brick_usage_[i];
    if (brick_owner_[b] != kNoNode) ++st.recycled_bricks;
    brick_stamp_[b] = 0;
  }
  // Step 2: every allocated node's pointer to a zero-stamped element is nulled.
  if (new_tiles + new_bricks > 0)
    tbb::parallel_for(tbb::blocked_range<size_t>(0, tile_parent_.size(), 1024),
                      [&](const tbb::blocked_range<size_t>& r) {
                        for (size_t t = r.begin(); t != r.end(); ++t) {
                          if (t != 0 && tile_parent_[t] == kNoNode) continue;
                          for (size_t node = t * 8; node < t * 8 + 8; ++node) {
                            const uint32_t ct = NodeChildTile::get(child_[node]);
                            if (ct != 0 && tile_stamp_[ct] == 0)
                              child_[node] = NodeChildTile::set(child_[node], 0);
                            if (NodeDataKind::get(data_[node]) == kDataBrick &&
                                brick_stamp_[NodeDataPayload::get(data_[node])] == 0)
                              data_[node] = 0;
                          }
                        }
                      });
  for (uint32_t t : freed_tiles) {
    std::fill_n(&child_[size_t(t) * 8], 8, 0u);
    std::fill_n(&data_[size_t(t) * 8], 8, 0u);
    tile_parent_[t] = kNoNode;
  }
  for (size_t i = 0; i < new_bricks; ++i) brick_owner_[brick_usage_[i]] = kNoNode;

  // Data first (§3.6.5), then subdivisions; the new elements move to the
  // back of their usage lists, as if just used.
  bool changed = false;
  size_t next_brick = 0;
  for (size_t i = 0; i < data.size(); ++i) {
    const uint32_t node = uint32_t(data[i].key);
    if ((node >> 3) != 0 && tile_parent_[node >> 3] == kNoNode) continue;  // freed above
    const Produced& p = produced[i];
    uint32_t word;
    if (p.constant) {
      const auto same = [&](const VolumeSample& c) {
        return c.density == p.value.density && c.color.r == p.value.color.r &&
               c.color.g == p.value.color.g && c.color.b == p.value.color.b;
      };
      auto it = std::find_if(constants_.begin(), constants_.end(), same);
      if (it == constants_.end()) {
        if (constants_.size() > NodeDataPayload::max) continue;
        constants_.push_back(p.value);
        it = constants_.end() - 1;
      }
      word = NodeDataKind::put(kDataConstant) |
             NodeDataPayload::put(uint32_t(it - constants_.begin()));
      ++st.constants;
    } else {
      if (next_brick == new_bricks) continue;  // pending: no brick left in this pass
      const uint32_t b = brick_usage_[next_brick++];
      const BrickVoxel* in = &produced_voxels[i * kBrickVoxels];
      unsigned char* out = brick_data(b);
      if (brick_bits() == 8)
        encode_brick8(in, region_of(node).level, reinterpret_cast<PoolVoxel8*>(out),
                      &brick_steps_[b]);
      else
        encode_brick(in, region_of(node).level, reinterpret_cast<PoolVoxel*>(out));
      brick_owner_[b] = node, brick_stamp_[b] = now;
      word = NodeDataKind::put(kDataBrick) | NodeDataPayload::put(b);
      ++st.bricks_uploaded;
    }
    data_[node] = word;
    if (p.terminal) child_[node] = NodeTerminal::set(child_[node], 1);
    changed = true;
  }
  std::rotate(brick_usage_.begin(), brick_usage_.begin() + std::ptrdiff_t(next_brick),
              brick_usage_.end());
  size_t next_tile = 0;
  for (size_t i = 0; i < new_tiles; ++i) {
    const uint32_t node = uint32_t(subdivide[i].key);
    if ((node >> 3) != 0 && tile_parent_[node >> 3] == kNoNode) continue;
    if (NodeChildTile::get(child_[node]) != 0) continue;
    const uint32_t t = tile_usage_[next_tile++];
    const NodeRegion r = region_of(node);
    tile_parent_[t] = node, tile_stamp_[t] = now;
    tile_code_[t] = LocX::put(r.x) | LocY::put(r.y) | LocZ::put(r.z);
    tile_depth_[t] = uint8_t(r.level + 1);
    child_[node] = NodeChildTile::set(child_[node], t);
    ++st.subdivisions, changed = true;
  }
  std::rotate(tile_usage_.begin(), tile_usage_.begin() + std::ptrdiff_t(next_tile),
              tile_usage_.end());
  // Freed elements not reused are at the front already (they were the oldest).
  update_empty_below(tiles_by_depth());

  for (uint32_t t = 1; t < tile_parent_.size(); ++t)
    st.tiles_resident += tile_parent_[t] != kNoNode;
  for (uint32_t owner : brick_owner_) st.bricks_resident += owner != kNoNode;
  passes_.push_back(st);
  ++pass_;
  if (options_.check_after_pass) {
    const std::string problem = validate();
    if (!problem.empty())
      throw Error("gigavoxels: after pass " + std::to_string(pass_) + ": " + problem);
  }
  PassOutcome out;
  out.changed = changed;
  out.served = st.bricks_uploaded + st.constants + st.subdivisions;
  out.pending = st.pending;
  return out;
}

// ---- Checks and introspection ----

std::string GigaVoxels::validate() const {
  const uint32_t tiles = tile_capacity(), bricks = brick_capacity();
  auto allocated = [&](uint32_t t) { return t == 0 || tile_parent_[t] != kNoNode; };
  for (uint32_t t = 0; t < tiles; ++t) {
    for (uint32_t c = 0; c < 8; ++c) {
      const uint32_t node = t * 8 + c;
      // Built only for a message: a string per node made validate() slow on
      // pools of millions of nodes.
      auto where = [node] { return "node " + std::to_string(node); };
      if (!allocated(t) || (t == 0 && c != 0)) {
        if (child_[node] != 0 || data_[node] != 0) return where() + " of a free tile has pointers";
        continue;
      }
      const uint32_t ct = NodeChildTile::get(child_[node]);
      if (ct != 0) {
        if (ct >= tiles || !allocated(ct)) return where() + " points to a free tile";
        if (tile_parent_[ct] != node) return where() + " points to another node's tile";
        if (tile_stamp_[ct] == 0) return where() + " points to an invalidated tile";
        const NodeRegion r = region_of(node);
        const uint32_t code = tile_code_[ct];
        if (tile_depth_[ct] != r.level + 1 || LocX::get(code) != r.x || LocY::get(code) != r.y ||
            LocZ::get(code) != r.z)
          return where() + ": child tile's localization code is not the node's";
      }
      const uint32_t dw = data_[node];
      const uint32_t kind = NodeDataKind::get(dw), payload = NodeDataPayload::get(dw);
      if (kind == kDataBrick) {
        if (payload >= bricks) return where() + " points past the brick pool";
        if (brick_owner_[payload] != node) return where() + " points to another node's brick";
        if (brick_stamp_[payload] == 0) return where() + " points to an invalidated brick";
      } else if (kind == kDataConstant) {
        if (payload >= constants_.size()) return where() + " names a missing constant";
      } else if (kind != kDataNone) {
        return where() + " has an unknown data kind";
      }
    }
  }
  for (uint32_t t = 1; t < tiles; ++t)
    if (allocated(t) && NodeChildTile::get(child_[tile_parent_[t]]) != t)
      return "tile " + std::to_string(t) + " is not its parent's child (orphan)";
  for (uint32_t b = 0; b < bricks; ++b) {
    const uint32_t owner = brick_owner_[b];
    if (owner != kNoNode &&
        (owner >= data_.size() ||
         data_[owner] != (NodeDataKind::put(kDataBrick) | NodeDataPayload::put(b))))
      return "brick " + std::to_string(b) + " is not its owner's brick";
  }
  auto permutation = [](const std::vector<uint32_t>& list, uint32_t first, uint32_t end) {
    std::vector<uint8_t> seen(end, 0);
    if (list.size() != end - first) return false;
    for (uint32_t e : list) {
      if (e < first || e >= end || seen[e]) return false;
      seen[e] = 1;
    }
    return true;
  };
  // The empty-below summaries, recomputed top-down by recursion (end_pass
  // builds them bottom-up): how deep the subtree of an empty node stays
  // empty and resident (-1: the node is not empty).
  // Memoized per node (each node's answer is asked by its parent's check
  // and by every ancestor's recursion: without it the checks cost the sum
  // of all subtree sizes).
  const int max_level = max_level_;
  constexpr int kUnknown = std::numeric_limits<int>::min();
  std::vector<int> empty_memo(child_.size(), kUnknown);
  auto empty_to = [&](auto&& self, uint32_t node, int level) -> int {
    int& memo = empty_memo[node];
    if (memo != kUnknown) return memo;
    const uint32_t dw = data_[node], cw = child_[node];
    if (NodeDataKind::get(dw) != kDataConstant ||
        constants_[NodeDataPayload::get(dw)].density > 0.f)
      return memo = -1;
    if (NodeTerminal::test(cw) || level >= max_level) return memo = kMaxLevel;
    const uint32_t ct = NodeChildTile::get(cw);
    int deepest = kMaxLevel;
    for (uint32_t c = 0; c < 8 && ct != 0; ++c)
      deepest = std::min(deepest, self(self, ct * 8 + c, level + 1));
    return memo = ct == 0 ? level : std::max(level, deepest);
  };
  for (uint32_t t = 0; t < tiles; ++t) {
    if (!allocated(t)) continue;
    for (uint32_t node = t * 8; node < (t == 0 ? 1u : t * 8 + 8); ++node) {
      const uint32_t ct = NodeChildTile::get(child_[node]);
      const int level = region_of(node).level;
      int expect = ct != 0 ? kMaxLevel : 0;
      for (uint32_t c = 0; c < 8 && ct != 0; ++c)
        expect = std::min(expect, empty_to(empty_to, ct * 8 + c, level + 1));
      if (int(NodeEmptyBelow::get(child_[node])) != std::max(expect, 0))
        return "node " + std::to_string(node) + ": empty-below summary " +
               std::to_string(NodeEmptyBelow::get(child_[node])) + ", expected " +
               std::to_string(std::max(expect, 0));
    }
  }
  if (!permutation(tile_usage_, 1, tiles)) return "the tile usage list is not a permutation";
  if (!permutation(brick_usage_, 0, bricks)) return "the brick usage list is not a permutation";
  return {};
}

size_t GigaVoxels::empty_below_nodes() const {
  size_t n = 0;
  for (uint32_t w : child_) n += NodeEmptyBelow::get(w) != 0;
  return n;
}

std::vector<GigaVoxels::ResidentBrick> GigaVoxels::resident_bricks() const {
  std::vector<ResidentBrick> out;
  for (uint32_t b = 0; b < brick_capacity(); ++b)
    if (brick_owner_[b] != kNoNode) {
      ResidentBrick rb{b, brick_owner_[b], region_of(brick_owner_[b]), {}};
      const unsigned char* in = brick_data(b);
      rb.voxels.resize(kBrickVoxels);
      if (brick_bits() == 8) {
        const float* st = brick_steps_[b].step;
        for (int i = 0; i < kBrickVoxels; ++i, in += kVoxelBytes<8>)
          rb.voxels[size_t(i)] = {pool_channel<8>(in, 0) * st[0], pool_channel<8>(in, 1) * st[1],
                                  pool_channel<8>(in, 2) * st[2], pool_channel<8>(in, 3) * st[3]};
      } else {
        const float s = inv_voxel_side(rb.region.level);
        for (int i = 0; i < kBrickVoxels; ++i, in += kVoxelBytes<16>)
          rb.voxels[size_t(i)] = {pool_channel<16>(in, 0) * s, pool_channel<16>(in, 1) * s,
                                  pool_channel<16>(in, 2) * s, pool_channel<16>(in, 3) * s};
      }
      out.push_back(std::move(rb));
    }
  return out;
}

}  // namespace voxcast::giga
