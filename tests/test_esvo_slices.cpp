// ESVO data management (esvo §7): slices on disk and the streamed ESVO.
//  * the slice file holds exactly the in-core octree's voxels, attributes and
//    contours (decoded here from the documented byte layout, independently of
//    the library, against the independent ESVO decoder of tests/support);
//  * streamed renders equal in-core renders once what they asked for is
//    resident; a small budget converges to the in-core image when the view
//    stops; the budget and the load/unload invariants hold after every pass;
//  * corrupted slices are refused and the rest still renders.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <map>
#include <memory>
#include <tuple>
#include <vector>

#include "support/attribute_oracle.hpp"
#include "support/cli_runner.hpp"
#include "support/file_bytes.hpp"
#include "support/independent_decoders.hpp"
#include "support/slice_check.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/esvo_format.hpp"
#include "voxcast/esvo_slices.hpp"
#include "voxcast/esvo_structure.hpp"
#include "voxcast/format_registry.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/render.hpp"
#include "voxcast/scene_file.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast {
namespace {

const std::filesystem::path kMeshes = std::filesystem::path(VOXCAST_TEST_DATA_DIR) / "meshes";

std::filesystem::path temp_file(const std::string& name) {
  const auto dir = std::filesystem::temp_directory_path() / "voxcast_test_slices";
  std::filesystem::create_directories(dir);
  return dir /
         (name + "-" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()) + ".vxs");
}

std::shared_ptr<const esvo::EsvoOctree> bunny(uint32_t resolution, bool contours) {
  const Mesh mesh = load_mesh(kMeshes / "stanford-bunny.obj");
  const GridTransform grid = GridTransform::fit(mesh.bounds(), resolution);
  VoxelizeOptions vo;
  vo.attributes = true;
  const VoxelSet v = voxelize(mesh, grid, vo);
  esvo::BuildOptions o;
  o.contours = contours;
  if (contours) o.geometry_error = 0.5;  // variable depth: leaves above the finest level
  return std::make_shared<esvo::EsvoOctree>(contours ? esvo::build_octree(v, mesh, o)
                                                     : esvo::build_octree(v, o));
}

// ---- Independent decoder of the slice file (byte offsets as documented) ----

template <class T>
T get(const std::vector<uint8_t>& b, size_t at) {
  T v;
  std::memcpy(&v, b.data() + at, sizeof v);
  return v;
}

struct Voxel {
  bool leaf = false;
  bool has_contour = false;
  uint32_t contour = 0;
  testing::independent::BlockSlot attributes;
};
using Key = std::tuple<int, uint32_t, uint32_t, uint32_t>;  // depth, x, y, z

void unspread(uint64_t code, uint32_t* x, uint32_t* y, uint32_t* z) {
  *x = *y = *z = 0;
  for (int i = 0; i < 21; ++i) {
    *x |= uint32_t(code >> (3 * i) & 1u) << i;
    *y |= uint32_t(code >> (3 * i + 1) & 1u) << i;
    *z |= uint32_t(code >> (3 * i + 2) & 1u) << i;
  }
}

struct DecodedSlices {
  std::map<Key, Voxel> voxels;
  std::vector<uint32_t> data_bytes, child_counts;
};

// Walks the hierarchy from the root: a slice's descriptors are the
// subdivided children, inside its region, of its parent's descriptors.
DecodedSlices decode_slice_file(const std::vector<uint8_t>& f) {
  DecodedSlices out;
  const uint32_t count = get<uint32_t>(f, 24);
  // Per slice: the Morton codes of its descriptors and their subdivided
  // children (codes at the next level).
  std::vector<std::vector<uint64_t>> sub(count);
  for (uint32_t i = 0; i < count; ++i) {
    const size_t e = 128 + 64 * size_t(i);
    const uint64_t region = get<uint64_t>(f, e), offset = get<uint64_t>(f, e + 8);
    const uint32_t parent = get<uint32_t>(f, e + 28), nodes = get<uint32_t>(f, e + 40);
    const uint32_t voxels = get<uint32_t>(f, e + 44);
    const int level = f[e + 56], depth = f[e + 57];
    out.data_bytes.push_back(get<uint32_t>(f, e + 24));
    out.child_counts.push_back(get<uint32_t>(f, e + 36));
    std::vector<uint64_t> codes;
    if (i == 0) {
      codes.push_back(0);
    } else {
      for (uint64_t c : sub[parent])
        if ((c >> (3 * (level - depth))) == region) codes.push_back(c);
    }
    EXPECT_EQ(codes.size(), nodes) << "slice " << i;
    // Raw: 8 bytes per child. Compressed (flag 2): block k (24 bytes) holds
    // descriptors 2k and 2k+1, child i of descriptor n at slot (n&1)*8 + i.
    const bool compressed = (get<uint32_t>(f, 20) & 2u) != 0;
    const size_t blocks = offset + 4 * size_t(nodes);
    size_t attr = blocks,
           contour = attr + (compressed ? 24 * ((size_t(nodes) + 1) / 2) : 8 * size_t(voxels));
    for (uint32_t n = 0; n < nodes && n < codes.size(); ++n) {
      const uint32_t d = get<uint32_t>(f, offset + 4 * size_t(n));
      const uint32_t leaf = d & 0xFF, valid = d >> 8 & 0xFF, cm = d >> 16 & 0xFF;
      for (int c = 0; c < 8; ++c) {
        if ((valid >> c & 1u) == 0) continue;
        const uint64_t code = codes[n] << 3 | uint64_t(c);
        Voxel v;
        v.leaf = (leaf >> c & 1u) != 0;
        if (compressed) {
          uint32_t block[6];
          std::memcpy(block, f.data() + blocks + 24 * size_t(n / 2), sizeof block);
          v.attributes = testing::independent::decode_block_slot(block, int(n & 1) * 8 + c);
        } else {
          v.attributes.color = testing::independent::decode_abgr(get<uint32_t>(f, attr));
          v.attributes.normal =
              testing::independent::decode_cube_normal(get<uint32_t>(f, attr + 4));
          attr += 8;
        }
        if (cm >> c & 1u) {
          v.has_contour = true;
          v.contour = get<uint32_t>(f, contour);
          contour += 4;
        }
        if (!v.leaf) sub[i].push_back(code);
        uint32_t x, y, z;
        unspread(code, &x, &y, &z);
        out.voxels[{level + 1, x, y, z}] = v;
      }
    }
  }
  return out;
}

void expect_same_voxels(const esvo::EsvoOctree& octree, const DecodedSlices& got) {
  const testing::independent::EsvoScan scan = testing::independent::scan_esvo(octree.words);
  ASSERT_EQ(scan.voxels.size(), got.voxels.size());
  size_t contours = 0, bad = 0;
  for (const testing::independent::EsvoVoxel& v : scan.voxels) {
    const auto it = got.voxels.find({v.depth, v.x, v.y, v.z});
    if (it == got.voxels.end()) {
      ++bad;
      continue;
    }
    const Voxel& s = it->second;
    contours += v.has_contour;
    bad += s.leaf != v.leaf || s.has_contour != v.has_contour ||
           (v.has_contour && s.contour != v.contour_value) ||
           s.attributes.color.r != v.attributes.color.r ||
           s.attributes.color.g != v.attributes.color.g ||
           s.attributes.color.b != v.attributes.color.b ||
           s.attributes.color.a != v.attributes.color.a ||
           s.attributes.normal.x != v.attributes.normal.x ||
           s.attributes.normal.y != v.attributes.normal.y ||
           s.attributes.normal.z != v.attributes.normal.z;
  }
  EXPECT_EQ(bad, 0u);
  EXPECT_EQ(contours > 0, octree.has_contours());
}

TEST(EsvoSlices, FileHoldsTheInCoreVoxels) {
  for (const bool contours : {false, true}) {
    const auto octree = bunny(128, contours);
    for (const uint64_t slice_bytes : {uint64_t(2048), uint64_t(1) << 20}) {
      SCOPED_TRACE(std::string(contours ? "contours " : "cubes ") + std::to_string(slice_bytes));
      const auto path = temp_file("voxels");
      esvo::SliceOptions so;
      so.slice_bytes = slice_bytes;
      esvo::write_slices(*octree, path, so);
      const std::vector<uint8_t> bytes = testing::read_bytes(path);
      const DecodedSlices d = decode_slice_file(bytes);
      expect_same_voxels(*octree, d);
      // Every slice within the target (one descriptor record is at most
      // 4 + 8 * 8 + 4 * 8 = 100 bytes, below these targets); small slices
      // split into more than eight children somewhere (§7.1).
      EXPECT_LE(*std::max_element(d.data_bytes.begin(), d.data_bytes.end()), slice_bytes);
      if (slice_bytes == 2048) {
        EXPECT_GT(*std::max_element(d.child_counts.begin(), d.child_counts.end()), 8u);
        EXPECT_GT(d.data_bytes.size(), 50u);
      } else {
        EXPECT_LT(d.data_bytes.size(), size_t(octree->levels() + 1));  // one slice per level
      }
      // The library's reader accepts it and agrees on the hierarchy.
      const auto file = esvo::SliceFile::open(path);
      EXPECT_EQ(file->slices().size(), d.data_bytes.size());
      EXPECT_EQ(file->has_contours(), contours);
      EXPECT_NE(file->describe().find("slice hierarchy"), std::string::npos);
      std::filesystem::remove(path);
    }
  }
}

