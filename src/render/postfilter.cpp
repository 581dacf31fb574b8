// Adaptive post-process filter (Laine & Karras 2010, §6.3, Figures 17-19).
//
// The renderer stores, per pixel, the projected size of the hit voxel as a
// one-byte log2 value in 3.5 fixed point (the paper's alpha channel). The
// filter blurs each pixel with a sparse, distance-ordered kernel whose radius
// starts at the pixel's own voxel size and is clamped to every neighbor's
// radius as the kernel is walked outwards (Figure 19). The clamp makes the
// radius agree between nearby regions, so a change of octree level does not
// produce a seam (Figure 17c vs 17d); misses carry radius 1, so the blur stops
// at silhouettes instead of mixing in the background.
#include <tbb/blocked_range2d.h>
#include <tbb/parallel_for.h>
#include <tbb/partitioner.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>
#include <span>
#include <string>
#include <vector>

#include "voxcast/error.hpp"
#include "voxcast/render.hpp"

namespace voxcast {

namespace {

// Kernel construction (§6.3: "96 samples distributed in a disc with radius of
// 24 pixels. The density of the samples falls as the square root of distance
// from the center, and each sample has an associated weight corresponding to
// the area of the disc it represents").
//
// Density rho(d) ∝ d^-1/2 means the number of samples within distance d is
//   N(d) = ∫ rho(s) 2πs ds ∝ d^(3/2),   so   N(d) = 96 (d / 24)^(3/2).
// The disc is cut into 96 annuli at the radii b_k = 24 (k/96)^(2/3), k = 0..96,
// each holding one sample (the same count per annulus is what realizes the
// density). Sample 0 sits in the center and stands for the inner disc
// [0, b_1]; sample i >= 1 sits at the radius that splits its annulus
// [b_i, b_i+1] in half by count, 24 ((i + 1/2) / 96)^(2/3), at the golden
// angle i * 137.5° (consecutive annuli are rotated so the samples do not line
// up into spokes). Its weight is the annulus area π (b_i+1² - b_i²): the area
// of the disc the sample represents; the weights sum to π 24² exactly.
//
// The filter fetches whole pixels (Figure 19, line 5), so each position is
// snapped to the nearest lattice point that is not taken yet and lies inside
// the disc; the distance stored in the table is that of the snapped offset,
// and the table is sorted by it (ascending, Figure 18), ties by construction
// order. Everything is deterministic: no random numbers, fixed iteration order.
std::array<PostFilterSample, kPostFilterSamples> build_kernel() {
  constexpr int N = kPostFilterSamples;
  constexpr double R = kPostFilterRadius;
  const double golden_angle = std::numbers::pi * (3.0 - std::sqrt(5.0));
  auto boundary = [&](int k) { return R * std::pow(double(k) / N, 2.0 / 3.0); };

  std::array<PostFilterSample, N> samples{};
  std::array<int, N> order{};
  const int side = 2 * int(R) + 1;
  std::vector<bool> taken(size_t(side) * side, false);
  auto is_taken = [&](int dx, int dy) -> std::vector<bool>::reference {
    return taken[size_t(dy + int(R)) * side + size_t(dx + int(R))];
  };
  for (int i = 0; i < N; ++i) {
    const double b0 = i == 0 ? 0.0 : boundary(i), b1 = boundary(i + 1);
    const double weight = std::numbers::pi * (b1 * b1 - b0 * b0);
    const double radius = i == 0 ? 0.0 : R * std::pow((i + 0.5) / N, 2.0 / 3.0);
    const double px = radius * std::cos(i * golden_angle), py = radius * std::sin(i * golden_angle);
    // Nearest free lattice point inside the disc (search a growing square).
    int best_x = 0, best_y = 0;
    double best = INFINITY;
    for (int reach = 1; !std::isfinite(best); ++reach) {
      const int cx = int(std::lround(px)), cy = int(std::lround(py));
      for (int dy = cy - reach; dy <= cy + reach; ++dy) {
        for (int dx = cx - reach; dx <= cx + reach; ++dx) {
          if (double(dx) * dx + double(dy) * dy > R * R || is_taken(dx, dy)) continue;
          const double e = (dx - px) * (dx - px) + (dy - py) * (dy - py);
          if (e < best) best = e, best_x = dx, best_y = dy;
        }
      }
    }
    is_taken(best_x, best_y) = true;
    samples[i].dx = best_x;
    samples[i].dy = best_y;
    samples[i].dist = float(std::sqrt(double(best_x) * best_x + double(best_y) * best_y));
    samples[i].weight = float(weight);
    order[i] = i;
  }
  std::stable_sort(order.begin(), order.end(),
                   [&](int a, int b) { return samples[a].dist < samples[b].dist; });
  std::array<PostFilterSample, N> sorted{};
  for (int i = 0; i < N; ++i) sorted[i] = samples[order[i]];
  return sorted;
}

// Decoded radius per code: r = 2^(code / 32) (3.5 fixed point, §6.3).
std::array<float, 256> build_radius_table() {
  std::array<float, 256> table{};
  for (int c = 0; c < 256; ++c) table[c] = float(std::exp2(double(c) / 32.0));
  return table;
}

}  // namespace

std::span<const PostFilterSample> post_filter_kernel() {
  static const std::array<PostFilterSample, kPostFilterSamples> kernel = build_kernel();
  return kernel;
}

uint8_t encode_filter_radius(float pixels) {
  if (!(pixels > 1.f)) return 0;  // <= 1 pixel or NaN: no blur
  const double code = std::round(std::log2(double(pixels)) * 32.0);
  return code >= 255.0 ? uint8_t(255) : uint8_t(code);  // +inf lands here too
}

float decode_filter_radius(uint8_t code) {
  static const std::array<float, 256> table = build_radius_table();
  return table[code];
}

namespace {

// Figure 19 for one pixel. NC: channel count known at compile time (0 =
// use `channels`); Checked: the pixel is closer than the kernel radius to
// the image border, so every sample is bounds-checked (samples outside the
// image are skipped). Accumulates in double in a fixed order, so the result
// depends only on the input, not on how rows are split among threads.
template <int NC, bool Checked>
void filter_pixel(const float* color, const uint8_t* code, const float* radius_of,
                  std::span<const PostFilterSample> kernel, const ptrdiff_t* offset, int W, int H,
                  int channels, int x, int y, float* out) {
  const int C = NC > 0 ? NC : channels;
  const size_t index = size_t(y) * W + x;
  const float* c = color + index * C;
  float r = radius_of[code[index]];  // line 1
  if (r <= 1.f) {                    // line 2: no filtering needed
    for (int k = 0; k < C; ++k) out[k] = c[k];
    return;
  }
  double accum[NC > 0 ? NC : 1] = {};
  std::vector<double> accum_dyn(NC > 0 ? 0 : C, 0.0);
  double* a = NC > 0 ? accum : accum_dyn.data();
  double accum_w = 0.0;
  for (size_t i = 0; i < kernel.size(); ++i) {  // line 4, ascending distance
    const PostFilterSample& s = kernel[i];
    if (s.dist > r) break;  // r only shrinks: no later sample can count
    if constexpr (Checked) {
      const int sx = x + s.dx, sy = y + s.dy;
      if (sx < 0 || sy < 0 || sx >= W || sy >= H) continue;  // outside the image
    }
    const size_t n = size_t(ptrdiff_t(index) + offset[i]);  // line 5
    r = std::min(r, radius_of[code[n]]);                    // line 6
    if (s.dist > r) break;                                  // line 7
    // Line 8: taper linearly to zero between r - 1 and r.
    const double w = double(s.weight) * double(std::min(r - s.dist, 1.f));
    const float* cn = color + n * C;
    for (int k = 0; k < C; ++k) a[k] += double(cn[k]) * w;  // line 9
    accum_w += w;                                           // line 10
  }
  // The center sample (distance 0, r > 1) always contributes: accum_w > 0.
  for (int k = 0; k < C; ++k) out[k] = float(a[k] / accum_w);  // line 12
}

// The RGB case, which the renderer uses: color and radius packed into one
// 16-byte texel like the paper's RGBA image with the radius in alpha (§6.3),
// so each sample touches one cache line instead of two, and the four lanes
// accumulate together. Float accumulation in the fixed kernel order keeps
// the result independent of the thread split.
struct alignas(16) Texel {
  float v[4];  // r, g, b, filter radius in pixels
};

template <bool Checked>
void filter_texel(const Texel* texels, std::span<const PostFilterSample> kernel,
                  const ptrdiff_t* offset, int W, int H, int x, int y, float* out) {
  const size_t index = size_t(y) * W + x;
  const Texel& t = texels[index];
  float r = t.v[3];  // line 1
  if (r <= 1.f) {    // line 2
    out[0] = t.v[0], out[1] = t.v[1], out[2] = t.v[2];
    return;
  }
  float a[4] = {0.f, 0.f, 0.f, 0.f};
  float accum_w = 0.f;
  for (size_t i = 0; i < kernel.size(); ++i) {  // line 4
    const PostFilterSample& s = kernel[i];
    if (s.dist > r) break;
    if constexpr (Checked) {
      const int sx = x + s.dx, sy = y + s.dy;
      if (sx < 0 || sy < 0 || sx >= W || sy >= H) continue;
    }
    const Texel& n = texels[size_t(ptrdiff_t(index) + offset[i])];  // line 5
    r = std::min(r, n.v[3]);                                        // line 6
    if (s.dist > r) break;                                          // line 7
    const float w = s.weight * std::min(r - s.dist, 1.f);           // line 8
    for (int k = 0; k < 4; ++k) a[k] += n.v[k] * w;                 // line 9 (lane 3 unused)
    accum_w += w;                                                   // line 10
  }
  // The center sample always counts, so accum_w > 0.
  for (int k = 0; k < 3; ++k) out[k] = a[k] / accum_w;  // line 12
}

}  // namespace

Image post_filter(const Image& color, const std::vector<uint8_t>& radius_code, int threads) {
  const int W = color.width, H = color.height, C = color.channels;
  if (W < 0 || H < 0 || C <= 0 || color.pixels.size() != size_t(W) * size_t(H) * size_t(C))
    throw Error("post_filter: malformed color image");
  if (radius_code.size() != size_t(W) * size_t(H))
    throw Error("post_filter: radius codes (" + std::to_string(radius_code.size()) +
                ") do not match the image (" + std::to_string(W) + "x" + std::to_string(H) + ")");
  if (threads < 0) throw Error("post_filter: threads must be >= 0");

  const std::span<const PostFilterSample> kernel = post_filter_kernel();
  std::array<float, 256> radius_of;
  for (int c = 0; c < 256; ++c) radius_of[c] = decode_filter_radius(uint8_t(c));
  std::array<ptrdiff_t, kPostFilterSamples> offset;  // pixel index deltas
  for (size_t i = 0; i < kernel.size(); ++i) offset[i] = ptrdiff_t(kernel[i].dy) * W + kernel[i].dx;
  Image out(W, H, C);

  std::vector<Texel> texels;
  if (C == 3) {
    texels.resize(size_t(W) * H);
    for (size_t i = 0; i < texels.size(); ++i) {
      const float* c = &color.pixels[i * 3];
      texels[i] = Texel{{c[0], c[1], c[2], radius_of[radius_code[i]]}};
    }
  }

  // Tiles of 64x16 pixels: a tile's samples (kernel radius 24 around it) stay
  // within ~110 KB of texels, which fits in L2; whole rows would not.
  auto filter_tiles = [&](const tbb::blocked_range2d<int>& tile) {
    constexpr int R = kPostFilterRadius;
    const float* in = color.pixels.data();
    const uint8_t* code = radius_code.data();
    auto run = [&]<int NC>() {
      for (int y = tile.rows().begin(); y != tile.rows().end(); ++y) {
        const bool row_inside = y >= R && y < H - R;
        for (int x = tile.cols().begin(); x != tile.cols().end(); ++x) {
          float* o = out.at(x, y);
          const bool inside = row_inside && x >= R && x < W - R;
          if constexpr (NC == 3) {
            if (inside)
              filter_texel<false>(texels.data(), kernel, offset.data(), W, H, x, y, o);
            else
              filter_texel<true>(texels.data(), kernel, offset.data(), W, H, x, y, o);
          } else if (inside) {
            filter_pixel<NC, false>(in, code, radius_of.data(), kernel, offset.data(), W, H, C, x,
                                    y, o);
          } else {
            filter_pixel<NC, true>(in, code, radius_of.data(), kernel, offset.data(), W, H, C, x, y,
                                   o);
          }
        }
      }
    };
    if (C == 3)
      run.template operator()<3>();
    else if (C == 1)
      run.template operator()<1>();
    else
      run.template operator()<0>();
  };
  const tbb::blocked_range2d<int> all(0, H, 16, 0, W, 64);
  auto go = [&] { tbb::parallel_for(all, filter_tiles, tbb::simple_partitioner()); };
  if (threads > 0) {
    tbb::task_arena arena(threads);
    arena.execute(go);
  } else {
    go();
  }
  return out;
}

}  // namespace voxcast
