#pragma once
// ESVO data management (Laine & Karras 2010, §7): the octree stored on disk
// as *slices* in one file with a directory, and a streamed ESVO structure
// that keeps only the slices the camera needs in memory.
//
// ---- What a slice is ----
// A slice holds the child descriptors of ONE octree level n (the "node
// level") inside one cubical region (a cube of the octree at depth r <= n,
// Morton code R), together with the attributes and contours of their
// children (the voxels of level n + 1). A slice therefore stores no
// positions, pointers or indices (§7 "Storage on disk"): which descriptors
// it holds is implied by the level above -- they are exactly the subdivided
// children of the parent slice's descriptors that lie in the region, in
// Morton order. The root slice is node level 0 (the root descriptor). The
// children of a slice are the slices of node level n + 1 that cover its
// region, planned by the parent: the region is kept (one child) when the
// next level fits the slice size, otherwise split at the shallowest depth
// k (r <= k <= n + 1) where every non-empty sub-cube fits -- so a slice may
// have more than eight children (§7.1). The hierarchy (the directory) is
// small and always in memory; slice contents are read on demand.
//
// ---- File layout (version 1), all integers little-endian ----
//   offset 0      FileHeader (128 bytes)
//          128    directory: slice_count x SliceEntry (64 bytes), in
//                 breadth-first order: the children of a slice are
//                 consecutive entries, sorted by region code, and all of
//                 one region depth; entry 0 is the root slice
//          D      slice data, in directory order, each starting where the
//                 previous ended (D = 128 + 64 * slice_count), to the end of
//                 the file
//   Slice data (node_count descriptors N, voxel_count V children, contour_count C):
//     N u32 descriptor words  | 23..16 contour mask | 15..8 valid mask | 7..0 leaf mask |
//                             (bits 31..24 zero; masks as in esvo.hpp, slot i = bit i)
//     raw attributes (header flag kFlagCompressed clear):
//     V x (u32 ABGR color, u32 cube normal)  the children's raw attributes
//                             (esvo.hpp "Raw attribute attachment"), descriptor
//                             by descriptor, slot order
//     compressed attributes (kFlagCompressed set; esvo §5.5):
//     P = ceil(N/2) x 6 u32   compression blocks (esvo.hpp "Compressed
//                             attribute attachment", block words 0-5): block k
//                             holds the children of the slice's descriptors
//                             2k and 2k+1, the child in slot i of descriptor
//                             d at block slot (d & 1) * 8 + i (consecutive
//                             descriptors in Morton order: neighbours in
//                             space, as §5.5 pairs siblings); unused block
//                             slots have index 0
//     C u32 contour values    the children's contours (esvo.hpp ContourValue),
//                             descriptor by descriptor, slot order
//   data_bytes = 4 N + 8 V + 4 C (raw) or 4 N + 24 ceil(N/2) + 4 C
//   (compressed); its xxh64 (seed 0) is SliceEntry::hash. SliceFile::read()
//   hands a compressed slice out decoded into the raw form, so the streamed
//   structure holds raw values in memory (§5.5 blocks are for the disk and
//   the bandwidth; they decode to the values the .vxs renders).
//   header.directory_hash = xxh64 of the header's first 120 bytes followed by
//   the directory.
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <mutex>
#include <span>
#include <string>
#include <vector>

#include "voxcast/bitfield.hpp"
#include "voxcast/esvo.hpp"
#include "voxcast/integrator.hpp"
#include "voxcast/mesh.hpp"
#include "voxcast/structure.hpp"
#include "voxcast/voxelize.hpp"

namespace voxcast {
class DisplacementMap;
class FormatRegistry;
class Progress;
}  // namespace voxcast