// The top-down slice builder (§7.1) writes the same bytes as slicing the
// in-core build, for several cell sizes (regions larger and smaller than a
// cell), slice sizes and with or without attributes.
TEST(EsvoSlices, TopDownBuilderEqualsSlicingTheInCoreBuild) {
  const Mesh mesh = load_mesh(kMeshes / "stanford-bunny.obj");
  struct Case {
    uint32_t resolution;
    bool attributes;
    uint64_t slice_bytes;
    std::vector<uint32_t> cells;  // 0 = from the budget
  };
  const Case cases[] = {{64, true, 2048, {8, 32, 0}},
                        {64, false, 1024, {16}},
                        {128, true, 4096, {16, 0}},
                        {128, true, uint64_t(1) << 20, {32}}};
  for (const Case& cs : cases) {
    const GridTransform grid = GridTransform::fit(mesh.bounds(), cs.resolution);
    VoxelizeOptions vo;
    vo.attributes = cs.attributes;
    const esvo::EsvoOctree octree = esvo::build_octree(voxelize(mesh, grid, vo));
    // Raw, and §5.5 blocks per slice (the compressed file of the same raw
    // in-core octree).
    for (const bool compressed : {false, true}) {
      const auto want_path = temp_file("in-core");
      esvo::SliceOptions so;
      so.slice_bytes = cs.slice_bytes;
      so.compressed = compressed;
      esvo::write_slices(octree, want_path, so);
      const std::vector<uint8_t> want = testing::read_bytes(want_path);
      std::filesystem::remove(want_path);
      for (const uint32_t cell : cs.cells) {
        SCOPED_TRACE(std::to_string(cs.resolution) + (cs.attributes ? " attributes" : " geometry") +
                     " slice " + std::to_string(cs.slice_bytes) + " cell " + std::to_string(cell) +
                     (compressed ? " compressed" : " raw"));
        const auto path = temp_file("top-down");
        esvo::SliceBuildOptions bo;
        bo.slice_bytes = cs.slice_bytes;
        bo.cell_size = cell;
        bo.compressed = compressed;
        esvo::SliceBuildStats st;
        esvo::build_slices(mesh, grid, vo, path, bo, &st);
        EXPECT_TRUE(testing::read_bytes(path) == want);
        EXPECT_EQ(st.file_bytes, want.size());
        if (cell != 0) {
          EXPECT_EQ(st.cell_size, cell);
        }
        EXPECT_GT(st.cells, 1u);
        std::filesystem::remove(path);
      }
    }
  }
}

// Contours top-down (§7.1): each unbuilt slice carries its region's
// triangles and ancestor contours; the file equals slicing the in-core
// contour build, full depth and with the variable depth: geometric
// (--geometry-error), a max level, and the attribute tolerances (§7.3,
// color only, normal only, with the geometric one and under a max level; a
// slice compares its voxels with its region's full-depth voxels in a
// second pass), at small slices (many levels of slices, splits into more
// than eight children) and large ones, on a mesh with smooth vertex colors.
/// A contour build's tolerances, in core and top-down.
struct ContourTolerances {
  double geometry_error = 0;
  int max_level = 0;
  double color_error = -1, normal_error = -1;
  esvo::BuildOptions in_core() const {
    esvo::BuildOptions o;
    o.contours = true;
    o.geometry_error = geometry_error, o.max_level = max_level;
    o.color_error = color_error, o.normal_error = normal_error;
    return o;
  }
  esvo::SliceBuildOptions top_down(uint64_t slice_bytes, bool compressed) const {
    esvo::SliceBuildOptions bo;
    bo.slice_bytes = slice_bytes;
    bo.contours = true;
    bo.geometry_error = geometry_error, bo.max_level = max_level;
    bo.color_error = color_error, bo.normal_error = normal_error;
    bo.compressed = compressed;
    return bo;
  }
};

TEST(EsvoSlices, TopDownContoursEqualSlicingTheInCoreBuild) {
  const Mesh mesh = testing::load_mesh_with_wave_colors("stanford-bunny.obj");
  struct Case {
    uint32_t resolution;
    double geometry_error;
    int max_level;
    uint64_t slice_bytes;
    uint32_t cell;  // 0 = from the budget
    double color_error = -1, normal_error = -1;
    bool compressed = false;  // §5.5 blocks per slice (with tolerances: no in-core peer, below)
  };
  const Case cases[] = {{64, 0, 0, 2048, 8, -1, -1, true},
                        {128, 1.0, 0, 4096, 0, -1, -1, true},
                        {128, 0, 6, 3000, 32, -1, -1, true},
                        {64, 0, 0, 2048, 8},
                        {64, 0.5, 0, 1024, 16},
                        {128, 1.0, 0, 4096, 0},
                        {128, 0, 6, 3000, 32},
                        {128, 0, 0, uint64_t(1) << 20, 0},
                        {64, 0, 0, 1024, 8, 10, -1},
                        {64, 0, 0, 2048, 16, -1, 8},
                        {128, 1.0, 0, 4096, 0, 16, 12},
                        {128, 0, 6, 3000, 32, -1, 10},
                        {128, 0, 0, uint64_t(1) << 20, 0, 4, 4}};
  for (const Case& cs : cases) {
    SCOPED_TRACE(std::to_string(cs.resolution) + " errors " + std::to_string(cs.geometry_error) +
                 "/" + std::to_string(cs.color_error) + "/" + std::to_string(cs.normal_error) +
                 " max level " + std::to_string(cs.max_level) + " slice " +
                 std::to_string(cs.slice_bytes) + " cell " + std::to_string(cs.cell) +
                 (cs.compressed ? " compressed" : ""));
    const GridTransform grid = GridTransform::fit(mesh.bounds(), cs.resolution);
    VoxelizeOptions vo;
    vo.attributes = true;
    const VoxelSet voxels = voxelize(mesh, grid, vo);
    const ContourTolerances tol{cs.geometry_error, cs.max_level, cs.color_error, cs.normal_error};
    const esvo::BuildOptions o = tol.in_core();
    const esvo::EsvoOctree octree = esvo::build_octree(voxels, mesh, o);
    ASSERT_TRUE(octree.has_contours());
    if (cs.color_error >= 0 || cs.normal_error >= 0) {
      // The tolerances decide: alone they prune the full-depth tree; with the
      // geometric one they subdivide voxels it would have left as leaves.
      esvo::BuildOptions without = o;
      without.color_error = without.normal_error = -1;
      const size_t words_without = esvo::build_octree(voxels, mesh, without).words.size();
      if (cs.geometry_error > 0)
        EXPECT_GT(octree.words.size(), words_without);
      else
        EXPECT_LT(octree.words.size(), words_without);
    }
    const auto want_path = temp_file("in-core-contours");
    esvo::SliceOptions so;
    so.slice_bytes = cs.slice_bytes;
    so.compressed = cs.compressed;
    esvo::write_slices(octree, want_path, so);
    const std::vector<uint8_t> want = testing::read_bytes(want_path);
    const auto want_file = esvo::SliceFile::open(want_path);
    const size_t want_slices = want_file->slices().size();
    uint64_t contours = 0;
    for (const auto& e : want_file->slices()) contours += e.contour_count;
    EXPECT_GT(contours, 0u);  // the case exercises contours
    std::filesystem::remove(want_path);

    const auto path = temp_file("top-down-contours");
    esvo::SliceBuildOptions bo = tol.top_down(cs.slice_bytes, cs.compressed);
    bo.cell_size = cs.cell;
    esvo::SliceBuildStats st;
    esvo::build_slices(mesh, grid, vo, path, bo, &st);
    const std::vector<uint8_t> got = testing::read_bytes(path);
    EXPECT_EQ(got.size(), want.size());
    EXPECT_TRUE(got == want);
    EXPECT_EQ(st.slices, want_slices);
    if (cs.slice_bytes < 8192) {
      EXPECT_GT(st.slices, 8u);
    }
    std::filesystem::remove(path);
  }
}

