// render --spp (RenderOptions::spp, render.hpp): the sub-pixel offsets are
// the R2 sequence, a pixel on a silhouette becomes a mix of the two sides,
// the image is the mean of frames at those offsets, and ESVO and DAG of the
// same voxels give the same antialiased image.
#include <gtest/gtest.h>

#include <cmath>
#include <memory>

#include "voxcast/dag.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/integrator.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/render.hpp"
#include "voxcast/surface_integrator.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast {
namespace {

// A 2x2 square facing +y (two triangles), white.
Mesh square() {
  Mesh m;
  m.positions = {{-1, 0, -1}, {-1, 0, 1}, {1, 0, 1}, {1, 0, -1}};
  m.normals.assign(4, Vec3{0, 1, 0});
  m.indices = {0, 1, 2, 0, 2, 3};
  m.materials = {Material{{1.f, 1.f, 1.f, 1.f}, -1}};
  m.triangle_material = {0, 0};
  validate_mesh(m);
  return m;
}

VoxelSet voxels_of(const Mesh& m) {
  VoxelizeOptions vo;
  vo.attributes = true;
  return voxelize(m, GridTransform::fit(m.bounds(), 64), vo);
}

RenderOptions top_view(int spp) {
  RenderOptions o;
  o.width = o.height = 24;
  o.camera.eye = {0.1f, 3, 0.13f};  // off-axis: the square's edges cross pixels
  o.camera.target = {0.1f, 0, 0.13f};
  o.camera.up = {0, 0, -1};
  o.camera.projection = Projection::Orthographic;
  o.camera.ortho_width = 2.9f;
  o.lod_pixels = 0.f;
  o.spp = spp;
  return o;
}

TEST(Antialias, SamplesAreTheR2Sequence) {
  // Sample 0 is the pixel center (spp 1 renders what it always rendered).
  EXPECT_EQ(antialias_sample(0).x, 0.5f);
  EXPECT_EQ(antialias_sample(0).y, 0.5f);
  // The plastic number p (p^3 = p + 1): a1 = 1/p, a2 = 1/p^2.
  double p = 1.3;
  for (int i = 0; i < 50; ++i) p = std::cbrt(p + 1);
  for (int k : {1, 2, 7, 100}) {
    const double x = 0.5 + k / p, y = 0.5 + k / (p * p);
    EXPECT_NEAR(antialias_sample(k).x, x - std::floor(x), 1e-6);
    EXPECT_NEAR(antialias_sample(k).y, y - std::floor(y), 1e-6);
  }
}

TEST(Antialias, SilhouettePixelsMixBothSides) {
  const esvo::EsvoStructure s(
      std::make_shared<const esvo::EsvoOctree>(esvo::build_octree(voxels_of(square()))));
  const RenderResult one = render(s, top_view(1)), aa = render(s, top_view(16));
  // The background and the square's shade, from a pixel well inside each.
  const float bg = one.color.at(0, 0)[0], fg = one.color.at(12, 12)[0];
  ASSERT_GT(fg, bg + 0.3f);
  int mixed_one = 0, mixed_aa = 0;
  for (int y = 0; y < 24; ++y)
    for (int x = 0; x < 24; ++x) {
      auto mixed = [&](const RenderResult& r) {
        const float v = r.color.at(x, y)[0];
        return v > bg + 0.02f && v < fg - 0.02f;
      };
      mixed_one += mixed(one);
      mixed_aa += mixed(aa);
    }
  EXPECT_EQ(mixed_one, 0);  // one ray per pixel: either side
  EXPECT_GT(mixed_aa, 20);  // the edge pixels of the square's four sides
  EXPECT_EQ(aa.rays, 16u * 24 * 24);
}

TEST(Antialias, ImageIsTheMeanOfFramesAtTheOffsets) {
  esvo::EsvoStructure s(
      std::make_shared<const esvo::EsvoOctree>(esvo::build_octree(voxels_of(square()))));
  const RenderOptions o = top_view(5);
  const RenderResult aa = render(s, o);
  // Frames of the surface integrator with FrameView::sample set, summed in
  // sample order like render() does.
  Image sum;
  for (int k = 0; k < o.spp; ++k) {
    SurfaceIntegrator integrator(o);
    FrameView view;
    view.camera = o.camera;
    view.width = o.width, view.height = o.height;
    view.lod_pixels = o.lod_pixels;
    view.sample = antialias_sample(k);
    Film film;
    render_frame(s, integrator, view, FrameOptions{}, &film);
    if (k == 0)
      sum = film.color;
    else
      for (size_t i = 0; i < sum.pixels.size(); ++i) sum.pixels[i] += film.color.pixels[i];
  }
  for (float& v : sum.pixels) v *= 1.f / float(o.spp);
  EXPECT_EQ(aa.color.pixels, sum.pixels);
}

TEST(Antialias, EsvoAndDagGiveTheSameImage) {
  const VoxelSet v = voxels_of(square());
  const esvo::EsvoStructure e(std::make_shared<const esvo::EsvoOctree>(esvo::build_octree(v)));
  const dag::DagStructure d(std::make_shared<const dag::SparseVoxelDag>(dag::build_dag(v)));
  const RenderResult a = render(e, top_view(8)), b = render(d, top_view(8));
  ASSERT_EQ(a.color.pixels.size(), b.color.pixels.size());
  for (size_t i = 0; i < a.color.pixels.size(); ++i)
    EXPECT_NEAR(a.color.pixels[i], b.color.pixels[i], 2e-3f) << i;
}

}  // namespace
}  // namespace voxcast
