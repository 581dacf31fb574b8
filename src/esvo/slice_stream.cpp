// The streamed ESVO (esvo §7 "Storage in memory", "Loading slices",
// "Dynamic loading"): resident slices as blocks, the octree caster's third
// node-access policy over them (after the in-core ESVO's and the DAG's), and
// the score-driven loading and unloading between passes.
// Layout and contract: include/voxcast/esvo_slices.hpp.
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <map>
#include <memory>
#include <span>
#include <thread>

#include "core/octree_caster.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo_slices.hpp"
#include "voxcast/morton.hpp"

namespace voxcast::esvo {
namespace sl = slice_layout;

namespace {
// A node id is (block << kLocalBits) | descriptor index in the block; a link
// with kAbsent set is a subdivided child whose slice (low 31 bits) is not
// resident. Block 0 always holds the root slice, so the root is node 0.
constexpr uint32_t kLocalBits = 19;
static_assert((1u << kLocalBits) == sl::kMaxSliceNodes);
constexpr uint32_t kLocalMask = (1u << kLocalBits) - 1;
constexpr uint32_t kAbsent = 1u << 31;
constexpr uint32_t kMaxBlocks = 1u << (31 - kLocalBits);  // 4096 resident slices
constexpr uint32_t kRequestKind = 0;                      // Request::key = slice index

enum class State : uint8_t { kOnDisk, kResident, kRefused };
}  // namespace

/// One resident descriptor (16 bytes): the slice's descriptor word and where
/// its children's attributes and contours and its subdivided children's
/// links start in the block.
struct StreamNode {
  uint32_t masks;    // slice descriptor word (esvo_slices.hpp)
  uint32_t attr;     // first child's attribute pair
  uint32_t contour;  // first contour value
  uint32_t link;     // first link
};
static_assert(sizeof(StreamNode) == 16);

/// What the caster reads of one block (the block table is indexed by block id).
struct BlockRef {
  const StreamNode* nodes = nullptr;
  const uint32_t* links = nullptr;
  const uint32_t* attrs = nullptr;
  const uint32_t* contours = nullptr;
};

struct StreamSource {
  GridTransform grid;
  const BlockRef* table = nullptr;
  // Usage stamps per block (written by the rays, relaxed) and this frame's stamp.
  std::atomic<uint32_t>* used = nullptr;
  uint32_t stamp = 0;
};

}  // namespace voxcast::esvo

namespace voxcast::detail {

/// Node-access policy of the streamed ESVO (core/octree_caster.hpp documents
/// the interface). Residency: a subdivided child is entered only when its
/// link names a node; otherwise the ray stops at it and report() asks for
/// the slice.
struct StreamedEsvoNodes {
  using Source = esvo::StreamSource;
  using Desc = esvo::StreamNode;
  using Index = NoIndex;
  static constexpr bool kContours = true;
  static constexpr bool kResidency = true;
  static constexpr bool kEnteredFace = false;

  explicit StreamedEsvoNodes(const Source& s) : table(s.table), used(s.used), stamp(s.stamp) {}
  static uint32_t root() { return 0; }

  template <class C>
  Desc fetch(uint32_t node, int, C& cnt) const {
    count_add(cnt, &RayCounters::descriptor_fetches);
    return table[node >> esvo::kLocalBits].nodes[node & esvo::kLocalMask];
  }
  static bool fetched(const Desc& d) { return d.masks != 0; }  // valid masks are never empty
  static void forget(Desc* d) { d->masks = 0; }
  static uint32_t mask(const Desc& d) { return esvo::sl::SliceValid::get(d.masks); }
  static bool valid(const Desc& d, int c) { return (d.masks >> (8 + c) & 1u) != 0; }
  static bool leaf(const Desc& d, int c, int) { return (d.masks >> c & 1u) != 0; }

  bool contour(const Desc& d, uint32_t node, int c, uint32_t* value) const {
    const uint32_t m = esvo::sl::SliceContourMask::get(d.masks);
    if ((m >> c & 1u) == 0) return false;
    *value = table[node >> esvo::kLocalBits]
                 .contours[d.contour + uint32_t(std::popcount(m & ((1u << c) - 1)))];
    return true;
  }
  static uint32_t link(const esvo::BlockRef* table, const Desc& d, uint32_t node, int c) {
    const uint32_t sub = esvo::sl::SliceValid::get(d.masks) & ~esvo::sl::SliceLeaf::get(d.masks);
    return table[node >> esvo::kLocalBits]
        .links[d.link + uint32_t(std::popcount(sub & ((1u << c) - 1)))];
  }
  bool resident(const Desc& d, uint32_t node, int c, int) const {
    return (link(table, d, node, c) & esvo::kAbsent) == 0;
  }
  /// Entering a child block stamps it as used in this frame (a load and a
  /// compare per PUSH; the store once per block and frame): a resident slice
  /// no ray entered adds nothing to the image and may be unloaded first.
  template <class I, class C>
  uint32_t descend(const Desc& d, uint32_t node, int c, int, I&, C&) const {
    const uint32_t l = link(table, d, node, c);
    std::atomic<uint32_t>& u = used[l >> esvo::kLocalBits];
    if (u.load(std::memory_order_relaxed) != stamp) u.store(stamp, std::memory_order_relaxed);
    return l;
  }
  static void name_hit(const OctreeCast<Index>& r, SurfaceHit* hit) {
    hit->voxel_ref = r.node;
    hit->child = uint32_t(r.child);
  }
  /// The ray stopped at a subdivided child whose slice is not resident: ask
  /// for that slice (OctreeWorld::trace calls this on CastStop::kNotResident).
  static void report(const Source& s, const OctreeCast<Index>& r, TraceContext& ctx) {
    const Desc d = s.table[r.node >> esvo::kLocalBits].nodes[r.node & esvo::kLocalMask];
    ctx.requests.push(esvo::kRequestKind, link(s.table, d, r.node, r.child) & ~esvo::kAbsent, 0.f);
  }