TEST(EsvoSlices, TopDownOptionsAreChecked) {
  const Mesh mesh = load_mesh(kMeshes / "stanford-bunny.obj");
  const GridTransform grid = GridTransform::fit(mesh.bounds(), 32);
  const auto path = temp_file("top-down-options");
  esvo::SliceBuildOptions bo;
  bo.geometry_error = 1;  // without contours
  EXPECT_THROW(esvo::build_slices(mesh, grid, {}, path, bo), Error);
  bo.contours = true;
  bo.geometry_error = std::nan("");
  EXPECT_THROW(esvo::build_slices(mesh, grid, {}, path, bo), Error);
  bo.geometry_error = 0;
  bo.max_level = 6;  // beyond the grid's 5 levels
  EXPECT_THROW(esvo::build_slices(mesh, grid, {}, path, bo), Error);
  bo.max_level = 0;
  bo.color_error = std::nan("");
  EXPECT_THROW(esvo::build_slices(mesh, grid, {}, path, bo), Error);
  bo.color_error = 300;
  EXPECT_THROW(esvo::build_slices(mesh, grid, {}, path, bo), Error);
  bo.color_error = -1;
  bo.normal_error = 181;
  EXPECT_THROW(esvo::build_slices(mesh, grid, {}, path, bo), Error);
  bo.normal_error = 10;
  bo.compressed = true;
  bo.contours = false;  // a tolerance without contours (compressed or not)
  EXPECT_THROW(esvo::build_slices(mesh, grid, {}, path, bo), Error);
  bo.compressed = false;
  EXPECT_THROW(esvo::build_slices(mesh, grid, {}, path, bo), Error);
  EXPECT_FALSE(std::filesystem::exists(path));
}

TEST(EsvoSlices, CompressedAttributesRefused) {
  const Mesh mesh = load_mesh(kMeshes / "stanford-bunny.obj");
  VoxelizeOptions vo;
  vo.attributes = true;
  const VoxelSet v = voxelize(mesh, GridTransform::fit(mesh.bounds(), 32), vo);
  esvo::BuildOptions o;
  o.attributes = esvo::AttributeFormat::Compressed;
  const esvo::EsvoOctree octree = esvo::build_octree(v, o);
  const auto path = temp_file("compressed");
  EXPECT_THROW(esvo::write_slices(octree, path), Error);
  EXPECT_FALSE(std::filesystem::exists(path));
}

// Compressed slices (§5.5 blocks per slice, esvo_slices.hpp): the same
// voxels, leaves and contours as the raw file of the same octree; each
// block, decoded by the independent decoder, is close to the raw values it
// was fitted to; SliceFile::read() hands out exactly those decoded values
// in the raw layout; the file is smaller. A file whose compressed flag is
// flipped (directory re-hashed) disagrees with its slice sizes: refused.
TEST(EsvoSlices, CompressedSlicesHoldBlocksOfTheRawValues) {
  const Mesh mesh = testing::load_mesh_with_wave_colors("stanford-bunny.obj");
  for (const bool contours : {false, true}) {
    SCOPED_TRACE(contours ? "contours" : "cubes");
    const GridTransform grid = GridTransform::fit(mesh.bounds(), 64);
    VoxelizeOptions vo;
    vo.attributes = true;
    const VoxelSet voxels = voxelize(mesh, grid, vo);
    esvo::BuildOptions o;
    o.contours = contours;
    const esvo::EsvoOctree octree =
        contours ? esvo::build_octree(voxels, mesh, o) : esvo::build_octree(voxels, o);
    const auto raw_path = temp_file("raw"), packed_path = temp_file("compressed");
    esvo::SliceOptions so;
    so.slice_bytes = 2048;
    esvo::write_slices(octree, raw_path, so);
    so.compressed = true;
    esvo::write_slices(octree, packed_path, so);
    const std::vector<uint8_t> raw_bytes = testing::read_bytes(raw_path),
                               packed_bytes = testing::read_bytes(packed_path);
    EXPECT_LT(double(packed_bytes.size()), 0.6 * double(raw_bytes.size()));
    const DecodedSlices raw = decode_slice_file(raw_bytes),
                        packed = decode_slice_file(packed_bytes);
    ASSERT_EQ(raw.voxels.size(), packed.voxels.size());
    double color_sum = 0, angle_sum = 0, color_max = 0, angle_max = 0;  // angles in radians
    size_t mismatched = 0;
    for (const auto& [key, r] : raw.voxels) {
      const auto it = packed.voxels.find(key);
      if (it == packed.voxels.end()) {
        ++mismatched;
        continue;
      }
      const Voxel& p = it->second;
      mismatched += p.leaf != r.leaf || p.has_contour != r.has_contour || p.contour != r.contour;
      for (int c = 0; c < 3; ++c) {
        const double d = std::abs(p.attributes.color.srgb[c] - r.attributes.color.srgb[c]);
        color_sum += d, color_max = std::max(color_max, d);
      }
      const double a =
          testing::independent::angle_between(p.attributes.normal, r.attributes.normal);
      angle_sum += a, angle_max = std::max(angle_max, a);
    }
    EXPECT_EQ(mismatched, 0u);
    const double n = double(raw.voxels.size());
    // Against the in-core §5.5 compression of the same values (blocks of
    // sibling pairs in its layout): about as close.
    esvo::BuildOptions oc = o;
    oc.attributes = esvo::AttributeFormat::Compressed;
    const esvo::EsvoOctree in_core =
        contours ? esvo::build_octree(voxels, mesh, oc) : esvo::build_octree(voxels, oc);
    double in_core_sum = 0, in_core_angle = 0;  // angles in radians
    size_t in_core_n = 0;
    for (const auto& v : testing::independent::scan_esvo(in_core.words).voxels) {
      const auto it = raw.voxels.find({v.depth, v.x, v.y, v.z});
      if (it == raw.voxels.end()) continue;
      ++in_core_n;
      for (int c = 0; c < 3; ++c)
        in_core_sum += std::abs(v.attributes.color.srgb[c] - it->second.attributes.color.srgb[c]);
      in_core_angle +=
          testing::independent::angle_between(v.attributes.normal, it->second.attributes.normal);
    }
    ASSERT_EQ(in_core_n, raw.voxels.size());
    const double in_core_mean = in_core_sum / (3 * double(in_core_n));
    EXPECT_GT(in_core_mean, 1.0);                         // the wave colors make it lossy
    EXPECT_LT(color_sum / (3 * n), 1.25 * in_core_mean);  // 8-bit sRGB steps, mean
    EXPECT_LE(color_max, 128.0);
    EXPECT_GT(in_core_angle, 0.0);
    EXPECT_LT(angle_sum / n, 1.25 * in_core_angle / double(in_core_n));  // radians, mean
    EXPECT_LT(angle_max, std::acos(-1.0) / 2);
    EXPECT_GT(color_sum, 0.0);  // lossy: it is compressed
    // read(): the decoded values in the raw layout, slice by slice, equal
    // to the independent decoder's (colors exactly, normals up to the raw
    // normal encoding).
    const auto file = esvo::SliceFile::open(packed_path);
    EXPECT_TRUE(file->compressed());
    size_t checked = 0, off = 0;
    for (uint32_t i = 0; i < file->slices().size(); ++i) {
      const esvo::slice_layout::SliceEntry& e = file->slices()[i];
      const std::vector<uint32_t> words = file->read(i);
      ASSERT_EQ(words.size(), e.node_count + 2 * size_t(e.voxel_count) + e.contour_count);
      size_t attr = e.node_count;
      for (uint32_t d = 0; d < e.node_count; ++d) {
        uint32_t block[6];
        std::memcpy(block, packed_bytes.data() + e.data_offset + 4 * e.node_count + 24 * (d / 2),
                    sizeof block);
        const uint32_t valid = words[d] >> 8 & 0xFF;
        for (int c = 0; c < 8; ++c) {
          if ((valid >> c & 1u) == 0) continue;
          const testing::independent::BlockSlot want =
              testing::independent::decode_block_slot(block, int(d & 1) * 8 + c);
          const testing::independent::RefColor got = testing::independent::decode_abgr(words[attr]);
          off += got.srgb[0] != want.color.srgb[0] || got.srgb[1] != want.color.srgb[1] ||
                 got.srgb[2] != want.color.srgb[2] ||
                 testing::independent::angle_between(
                     testing::independent::decode_cube_normal(words[attr + 1]), want.normal) > 0.05;
          attr += 2;
          ++checked;
        }
      }
    }
    EXPECT_EQ(checked, raw.voxels.size());
    EXPECT_EQ(off, 0u);
    // The flag flipped, the directory re-hashed: the sizes disagree.
    std::vector<uint8_t> flipped = packed_bytes;
    flipped[20] ^= 2;
    testing::rehash_slice_file(flipped);
    EXPECT_NE(testing::check_slice_file(flipped).find("data size"), std::string::npos);
    std::filesystem::remove(raw_path);
    std::filesystem::remove(packed_path);
  }
}

