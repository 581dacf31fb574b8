// The frame loop of integrator.hpp against a toy streaming structure whose
// answers are known exactly: a plane of N x N cells, each either resident
// (the ray hits it) or not (the ray misses and asks for it). Checks the
// pass loop's contract: one-pass mode serves requests after the pass,
// exact mode runs until nothing is missing, only tiles that asked are
// rendered again, requests reach end_pass sorted and deduplicated, and the
// result does not depend on the thread count.
#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <set>
#include <vector>

#include "voxcast/integrator.hpp"

namespace voxcast {
namespace {

constexpr int kCells = 8;  // the plane z = 0, x, y in [0, 1), kCells^2 cells

class StreamingPlane final : public Structure, public SurfaceQuery {
 public:
  explicit StreamingPlane(int per_pass) : per_pass_(per_pass), resident_(kCells * kCells, 0) {}
  std::string name() const override { return "plane"; }
  Aabb bounds() const override { return Aabb{{0, 0, 0}, {1, 1, 0}}; }
  const SurfaceQuery* surface() const override { return this; }

  bool trace(const Ray& ray, const LodFootprint&, TraceContext& ctx, SurfaceHit* hit,
             const BeamStart*) const override {
    if (ray.dir.z == 0.f) return false;
    const float t = -ray.origin.z / ray.dir.z;
    if (!(t >= 0.f && t <= ray.tmax)) return false;
    const Vec3 p = ray.origin + ray.dir * t;
    if (!(p.x >= 0.f && p.x < 1.f && p.y >= 0.f && p.y < 1.f)) return false;
    const int cell = int(p.y * kCells) * kCells + int(p.x * kCells);
    if (ctx.counting) ++ctx.counters.iterations;  // one per ray that reaches the plane
    if (!resident_[size_t(cell)]) {
      ctx.requests.push(0, uint64_t(cell), 1.f);
      return false;
    }
    hit->t = t, hit->position = p, hit->voxel_ref = uint64_t(cell);
    return true;
  }
  void attributes(const SurfaceHit& hit, TraceContext&, Color* color, Vec3* normal) const override {
    *color = Color{float(hit.voxel_ref), 0.f, 0.f, 1.f};
    *normal = {0, 0, 1};
  }
  PassOutcome end_pass(std::span<const Request> requests) override {
    seen.emplace_back(requests.begin(), requests.end());
    PassOutcome out;
    for (const Request& r : requests) {
      if (out.served == uint64_t(per_pass_)) {
        ++out.pending;
        continue;
      }
      resident_[size_t(r.key)] = 1, ++out.served, out.changed = true;
    }
    return out;
  }
  int resident_count() const { return int(std::count(resident_.begin(), resident_.end(), 1)); }
  std::vector<std::vector<Request>> seen;

