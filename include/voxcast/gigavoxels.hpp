#pragma once
// GigaVoxels (Crassin et al. 2010, ../shared/papers/gigavoxels-crassin-2010.md;
// docs/ARCHITECTURE.md "GigaVoxels"): a sparse voxel octree of small bricks
// that holds only what the rays ask for, at the resolution they need.
//
//  * Pools (§3.4): a node pool of 2x2x2 node tiles and a brick pool of
//    (M+2)^3-voxel bricks (M = 16 plus a one-voxel border, so that trilinear
//    lookups anywhere inside a node stay inside its brick and match the
//    neighbours': seamless filtering). Both sizes are fixed at construction
//    by a memory budget; both pools are LRU caches.
//  * Rendering (§3.5): the VolumeQuery descends by point location (child =
//    c + int(2x)), stops where the node's voxel is no larger than the pixel
//    cone (LodFootprint) and yields one span per node: constant nodes as
//    constant spans, brick nodes as brick spans that sample() filters
//    quadrilinearly between the brick and its parent's.
//  * Cache and requests (§3.6) through the frame loop (integrator.hpp): rays
//    stamp every tile and brick they use (ctx.frame, ctx.pass) and push a
//    data request (kind 1) for a node without data or a subdivide request
//    (kind 0) for a node without children, answering meanwhile with the
//    deepest ancestor that has data. end_pass() sorts the usage lists by
//    order-preserving compaction (used in this pass to the back), recycles
//    the front (never what this pass used), invalidates pointers in two steps
//    (zero the recycled elements' timestamps, then null every pointer to a
//    zero-stamped element), has the producer fill bricks on worker threads and
//    decide constant vs brick, and subdivides.
//
// FrameView::frame must change from one frame to the next: the timestamps
// tell this pass's use from older use by (frame, pass).
#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "voxcast/bitfield.hpp"
#include "voxcast/camera.hpp"
#include "voxcast/image.hpp"
#include "voxcast/structure.hpp"
#include "voxcast/volume_query.hpp"

namespace voxcast {
struct Mesh;
}