// Compressed slices with the attribute tolerances (§7.3 after §5.5, top-
// down): every leaf above the finest level (and the max level) decodes, by
// the independent block decoder, to attributes within tolerance of every
// full-depth voxel below it; the raw build's tree compressed afterwards
// breaks that somewhere (so the property can fail), and the decoded test
// refines a superset of it. Several tolerance mixes and slice sizes.
TEST(EsvoSlices, CompressedTopDownToleranceHoldsForTheDecodedValues) {
  const Mesh mesh = testing::load_mesh_with_wave_colors("stanford-bunny.obj");
  struct Case {
    uint32_t resolution;
    double geometry_error;
    int max_level;
    uint64_t slice_bytes;
    double color_error, normal_error;
  };
  const Case cases[] = {{64, 0, 0, 1024, 12, -1},
                        {64, 0, 0, 2048, -1, 8},
                        {128, 1.0, 0, 4096, 16, 12},
                        {128, 0, 6, 3000, 10, 10}};
  for (const Case& cs : cases) {
    SCOPED_TRACE(std::to_string(cs.resolution) + " errors " + std::to_string(cs.geometry_error) +
                 "/" + std::to_string(cs.color_error) + "/" + std::to_string(cs.normal_error) +
                 " max level " + std::to_string(cs.max_level));
    const GridTransform grid = GridTransform::fit(mesh.bounds(), cs.resolution);
    VoxelizeOptions vo;
    vo.attributes = true;
    const VoxelSet full = voxelize(mesh, grid, vo);
    const int L = grid.levels;
    testing::TempDir dir;
    const ContourTolerances tol{cs.geometry_error, cs.max_level, cs.color_error, cs.normal_error};
    esvo::build_slices(mesh, grid, vo, dir.file("raw.vxs"), tol.top_down(cs.slice_bytes, false));
    esvo::build_slices(mesh, grid, vo, dir.file("packed.vxs"), tol.top_down(cs.slice_bytes, true));
    // The raw build's tree with its attributes compressed afterwards.
    const esvo::BuildOptions o = tol.in_core();
    esvo::SliceOptions so;
    so.slice_bytes = cs.slice_bytes;
    so.compressed = true;
    esvo::write_slices(esvo::build_octree(full, mesh, o), dir.file("after.vxs"), so);

    // Leaves out of tolerance against the full-depth voxels (8-bit sRGB max
    // channel difference; normal angle, 0.01 degree of slack for the cube
    // encoding of normals).
    const double max_angle = cs.normal_error * std::acos(-1.0) / 180 + 0.01 * std::acos(-1.0) / 180;
    auto violations = [&](const DecodedSlices& f, size_t* leaves) {
      size_t bad = 0;
      *leaves = 0;
      for (const auto& [key, v] : f.voxels) {
        const int d = std::get<0>(key);
        if (!v.leaf || d >= L || (cs.max_level > 0 && d >= cs.max_level)) continue;
        ++*leaves;
        const uint64_t c =
            testing::independent::interleave3(std::get<1>(key), std::get<2>(key), std::get<3>(key));
        const int shift = 3 * (L - d);
        const auto lo = std::lower_bound(full.codes.begin(), full.codes.end(), c << shift);
        const auto hi = std::lower_bound(full.codes.begin(), full.codes.end(), (c + 1) << shift);
        bool out = false;
        for (auto it = lo; it != hi && !out; ++it) {
          const size_t k = size_t(it - full.codes.begin());
          if (cs.color_error >= 0) {
            const testing::independent::RefColor fc =
                testing::independent::decode_abgr(esvo::encode_color_abgr(full.colors[k]));
            for (int ch = 0; ch < 3; ++ch)
              out |= std::abs(fc.srgb[ch] - v.attributes.color.srgb[ch]) > cs.color_error;
          }
          if (cs.normal_error >= 0) {
            const Vec3 fn = full.normals[k];
            out |= testing::independent::angle_between({fn.x, fn.y, fn.z}, v.attributes.normal) >
                   max_angle;
          }
        }
        bad += out;
      }
      return bad;
    };
    const DecodedSlices packed = decode_slice_file(testing::read_bytes(dir.file("packed.vxs"))),
                        raw = decode_slice_file(testing::read_bytes(dir.file("raw.vxs"))),
                        after = decode_slice_file(testing::read_bytes(dir.file("after.vxs")));
    size_t leaves = 0, after_leaves = 0;
    EXPECT_EQ(violations(packed, &leaves), 0u);
    EXPECT_GT(leaves, 50u);  // variable depth: leaves above the finest level
    EXPECT_GT(violations(after, &after_leaves), 0u);
    // A superset of the raw tolerance's tree.
    size_t missing = 0;
    for (const auto& [key, v] : raw.voxels) missing += packed.voxels.count(key) == 0;
    EXPECT_EQ(missing, 0u);
    EXPECT_GT(packed.voxels.size(), raw.voxels.size());
    // It streams and checks like any slice file.
    EXPECT_EQ(testing::check_slice_file(testing::read_bytes(dir.file("packed.vxs"))), "");
  }
}

TEST(EsvoSlices, DamagedHeaderOrDirectoryRefused) {
  const auto octree = bunny(64, false);
  const auto path = temp_file("damaged");
  esvo::SliceOptions so;
  so.slice_bytes = 1024;
  esvo::write_slices(*octree, path, so);
  const std::vector<uint8_t> good = testing::read_bytes(path);
  EXPECT_NO_THROW(esvo::SliceFile::open(path));
  // Every byte of the header and the directory is covered by the directory
  // hash or checked: flipping any one of a sample is refused at open.
  const size_t dir_end = 128 + 64 * size_t(get<uint32_t>(good, 24));
  // (About 300 positions spread over the header and directory.)
  const size_t step = std::max<size_t>(7, dir_end / 300) | 1;
  for (size_t at = 0; at < dir_end; at += step) {
    std::vector<uint8_t> bad = good;
    bad[at] ^= 0x10;
    testing::write_bytes(path, bad);
    EXPECT_THROW(esvo::SliceFile::open(path), Error) << "byte " << at;
  }
  std::vector<uint8_t> cut(good.begin(), good.end() - 4);
  testing::write_bytes(path, cut);
  EXPECT_THROW(esvo::SliceFile::open(path), Error);
  std::filesystem::remove(path);
}

// Committed regression inputs (tests/data/regress/slices, also the fuzz
// target's checks): "accept-*" files open (a damaged slice among them is
// refused while streaming, the rest streams with every invariant intact),
// any other is refused at open with a one-line error.
TEST(EsvoSlices, RegressionInputs) {
  const auto dir = std::filesystem::path(VOXCAST_TEST_DATA_DIR) / "regress" / "slices";
  int files = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    ++files;
    const std::vector<uint8_t> bytes = testing::read_bytes(entry.path());
    const std::string error = testing::check_slice_file(bytes);
    const bool expect_accept = entry.path().filename().string().rfind("accept-", 0) == 0;
    EXPECT_EQ(error.empty(), expect_accept) << entry.path() << ": " << error;
    EXPECT_EQ(error.find('\n'), std::string::npos) << error;
  }
  EXPECT_GE(files, 8);
  // Re-hashing keeps a good file good, and the damaged slices are refused
  // while streaming, not at open.
  auto good = testing::read_bytes(dir / "accept-slices-bunny16.vxs");
  testing::rehash_slice_file(good);
  EXPECT_EQ(good, testing::read_bytes(dir / "accept-slices-bunny16.vxs"));
  for (const char* name : {"accept-slices-contour-bit-in-a-file-without-contours.vxs",
                           "accept-slices-slice-hash-mismatch.vxs"}) {
    esvo::StreamedEsvo s(esvo::SliceFile::open(dir / name));
    s.load_all();
    s.check_invariants();
    EXPECT_GT(s.stats().refused, 0u) << name;
    EXPECT_LT(s.stats().resident_slices, s.file().slices().size()) << name;
  }
}

// Damage behind recomputed hashes (a buggy writer, a hostile file): 32-bit
// words of the header, directory and slice data set to 0xFFFFFFFF, 0,
// 0x80000000 and +1, every hash recomputed, then opened and streamed
// (check_slice_file aborts on a broken invariant or a crash would end the
// test). Each file is refused in one line or streams with its invariants.
TEST(EsvoSlices, RehashedWordEditsAreRefusedOrStreamSafely) {
  const auto dir = std::filesystem::path(VOXCAST_TEST_DATA_DIR) / "regress" / "slices";
  // Raw attributes, and §5.5 blocks per slice (decoded on read).
  for (const char* name : {"accept-slices-bunny16.vxs", "accept-slices-compressed-bunny16.vxs"}) {
    SCOPED_TRACE(name);
    const std::vector<uint8_t> good = testing::read_bytes(dir / name);
    ASSERT_GT(good.size(), 256u);
    // Every word of the first 4 KiB (header and directory), then a stride
    // through the slice data: ~1,200 files.
    std::vector<size_t> at;
    for (size_t o = 0; o + 4 <= good.size() && o < 4096; o += 4) at.push_back(o);
    const size_t stride = std::max<size_t>(4, (good.size() / 300) & ~size_t(3));
    for (size_t o = 4096; o + 4 <= good.size(); o += stride) at.push_back(o);
    size_t refused = 0, accepted = 0;
    for (size_t o : at)
      for (const uint32_t edit : {0xFFFFFFFFu, 0u, 0x80000000u, 1u}) {
        std::vector<uint8_t> b = good;
        uint32_t w;
        std::memcpy(&w, b.data() + o, 4);
        const uint32_t v = edit == 1u ? w + 1 : edit;
        if (v == w) continue;
        std::memcpy(b.data() + o, &v, 4);
        testing::rehash_slice_file(b);
        const std::string error = testing::check_slice_file(b);
        EXPECT_EQ(error.find('\n'), std::string::npos) << o << ": " << error;
        (error.empty() ? accepted : refused) += 1;
      }
    EXPECT_GT(refused, 0u);  // the validators behind the hashes do refuse
  }
}