 private:
  int per_pass_;
  std::vector<uint8_t> resident_;
};

/// Writes the hit cell + 1 (0 on a miss) and counts rendered tiles.
class CellIntegrator final : public Integrator {
 public:
  uint32_t aovs() const override { return kAovColor | kAovDepth; }
  void render_tile(const Structure& s, const FrameView& view, const TileRect& tile,
                   TraceContext& ctx, Film& film) override {
    tiles.fetch_add(1);
    const CameraRays cam = view.rays();
    for (int y = tile.y0; y < tile.y1; ++y)
      for (int x = tile.x0; x < tile.x1; ++x) {
        SurfaceHit hit;
        const bool found = s.surface()->trace(cam.ray(x, y), view.lod(), ctx, &hit);
        Color c{-1.f, 0.f, 0.f, 1.f};
        Vec3 n;
        if (found) s.surface()->attributes(hit, ctx, &c, &n);
        film.color.at(x, y)[0] = c.r + 1.f;
        *film.depth.at(x, y) = found ? hit.t : INFINITY;
      }
  }
  std::atomic<int> tiles{0};
};

FrameView top_view() {
  FrameView v;
  v.width = 64, v.height = 64, v.lod_pixels = 0.f;
  v.camera.projection = Projection::Orthographic;
  v.camera.eye = {0.5f, 0.5f, 2.f}, v.camera.target = {0.5f, 0.5f, 0.f};
  v.camera.ortho_width = 1.f;
  return v;
}

TEST(FrameLoop, OnePassServesAfterThePassAndShowsWhatWasResident) {
  StreamingPlane plane(1000);
  CellIntegrator integrator;
  Film film;
  FrameOptions o;
  o.max_passes = 1;
  const FrameStats s = render_frame(plane, integrator, top_view(), o, &film);
  ASSERT_EQ(s.passes.size(), 1u);
  EXPECT_EQ(s.passes[0].requests, uint64_t(kCells * kCells));  // one per cell, deduplicated
  EXPECT_EQ(plane.resident_count(), kCells * kCells);          // served after the pass
  EXPECT_EQ(film.color.at(10, 10)[0], 0.f);  // the image of pass 0: nothing was resident
  // The next frame finds everything resident: one pass, no request.
  const FrameStats s2 = render_frame(plane, integrator, top_view(), o, &film);
  EXPECT_EQ(s2.requests, 0u);
  EXPECT_GT(film.color.at(10, 10)[0], 0.f);
}

TEST(FrameLoop, ExactModeRunsUntilNothingIsMissingAndRetracesOnlyAskingTiles) {
  StreamingPlane plane(5);  // 5 cells per pass: 64 cells need 13 serving passes
  CellIntegrator integrator;
  Film film;
  FrameOptions o;
  o.max_passes = 100;
  o.tile_size = 8;
  const FrameStats s = render_frame(plane, integrator, top_view(), o, &film);
  EXPECT_EQ(plane.resident_count(), kCells * kCells);
  ASSERT_GE(s.passes.size(), 13u);
  EXPECT_EQ(s.passes.back().requests, 0u);  // the last pass asked for nothing
  for (size_t i = 1; i < s.passes.size(); ++i)
    EXPECT_LE(s.passes[i].tiles, s.passes[i - 1].tiles) << "pass " << i;
  // 8 x 8 tiles of 8 x 8 pixels: one cell per tile. Pass k >= 1 renders the
  // tiles still missing their cell after k - 1 servings of 5 cells... plus
  // those just served, i.e. the 64 - 5 (k - 1) tiles that asked in pass k - 1.
  for (size_t k = 1; k < s.passes.size(); ++k)
    EXPECT_EQ(s.passes[k].tiles, std::max(0, 64 - 5 * int(k - 1))) << "pass " << k;
  // Every pixel now shows its cell: equal to a frame on a fully resident plane.
  Film again;
  render_frame(plane, integrator, top_view(), o, &again);
  EXPECT_EQ(film.color.pixels, again.color.pixels);
  // Requests arrive sorted by (kind, key) and without duplicates.
  for (const auto& list : plane.seen) {
    for (size_t i = 1; i < list.size(); ++i) EXPECT_LT(list[i - 1].key, list[i].key);
  }
}

TEST(FrameLoop, RequestsAndImageDoNotDependOnThreads) {
  std::vector<std::vector<std::vector<Request>>> seen;
  std::vector<std::vector<float>> images;
  for (int threads : {1, 2}) {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, size_t(threads));
    StreamingPlane plane(7);
    CellIntegrator integrator;
    Film film;
    FrameOptions o;
    o.max_passes = 4, o.tile_size = 4;
    render_frame(plane, integrator, top_view(), o, &film);
    seen.push_back(plane.seen);
    images.push_back(film.color.pixels);
  }
  ASSERT_EQ(seen[0].size(), seen[1].size());
  for (size_t p = 0; p < seen[0].size(); ++p) {
    ASSERT_EQ(seen[0][p].size(), seen[1][p].size());
    for (size_t i = 0; i < seen[0][p].size(); ++i) EXPECT_EQ(seen[0][p][i].key, seen[1][p][i].key);
  }
  EXPECT_EQ(images[0], images[1]);
}

TEST(FrameLoop, FullRequestBufferDropsAndCounts) {
  StreamingPlane plane(1000);
  CellIntegrator integrator;
  Film film;
  FrameOptions o;
  o.requests_per_thread = 3;
  const FrameStats s = render_frame(plane, integrator, top_view(), o, &film);
  EXPECT_GT(s.passes[0].dropped, 0u);
  EXPECT_LE(s.passes[0].requests, 3u * 64u);
  EXPECT_LT(plane.resident_count(), kCells * kCells);
}

// Counting: each pass counts the rays of the tiles it rendered; the frame
// counts each final pixel once (a tile rendered again replaces its earlier
// counts). Oracle: the toy plane counts one iteration per ray that reaches
// it, and every pixel of top_view() does.
TEST(FrameLoop, CountersArePerPassAndTheFrameCountsEachPixelOnce) {
  StreamingPlane plane(5);
  CellIntegrator integrator;
  Film film;
  FrameOptions o;
  o.max_passes = 100;
  o.tile_size = 8;
  o.counting = true;
  const FrameStats s = render_frame(plane, integrator, top_view(), o, &film);
  ASSERT_GE(s.passes.size(), 13u);
  uint64_t passes_sum = 0;
  for (size_t k = 0; k < s.passes.size(); ++k) {
    EXPECT_EQ(s.passes[k].counters.iterations, uint64_t(s.passes[k].tiles) * 8u * 8u)
        << "pass " << k;
    passes_sum += s.passes[k].counters.iterations;
  }
  EXPECT_EQ(s.counters.iterations, 64u * 64u);
  EXPECT_GT(passes_sum, s.counters.iterations);  // tiles were rendered again
  // Without counting, nothing is counted.
  StreamingPlane fresh(5);
  o.counting = false;
  const FrameStats quiet = render_frame(fresh, integrator, top_view(), o, &film);
  EXPECT_EQ(quiet.counters.iterations, 0u);
  for (const PassStats& p : quiet.passes) EXPECT_EQ(p.counters.iterations, 0u);
}

TEST(FrameLoop, RejectsBadOptions) {
  StreamingPlane plane(1);
  CellIntegrator integrator;
  Film film;
  FrameOptions o;
  o.max_passes = 0;
  EXPECT_ANY_THROW(render_frame(plane, integrator, top_view(), o, &film));
  FrameView v = top_view();
  v.width = 0;
  EXPECT_ANY_THROW(render_frame(plane, integrator, v, FrameOptions{}, &film));
}

}  // namespace
}  // namespace voxcast