namespace voxcast::giga {

/// M: voxels per brick side (without the border). The paper allows 8 or 16
/// (§3.4); 16 measured faster on the warm cloud frame (docs/BENCHMARKS.md
/// "GigaVoxels: 16³ bricks"): a ray crosses half as many bricks, so the
/// per-span work (locate, set-up of two lookups, loop exits) is paid half
/// as often, and the border costs 1.42x the useful voxels instead of 1.95x.
/// A brick is 18³ x 8 B = 46,656 B.
constexpr int kBrickSide = 16;
/// Stored voxels per brick side: one border voxel on each side.
constexpr int kBrickStored = kBrickSide + 2;
constexpr int kBrickVoxels = kBrickStored * kBrickStored * kBrickStored;
/// Deepest node level (localization codes hold 10 bits per axis, §3.6.6).
constexpr int kMaxLevel = 10;

/// One brick voxel as a producer makes it, 16 bytes: extinction per
/// unit-cube length and the color premultiplied by it (so that trilinear
/// filtering of a voxel next to empty space does not darken its color; the
/// color is (r, g, b) / density).
///   byte 0: float density   byte 4: float r*density
///   byte 8: float g*density byte 12: float b*density
/// A brick is kBrickVoxels of these, x fastest: stored (i, j, k) at
/// i + 18 (j + 18 k), where stored i is voxel i - 1 of the node's M^3 grid
/// (0 and M + 1: the border). The pool keeps them as PoolVoxel.
struct BrickVoxel {
  float density, r, g, b;
};
static_assert(sizeof(BrickVoxel) == 16 && offsetof(BrickVoxel, r) == 4 &&
              offsetof(BrickVoxel, b) == 12);

/// One voxel as the brick pool stores it, 8 bytes: BrickVoxel's four
/// channels times the side of a voxel of the node's level (extinction per
/// voxel: the optical depth across one voxel, a dimensionless number of
/// the same range at every level), as IEEE 754 binary16 (half) floats,
/// rounded to nearest even, saturated at the largest half (65504).
///   byte 0: half density*v  byte 2: half r*density*v
///   byte 4: half g*density*v byte 6: half b*density*v   (v = 2^-L / 16)
/// Half of the 16-byte float voxel: warm frames are bound by brick loads
/// (docs/BENCHMARKS.md, 2026-12-06), and twice the bricks fit a budget (the
/// paper's pools trade precision for capacity the same way: §3.4 stores
/// RGBA8 bricks in GPU textures). Relative rounding error at most 2^-11
/// (values below 2^-14 per voxel: absolute 2^-25). The scale is a power of
/// two, exact, and the same for a voxel in every brick that holds it as a
/// border: neighbouring bricks' borders stay equal (seamless filtering).
/// Same layout and order as BrickVoxel; brick b of the pool is
/// kBrickVoxels of these from voxel index b * kBrickVoxels.
struct PoolVoxel {
  uint16_t density, r, g, b;  // trivial: the pool is allocated without writing it
};
static_assert(sizeof(PoolVoxel) == 8 && offsetof(PoolVoxel, r) == 2 && offsetof(PoolVoxel, b) == 6);
/// What the pool gives back for channel value `value` (a BrickVoxel field)
/// of a level-`level` voxel: the value through PoolVoxel's half rounding.
float stored_value(int level, float value);

/// One voxel of an 8-bit brick pool (GigaOptions::brick_bits = 8), 4 bytes:
/// BrickVoxel's four channels as unsigned 8-bit fractions of the brick's
/// own range per channel, the RGBA8 bricks of the paper's GPU pools (§3.4).
///   byte 0: density q  byte 1: r*density q  byte 2: g*density q  byte 3: b*density q
/// Channel c of a voxel is q * step[c], step[c] = (the brick's largest
/// value of channel c) / 255, a BrickSteps8 per brick kept beside the pool;
/// q = round(value / step[c]), so the error is at most step[c] / 2. Half the
/// bytes of PoolVoxel: twice the bricks fit a budget and a warm frame, bound
/// by its brick loads (docs/BENCHMARKS.md), reads half the cache lines. The
/// price: a brick's faint voxels keep only 1/255 of its brightest one's
/// range, and a voxel held by two bricks (a border) may round differently in
/// each (a seam of at most half the larger step). Scalar data under a steep
/// transfer function wants the default 16-bit pool.
struct PoolVoxel8 {
  uint8_t density, r, g, b;
};
static_assert(sizeof(PoolVoxel8) == 4 && offsetof(PoolVoxel8, b) == 3);
/// Bytes of one pool voxel at `bits` per channel (GigaOptions::brick_bits).
constexpr size_t pool_voxel_bytes(int bits) {
  return bits == 8 ? sizeof(PoolVoxel8) : sizeof(PoolVoxel);
}
struct BrickSteps8 {
  float step[4];  // density, r*density, g*density, b*density per unit q
};

// ---- Node pool layout (§3.4.2, Figure 3.5): two 32-bit words per node, in
// two separate arrays (structure and data are read at different times of the
// descent). Node n is child (n & 7) of tile n >> 3; its words are at byte
// offset 4 n of each array; tile t's eight words at byte 32 t. Child bits:
// bit 0 = x, bit 1 = y, bit 2 = z (the child whose half contains int(2x)).
// Tile 0 holds the root in its node 0 (nodes 1..7 unused) and is never
// recycled, so a child pointer of 0 means "no children".

/// Structure word: child tile pointer (26 bits: pools hold at most 2^26
/// tiles), the empty-below summary and the terminal flag.
using NodeChildTile = BitField<0, 26>;  // bits 0..25
/// Empty below (kept by end_pass, 0 = none): D > the node's level L when
/// the node has a child tile and every node of levels L + 1 .. D under it
/// that a descent can reach is resident and an empty constant (a node there
/// without children is terminal or at level D). A ray whose cone stops the
/// descent between L + 1 and D all across the node's box meets only empty
/// space there and crosses the box in one step (march).
using NodeEmptyBelow = BitField<26, 4>;  // bits 26..29
using NodeTerminal = BitField<30, 1>;    // bit 30: refined to the maximum
/// Data word: kind (2 bits) + payload (30 bits): a brick index or an index
/// into the structure's table of constant values.
using NodeDataPayload = BitField<0, 30>;  // bits 0..29
using NodeDataKind = BitField<30, 2>;     // bits 30..31
enum : uint32_t { kDataNone = 0, kDataConstant = 1, kDataBrick = 2 };
static_assert(NodeChildTile::mask == 0x03FFFFFFu && NodeEmptyBelow::mask == 0x3C000000u &&
              NodeTerminal::mask == 0x40000000u);
static_assert(NodeEmptyBelow::max >= kMaxLevel);
static_assert(NodeDataPayload::mask == 0x3FFFFFFFu && NodeDataKind::mask == 0xC0000000u);

/// Per-tile localization code (§3.6.6): the parent node's cell coordinates
/// at the parent's level, 10 bits per axis. With the tile's depth (8 bits,
/// the level of the tile's nodes), node c of the tile is at that level, cell
/// 2 * code + (c & 1, c >> 1 & 1, c >> 2).
using LocX = BitField<0, 10>;
using LocY = BitField<10, 10>;
using LocZ = BitField<20, 10>;
static_assert(LocZ::mask == 0x3FF00000u);

/// Request kinds pushed into TraceContext::requests (key = node index).
enum : uint32_t { kRequestSubdivide = 0, kRequestData = 1 };

/// A node's place in the octree: level L, cell (x, y, z) of the 2^L grid
/// over the unit cube.
struct NodeRegion {
  int level = 0;
  uint32_t x = 0, y = 0, z = 0;
};

/// What a producer made of a node.
struct Produced {
  bool constant = false;  // the whole node (with its border) holds `value`
  bool terminal = false;  // no finer level differs: never subdivide
  VolumeSample value;     // constant nodes only
};

/// The source of a volume (§3.6.7 "data provider"): filtered voxels at every
/// level, over the unit cube. Called from worker threads: must be thread-safe.
class Producer {
 public:
  virtual ~Producer() = default;
  virtual std::string name() const = 0;
  /// Level of the finest nodes (their bricks hold the full resolution
  /// 2^max_level x M per axis); nodes at this level are terminal.
  virtual int max_level() const = 0;
  /// Voxel (x, y, z) of level L's grid ((2^L M)^3 voxels over the unit
  /// cube), filtered for that level; empty outside the cube. Density is
  /// extinction per unit-cube length; color linear RGB.
  virtual VolumeSample voxel(int level, int64_t x, int64_t y, int64_t z) const = 0;
  /// True when the node's region (with a one-voxel margin) is provably
  /// constant at its level and every finer one; sets *value. Default: never.
  virtual bool constant_below(const NodeRegion& r, VolumeSample* value) const {
    (void)r, (void)value;
    return false;
  }
  /// Fills `out` (kBrickVoxels, the layout of BrickVoxel) with the node's
  /// brick from voxel() and decides constant vs brick: constant_below() ->
  /// constant and terminal; all stored voxels equal -> constant (terminal
  /// only at max_level); otherwise a brick.
  Produced produce(const NodeRegion& r, std::span<BrickVoxel> out) const;
};

/// Procedural producers (issue 12 item 5), `resolution` = voxels per axis
/// at the finest level (a power of two, 8 .. 8192):
///  * "cloud": band-limited value-noise fBm inside a soft sphere (octaves
///    finer than a level's voxel are dropped: each level is prefiltered);
///  * "mandelbulb": the power-8 Mandelbulb distance estimate;
///  * "menger": the Menger sponge signed distance;
/// the two fractals as solids whose voxel density is the coverage
/// clamp(0.5 - d / voxel, 0, 1) of their distance d. Throws voxcast::Error
/// for an unknown name or resolution.
std::shared_ptr<Producer> make_procedural(const std::string& name, int resolution);

/// A scalar volume read from a file (inrimage.cpp).
struct ScalarVolume {
  int nx = 0, ny = 0, nz = 0;
  float vx = 1.f, vy = 1.f, vz = 1.f;  // voxel size (VX, VY, VZ)
  std::vector<float> values;           // x fastest
  float at(int x, int y, int z) const {
    return values[(size_t(z) * size_t(ny) + size_t(y)) * size_t(nx) + size_t(x)];
  }
};
/// INRIMAGE-4 (.inr): a text header "#INRIMAGE-4#{" of KEY=VALUE lines padded
/// to a multiple of 256 bytes and closed by "##}", then XDIM*YDIM*ZDIM*VDIM
/// raw samples of TYPE (unsigned fixed | signed fixed | float) and PIXSIZE
/// bits, byte order CPU (decm/alpha/pc little endian, sun/sgi big). VDIM must
/// be 1. Validates every field and the data size; throws voxcast::Error with
/// a one-line message naming the problem.
ScalarVolume parse_inrimage(std::span<const unsigned char> bytes);
/// parse_inrimage of a file, gzip'd (.inr.gz) or not (told by its first bytes).
ScalarVolume read_inrimage(const std::string& path);
/// Inflates a gzip stream (one-line INRIMAGE errors for a truncated or
/// corrupted stream; refuses output beyond the largest accepted volume).
std::vector<unsigned char> gunzip(std::span<const unsigned char> bytes);
/// Writes `v` as an INRIMAGE-4 float file (tests and tools).
std::vector<unsigned char> write_inrimage(const ScalarVolume& v);
/// MetaImage (ITK): a text header of "Key = Value" lines (ObjectType Image,
/// NDims 3, DimSize, ElementSpacing, ElementType MET_UCHAR | MET_CHAR |
/// MET_USHORT | MET_SHORT | MET_UINT | MET_INT | MET_FLOAT | MET_DOUBLE,
/// ElementNumberOfChannels 1, BinaryDataByteOrderMSB / ElementByteOrderMSB,
/// HeaderSize, CompressedData False) ended by ElementDataFile: LOCAL (the
/// samples follow in the same file, .mha) or the name of a raw file next to
/// the header (.mhd + .raw), read through `read_data_file`. Placement keys
/// (Offset, TransformMatrix, ...) are ignored, unknown keys refused; the data
/// size must match exactly. Throws voxcast::Error with a one-line message.
ScalarVolume parse_metaimage(
    std::span<const unsigned char> bytes,
    const std::function<std::vector<unsigned char>(const std::string&)>& read_data_file = {});
/// parse_metaimage of a .mhd / .mha file (a data file is looked up next to it).
ScalarVolume read_metaimage(const std::string& path);
/// Writes `v` as a MetaImage .mha (float samples after the header).
std::vector<unsigned char> write_metaimage(const ScalarVolume& v);
/// A scalar volume file by its extension: .inr / .inr.gz (INRIMAGE-4) or
/// .mhd / .mha (MetaImage); throws voxcast::Error for another extension.
ScalarVolume read_volume_file(const std::string& path);
/// A mesh voxelized by the pipeline (conservative surface voxels plus the
/// interior, fill_solid) on the grid GridTransform::fit gives it at
/// `resolution` (a power of two, 1..1024): 1 in every solid voxel, 0
/// elsewhere; voxel sizes the grid's. Throws voxcast::Error.
ScalarVolume solid_volume(const Mesh& mesh, int resolution);
/// A producer over a scalar volume: the data centered in the unit cube
/// (longest side = 1, voxel sizes honoured), values mapped linearly from
/// [min, max] of the data to densities [0, 1] (a scalar for the volume
/// integrator's transfer function), color white; coarser levels average
/// 2x2x2 voxels of the level below.
std::shared_ptr<Producer> make_volume_producer(const ScalarVolume& v);

/// An OpenVDB FloatGrid read from a .vdb file (vdb_volume.cpp), served brick
/// by brick: the grid's first FloatGrid named "density", else its first
/// FloatGrid. A fog volume's values are its densities; a level set's signed
/// distance phi becomes the coverage clamp(0.5 - phi / voxel, 0, 1) (the
/// procedural fractals' rule: 1 inside, 0 outside, a one-voxel ramp at the
/// surface, the interior tiles 1). A density is extinction per grid voxel
/// length (OpenVDB's VolumeRender convention with scattering + absorption =
/// 1); the producer serves it per unit-cube length (x the cube's voxels per
/// side). The cube is the bounding box of the grid's non-zero densities,
/// centered, its side the next 8 x 2^L voxels; the finest level holds the
/// grid's voxels exactly, every coarser level the 2x2x2 box filter (mean) of
/// the one below, built sparsely at load. The file is read through
/// read_vdb's checks (src/io/vdb_grids.hpp). Throws voxcast::Error with a
/// one-line message: unreadable or damaged file, no FloatGrid, a rotated,
/// non-uniform or non-linear transform, no non-zero density, an extent
/// above 8192 voxels.
struct VdbVolume {
  std::shared_ptr<Producer> producer;
  /// World placement of the unit cube (GigaOptions::origin, size): the grid's
  /// own world coordinates.
  Vec3 origin{0, 0, 0};
  float size = 1.f;
  std::string grid_name;
  bool level_set = false;
  uint64_t active_voxels = 0;
  int64_t extent[3] = {0, 0, 0};  // non-zero bounding box, voxels per axis
  double voxel_size = 1.0;        // world side of a grid voxel
  float min_density = 0.f, max_density = 0.f;
  uint64_t grid_bytes = 0, pyramid_bytes = 0;  // the grid and its coarser levels in memory
};
VdbVolume read_vdb_volume(const std::string& path);

/// Writes the finest level of `producer` as a .vdb fog volume: one FloatGrid
/// "density" whose voxel (i, j, k) (centered at origin + (i + 1/2) h, h =
/// size / voxels per side) holds the producer's density x density_scale per
/// grid voxel (extinction per unit cube / voxels per side), zeros left
/// inactive; the header's UUID derived from the content (same volume, same
/// bytes). The finest level must be at most 1024 voxels per side. Throws
/// voxcast::Error.
void write_vdb_volume(const Producer& producer, const std::string& path, Vec3 origin = {0, 0, 0},
                      float size = 1.f, float density_scale = 1.f);

/// The benchmark peer (issue 12): OpenVDB's own ray marcher,
/// openvdb::tools::VolumeRender with a VolumeRayIntersector, over the same
/// density grid, through voxcast's camera rays (pixel centers). Its model:
/// steps of `step` grid voxels with trilinear samples, extinction = density
/// per voxel, single scattering of a white directional light towards
/// `light_dir` (albedo 1), a shadow ray per sample with the same step, no
/// ambient; color = the scattered light, alpha = 1 - mean transmittance.
/// The image is RGB, the scattered light composited over `background` by the
/// mean transmittance.
struct VdbPeerOptions {
  double step = 0.5;  // primary and shadow steps, in grid voxels
  Vec3 light_dir{0.4f, 0.8f, 0.45f};
  Color background{0.f, 0.f, 0.f, 1.f};
  bool threaded = true;  // TBB over rows (OpenVDB's render(true))
};
class VdbPeer {
 public:
  /// Throws voxcast::Error when `volume` is not from read_vdb_volume.
  explicit VdbPeer(const VdbVolume& volume);
  ~VdbPeer();
  VdbPeer(const VdbPeer&) = delete;
  VdbPeer& operator=(const VdbPeer&) = delete;
  /// One frame of `camera` at width x height.
  Image render(const Camera& camera, int width, int height, const VdbPeerOptions& options) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

struct GigaOptions {
  /// Memory for both pools (node tiles and bricks in equal numbers).
  uint64_t budget_bytes = uint64_t(256) << 20;
  /// Explicit pool sizes (both > 0: used instead of the budget).
  uint32_t tiles = 0, bricks = 0;
  /// World placement of the unit cube: [origin, origin + size]^3.
  Vec3 origin{0, 0, 0};
  float size = 1.f;
  /// Producer calls per end_pass (the rest stays pending for later passes).
  uint32_t max_data_per_pass = 2048;
  /// Run validate() after every end_pass and throw voxcast::Error on a
  /// broken invariant (tests).
  bool check_after_pass = false;
  /// Bits per channel of a pool voxel: 16 (PoolVoxel, binary16, the
  /// default) or 8 (PoolVoxel8, unorm8 of each brick's range: half the
  /// bytes, so twice the bricks per budget and faster warm frames).
  int brick_bits = 16;
};

/// What one end_pass did.
struct GigaPassStats {
  uint64_t data_requests = 0, subdivide_requests = 0;  // valid requests received
  uint64_t bricks_uploaded = 0, constants = 0, subdivisions = 0;
  uint64_t recycled_bricks = 0, recycled_tiles = 0;  // evictions of elements in use before
  uint64_t pending = 0;                              // valid requests not served
  uint64_t bricks_used = 0, tiles_used = 0;          // cache hits: elements the pass's rays used
  uint64_t bricks_resident = 0, tiles_resident = 0;  // pool occupancy after serving
};

class GigaVoxels : public Structure, public VolumeQuery {
 public:
  GigaVoxels(std::shared_ptr<const Producer> producer, GigaOptions options = {});
  std::string name() const override { return "gigavoxels"; }
  Aabb bounds() const override;
  const VolumeQuery* volume() const override { return this; }
  void begin_frame(const FrameView& view) override;
  PassOutcome end_pass(std::span<const Request> requests) override;