  const esvo::BlockRef* table;
  std::atomic<uint32_t>* used;
  uint32_t stamp;
};

}  // namespace voxcast::detail

namespace voxcast::esvo {

namespace {

/// The bytes a slice's block occupies in the arena: its arrays (below),
/// rounded up to 16 so that every block starts 16-byte aligned.
uint64_t block_bytes(const sl::SliceEntry& e) {
  const uint64_t raw = uint64_t(e.node_count) * (sizeof(StreamNode) + 8 + 4) +
                       uint64_t(e.link_count) * 4 + uint64_t(e.voxel_count) * 8 +
                       uint64_t(e.contour_count) * 4;
  return (raw + 15) & ~uint64_t(15);
}

/// A resident slice (§7 "blocks"): what the caster reads plus, in memory
/// only, the descriptors' Morton codes and which parent links point at them.
/// Its arrays live in one extent of the arena, in this order (each array's
/// alignment holds: descriptors are 16 bytes, codes 8).
struct Block {
  uint32_t slice = 0;
  uint64_t offset = 0, size = 0;  // its extent in the arena
  std::span<StreamNode> nodes;
  std::span<uint64_t> codes;         // per descriptor, at the slice's node level
  std::span<uint32_t> parent_links;  // per descriptor: its link's index in the parent block
  std::span<uint32_t> links;         // per subdivided child
  std::span<uint32_t> attrs;         // per child: color, normal
  std::span<uint32_t> contours;
  uint64_t bytes() const { return size; }
  /// Points the arrays at the extent starting at `base` (after a move, too).
  void place(const sl::SliceEntry& e, std::byte* base) {
    std::byte* p = base;
    auto take = [&p]<class T>(std::span<T>& s, size_t n) {
      s = {reinterpret_cast<T*>(p), n};
      p += n * sizeof(T);
    };
    take(nodes, e.node_count);
    take(codes, e.node_count);
    take(parent_links, e.node_count);
    take(links, e.link_count);
    take(attrs, size_t(e.voxel_count) * 2);
    take(contours, e.contour_count);
  }
};

/// The memory of the resident blocks (§7 "Storage in memory", issue 13
/// item 3): one arena of `capacity` bytes (the budget, or every slice's
/// block when that is less or the budget is unlimited), so the budget is a
/// hard cap by construction. Blocks are placed first fit. When no gap fits
/// but the free bytes do, the compaction is incremental: the blocks after the
/// first gap slide down one at a time, and it stops as soon as the gap
/// ahead of the next block fits the allocation -- only what the failed
/// allocation needs moves. Moves happen in end_pass only (the pinning rule).
class Arena {
 public:
  explicit Arena(uint64_t capacity)
      : capacity_(capacity), memory_(new std::byte[std::max<uint64_t>(capacity, 16)]) {}
  uint64_t capacity() const { return capacity_; }
  uint64_t used() const { return used_; }
  uint64_t moved_bytes() const { return moved_bytes_; }
  uint64_t compactions() const { return compactions_; }
  uint64_t full_compaction_bytes() const { return full_bytes_; }
  std::byte* at(uint64_t offset) const { return memory_.get() + offset; }
  /// Extents by offset: (block id, bytes).
  const std::map<uint64_t, std::pair<uint32_t, uint64_t>>& extents() const { return extents_; }

  /// An extent of `bytes` for block `id`; `moved(id, to)` is called for every
  /// block the compaction moved. Throws when the free bytes do not suffice
  /// (the planner never asks for that).
  template <class Moved>
  uint64_t allocate(uint32_t id, uint64_t bytes, const Moved& moved) {
    if (bytes > capacity_ - used_)
      throw Error("streamed esvo arena: " + std::to_string(bytes) + " B asked for, " +
                  std::to_string(capacity_ - used_) + " B free");
    uint64_t end = 0;  // end of the previous extent
    for (const auto& [off, ext] : extents_) {
      if (off - end >= bytes) return insert(end, id, bytes);
      end = off + ext.second;
    }
    if (capacity_ - end >= bytes) return insert(end, id, bytes);
    // Incremental compaction: slide extents down from the first gap until
    // the gap ahead of the next one (or the tail) fits.
    ++compactions_;
    uint64_t to = 0;
    {
      // What a full compaction would move: every extent after the first gap.
      bool gap = false;
      uint64_t at = 0;
      for (const auto& [off, ext] : extents_) {
        gap = gap || off != at;
        if (gap) full_bytes_ += ext.second;
        at = off + ext.second;
      }
    }
    for (auto it = extents_.begin(); it != extents_.end();) {
      const auto [off, ext] = *it;
      if (off - to >= bytes) return insert(to, id, bytes);
      if (off != to) {
        std::memmove(memory_.get() + to, memory_.get() + off, ext.second);
        moved_bytes_ += ext.second;
        it = extents_.erase(it);
        extents_.emplace_hint(it, to, ext);
        moved(ext.first, to);
      } else {
        ++it;
      }
      to += ext.second;
    }
    return insert(to, id, bytes);  // the tail: capacity - used >= bytes
  }
  void release(uint64_t offset) {
    const auto it = extents_.find(offset);
    used_ -= it->second.second;
    extents_.erase(it);
  }