namespace voxcast::esvo {

namespace slice_layout {
inline constexpr char kMagic[8] = {'V', 'X', 'S', 'L', 'I', 'C', 'E', '\0'};
inline constexpr uint32_t kVersion = 1;
inline constexpr uint32_t kFlagContours = 1;    // FileHeader::flags
inline constexpr uint32_t kFlagCompressed = 2;  // §5.5 compression blocks instead of raw values
inline constexpr uint32_t kNoParent = 0xFFFFFFFFu;

struct FileHeader {
  char magic[8];            //   0: kMagic
  uint32_t version;         //   8: kVersion
  uint32_t header_bytes;    //  12: 128
  uint32_t entry_bytes;     //  16: 64
  uint32_t flags;           //  20: kFlagContours | kFlagCompressed
  uint32_t slice_count;     //  24
  uint32_t levels;          //  28: grid levels (leaves at depth `levels`)
  uint32_t resolution;      //  32: 2^levels
  uint32_t reserved0;       //  36: 0
  double voxel_size;        //  40
  float origin[3];          //  48: grid min corner (world)
  uint32_t reserved1;       //  60: 0
  uint64_t slice_bytes;     //  64: the target slice size the file was planned with
  uint64_t data_offset;     //  72: D
  uint64_t file_bytes;      //  80: total size
  uint64_t total_nodes;     //  88: descriptors in all slices
  uint64_t total_voxels;    //  96: voxels (attributes) in all slices
  uint64_t reserved2;       // 104: 0
  uint64_t reserved3;       // 112: 0
  uint64_t directory_hash;  // 120
};
static_assert(sizeof(FileHeader) == 128 && offsetof(FileHeader, version) == 8 &&
              offsetof(FileHeader, slice_count) == 24 && offsetof(FileHeader, voxel_size) == 40 &&
              offsetof(FileHeader, origin) == 48 && offsetof(FileHeader, slice_bytes) == 64 &&
              offsetof(FileHeader, data_offset) == 72 && offsetof(FileHeader, total_nodes) == 88 &&
              offsetof(FileHeader, directory_hash) == 120);
inline constexpr size_t kHashedHeaderBytes = offsetof(FileHeader, directory_hash);

struct SliceEntry {
  uint64_t region_code;    //  0: Morton code of the region cube at region_depth
  uint64_t data_offset;    //  8: absolute file offset of the slice data
  uint64_t hash;           // 16: xxh64 of the slice data
  uint32_t data_bytes;     // 24: 4 N + 8 V + 4 C
  uint32_t parent;         // 28: parent slice index (kNoParent for the root)
  uint32_t first_child;    // 32: index of the first child slice (0 when none)
  uint32_t child_count;    // 36
  uint32_t node_count;     // 40: N
  uint32_t voxel_count;    // 44: V (sum of the valid masks' popcounts)
  uint32_t contour_count;  // 48: C (sum of the contour masks' popcounts)
  uint32_t link_count;     // 52: subdivided children (sum of popcount(valid & ~leaf))
  uint8_t node_level;      // 56: n
  uint8_t region_depth;    // 57: r
  uint16_t reserved0;      // 58: 0
  uint32_t reserved1;      // 60: 0
};
static_assert(sizeof(SliceEntry) == 64 && offsetof(SliceEntry, data_offset) == 8 &&
              offsetof(SliceEntry, hash) == 16 && offsetof(SliceEntry, data_bytes) == 24 &&
              offsetof(SliceEntry, parent) == 28 && offsetof(SliceEntry, node_count) == 40 &&
              offsetof(SliceEntry, link_count) == 52 && offsetof(SliceEntry, node_level) == 56 &&
              offsetof(SliceEntry, region_depth) == 57);

// Descriptor word of a slice: | 31..24 zero | 23..16 contour mask | 15..8 valid | 7..0 leaf |
using SliceValid = BitField<8, 8>;
using SliceLeaf = BitField<0, 8>;
using SliceContourMask = BitField<16, 8>;
static_assert(SliceValid::mask == 0xFF00u && SliceLeaf::mask == 0xFFu &&
              SliceContourMask::mask == 0xFF0000u);
static_assert(fields_tile<SliceContourMask, SliceValid, SliceLeaf>(0xFFFFFFu));

/// Most descriptors one slice may hold (the streamed structure names a
/// node by 19 bits within its block, see StreamedEsvo).
inline constexpr uint32_t kMaxSliceNodes = 1u << 19;
}  // namespace slice_layout

struct SliceOptions {
  /// Target bytes of slice data (§7: "about 1 MB"). A region whose next level
  /// exceeds it is split; a single descriptor's record is never split, so a
  /// slice can exceed a tiny target by one record.
  uint64_t slice_bytes = uint64_t(1) << 20;
  /// Store the attributes as §5.5 compression blocks (see the layout above),
  /// encoded from the octree's raw values.
  bool compressed = false;
};

/// The slice file of an in-core octree: the same voxels, attributes and
/// contours. The octree's attributes must be raw (a compressed §5.5 octree
/// is refused: its blocks pair descriptors of its layout, which a slice does
/// not preserve, and re-encoding decoded values would compress twice);
/// `options.compressed` encodes the slices' own blocks from them.
/// Written to a temporary file and renamed into place. Throws voxcast::Error.
void write_slices(const EsvoOctree& octree, const std::filesystem::path& path,
                  const SliceOptions& options = {});

struct SliceBuildOptions {
  uint64_t slice_bytes = uint64_t(1) << 20;  // as SliceOptions::slice_bytes
  /// Bytes the build may use (0 = 90% of free memory): picks the cell size.
  uint64_t memory_budget = 0;
  /// Voxels per side of the cells a region is voxelized in (a power of two;
  /// 0 = the largest whose working set per worker fits half the budget).
  uint32_t cell_size = 0;
  /// Contours (§5.2, §7.2) and the variable depth (§7.1, §7.3), as
  /// BuildOptions::contours, max_level, geometry_error, color_error and
  /// normal_error (with `compressed` below: of the decoded values, see
  /// there): planned top-down, each unbuilt slice
  /// carrying its region's triangles and ancestor contours; the attribute
  /// tolerances compare each of a slice's voxels with the full-depth voxels
  /// of its region in a second pass over them.
  bool contours = false;
  int max_level = 0;
  double geometry_error = 0;
  double color_error = -1;   // < 0: unset
  double normal_error = -1;  // < 0: unset
  /// Displacement mapping (§7.4): the mesh displaced by this map and scale
  /// (voxelize_displaced(); without contours). Each slice's region is
  /// voxelized from the displacement primitives whose bound overlaps it;
  /// the cells are 128^3 unless cell_size is given. The file equals slicing
  /// the in-core displaced build.
  const DisplacementMap* displacement = nullptr;
  float displacement_scale = 0;
  /// §5.5 compression blocks per slice, as SliceOptions::compressed: the file
  /// equals write_slices(the in-core raw build, {.compressed = true}). With
  /// the attribute tolerances their test is of what the file holds (§7.3:
  /// "attribute quantization and compression is performed before the
  /// test"): a voxel is refined if its raw or its decoded value is out of
  /// tolerance, as the in-core compressed build refines; the blocks then
  /// pair the slices' descriptors, so the tree is the one these slices
  /// need (no in-core build pairs the same way).
  bool compressed = false;
};
struct SliceBuildStats {
  uint64_t slices = 0;
  uint32_t cell_size = 0;
  uint64_t cells = 0;            // cell voxelizations (over all levels)
  uint64_t voxels_streamed = 0;  // finest voxels reduced (over all levels)
  uint64_t max_cell_voxels = 0;
  uint64_t file_bytes = 0;
};

/// The top-down slice builder (§7.1): the slice file of `mesh` voxelized
/// into `grid`, never holding the octree: level by level, the slices of a
/// level built in parallel with no dependencies between them, each from the
/// voxels of its region (voxelized cell by cell) and written when done. The
/// file equals write_slices(build_octree(voxelize(mesh, grid, voxelize)))
/// byte for byte, and with `options.contours` the slicing of
/// build_octree(voxels, mesh, build options) with the same contour options
/// (with options.compressed: those writes with SliceOptions::compressed,
/// except together with the attribute tolerances, whose tree is the
/// slices' own; SliceBuildOptions::compressed). Throws voxcast::Error.
void build_slices(const Mesh& mesh, const GridTransform& grid, const VoxelizeOptions& voxelize,
                  const std::filesystem::path& path, const SliceBuildOptions& options = {},
                  SliceBuildStats* stats = nullptr);

/// Adds the "esvo-sliced" format (slice files through load_scene(): a
/// StreamedEsvo; called by register_builtin_formats()).
void register_sliced_format(FormatRegistry& registry);

/// True if `path` starts with the slice file magic (cheap: reads 8 bytes).
bool is_slice_file(const std::filesystem::path& path);

/// An open slice file: the header and the directory, verified (hash,
/// hierarchy, offsets, counts); slice contents are read on demand.
class SliceFile {
 public:
  /// Throws voxcast::Error with a one-line reason naming the file.
  static std::shared_ptr<SliceFile> open(const std::filesystem::path& path);
  ~SliceFile();
  SliceFile(const SliceFile&) = delete;
  SliceFile& operator=(const SliceFile&) = delete;