  int march(const Ray& ray, float t_begin, const LodFootprint& lod, TraceContext& ctx,
            std::span<VolumeSpan> out) const override;
  VolumeSample sample(Vec3 p, float level, TraceContext& ctx,
                      const VolumeSpan* span = nullptr) const override;
  /// sample() of every point of a brick span with the span's brick and its
  /// parent's resolved once: per point two SIMD trilinear lookups at most,
  /// no descent, no allocation (the hot loop of the volume integrator).
  void sample_span(const Ray& ray, const VolumeSpan& span, const float* t, const float* level,
                   int n, TraceContext& ctx, VolumeSample* out) const override;

  /// Pool capacities.
  uint32_t tile_capacity() const { return uint32_t(tile_parent_.size()); }
  uint32_t brick_capacity() const { return uint32_t(brick_owner_.size()); }
  /// Bytes of both pools and their bookkeeping: the node pool (tiles: 8
  /// nodes of two words, localization code, depth, parent, usage and
  /// timestamp) and the brick pool (bricks of PoolVoxel or PoolVoxel8 with
  /// owner, usage and timestamp; 8-bit pools add a BrickSteps8 per brick).
  uint64_t pool_bytes() const { return node_pool_bytes() + brick_pool_bytes(); }
  uint64_t node_pool_bytes() const;
  uint64_t brick_pool_bytes() const;
  /// Bits per channel of the brick pool's voxels (GigaOptions::brick_bits).
  int brick_bits() const { return options_.brick_bits; }
  const Producer& producer() const { return *producer_; }
  /// end_pass statistics since begin_frame.
  const std::vector<GigaPassStats>& pass_stats() const { return passes_; }