 private:
  uint64_t insert(uint64_t offset, uint32_t id, uint64_t bytes) {
    extents_.emplace(offset, std::make_pair(id, bytes));
    used_ += bytes;
    return offset;
  }
  uint64_t capacity_;
  std::unique_ptr<std::byte[]> memory_;  // not value-initialized: untouched pages stay virtual
  std::map<uint64_t, std::pair<uint32_t, uint64_t>> extents_;
  uint64_t used_ = 0, moved_bytes_ = 0, compactions_ = 0, full_bytes_ = 0;
};

/// Slice data -> the contents of `b` (placed; no links or codes yet): every
/// descriptor word and count is checked against the directory, so that a
/// block that parses cannot send a ray out of bounds.
void parse_slice(const SliceFile& file, uint32_t i, Block& b) {
  const sl::SliceEntry& e = file.slices()[i];
  const std::vector<uint32_t> words = file.read(i);  // hash verified
  auto bad = [&](const char* why) {
    return Error("slice file '" + file.path().string() + "': slice " + std::to_string(i) + ": " +
                 why);
  };
  b.slice = i;
  const bool deepest = e.node_level + 1u >= file.header().levels;
  uint32_t voxels = 0, contours = 0, links = 0;
  for (uint32_t n = 0; n < e.node_count; ++n) {
    const uint32_t d = words[n];
    const uint32_t valid = sl::SliceValid::get(d), leaf = sl::SliceLeaf::get(d),
                   cm = sl::SliceContourMask::get(d);
    if ((d >> 24) != 0 || valid == 0 || (leaf & ~valid) != 0 || (cm & ~valid) != 0)
      throw bad("malformed descriptor");
    if (cm != 0 && !file.has_contours()) throw bad("contour in a file without contours");
    if (deepest && (valid & ~leaf) != 0) throw bad("subdivided voxel at the finest level");
    b.nodes[n] = {d, voxels, contours, links};
    voxels += uint32_t(std::popcount(valid));
    contours += uint32_t(std::popcount(cm));
    links += uint32_t(std::popcount(valid & ~leaf));
  }
  if (voxels != e.voxel_count || contours != e.contour_count || links != e.link_count ||
      words.size() != size_t(e.node_count) + 2 * size_t(voxels) + contours)
    throw bad("counts disagree with the directory");
  std::copy(words.begin() + e.node_count, words.begin() + e.node_count + 2 * voxels,
            b.attrs.begin());
  std::copy(words.begin() + e.node_count + 2 * voxels, words.end(), b.contours.begin());
}

}  // namespace

struct StreamedEsvo::Impl {
  std::shared_ptr<const SliceFile> file;
  StreamOptions options;
  StreamSource source;
  std::vector<BlockRef> table = std::vector<BlockRef>(kMaxBlocks);
  std::vector<std::unique_ptr<Block>> blocks = std::vector<std::unique_ptr<Block>>(kMaxBlocks);
  std::unique_ptr<Arena> arena;    // every block's arrays
  std::vector<uint32_t> free_ids;  // block ids, used from the back
  std::vector<State> state;
  std::vector<uint16_t> block_of;           // per slice: its block id while resident
  std::vector<uint32_t> resident_children;  // per slice
  uint64_t resident_bytes = 0;
  // Usage (gigavoxels §3.6.2-style stamps): a ray entering a block stamps
  // it with the frame's stamp (StreamedEsvoNodes::descend). A resident leaf
  // slice no ray entered in this frame adds nothing to the image: its score
  // counts as 0.
  std::vector<std::atomic<uint32_t>> used = std::vector<std::atomic<uint32_t>>(kMaxBlocks);
  uint32_t stamp = 0;
  // The frame's view (begin_frame), for the scores.
  bool has_view = false;
  CameraRays rays{Camera{}, 1, 1};
  LodFootprint lod;

  const sl::SliceEntry& entry(uint32_t i) const { return file->slices()[i]; }