// ---- Streaming ----

RenderOptions view_options(const Aabb& bounds, int size, float lod, float azimuth = 30.f,
                           float elevation = 20.f, float distance = 0.f) {
  RenderOptions ro;
  ro.width = ro.height = size;
  ro.camera = Camera::orbit(bounds, size, size, azimuth, elevation, distance);
  ro.lod_pixels = lod;
  ro.want_depth = true;
  return ro;
}

bool same_pixels(const Image& a, const Image& b) {
  return a.width == b.width && a.height == b.height && a.pixels.size() == b.pixels.size() &&
         std::memcmp(a.pixels.data(), b.pixels.data(), a.pixels.size() * sizeof(float)) == 0;
}

/// Renders frames of `ro` (one pass each) until a frame loads nothing,
/// checking the invariants after every pass; returns the last render.
RenderResult stream_until_still(esvo::StreamedEsvo& s, const RenderOptions& ro, int* frames,
                                int limit = 64) {
  RenderResult r;
  for (*frames = 0; *frames < limit; ++*frames) {
    const uint64_t before = s.stats().loaded + s.stats().unloaded + s.stats().refused;
    r = render(static_cast<Structure&>(s), ro);
    s.check_invariants();
    if (s.stats().loaded + s.stats().unloaded + s.stats().refused == before &&
        s.stats().pending == 0)
      break;
  }
  return r;
}

/// The bunny at `resolution`, in core and as a slice file (removed at the end).
struct SlicedBunny {
  SlicedBunny(uint32_t resolution, bool contours, uint64_t slice_bytes, const std::string& name)
      : octree(bunny(resolution, contours)),
        path(temp_file(name + (contours ? "-c" : ""))),
        in_core(octree) {
    esvo::SliceOptions so;
    so.slice_bytes = slice_bytes;
    esvo::write_slices(*octree, path, so);
  }
  ~SlicedBunny() { std::filesystem::remove(path); }
  std::shared_ptr<const esvo::EsvoOctree> octree;
  std::filesystem::path path;
  esvo::EsvoStructure in_core;
};

class Streamed : public ::testing::TestWithParam<bool> {};  // contours

TEST_P(Streamed, UnlimitedBudgetEqualsInCore) {
  const SlicedBunny b(128, GetParam(), 4096, "unlimited");  // many slices, deep hierarchy
  const auto& path = b.path;
  const esvo::EsvoStructure& in_core = b.in_core;
  for (const float lod : {0.f, 1.f}) {
    SCOPED_TRACE("lod " + std::to_string(lod));
    const RenderOptions ro = view_options(in_core.bounds(), 96, lod);
    const RenderResult want = render(in_core, ro);
    ASSERT_GT(want.hits, want.rays / 10);  // a picture worth comparing
    esvo::StreamedEsvo s(esvo::SliceFile::open(path));
    int frames = 0;
    const RenderResult got = stream_until_still(s, ro, &frames);
    EXPECT_LT(frames, 64);
    EXPECT_GT(frames, 2);  // it did stream: the first frame only had the root slice
    EXPECT_TRUE(same_pixels(got.color, want.color));
    EXPECT_TRUE(same_pixels(got.depth, want.depth));
    EXPECT_EQ(s.stats().refused, 0u);
    // The multi-pass mode reaches the same image within one frame.
    esvo::StreamedEsvo s2(esvo::SliceFile::open(path));
    RenderOptions multi = ro;
    multi.max_passes = 64;
    const RenderResult one = render(static_cast<Structure&>(s2), multi);
    EXPECT_TRUE(same_pixels(one.color, want.color));
    EXPECT_GT(one.passes, 2);
    // Everything resident: the same image as well.
    esvo::StreamedEsvo all(esvo::SliceFile::open(path));
    all.load_all();
    all.check_invariants();
    EXPECT_EQ(all.stats().resident_slices, all.file().slices().size());
    EXPECT_TRUE(same_pixels(render(static_cast<Structure&>(all), ro).color, want.color));
  }
}

// Slice files through the format registry (load_scene, every reader's
// loader): opened whole they are the in-core octree (occupied bounds bit for
// bit, the same images with depth, normals and the beam); info's open keeps
// only the root; a damaged slice refuses the whole-file open (one line
// naming the file) and is refused on its own when streaming.
TEST_P(Streamed, LoadSceneOpensSliceFilesThroughTheRegistry) {
  const SlicedBunny b(64, GetParam(), 2048, "registry");
  const std::filesystem::path vxc = temp_file("registry-in-core").replace_extension(".vxc");
  save_esvo_scene(vxc, *b.octree, SceneInfo{"bunny", "conservative", 0, 0});
  const LoadedScene in_core = load_scene(vxc), sliced = load_scene(b.path);
  std::filesystem::remove(vxc);
  EXPECT_EQ(sliced.format, "esvo-sliced");
  EXPECT_TRUE(sliced.sections.empty());
  const auto& s = dynamic_cast<const esvo::StreamedEsvo&>(*sliced.structure);
  EXPECT_EQ(s.stats().resident_slices, s.file().slices().size());
  EXPECT_GT(s.file().slices().size(), 8u);
  s.check_invariants();
  for (int a = 0; a < 3; ++a) {
    EXPECT_EQ(sliced.occupied.lo[a], in_core.occupied.lo[a]) << a;
    EXPECT_EQ(sliced.occupied.hi[a], in_core.occupied.hi[a]) << a;
  }
  for (const int beam : {0, 4}) {
    RenderOptions ro = view_options(in_core.occupied, 64, 1.f);
    ro.want_normal = true;
    ro.beam = beam;
    const RenderResult want = render(*in_core.structure, ro), got = render(*sliced.structure, ro);
    EXPECT_GT(want.hits, want.rays / 10);
    EXPECT_TRUE(same_pixels(got.color, want.color)) << beam;
    EXPECT_TRUE(same_pixels(got.depth, want.depth)) << beam;
    EXPECT_TRUE(same_pixels(got.normal, want.normal)) << beam;
  }
  const SceneFormat& f = format_registry().get("esvo-sliced");
  const SceneDescription d = f.describe(*sliced.structure, {});
  EXPECT_EQ(d.grid.resolution, b.octree->grid.resolution);
  EXPECT_NE(d.details.find("slice hierarchy"), std::string::npos);
  EXPECT_EQ(f.memory_bytes(*sliced.structure), s.stats().resident_bytes);
  EXPECT_EQ(f.stream_counters(*sliced.structure).resident_parts, s.file().slices().size());
  // Saving it as a container is refused (its files come from --slices).
  EXPECT_NE(testing::error_of([&] {
              save_scene(temp_file("never"), "esvo-sliced", *sliced.structure, {});
            }).find("not saved as a scene container"),
            std::string::npos);
  // The root only (info), and a budget the whole file does not fit: root only too.
  SceneLoadOptions lazy;
  lazy.load_all = false;
  EXPECT_EQ(dynamic_cast<const esvo::StreamedEsvo&>(*load_scene(b.path, lazy).structure)
                .stats()
                .resident_slices,
            1u);
  SceneLoadOptions small;
  small.stream_budget = esvo::StreamedEsvo::block_bytes(s.file().slices()[0]) + 1;
  const LoadedScene partial = load_scene(b.path, small);
  EXPECT_EQ(dynamic_cast<const esvo::StreamedEsvo&>(*partial.structure).stats().resident_slices,
            1u);
  // A damaged slice (its last data byte): the whole-file open refuses the file.
  std::vector<uint8_t> bytes = testing::read_bytes(b.path);
  bytes.back() ^= 0x40;
  const std::filesystem::path bad = temp_file("registry-damaged");
  testing::write_bytes(bad, bytes);
  const std::string e = testing::error_of([&] { (void)load_scene(bad); });
  EXPECT_NE(e.find(bad.string()), std::string::npos) << e;
  EXPECT_NE(e.find("slice"), std::string::npos) << e;
  EXPECT_EQ(e.find('\n'), std::string::npos) << e;
  EXPECT_NO_THROW((void)load_scene(bad, lazy));
  std::filesystem::remove(bad);
}