  /// Checks every pointer of the node pool: a child pointer names an
  /// allocated tile whose parent is that node and whose localization code and
  /// depth are the node's child's; a brick pointer names a brick owned by
  /// that node; the usage lists are permutations of the recyclable elements.
  /// Returns "" or the first violation.
  std::string validate() const;

  // ---- Introspection (tests, statistics). ----
  /// Brick-holding nodes currently resident, with their regions.
  struct ResidentBrick {
    uint32_t brick = 0;  // index in the brick pool
    uint32_t node = 0;   // the node that points to it
    NodeRegion region;
    std::vector<BrickVoxel> voxels;  // decoded from the pool (PoolVoxel)
  };
  std::vector<ResidentBrick> resident_bricks() const;
  /// Nodes whose NodeEmptyBelow summary is set (march crosses their box in
  /// one step when the cone allows).
  size_t empty_below_nodes() const;
  /// The usage lists (front = least recently used) and timestamps.
  const std::vector<uint32_t>& tile_usage() const { return tile_usage_; }
  const std::vector<uint32_t>& brick_usage() const { return brick_usage_; }
  uint32_t tile_stamp(uint32_t tile) const { return tile_stamp_[tile]; }
  uint32_t brick_stamp(uint32_t brick) const { return brick_stamp_[brick]; }
  /// The stamp rays write in (frame, pass): never 0 (0 marks recycled elements).
  static uint32_t stamp(uint32_t frame, uint32_t pass);