  /// §7 "Dynamic loading": how big the voxels this slice refines (its node
  /// level's) look, in LOD footprints at the slice region's distance from
  /// the eye; 0 outside the view frustum. Larger = more visible gain.
  double score(uint32_t i) const {
    if (!has_view) return 1.0;
    const sl::SliceEntry& e = entry(i);
    const GridTransform grid = file->grid();
    const MortonCoord m = morton_decode(e.region_code);
    const double side_r = grid.side() / double(uint64_t(1) << e.region_depth);
    const Vec3 lo =
        grid.origin + Vec3{float(m.x * side_r), float(m.y * side_r), float(m.z * side_r)};
    const Vec3 hi = lo + Vec3{float(side_r), float(side_r), float(side_r)};
    // Outside the frustum when all 8 corners are beyond one of its planes.
    int outside[5] = {0, 0, 0, 0, 0};
    for (int k = 0; k < 8; ++k) {
      const Vec3 p{(k & 1) ? hi.x : lo.x, (k & 2) ? hi.y : lo.y, (k & 4) ? hi.z : lo.z};
      const Vec3 q = p - rays.eye;
      const float x = dot(q, rays.right), y = dot(q, rays.true_up), z = dot(q, rays.forward);
      const float wx = rays.ortho ? rays.half_width : z * rays.tan_half * rays.aspect;
      const float wy = rays.ortho ? rays.half_height : z * rays.tan_half;
      outside[0] += x > wx, outside[1] += x<-wx, outside[2] += y> wy, outside[3] += y < -wy;
      outside[4] += !rays.ortho && z < 0.f;
    }
    for (int o : outside)
      if (o == 8) return 0.0;
    const Vec3 nearest{std::clamp(rays.eye.x, lo.x, hi.x), std::clamp(rays.eye.y, lo.y, hi.y),
                       std::clamp(rays.eye.z, lo.z, hi.z)};
    const double dist = length(nearest - rays.eye);
    const double footprint = double(lod.size_at_origin) + double(lod.size_per_t) * dist;
    const double side_n = grid.side() / double(uint64_t(1) << e.node_level);
    return side_n / std::max(footprint, 1e-30);
  }

  /// A block for slice i in the arena (compacting if need be), with a free
  /// block id; not linked yet.
  uint32_t allocate(uint32_t i) {
    const uint32_t id = free_ids.back();
    const sl::SliceEntry& e = entry(i);
    auto b = std::make_unique<Block>();
    b->slice = i;
    b->size = block_bytes(e);
    b->offset = arena->allocate(id, b->size, [&](uint32_t moved, uint64_t to) {
      Block& m = *blocks[moved];
      m.offset = to;
      m.place(entry(m.slice), arena->at(to));
      if (table[moved].nodes != nullptr)  // linked: the caster's view of it too
        table[moved] = {m.nodes.data(), m.links.data(), m.attrs.data(), m.contours.data()};
    });
    b->place(e, arena->at(b->offset));
    free_ids.pop_back();
    blocks[id] = std::move(b);
    return id;
  }
  /// Gives back a block that was allocated and not (or no longer) linked.
  void release(uint32_t id) {
    arena->release(blocks[id]->offset);
    blocks[id].reset();
    table[id] = {};
    free_ids.push_back(id);
  }

  /// Links the parsed block `id` into its parent block (which must be
  /// resident) and fills its own links; throws (touching nothing but the
  /// block) when the block does not fit what the parent level implies.
  void link(uint32_t id) {
    Block* b = blocks[id].get();
    const uint32_t i = b->slice;
    const sl::SliceEntry& e = entry(i);
    const sl::SliceEntry& pe = entry(e.parent);
    Block& p = *blocks[block_of[e.parent]];
    auto bad = [&](const char* why) {
      return Error("slice file '" + file->path().string() + "': slice " + std::to_string(i) + ": " +
                   why);
    };
    // The descriptors this slice holds: the subdivided children of the
    // parent's descriptors inside the region (§7: implied by the parent level).
    const int n = pe.node_level, k = e.region_depth;
    const int kp = std::min(k, n);
    const uint64_t Rp = e.region_code >> (3 * (k - kp));
    const uint64_t lo = Rp << (3 * (n - kp)), hi = (Rp + 1) << (3 * (n - kp));
    const size_t a = size_t(std::lower_bound(p.codes.begin(), p.codes.end(), lo) - p.codes.begin());
    uint32_t j = 0;
    for (size_t q = a; q < p.codes.size() && p.codes[q] < hi; ++q) {
      const StreamNode& d = p.nodes[q];
      const uint32_t sub = sl::SliceValid::get(d.masks) & ~sl::SliceLeaf::get(d.masks);
      uint32_t rank = 0;
      for (int c = 0; c < 8; ++c) {
        if ((sub >> c & 1u) == 0) continue;
        const uint64_t code = p.codes[q] << 3 | uint64_t(c);
        const uint32_t li = d.link + rank++;
        if ((code >> (3 * (n + 1 - k))) != e.region_code) continue;
        if (p.links[li] != (kAbsent | i)) throw bad("the parent's link disagrees");
        if (j >= e.node_count) throw bad("more voxels in the region than descriptors");
        b->codes[j] = code;
        b->parent_links[j] = li;
        ++j;
      }
    }
    if (j != e.node_count) throw bad("fewer voxels in the region than descriptors");
    // Its own links: absent, naming the child slice that covers each
    // subdivided child (the children share one region depth, sorted).
    const auto& all = file->slices();
    const auto first = all.begin() + e.first_child, last = first + e.child_count;
    for (uint32_t q = 0; q < e.node_count; ++q) {
      const StreamNode& d = b->nodes[q];
      const uint32_t sub = sl::SliceValid::get(d.masks) & ~sl::SliceLeaf::get(d.masks);
      uint32_t rank = 0;
      for (int c = 0; c < 8; ++c) {
        if ((sub >> c & 1u) == 0) continue;
        if (e.child_count == 0) throw bad("subdivided voxel without a child slice");
        const uint64_t key =
            (b->codes[q] << 3 | uint64_t(c)) >> (3 * (e.node_level + 1 - first->region_depth));
        const auto it = std::lower_bound(first, last, key, [](const sl::SliceEntry& s, uint64_t v) {
          return s.region_code < v;
        });
        if (it == last || it->region_code != key)
          throw bad("subdivided voxel without a child slice");
        b->links[d.link + rank++] = kAbsent | uint32_t(it - all.begin());
      }
    }
    // Commit.
    for (uint32_t q = 0; q < e.node_count; ++q) p.links[b->parent_links[q]] = id << kLocalBits | q;
    table[id] = {b->nodes.data(), b->links.data(), b->attrs.data(), b->contours.data()};
    resident_bytes += b->bytes();
    // Loaded for a ray of this frame: counts as used until the next frame.
    used[id].store(stamp, std::memory_order_relaxed);
    block_of[i] = uint16_t(id);
    state[i] = State::kResident;
    ++resident_children[e.parent];
  }