TEST_P(Streamed, SmallBudgetConvergesWhenTheViewStops) {
  const SlicedBunny b(256, GetParam(), 8192, "budget");
  const auto& path = b.path;
  const esvo::EsvoStructure& in_core = b.in_core;
  const Aabb box = in_core.bounds();
  // The final view: the whole bunny, 1-pixel LOD. What it needs resident:
  const RenderOptions still = view_options(box, 80, 1.f, 30.f, 20.f);
  const RenderResult want = render(in_core, still);
  uint64_t needed = 0;
  {
    esvo::StreamedEsvo s(esvo::SliceFile::open(path));
    int frames = 0;
    stream_until_still(s, still, &frames);
    needed = s.stats().resident_bytes;
  }
  uint64_t total = 0;
  {
    esvo::StreamedEsvo s(esvo::SliceFile::open(path));
    s.load_all();
    total = s.stats().resident_bytes;
  }
  ASSERT_LT(3 * needed, total);  // the budget below is well under the scene
  esvo::StreamOptions opt;
  opt.budget_bytes = needed;
  esvo::StreamedEsvo s(esvo::SliceFile::open(path), opt);
  // Fly first: close-ups from other sides fill the budget with slices the
  // final view does not need (invariants and the budget after every pass).
  int frames = 0;
  for (const float az : {200.f, 250.f, 300.f}) {
    const RenderOptions fly = view_options(box, 80, 0.5f, az, -10.f, 0.35f * length(box.extent()));
    for (int k = 0; k < 6; ++k) {
      render(static_cast<Structure&>(s), fly);
      s.check_invariants();
      EXPECT_LE(s.stats().resident_bytes, opt.budget_bytes);
    }
  }
  EXPECT_GT(s.stats().unloaded, 0u);  // the fly-through had to unload
  const RenderResult got = stream_until_still(s, still, &frames);
  EXPECT_LT(frames, 64);
  EXPECT_LE(s.stats().peak_resident_bytes, opt.budget_bytes);
  // The arena is the budget (a hard cap): the unloads left holes that later
  // loads needed closed, and the incremental compaction moved less than
  // compacting everything after the first hole would have.
  const esvo::StreamStats& st = s.stats();
  std::printf("arena: %llu compactions, %llu B moved, %llu B by full compactions\n",
              (unsigned long long)st.compactions, (unsigned long long)st.bytes_moved,
              (unsigned long long)st.full_compaction_bytes);
  EXPECT_GT(st.compactions, 0u);
  EXPECT_LT(st.bytes_moved, st.full_compaction_bytes);
  EXPECT_TRUE(same_pixels(got.color, want.color));
  EXPECT_TRUE(same_pixels(got.depth, want.depth));
}

// The coarse beam pass (§6.2) on the streamed structure: a voxel whose slice
// is not resident is kept whole, so every frame of a fly-through within a
// small budget renders the same pixels and asks for the same slices with and
// without the beam (two streams side by side), and the beam does skip work.
TEST_P(Streamed, BeamLeavesStreamedFramesUnchanged) {
  const SlicedBunny b(256, GetParam(), 8192, "beam");
  const Aabb box = b.in_core.bounds();
  esvo::StreamOptions opt;
  opt.budget_bytes = 96 * 1024;
  esvo::StreamedEsvo plain(esvo::SliceFile::open(b.path), opt);
  esvo::StreamedEsvo beamed(esvo::SliceFile::open(b.path), opt);
  uint64_t iterations_plain = 0, iterations_beam = 0;
  int partial = 0;  // frames rendered with requests left
  for (const float az : {30.f, 120.f, 210.f}) {
    RenderOptions ro = view_options(box, 64, 1.f, az, 15.f, 0.6f * length(box.extent()));
    ro.collect_stats = true;
    for (int k = 0; k < 4; ++k) {
      ro.beam = 0;
      const RenderResult a = render(static_cast<Structure&>(plain), ro);
      ro.beam = 8;
      const RenderResult c = render(static_cast<Structure&>(beamed), ro);
      EXPECT_TRUE(same_pixels(a.color, c.color)) << az << " " << k;
      EXPECT_TRUE(same_pixels(a.depth, c.depth)) << az << " " << k;
      EXPECT_EQ(plain.stats().loaded, beamed.stats().loaded);
      EXPECT_EQ(plain.stats().pending, beamed.stats().pending);
      EXPECT_EQ(plain.stats().resident_bytes, beamed.stats().resident_bytes);
      partial += plain.stats().pending > 0;
      iterations_plain += a.counters.iterations;
      iterations_beam += c.counters.iterations + c.coarse_counters.iterations;
      beamed.check_invariants();
    }
  }
  EXPECT_GT(partial, 0);                         // some frames ran with slices missing
  EXPECT_LT(iterations_beam, iterations_plain);  // the coarse pass skips work
  std::printf("iterations: %llu without the beam, %llu with (coarse pass included)\n",
              (unsigned long long)iterations_plain, (unsigned long long)iterations_beam);
}

// Figure 21: loading a slice merges it into its leaf block and splits the
// result into one block per child slice, moving what lies in none to the
// trunk; unloading is the exact inverse. From states along a stream, every
// next-level slice is loaded and unloaded again and every unloadable slice
// unloaded and loaded again: the invariants hold after each step (one block
// per next-level slice, trunk links only into resident blocks' roots,
// blocks depth-first within their regions) and the memory image returns to
// the same words.
TEST_P(Streamed, LoadAndUnloadMergeAndSplitBlocksExactly) {
  const SlicedBunny b(64, GetParam(), 2048, "fig21");
  esvo::StreamedEsvo s(esvo::SliceFile::open(b.path));
  const auto& all = s.file().slices();
  const RenderOptions ro = view_options(b.in_core.bounds(), 48, 0.f);
  size_t round_trips = 0, splits = 0;
  for (int frame = 0; frame < 6; ++frame) {
    for (uint32_t i = 1; i < all.size(); ++i) {
      const bool next_level = !s.resident(i) && !s.refused(i) && s.resident(all[i].parent);
      bool leaf = s.resident(i);
      for (uint32_t c = 0; leaf && c < all[i].child_count; ++c)
        leaf = !s.resident(all[i].first_child + c);
      if (!next_level && !leaf) continue;
      const std::vector<uint32_t> before = s.memory_image();
      const uint64_t trunk = s.stats().trunk_descriptors;
      if (next_level) {
        ASSERT_TRUE(s.load_slice(i)) << i;
        s.check_invariants();
        splits += s.stats().trunk_descriptors > trunk;
        ASSERT_TRUE(s.unload_slice(i)) << i;
      } else {
        ASSERT_TRUE(s.unload_slice(i)) << i;
        s.check_invariants();
        ASSERT_TRUE(s.load_slice(i)) << i;
      }
      s.check_invariants();
      EXPECT_EQ(s.memory_image(), before) << "slice " << i;
      ++round_trips;
    }
    render(static_cast<Structure&>(s), ro);
    s.check_invariants();
  }
  EXPECT_GT(round_trips, 50u);
  EXPECT_GT(splits, 5u);  // loads that moved block roots to the trunk
  // Everything resident: the trunk is the small top, the leaf blocks hold
  // the rest, and the image is the in-core one.
  s.load_all();
  s.check_invariants();
  EXPECT_GT(s.stats().trunk_descriptors, 0u);
  EXPECT_LT(s.stats().trunk_descriptors * 10, s.file().header().total_nodes);
  EXPECT_TRUE(
      same_pixels(render(static_cast<Structure&>(s), ro).color, render(b.in_core, ro).color));
}

// A budget far below what the view needs: the resident set settles (no
// slice is loaded and unloaded again and again) and stays within the budget.
TEST_P(Streamed, TooSmallBudgetSettlesWithoutThrashing) {
  const SlicedBunny b(256, GetParam(), 8192, "thrash");
  const RenderOptions still = view_options(b.in_core.bounds(), 80, 0.5f, 120.f, 10.f);
  uint64_t needed = 0;
  {
    esvo::StreamedEsvo s(esvo::SliceFile::open(b.path));
    int frames = 0;
    stream_until_still(s, still, &frames);
    needed = s.stats().resident_bytes;
  }
  esvo::StreamOptions opt;
  opt.budget_bytes = needed / 3;
  esvo::StreamedEsvo s(esvo::SliceFile::open(b.path), opt);
  int quiet = 0, frames = 0;
  for (; frames < 60 && quiet < 4; ++frames) {
    const uint64_t before = s.stats().loaded + s.stats().unloaded;
    render(static_cast<Structure&>(s), still);
    s.check_invariants();
    quiet = s.stats().loaded + s.stats().unloaded == before ? quiet + 1 : 0;
  }
  EXPECT_EQ(quiet, 4) << "still loading and unloading after " << frames << " frames";
  EXPECT_GT(s.stats().pending, 0u);  // it did run out of budget
  EXPECT_LE(s.stats().peak_resident_bytes, opt.budget_bytes);
}