  const slice_layout::FileHeader& header() const { return header_; }
  const std::vector<slice_layout::SliceEntry>& slices() const { return slices_; }
  GridTransform grid() const;
  bool has_contours() const { return (header_.flags & slice_layout::kFlagContours) != 0; }
  /// §5.5 compression blocks on disk (read() decodes them).
  bool compressed() const { return (header_.flags & slice_layout::kFlagCompressed) != 0; }
  const std::filesystem::path& path() const { return path_; }

  /// Slice i's data as words in the raw layout (pread; safe from several
  /// threads at once): N descriptor words, 2 V raw attribute words, C
  /// contours; a compressed slice is verified as stored, then decoded.
  /// Throws voxcast::Error on a read error or a hash mismatch.
  std::vector<uint32_t> read(uint32_t i) const;
  /// Every slice read and its hash checked, one slice in memory at a time
  /// (`info`: the damage a whole-file load refuses, without the load);
  /// `progress` advances by the data bytes. Throws as read().
  void verify_hashes(Progress* progress = nullptr) const;

  /// The octree's occupied bounds walked down to depth `max_level`, read
  /// from the slices of node levels below it (a few, small: the top of the
  /// hierarchy): equal bit for bit to esvo::occupied_bounds() of the in-core
  /// octree the file slices, whatever is resident, so a slice file and its
  /// .vxc frame the same automatic camera. A damaged slice ends the walk at
  /// the coarser cubes of its descriptors (no throw).
  Aabb occupied_bounds(int max_level = 7) const;