  /// Unloads a resident slice without resident children (the inverse of link).
  void unlink(uint32_t i) {
    const sl::SliceEntry& e = entry(i);
    const uint32_t id = block_of[i];
    Block& p = *blocks[block_of[e.parent]];
    for (uint32_t li : blocks[id]->parent_links) p.links[li] = kAbsent | i;
    resident_bytes -= blocks[id]->bytes();
    release(id);
    state[i] = State::kOnDisk;
    --resident_children[e.parent];
  }

  /// Places `list` in the arena (in list order), reads and parses the
  /// slices into their blocks on worker threads (several reads in flight),
  /// then links in list order (deterministic). Returns loaded, refused.
  std::pair<uint64_t, uint64_t> load(const std::vector<uint32_t>& list, uint64_t* bytes_read) {
    std::vector<uint32_t> ids(list.size());
    for (size_t k = 0; k < list.size(); ++k) ids[k] = allocate(list[k]);
    std::vector<char> parsed(list.size(), 0);
    std::vector<std::string> errors(list.size());
    std::atomic<size_t> next{0};
    auto work = [&] {
      for (size_t k; (k = next.fetch_add(1)) < list.size();) {
        try {
          parse_slice(*file, list[k], *blocks[ids[k]]);
          parsed[k] = 1;
        } catch (const std::exception& ex) {
          errors[k] = ex.what();
        }
      }
    };
    const size_t threads = std::min<size_t>(list.size(), size_t(std::max(1, options.io_threads)));
    std::vector<std::thread> pool;
    for (size_t t = 1; t < threads; ++t) pool.emplace_back(work);
    work();
    for (std::thread& t : pool) t.join();
    uint64_t loaded = 0, refused = 0;
    for (size_t k = 0; k < list.size(); ++k) {
      if (parsed[k]) {
        try {
          link(ids[k]);
          ++loaded;
          *bytes_read += entry(list[k]).data_bytes;
          continue;
        } catch (const std::exception& ex) {
          errors[k] = ex.what();
        }
      }
      release(ids[k]);
      state[list[k]] = State::kRefused;
      last_error = errors[k];
      ++refused;
    }
    return {loaded, refused};
  }