TEST_P(Streamed, CorruptedSliceRefusedTheRestRenders) {
  const SlicedBunny b(128, GetParam(), 4096, "corrupt");
  const auto& path = b.path;
  const esvo::EsvoStructure& in_core = b.in_core;
  const RenderOptions ro = view_options(in_core.bounds(), 96, 0.f);
  const RenderResult want = render(in_core, ro);
  // Which slices the view loads, then damage one of the deepest level's.
  std::vector<uint32_t> used;
  {
    esvo::StreamedEsvo s(esvo::SliceFile::open(path));
    int frames = 0;
    stream_until_still(s, ro, &frames);
    int deepest = 0;
    for (uint32_t i = 1; i < s.file().slices().size(); ++i)
      if (s.resident(i)) deepest = std::max<int>(deepest, s.file().slices()[i].node_level);
    for (uint32_t i = 1; i < s.file().slices().size(); ++i)
      if (s.resident(i) && s.file().slices()[i].node_level == deepest) used.push_back(i);
  }
  ASSERT_FALSE(used.empty());
  const uint32_t victim = used[used.size() / 2];
  std::vector<uint8_t> bytes = testing::read_bytes(path);
  const size_t e = 128 + 64 * size_t(victim);
  bytes[get<uint64_t>(bytes, e + 8) + get<uint32_t>(bytes, e + 24) / 2] ^= 0x01;
  testing::write_bytes(path, bytes);

  esvo::StreamedEsvo s(esvo::SliceFile::open(path));  // the directory is intact
  int frames = 0;
  const RenderResult got = stream_until_still(s, ro, &frames);
  EXPECT_TRUE(s.refused(victim));
  EXPECT_EQ(s.stats().refused, 1u);
  EXPECT_FALSE(s.resident(victim));
  // The coarser voxel stands in: every in-core hit is still a hit (its
  // shape contains the finer one's), and most of the image is unchanged.
  size_t lost = 0, differ = 0;
  const size_t n = size_t(ro.width) * size_t(ro.height);
  for (size_t p = 0; p < n; ++p) {
    lost += std::isfinite(want.depth.pixels[p]) && !std::isfinite(got.depth.pixels[p]);
    differ += std::memcmp(&want.color.pixels[3 * p], &got.color.pixels[3 * p], 12) != 0;
  }
  EXPECT_EQ(lost, 0u);
  EXPECT_GT(differ, 0u);
  EXPECT_LT(differ, n / 10);
  // Opened whole (render within its memory budget) the file is refused, and
  // `info`, which does not load it, refuses it alike (it used to describe it).
  EXPECT_THROW(esvo::SliceFile::open(path)->verify_hashes(), Error);
  const std::string png = path.string() + ".png";
  for (const std::string& cmd : {"info '" + path.string() + "'",
                                 "render '" + path.string() + "' --size 32x24 -o '" + png + "'"}) {
    SCOPED_TRACE(cmd);
    const auto r = testing::run_cli(cmd);
    EXPECT_EQ(r.exit_code, 1) << r.output;
    EXPECT_NE(r.output.find("slice " + std::to_string(victim) + ": hash mismatch"),
              std::string::npos)
        << r.output;
  }
  EXPECT_FALSE(std::filesystem::exists(png));
}

// The file's occupied bounds (the automatic camera's box) are the in-core
// octree's, bit for bit, at every walk depth and whatever is resident: the
// bunny at 256^3 is deeper than the default walk (7 levels), so the
// resident voxels' bounds would differ. A damaged slice does not throw: the
// walk ends at its descriptors' coarser cubes, which contain what they hold.
// Compressed slices stream like raw ones: decoded on load (read()), the
// converged streamed image equals the whole file opened at once; the hits
// (depth) are the raw in-core octree's; within a budget the resident bytes
// stay under it and every pass keeps the invariants; streaming the view
// reads fewer bytes than from the raw file (whose slices are planned with
// the raw record sizes, so its hierarchy differs).
TEST_P(Streamed, CompressedSlicesStreamLikeRawOnes) {
  const SlicedBunny b(128, GetParam(), 4096, "compressed-raw");
  const auto path = temp_file(std::string("compressed-stream") + (GetParam() ? "-c" : ""));
  esvo::SliceOptions so;
  so.slice_bytes = 4096;
  so.compressed = true;
  esvo::write_slices(*b.octree, path, so);
  const RenderOptions ro = view_options(b.in_core.bounds(), 96, 0.f);
  const RenderResult raw = render(b.in_core, ro);
  esvo::StreamedEsvo whole(esvo::SliceFile::open(path));
  whole.load_all();
  whole.check_invariants();
  const RenderResult want = render(static_cast<Structure&>(whole), ro);
  EXPECT_TRUE(same_pixels(want.depth, raw.depth));
  EXPECT_FALSE(same_pixels(want.color, raw.color));  // decoded §5.5 values
  esvo::StreamedEsvo s(esvo::SliceFile::open(path));
  int frames = 0;
  const RenderResult got = stream_until_still(s, ro, &frames);
  EXPECT_GT(frames, 2);
  EXPECT_TRUE(same_pixels(got.color, want.color));
  EXPECT_TRUE(same_pixels(got.depth, want.depth));
  esvo::StreamedEsvo from_raw(esvo::SliceFile::open(b.path));
  stream_until_still(from_raw, ro, &frames);
  EXPECT_LT(s.stats().bytes_read, from_raw.stats().bytes_read);
  // Within a budget of a third of the whole scene.
  esvo::StreamOptions small;
  small.budget_bytes = whole.stats().resident_bytes / 3;
  esvo::StreamedEsvo budgeted(esvo::SliceFile::open(path), small);
  for (int f = 0; f < 12; ++f) {
    render(static_cast<Structure&>(budgeted),
           view_options(b.in_core.bounds(), 64, 0.f, 30.f + 25.f * float(f), 20.f));
    budgeted.check_invariants();
    EXPECT_LE(budgeted.stats().resident_bytes, small.budget_bytes);
  }
  EXPECT_GT(budgeted.stats().loaded, 0u);
  EXPECT_EQ(budgeted.stats().refused, 0u);
  std::filesystem::remove(path);
}

TEST_P(Streamed, FileOccupiedBoundsAreTheInCoreOctrees) {
  const SlicedBunny b(256, GetParam(), 8192, "bounds");
  const auto file = esvo::SliceFile::open(b.path);
  for (const int max_level : {0, 1, 3, 6, 7, 8, 9}) {
    const Aabb want = esvo::occupied_bounds(*b.octree, max_level),
               got = file->occupied_bounds(max_level);
    for (int a = 0; a < 3; ++a) {
      EXPECT_EQ(got.lo[a], want.lo[a]) << max_level << " " << a;
      EXPECT_EQ(got.hi[a], want.hi[a]) << max_level << " " << a;
    }
  }
  const Aabb b7 = esvo::occupied_bounds(*b.octree, 7), b8 = esvo::occupied_bounds(*b.octree, 8);
  bool deeper_differs = false;
  for (int a = 0; a < 3; ++a) deeper_differs |= b7.lo[a] != b8.lo[a] || b7.hi[a] != b8.hi[a];
  if (!GetParam()) {  // (variable depth: the contoured leaves above 7 set the box)
    EXPECT_TRUE(deeper_differs);
  }
  SceneLoadOptions small;
  small.stream_budget = esvo::StreamedEsvo::block_bytes(file->slices()[0]) + 1;
  const LoadedScene partial = load_scene(b.path, small);
  const Aabb want = esvo::occupied_bounds(*b.octree);
  for (int a = 0; a < 3; ++a) {
    EXPECT_EQ(partial.occupied.lo[a], want.lo[a]) << a;
    EXPECT_EQ(partial.occupied.hi[a], want.hi[a]) << a;
  }
  // Damage every slice of node level 3 (the walk reads levels 0..6).
  std::vector<uint8_t> bytes = testing::read_bytes(b.path);
  int damaged = 0;
  for (size_t i = 0; i < file->slices().size(); ++i) {
    const esvo::slice_layout::SliceEntry& e = file->slices()[i];
    if (e.node_level != 3) continue;
    bytes[e.data_offset + e.data_bytes / 2] ^= 0x10;
    ++damaged;
  }
  ASSERT_GT(damaged, 0);
  testing::write_bytes(b.path, bytes);
  const Aabb coarse = esvo::SliceFile::open(b.path)->occupied_bounds();
  const Aabb at3 = esvo::occupied_bounds(*b.octree, 3);
  for (int a = 0; a < 3; ++a) {
    EXPECT_LE(coarse.lo[a], want.lo[a]) << a;
    EXPECT_GE(coarse.hi[a], want.hi[a]) << a;
    EXPECT_GE(coarse.lo[a], at3.lo[a]) << a;
    EXPECT_LE(coarse.hi[a], at3.hi[a]) << a;
  }
}

INSTANTIATE_TEST_SUITE_P(Contours, Streamed, ::testing::Values(false, true),
                         [](const ::testing::TestParamInfo<bool>& i) {
                           return i.param ? std::string("contours") : std::string("cubes");
                         });

}  // namespace
}  // namespace voxcast