  /// The slice hierarchy for `voxcast info`: per node level the slice count,
  /// data bytes (min/mean/max) and the largest fan-out.
  std::string describe() const;

 private:
  SliceFile() = default;
  /// Slice i's stored words (compressed ones as stored), hash checked.
  void read_stored(uint32_t i, std::vector<uint32_t>* words) const;
  std::filesystem::path path_;
  int fd_ = -1;
  slice_layout::FileHeader header_{};
  std::vector<slice_layout::SliceEntry> slices_;
};

struct StreamOptions {
  /// Bytes the resident blocks may occupy (0 = unlimited). The root slice
  /// is always resident; a budget below it is refused.
  uint64_t budget_bytes = 0;
  int io_threads = 4;  // worker threads reading slices in one end_pass
  uint32_t max_loads_per_pass = 512;
};

/// Counters since construction (cumulative) and of the last end_pass.
struct StreamStats {
  uint64_t loaded = 0, unloaded = 0, refused = 0;
  uint64_t bytes_read = 0;      // slice data read from the file
  uint64_t resident_bytes = 0;  // now
  uint64_t peak_resident_bytes = 0;
  uint32_t resident_slices = 0;  // now
  uint64_t pending = 0;          // requests left unserved by the last end_pass
  uint64_t compactions = 0;      // arena allocations that had to compact
  uint64_t bytes_moved = 0;      // by those compactions
  /// What compacting everything after the first hole would have moved in
  /// those compactions (the incremental compaction moves only what each
  /// failed allocation needs: bytes_moved <= this).
  uint64_t full_compaction_bytes = 0;
  uint64_t trunk_descriptors = 0;  // now, in the trunk
  uint32_t trunk_chunks = 0;       // now (kTrunkSlots descriptors each)
  uint32_t leaf_blocks = 0;        // now, with an extent (blocks of no descriptors not counted)
};

/// The streamed ESVO (§7 "Storage in memory", "Dynamic loading"): the
/// resident slices as blocks, the third node-access policy of the octree
/// caster (src/core/octree_caster.hpp) over them. A ray reaching a
/// subdivided child whose slice is not resident stops at that (coarser)
/// voxel, shows its attributes like a LOD stop and pushes a request for the
/// slice through its TraceContext. end_pass loads the requested slices on
/// worker threads, in order of their score (the projected size of their
/// voxels in LOD footprints for the frame's camera: a constant
/// voxel-to-pixel ratio), within the budget, unloading resident leaf slices
/// (no resident children) that no ray entered in this frame or that score
/// lower, when that makes room for a higher-scoring one. A
/// slice whose hash or structure is wrong is refused once and for all; its
/// parent's voxels keep standing in for it.
///
/// Memory (§7 "Storage in memory", Figure 21; docs/ARCHITECTURE.md
/// "Streamed ESVO"): a *trunk* and *leaf blocks*. A leaf block is one
/// subtree in depth-first order -- 16-byte descriptors (masks + offsets into
/// the block's attributes, contours and links), per subdivided child a
/// 32-bit link (a node of the same block, or "absent" + the slice to
/// request), the children's raw attributes and contours -- and corresponds
/// one to one to a next-level slice (parent resident, itself not): the
/// descriptors of that slice's region from its region depth down to the
/// level above it (none when those levels are one voxel: a block of no
/// bytes). Loading slice S merges its descriptors into S's block; the result
/// is split into one block per child slice of S (each child's region), and
/// what lies in none of them (the levels above the children's region depth)
/// moves to the trunk, whose descriptors have room for all eight children's
/// attributes, contours and links (cheap to modify) and live in chunks of 64
/// (blocks like the others to the caster). A resident slice without child
/// slices keeps its merged block. Unloading S (no resident children) is the
/// exact inverse. The blocks and trunk chunks are extents of one arena of the
/// budget's size (a hard cap), compacted incrementally when an allocation
/// finds no hole (StreamStats::compactions).
class StreamedEsvo final : public SurfaceQuery, public Structure {
 public:
  StreamedEsvo(std::shared_ptr<const SliceFile> file, const StreamOptions& options = {});
  ~StreamedEsvo() override;