  std::string last_error;
};

StreamedEsvo::StreamedEsvo(std::shared_ptr<const SliceFile> file, const StreamOptions& options)
    : file_(std::move(file)), impl_(std::make_unique<Impl>()) {
  if (!file_) throw Error("StreamedEsvo: no slice file");
  Impl& m = *impl_;
  m.file = file_;
  m.options = options;
  m.source = {file_->grid(), m.table.data(), m.used.data(), 0};
  const size_t n = file_->slices().size();
  m.state.assign(n, State::kOnDisk);
  m.block_of.assign(n, 0);
  m.resident_children.assign(n, 0);
  for (uint32_t id = kMaxBlocks; id-- > 0;) m.free_ids.push_back(id);  // 0 (the root), then 1...
  const sl::SliceEntry& root = file_->slices()[0];
  if (options.budget_bytes != 0 && block_bytes(root) > options.budget_bytes)
    throw Error("streaming budget " + std::to_string(options.budget_bytes) +
                " B is below the root slice's " + std::to_string(block_bytes(root)) + " B");
  // The arena: the budget, or all the slices' blocks when that is less.
  uint64_t whole = 0;
  for (const sl::SliceEntry& e : file_->slices()) whole += block_bytes(e);
  m.arena = std::make_unique<Arena>(
      options.budget_bytes != 0 ? std::min(options.budget_bytes, whole) : whole);
  // The root slice: parsed like any other (a corrupt root is fatal), with
  // the root descriptor at code 0 and no parent links to fill.
  const uint32_t root_id = m.allocate(0);
  Block* b = m.blocks[root_id].get();
  parse_slice(*file_, 0, *b);
  const uint64_t bytes_read = root.data_bytes;
  b->codes[0] = 0;
  b->parent_links[0] = 0;
  // Its links, as link() fills them for every other block.
  const auto& all = file_->slices();
  const auto first = all.begin() + root.first_child, last = first + root.child_count;
  const StreamNode& d = b->nodes[0];
  const uint32_t sub = sl::SliceValid::get(d.masks) & ~sl::SliceLeaf::get(d.masks);
  uint32_t rank = 0;
  for (int c = 0; c < 8; ++c) {
    if ((sub >> c & 1u) == 0) continue;
    if (root.child_count == 0) throw Error("slice file: root voxel without a child slice");
    const uint64_t key = uint64_t(c) >> (3 * (1 - first->region_depth));
    const auto it = std::lower_bound(
        first, last, key, [](const sl::SliceEntry& s, uint64_t v) { return s.region_code < v; });
    if (it == last || it->region_code != key)
      throw Error("slice file: root voxel without a child slice");
    b->links[d.link + rank++] = kAbsent | uint32_t(it - all.begin());
  }
  m.table[0] = {b->nodes.data(), b->links.data(), b->attrs.data(), b->contours.data()};
  m.resident_bytes = b->bytes();
  m.state[0] = State::kResident;
  stats_.loaded = 1;
  stats_.bytes_read = bytes_read;
  stats_.resident_bytes = stats_.peak_resident_bytes = m.resident_bytes;
  stats_.resident_slices = 1;
}

StreamedEsvo::~StreamedEsvo() = default;

uint64_t StreamedEsvo::block_bytes(const sl::SliceEntry& e) {
  return ::voxcast::esvo::block_bytes(e);
}

Aabb StreamedEsvo::bounds() const {
  return ::voxcast::detail::OctreeWorld<::voxcast::detail::StreamedEsvoNodes>(impl_->source)
      .bounds();
}

bool StreamedEsvo::trace(const Ray& ray, const LodFootprint& lod, TraceContext& ctx,
                         SurfaceHit* hit, const BeamStart* beam) const {
  return ::voxcast::detail::OctreeWorld<::voxcast::detail::StreamedEsvoNodes>(impl_->source)
      .trace(ray, lod, ctx, hit, beam);
}

float StreamedEsvo::transmittance(const Ray& ray, const LodFootprint& lod, TraceContext& ctx,
                                  const BeamStart* beam) const {
  return ::voxcast::detail::OctreeWorld<::voxcast::detail::StreamedEsvoNodes>(impl_->source)
      .transmittance(ray, lod, ctx, beam);
}

void StreamedEsvo::attributes(const SurfaceHit& hit, TraceContext& ctx, Color* color,
                              Vec3* normal) const {
  const uint32_t node = uint32_t(hit.voxel_ref);
  const BlockRef& b = impl_->table[node >> kLocalBits];
  const StreamNode& d = b.nodes[node & kLocalMask];
  const uint32_t index =
      d.attr + uint32_t(std::popcount(sl::SliceValid::get(d.masks) & ((1u << hit.child) - 1)));
  if (ctx.counting) ctx.counters.attribute_bytes += 8;  // the raw pair (§5.4)
  if (color) *color = decode_color_abgr(b.attrs[size_t(index) * 2]);
  if (normal) *normal = decode_normal_cube(b.attrs[size_t(index) * 2 + 1]);
}

void StreamedEsvo::begin_frame(const FrameView& view) {
  Impl& m = *impl_;
  m.has_view = true;
  m.source.stamp = ++m.stamp;
  m.rays = view.rays();
  m.lod = view.lod();
}

PassOutcome StreamedEsvo::end_pass(std::span<const Request> requests) {
  Impl& m = *impl_;
  const auto& all = file_->slices();
  // Candidates: requested slices on disk whose parent is resident, best score first.
  std::vector<std::pair<double, uint32_t>> cand;
  for (const Request& r : requests) {
    if (r.kind != kRequestKind || r.key >= all.size()) continue;
    const uint32_t i = uint32_t(r.key);
    if (i == 0 || m.state[i] != State::kOnDisk || m.state[all[i].parent] != State::kResident)
      continue;
    cand.push_back({m.score(i), i});
  }
  std::sort(cand.begin(), cand.end(), [](const auto& a, const auto& b) {
    return a.first != b.first ? a.first > b.first : a.second < b.second;
  });

  // Plan within the budget: unload lower-scoring resident leaf slices (no
  // resident children, not a planned load's parent) while that improves the
  // total score, i.e. only for a candidate that scores higher.
  const uint64_t budget = m.options.budget_bytes;
  std::vector<uint32_t> to_load, victims;
  std::vector<uint8_t> mark(all.size(), 0);  // 1 = victim, 2 = parent of a planned load
  uint64_t after = m.resident_bytes;
  size_t free_ids = m.free_ids.size();
  uint64_t pending = 0;
  std::vector<std::pair<double, uint32_t>> leaves;  // resident leaf slices by score
  for (uint32_t i = 1; i < all.size(); ++i)
    if (m.state[i] == State::kResident && m.resident_children[i] == 0)
      leaves.push_back(
          {m.used[m.block_of[i]].load(std::memory_order_relaxed) == m.stamp ? m.score(i) : 0.0, i});
  std::sort(leaves.begin(), leaves.end());
  size_t next_leaf = 0;
  for (const auto& [score, i] : cand) {
    const uint32_t parent = all[i].parent;
    if (to_load.size() >= m.options.max_loads_per_pass || mark[parent] == 1) {
      ++pending;
      continue;
    }
    const uint64_t need = block_bytes(all[i]);
    const uint8_t parent_mark = mark[parent];
    mark[parent] = 2;  // never its own parent's victim
    std::vector<uint32_t> take;
    uint64_t freed = 0;
    size_t ids = free_ids, scan = next_leaf;
    while ((budget != 0 && after - freed + need > budget) || ids == 0) {
      while (scan < leaves.size() && mark[leaves[scan].second] != 0) ++scan;
      if (scan >= leaves.size() || !(leaves[scan].first < score)) break;
      take.push_back(leaves[scan].second);
      freed += m.blocks[m.block_of[leaves[scan].second]]->bytes();
      ++ids;
      ++scan;
    }
    if ((budget != 0 && after - freed + need > budget) || ids == 0) {
      mark[parent] = parent_mark;
      ++pending;
      continue;
    }
    for (uint32_t v : take) mark[v] = 1, victims.push_back(v);
    next_leaf = scan;
    after = after - freed + need;
    free_ids = ids - 1;
    to_load.push_back(i);
  }
  // A victim's slot in `leaves` is consumed; a parent left childless by a
  // victim becomes a leaf for later passes (not this one: keeps it simple
  // and the plan monotone).
  for (uint32_t v : victims) m.unlink(v);
  const auto [loaded, refused] = m.load(to_load, &stats_.bytes_read);

  stats_.loaded += loaded;
  stats_.unloaded += victims.size();
  stats_.refused += refused;
  stats_.pending = pending;
  stats_.resident_bytes = m.resident_bytes;
  stats_.peak_resident_bytes = std::max(stats_.peak_resident_bytes, m.resident_bytes);
  stats_.resident_slices = uint32_t(kMaxBlocks - m.free_ids.size());
  stats_.compactions = m.arena->compactions();
  stats_.bytes_moved = m.arena->moved_bytes();
  stats_.full_compaction_bytes = m.arena->full_compaction_bytes();
  PassOutcome out;
  out.changed = loaded > 0;
  out.served = loaded + refused;
  out.pending = pending;
  return out;
}

bool StreamedEsvo::fits_whole() const {
  const auto& all = file_->slices();
  uint64_t total = 0;
  for (const sl::SliceEntry& e : all) total += block_bytes(e);
  return all.size() <= kMaxBlocks &&
         (impl_->options.budget_bytes == 0 || total <= impl_->options.budget_bytes);
}

void StreamedEsvo::load_all() {
  Impl& m = *impl_;
  const auto& all = file_->slices();
  uint64_t total = 0;
  for (const sl::SliceEntry& e : all) total += block_bytes(e);
  if (m.options.budget_bytes != 0 && total > m.options.budget_bytes)
    throw Error("load_all: the slices need " + std::to_string(total) + " B, more than the budget");
  if (all.size() > kMaxBlocks)
    throw Error("load_all: more slices than resident blocks (" + std::to_string(kMaxBlocks) + ")");
  while (true) {
    std::vector<uint32_t> list;
    for (uint32_t i = 1; i < all.size(); ++i)
      if (m.state[i] == State::kOnDisk && m.state[all[i].parent] == State::kResident)
        list.push_back(i);
    if (list.empty()) break;
    const auto [loaded, refused] = m.load(list, &stats_.bytes_read);
    stats_.loaded += loaded;
    stats_.refused += refused;
  }
  stats_.resident_bytes = m.resident_bytes;
  stats_.peak_resident_bytes = std::max(stats_.peak_resident_bytes, m.resident_bytes);
  stats_.resident_slices = uint32_t(kMaxBlocks - m.free_ids.size());
  stats_.compactions = m.arena->compactions();
  stats_.bytes_moved = m.arena->moved_bytes();
}

Aabb StreamedEsvo::occupied() const {
  // As occupied_bounds() of the in-core octree (src/esvo/bounds.cpp): every
  // voxel that ends a walk extends the box by its cube, in float.
  const Impl& m = *impl_;
  const GridTransform grid = file_->grid();
  const double side = grid.side();
  Aabb box;
  for (uint32_t i = 0; i < file_->slices().size(); ++i) {
    if (m.state[i] != State::kResident) continue;
    const Block& b = *m.blocks[m.block_of[i]];
    const int level = file_->slices()[i].node_level + 1;
    const double size = side / double(uint64_t(1) << level);
    for (size_t q = 0; q < b.nodes.size(); ++q) {
      const StreamNode& d = b.nodes[q];
      const uint32_t valid = sl::SliceValid::get(d.masks), leaf = sl::SliceLeaf::get(d.masks);
      uint32_t rank = 0;
      for (int c = 0; c < 8; ++c) {
        if ((valid >> c & 1u) == 0) continue;
        const bool ends = (leaf >> c & 1u) != 0 || (b.links[d.link + rank++] & kAbsent) != 0;
        if (!ends) continue;
        const MortonCoord p = morton_decode(b.codes[q] << 3 | uint64_t(c));
        const Vec3 lo{float(grid.origin.x + p.x * size), float(grid.origin.y + p.y * size),
                      float(grid.origin.z + p.z * size)};
        box.extend(lo);
        box.extend(lo + Vec3{float(size), float(size), float(size)});
      }
    }
  }
  return box;
}

const std::string& StreamedEsvo::last_refusal() const {
  return impl_->last_error;
}

bool StreamedEsvo::resident(uint32_t slice) const {
  return slice < impl_->state.size() && impl_->state[slice] == State::kResident;
}
bool StreamedEsvo::refused(uint32_t slice) const {
  return slice < impl_->state.size() && impl_->state[slice] == State::kRefused;
}

void StreamedEsvo::check_invariants() const {
  const Impl& m = *impl_;
  const auto& all = file_->slices();
  auto fail = [](const std::string& why) { throw Error("streamed esvo invariant: " + why); };
  uint64_t bytes = 0;
  uint32_t count = 0;
  std::vector<uint32_t> children(all.size(), 0);
  for (uint32_t i = 0; i < all.size(); ++i) {
    if (m.state[i] != State::kResident) continue;
    ++count;
    const uint32_t id = m.block_of[i];
    const Block* b = m.blocks[id].get();
    if (b == nullptr || b->slice != i) fail("slice " + std::to_string(i) + " has no block");
    if (m.table[id].nodes != b->nodes.data() || m.table[id].links != b->links.data())
      fail("block table entry " + std::to_string(id));
    bytes += b->bytes();
    if (b->bytes() != block_bytes(all[i])) fail("block size of slice " + std::to_string(i));
    if (i != 0) {
      const uint32_t p = all[i].parent;
      if (m.state[p] != State::kResident)
        fail("slice " + std::to_string(i) + " resident without its parent");
      ++children[p];
      const Block& pb = *m.blocks[m.block_of[p]];
      for (uint32_t q = 0; q < b->nodes.size(); ++q)
        if (pb.links[b->parent_links[q]] != (id << kLocalBits | q))
          fail("parent link of slice " + std::to_string(i) + " descriptor " + std::to_string(q));
    }
    // Every link: a descriptor of a resident child block whose parent link
    // is this one, or absent naming a child slice that is not resident.
    for (uint32_t q = 0; q < b->nodes.size(); ++q) {
      const StreamNode& d = b->nodes[q];
      const uint32_t sub = sl::SliceValid::get(d.masks) & ~sl::SliceLeaf::get(d.masks);
      for (uint32_t r = 0; r < uint32_t(std::popcount(sub)); ++r) {
        const uint32_t li = d.link + r, v = b->links[li];
        if (v & kAbsent) {
          const uint32_t s = v & ~kAbsent;
          if (s >= all.size() || all[s].parent != i || m.state[s] == State::kResident)
            fail("absent link " + std::to_string(li) + " of slice " + std::to_string(i));
        } else {
          const Block* c = m.blocks[v >> kLocalBits].get();
          if (c == nullptr || all[c->slice].parent != i || (v & kLocalMask) >= c->nodes.size() ||
              c->parent_links[v & kLocalMask] != li)
            fail("link " + std::to_string(li) + " of slice " + std::to_string(i));
        }
      }
    }
  }
  for (uint32_t i = 0; i < all.size(); ++i)
    if (children[i] != m.resident_children[i])
      fail("resident child count of slice " + std::to_string(i));
  if (bytes != m.resident_bytes || bytes != stats_.resident_bytes)
    fail("resident bytes " + std::to_string(m.resident_bytes) + " != blocks' " +
         std::to_string(bytes));
  if (m.options.budget_bytes != 0 && bytes > m.options.budget_bytes) fail("over the budget");
  if (count != kMaxBlocks - m.free_ids.size()) fail("free block ids");
  // The arena: within the budget; one extent per resident block, in order,
  // without overlaps, where the block and the caster's table say.
  const Arena& a = *m.arena;
  if (m.options.budget_bytes != 0 && a.capacity() > m.options.budget_bytes)
    fail("arena larger than the budget");
  uint64_t end = 0, sum = 0;
  for (const auto& [off, ext] : a.extents()) {
    const auto [id, size] = ext;
    if (off < end || off + size > a.capacity()) fail("arena extent at " + std::to_string(off));
    const Block* b = id < kMaxBlocks ? m.blocks[id].get() : nullptr;
    if (b == nullptr || b->offset != off || b->size != size ||
        m.state[b->slice] != State::kResident || m.block_of[b->slice] != id ||
        reinterpret_cast<const std::byte*>(b->nodes.data()) != a.at(off) ||
        m.table[id].nodes != b->nodes.data() || m.table[id].attrs != b->attrs.data() ||
        m.table[id].contours != b->contours.data())
      fail("arena extent at " + std::to_string(off) + " of block " + std::to_string(id));
    end = off + size;
    sum += size;
  }
  if (a.extents().size() != count || sum != bytes || a.used() != bytes) fail("arena bytes");
}

}  // namespace voxcast::esvo