namespace voxcast {
namespace {

// The CLI: build --slices, info on a slice file, render --budget --frames
// (per-frame streaming lines; the budget bounds the resident MiB printed).
TEST(EsvoSlicesCli, BuildInfoRender) {
  testing::TempDir dir;
  const std::string mesh = (kMeshes / "stanford-bunny.obj").string();
  const std::string out = dir.file("b.vxs");
  auto r = testing::run_cli("build '" + mesh + "' --resolution 64 --slices --slice-size 2K -o '" +
                            out + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find(" slices (target 2.00 KiB)"), std::string::npos) << r.output;
  const auto file = esvo::SliceFile::open(out);
  r = testing::run_cli("info '" + out + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("slice hierarchy (esvo §7): " + std::to_string(file->slices().size()) +
                          " slices"),
            std::string::npos)
      << r.output;
  r = testing::run_cli("render '" + out +
                       "' --budget 40K --frames 5 --size 64x64 --write-frames -o '" +
                       dir.file("b.png") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  // --write-frames: every frame, the last one equal to -o.
  for (int f = 0; f < 5; ++f)
    EXPECT_TRUE(std::filesystem::exists(dir.file("b-00" + std::to_string(f) + ".png"))) << f;
  EXPECT_EQ(testing::read_bytes(dir.file("b-004.png")), testing::read_bytes(dir.file("b.png")));
  for (int f = 0; f < 5; ++f)
    EXPECT_NE(r.output.find("frame " + std::to_string(f) + ": loaded "), std::string::npos)
        << r.output;
  EXPECT_TRUE(std::filesystem::exists(dir.file("b.png")));
  // Every frame's resident size within the 40 KiB budget.
  int frames = 0;
  for (size_t at = 0; (at = r.output.find(" slices ", at)) != std::string::npos; ++at) {
    const size_t mib = r.output.find(" MiB", at);
    if (mib == std::string::npos || r.output.compare(at, 8, " slices ") != 0) continue;
    const double resident = std::stod(r.output.substr(at + 8, mib - at - 8));
    EXPECT_LE(resident, 40.0 / 1024.0 + 0.005) << r.output;
    ++frames;
  }
  EXPECT_EQ(frames, 5) << r.output;
  // Compressed attributes (§5.5 blocks per slice): built top-down, shown by
  // info, rendered with the same hits as the raw file; not with the
  // attribute tolerances (a usage error).
  r = testing::run_cli("build '" + mesh +
                       "' --resolution 64 --slices --slice-size 2K --attributes compressed -o '" +
                       dir.file("c.vxs") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("top-down from"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find(", compressed attributes"), std::string::npos) << r.output;
  EXPECT_LT(std::filesystem::file_size(dir.file("c.vxs")), 0.6 * std::filesystem::file_size(out));
  r = testing::run_cli("info --json '" + dir.file("c.vxs") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("\"attributes\": \"compressed\""), std::string::npos) << r.output;
  for (const char* in : {"c.vxs", "b.vxs"}) {
    r = testing::run_cli("render '" + dir.file(in) + "' --size 48x40 --depth '" +
                         dir.file(std::string(in) + ".pfm") + "' -o '" +
                         dir.file(std::string(in) + ".png") + "'");
    ASSERT_EQ(r.exit_code, 0) << r.output;
  }
  EXPECT_EQ(testing::read_bytes(dir.file("c.vxs.pfm")), testing::read_bytes(dir.file("b.vxs.pfm")));
  EXPECT_NE(testing::read_bytes(dir.file("c.vxs.png")), testing::read_bytes(dir.file("b.vxs.png")));
  r = testing::run_cli("render '" + dir.file("c.vxs") +
                       "' --budget 40K --frames 3 --size 64x64 -o '" + dir.file("c.png") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = testing::run_cli("build '" + mesh +
                       "' --resolution 32 --contours --color-error 8 --normal-error 10 --slices "
                       "--attributes compressed -o '" +
                       dir.file("c2.vxs") + "'");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("contours, compressed attributes"), std::string::npos) << r.output;
  r = testing::run_cli("build '" + mesh +
                       "' --resolution 16 --contours --color-error 8 --fill solid --slices "
                       "--attributes compressed -o '" +
                       dir.file("c3.vxs") + "'");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_FALSE(std::filesystem::exists(dir.file("c3.vxs")));
  // Usage errors: --budget on a .vxc.
  r = testing::run_cli("build '" + mesh + "' --resolution 16 -o '" + dir.file("d.vxc") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = testing::run_cli("render '" + dir.file("d.vxc") + "' --budget 1M -o '" + dir.file("d.png") +
                       "'");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  r = testing::run_cli("render '" + out + "' --budget lots -o '" + dir.file("e.png") + "'");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  r = testing::run_cli("render '" + out + "' --write-frames -o '" + dir.file("e.png") + "'");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  // --beam streams the same frames.
  r = testing::run_cli("render '" + out + "' --budget 40K --frames 3 --size 64x64 --beam 4 -o '" +
                       dir.file("beam.png") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = testing::run_cli("render '" + out + "' --budget 40K --frames 3 --size 64x64 -o '" +
                       dir.file("nobeam.png") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(testing::read_bytes(dir.file("beam.png")), testing::read_bytes(dir.file("nobeam.png")));
  // Streamed frames render color only.
  r = testing::run_cli("render '" + out + "' --budget 40K --depth '" + dir.file("e.pfm") +
                       "' -o '" + dir.file("e.png") + "'");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_FALSE(std::filesystem::exists(dir.file("e.png")));
  // Without --budget/--frames a slice file loads through the registry like
  // any scene: the images of the in-core scene of the same octree.
  r = testing::run_cli("build '" + mesh + "' --resolution 64 -o '" + dir.file("b.vxc") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  for (const char* in : {"b.vxs", "b.vxc"}) {
    r = testing::run_cli("render '" + dir.file(in) + "' --size 48x40 --beam 4 --depth '" +
                         dir.file(std::string(in) + ".pfm") + "' -o '" +
                         dir.file(std::string(in) + ".png") + "'");
    ASSERT_EQ(r.exit_code, 0) << r.output;
  }
  EXPECT_EQ(testing::read_bytes(dir.file("b.vxs.png")), testing::read_bytes(dir.file("b.vxc.png")));
  EXPECT_EQ(testing::read_bytes(dir.file("b.vxs.pfm")), testing::read_bytes(dir.file("b.vxc.pfm")));
  // The automatic camera is the same for a slice file (opened whole or
  // streamed within a budget) and its .vxc, also deeper than the bounds
  // walk (256^3: 8 levels).
  {
    const std::string deep = " --resolution 256 --slice-size 16K";
    r = testing::run_cli("build '" + mesh + "'" + deep + " --slices -o '" + dir.file("a.vxs") +
                         "'");
    ASSERT_EQ(r.exit_code, 0) << r.output;
    r = testing::run_cli("build '" + mesh + "' --resolution 256 -o '" + dir.file("a.vxc") + "'");
    ASSERT_EQ(r.exit_code, 0) << r.output;
    auto camera_of = [&](const std::string& args) {
      const auto run =
          testing::run_cli("render " + args + " --size 32x24 -o '" + dir.file("a.png") + "'");
      EXPECT_EQ(run.exit_code, 0) << run.output;
      const size_t at = run.output.find("camera: ");
      EXPECT_NE(at, std::string::npos) << run.output;
      return at == std::string::npos ? std::string()
                                     : run.output.substr(at, run.output.find('\n', at) - at);
    };
    const std::string want = camera_of("'" + dir.file("a.vxc") + "'");
    EXPECT_EQ(camera_of("'" + dir.file("a.vxs") + "'"), want);
    EXPECT_EQ(camera_of("'" + dir.file("a.vxs") + "' --budget 64K --frames 2"), want);
    EXPECT_EQ(camera_of("'" + dir.file("a.vxs") + "' --budget 64K --frames 2 --camera ortho")
                  .find("camera: ortho,"),
              0u);
  }
  r = testing::run_cli("info --json '" + out + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("\"format\": \"esvo-sliced\""), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("\"resident_slices\": 1"), std::string::npos) << r.output;
  // Contours and the geometric variable depth are built top-down; the image
  // equals the in-core contour build's.
  r = testing::run_cli("build '" + mesh +
                       "' --resolution 64 --contours --geometry-error 0.5 --slices --slice-size 2K "
                       "-o '" +
                       dir.file("g.vxs") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("top-down from"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find(", contours"), std::string::npos) << r.output;
  r = testing::run_cli("build '" + mesh + "' --resolution 64 --contours --geometry-error 0.5 -o '" +
                       dir.file("g.vxc") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  for (const char* in : {"g.vxs", "g.vxc"}) {
    r = testing::run_cli("render '" + dir.file(in) + "' --size 48x40 -o '" +
                         dir.file(std::string(in) + ".png") + "'");
    ASSERT_EQ(r.exit_code, 0) << r.output;
  }
  EXPECT_EQ(testing::read_bytes(dir.file("g.vxs.png")), testing::read_bytes(dir.file("g.vxc.png")));
  // The attribute tolerances (§7.3) too: the same image as the in-core build.
  const std::string tol = "' --resolution 64 --contours --color-error 8 --normal-error 10";
  r = testing::run_cli("build '" + mesh + tol + " --slices --slice-size 2K -o '" +
                       dir.file("h.vxs") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("top-down from"), std::string::npos) << r.output;
  r = testing::run_cli("build '" + mesh + tol + " -o '" + dir.file("h.vxc") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  for (const char* in : {"h.vxs", "h.vxc"}) {
    r = testing::run_cli("render '" + dir.file(in) + "' --size 48x40 -o '" +
                         dir.file(std::string(in) + ".png") + "'");
    ASSERT_EQ(r.exit_code, 0) << r.output;
  }
  EXPECT_EQ(testing::read_bytes(dir.file("h.vxs.png")), testing::read_bytes(dir.file("h.vxc.png")));
  // Slice files are written by --slices, not by --format.
  r = testing::run_cli("build '" + mesh + "' --resolution 16 --format esvo-sliced -o '" +
                       dir.file("f.vxc") + "'");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("written by --slices"), std::string::npos) << r.output;
}

}  // namespace
}  // namespace voxcast