 private:
  NodeRegion region_of(uint32_t node) const;
  /// World side of a voxel at `level` (a table: the descent asks at every step).
  float voxel_world(int level) const { return voxel_world_[level]; }
  VolumeSample node_value(uint32_t node, int level, const uint32_t cell[3], Vec3 q,
                          TraceContext& ctx) const;
  void touch_tile(uint32_t tile, uint32_t s) const;
  void touch_brick(uint32_t brick, uint32_t s) const;
  /// The tiles in allocated order of depth, shallowest first (root's tile
  /// excluded).
  std::vector<uint32_t> tiles_by_depth() const;
  /// Stamps `now` on the tiles under a node with an empty-below summary
  /// whose tile this pass used: march crosses such a node's box without
  /// descending (it touches only the node's child tile), where the descent
  /// would have stamped the tiles it passed (§3.6.2: what the rays use stays).
  void stamp_empty_below(const std::vector<uint32_t>& order, uint32_t now);
  /// Recomputes every node's NodeEmptyBelow from the pool, deepest tiles first.
  void update_empty_below(const std::vector<uint32_t>& order);

  std::shared_ptr<const Producer> producer_;
  int max_level_ = 0;  // producer_->max_level(), read per span without a virtual call
  GigaOptions options_;
  float inv_size_;
  float voxel_world_[kMaxLevel + 1];
  // Node pool (§3.4): structure and data words, per-tile bookkeeping.
  std::vector<uint32_t> child_, data_;
  mutable std::vector<uint32_t> tile_stamp_;
  std::vector<uint32_t> tile_code_;
  std::vector<uint8_t> tile_depth_;
  std::vector<uint32_t> tile_parent_;  // node pointing to the tile; kNoNode when free
  std::vector<uint32_t> tile_usage_;   // LRU order of tiles 1.. (tile 0 is the root's)
  // Brick pool: one allocation aligned to 2 MiB huge pages (gigavoxels.cpp,
  // allocate_brick_pool), released by PoolFree.
  struct PoolFree {
    void operator()(unsigned char* p) const noexcept;
  };
  std::unique_ptr<unsigned char[], PoolFree> bricks_;
  size_t voxel_bytes_ = sizeof(PoolVoxel);  // PoolVoxel or PoolVoxel8 (brick_bits)
  std::vector<BrickSteps8> brick_steps_;    // per brick, 8-bit pools only
  /// Brick b's first byte.
  unsigned char* brick_data(uint32_t b) const {
    return bricks_.get() + size_t(b) * kBrickVoxels * voxel_bytes_;
  }
  mutable std::vector<uint32_t> brick_stamp_;
  std::vector<uint32_t> brick_owner_;  // node holding the brick; kNoNode when free
  std::vector<uint32_t> brick_usage_;
  // Constant values of constant nodes (deduplicated).
  std::vector<VolumeSample> constants_;
  uint32_t frame_ = 0, pass_ = 0;
  std::vector<GigaPassStats> passes_;
};

/// Synthesis (§3.7-3.8): a volume made of a node graph instead of stored
/// voxels. Each node is an N^3-tree node with N = 3: 27 children, x fastest
/// (child (x, y, z) at x + 3 (y + 3 z)), each empty, solid, or a node of the
/// graph, so a subtree is instanced wherever the graph names it and a node
/// naming itself recurses. The recursion is bounded: at depth max_depth a
/// node reference counts as solid (depth 1 = the root's children). march()
/// descends by point location (child int(3x)) and stops at a leaf, at the
/// bound, or where the cell is no larger than the pixel cone, answering
/// with the subtree's mean coverage (its prefiltered value) x density as a
/// constant span: the integrator integrates every span in closed form.
constexpr int32_t kGraphEmpty = -1, kGraphSolid = -2;
constexpr int kMaxRecursionDepth = 16;
struct GraphNode {
  std::array<int32_t, 27> child{};  // kGraphEmpty, kGraphSolid or a node index
};
class RecursiveVolume : public Structure, public VolumeQuery {
 public:
  /// Node 0 is the root. Throws voxcast::Error for an empty graph, a child
  /// naming no node, a depth outside 1..kMaxRecursionDepth, a negative
  /// density or a non-positive size.
  RecursiveVolume(std::vector<GraphNode> nodes, int max_depth, float density,
                  Color color = {1.f, 1.f, 1.f, 1.f}, Vec3 origin = {0, 0, 0}, float size = 1.f);
  /// The Menger sponge as a graph of one node: its 20 corner and edge
  /// cells name the node itself, the 7 middle cells are empty.
  static RecursiveVolume menger(int max_depth, float density, Color color = {1.f, 1.f, 1.f, 1.f},
                                Vec3 origin = {0, 0, 0}, float size = 1.f);
  std::string name() const override { return "recursive"; }
  Aabb bounds() const override;
  const VolumeQuery* volume() const override { return this; }
  int march(const Ray& ray, float t_begin, const LodFootprint& lod, TraceContext& ctx,
            std::span<VolumeSpan> out) const override;
  /// The finest-level medium at p (every span is constant, so the
  /// integrator samples nothing; for tests and tools).
  VolumeSample sample(Vec3 p, float level, TraceContext& ctx,
                      const VolumeSpan* span = nullptr) const override;
  /// Mean solid fraction of `node` placed at `depth` (0 = the root), with
  /// the recursion cut at max_depth.
  float coverage(int32_t node, int depth) const;
  int max_depth() const { return max_depth_; }

 private:
  std::vector<GraphNode> nodes_;
  int max_depth_;
  float density_;
  Color color_;
  Vec3 origin_;
  float size_;
  std::vector<float> coverage_;  // [levels left][node]
};

/// make_procedural("menger", resolution)'s sponge as a recursive node graph
/// (the CLI's procedural:menger-recursive): the same placement ([0.1, 0.9]^3
/// of the unit cube), density and color, its recursion depth the
/// procedural sponge's iterations (until the finest bars are about one
/// voxel of `resolution` wide). Throws voxcast::Error as make_procedural.
RecursiveVolume make_recursive_menger(int resolution);

}  // namespace voxcast::giga