  std::string name() const override { return "esvo-sliced"; }
  Aabb bounds() const override;
  const SurfaceQuery* surface() const override { return this; }

  bool trace(const Ray& ray, const LodFootprint& lod, TraceContext& ctx, SurfaceHit* hit,
             const BeamStart* beam = nullptr) const override;
  float transmittance(const Ray& ray, const LodFootprint& lod, TraceContext& ctx,
                      const BeamStart* beam = nullptr) const override;
  void attributes(const SurfaceHit& hit, TraceContext& ctx, Color* color,
                  Vec3* normal) const override;
  /// The coarse beam pass (§6.2) over the resident octree: a subdivided
  /// voxel whose slice is not resident is kept whole (the rays stop at it),
  /// so hits with and without the beam are the same, requests included.
  void beam_start(const BeamFrustum& beam, TraceContext& ctx, BeamStart* start) const override;

  void begin_frame(const FrameView& view) override;
  PassOutcome end_pass(std::span<const Request> requests) override;

  /// Loads every slice (ignores the budget's ordering but not its size:
  /// throws voxcast::Error when the whole file does not fit). `progress`
  /// (optional): its current phase gets the slice data bytes as units and
  /// advances as slices are read, checked and merged.
  void load_all(Progress* progress = nullptr);
  /// Whether load_all() can hold every slice (the budget, the block table).
  bool fits_whole() const;

  /// What slice `e` adds to the leaf blocks while resident (its descriptors,
  /// links, attributes and contours, and one block's rounding). Trunk
  /// descriptors a split moves cost more; the budget counts the arena.
  static uint64_t block_bytes(const slice_layout::SliceEntry& e);

  /// Loads one next-level slice now (outside a pass; the budget holds): true
  /// if it was loaded (false: not a next-level slice, no room, or refused).
  bool load_slice(uint32_t slice);
  /// Unloads one resident slice without resident children now: true if done.
  bool unload_slice(uint32_t slice);
  /// The resident octree's memory as words, independent of block ids and
  /// arena offsets: every leaf block's bytes by slice (links within it as
  /// local indices), then the trunk's descriptors depth-first with their
  /// contents and link targets. Unloading what was just loaded restores it.
  std::vector<uint32_t> memory_image() const;

  /// The occupied bounds of the whole octree for automatic cameras,
  /// file().occupied_bounds() whatever is resident (equal bit for bit to
  /// the in-core octree's esvo::occupied_bounds()); computed on the first
  /// call (`progress`, optional: its current phase gets one unit for it).
  Aabb occupied(Progress* progress = nullptr) const;
  /// Why the last refused slice was refused ("" when none was).
  const std::string& last_refusal() const;

  const StreamStats& stats() const { return stats_; }
  const SliceFile& file() const { return *file_; }
  bool resident(uint32_t slice) const;
  bool refused(uint32_t slice) const;
  /// Throws voxcast::Error naming the first broken invariant: every resident
  /// slice's parent is resident; every next-level slice (and every resident
  /// slice without child slices) has exactly one leaf block and no other
  /// slice has one; a leaf block is one subtree of its slice's region and
  /// levels, depth-first, linking only within itself or "absent" to its
  /// slice; trunk descriptors link only to trunk descriptors and the roots of
  /// resident blocks; every absent link names the next-level slice covering
  /// its voxel; the arena's extents are the blocks', within the budget.
  void check_invariants() const;

  struct Impl;

 private:
  void refresh_stats();
  mutable Aabb occupied_cache_;
  mutable std::once_flag occupied_once_;
  std::shared_ptr<const SliceFile> file_;
  std::unique_ptr<Impl> impl_;
  StreamStats stats_;
};

}  // namespace voxcast::esvo
