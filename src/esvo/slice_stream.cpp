// The streamed ESVO (esvo §7 "Storage in memory", "Loading slices",
// "Dynamic loading"): the resident octree as a trunk and depth-first leaf
// blocks (Figure 21), the octree caster's third node-access policy over them
// (after the in-core ESVO's and the DAG's), and the score-driven loading and
// unloading between passes.
// Layout and contract: include/voxcast/esvo_slices.hpp.
#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstring>
#include <map>
#include <memory>
#include <set>
#include <span>
#include <thread>
#include <unordered_map>

#include "core/octree_caster.hpp"
#include "voxcast/error.hpp"
#include "voxcast/esvo_slices.hpp"
#include "voxcast/morton.hpp"
#include "voxcast/progress.hpp"

namespace voxcast::esvo {
namespace sl = slice_layout;

namespace {
// A node id is (block << kLocalBits) | descriptor index in the block (leaf
// blocks and trunk chunks alike); a link with kAbsent set is a subdivided
// child whose slice (low 31 bits) is not resident. The root descriptor moves
// (from a leaf block to the trunk when its block splits), so its node id is
// part of the caster's source.
constexpr uint32_t kLocalBits = 19;
static_assert((1u << kLocalBits) == sl::kMaxSliceNodes);
constexpr uint32_t kLocalMask = (1u << kLocalBits) - 1;
constexpr uint32_t kAbsent = 1u << 31;
constexpr uint32_t kMaxBlocks = 1u << (31 - kLocalBits);  // 4096 blocks and trunk chunks
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
  /// Entering a descriptor of this level stamps the block as used (its
  /// deepest level: the one its slice's unloading would drop); -1: never.
  int stamp_level = -1;
};

struct StreamSource {
  GridTransform grid;
  const BlockRef* table = nullptr;
  // Usage stamps per block (written by the rays, relaxed) and this frame's stamp.
  std::atomic<uint32_t>* used = nullptr;
  uint32_t stamp = 0;
  uint32_t root = 0;  // the root descriptor's node id
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

  explicit StreamedEsvoNodes(const Source& s)
      : table(s.table), used(s.used), stamp(s.stamp), root_node(s.root) {}
  uint32_t root() const { return root_node; }

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
  /// Entering a descriptor of a block's deepest level stamps the block as
  /// used in this frame (a compare per PUSH, a load and compare when it is
  /// that level, the store once per block and frame): a resident slice whose
  /// level no ray entered adds nothing to the image and may be unloaded first.
  template <class I, class C>
  uint32_t descend(const Desc& d, uint32_t node, int c, int s, I&, C&) const {
    const uint32_t l = link(table, d, node, c);
    if (table[l >> esvo::kLocalBits].stamp_level == kOctreeMaxScale - s) {
      std::atomic<uint32_t>& u = used[l >> esvo::kLocalBits];
      if (u.load(std::memory_order_relaxed) != stamp) u.store(stamp, std::memory_order_relaxed);
    }
    return l;
  }
  /// The beam walk's split of descend(): a node's children are named by its
  /// links, so children() passes the node on and child() reads the link
  /// (the walk asks resident() first; it stamps nothing: the rays do).
  template <class C>
  static uint32_t children(const Desc&, uint32_t node, int, C&) {
    return node;
  }
  template <class C>
  uint32_t child(const Desc& d, uint32_t node, int c, int, C&) const {
    return link(table, d, node, c);
  }
  static void name_hit(const Source&, const OctreeCast<Index>& r, SurfaceHit* hit) {
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
  uint32_t root_node;
};

}  // namespace voxcast::detail

namespace voxcast::esvo {

namespace {

constexpr uint32_t kNoBlock = 0xFFFFFFFFu;     // block_of: the slice has no block
constexpr uint32_t kEmptyBlock = 0xFFFFFFFEu;  // block_of: a block of no descriptors (no extent)
constexpr uint32_t kNoNode = 0xFFFFFFFFu;
/// Descriptors per trunk chunk; a trunk descriptor has room for every
/// attribute, contour and link of its eight children (§7 "Storage in memory").
constexpr uint32_t kTrunkSlots = 64;
constexpr uint64_t kTrunkChunkBytes = kTrunkSlots * (sizeof(StreamNode) + 8 * 4 + 16 * 4 + 8 * 4);
static_assert(kTrunkChunkBytes % 16 == 0);

uint32_t subdivided(uint32_t masks) {
  return sl::SliceValid::get(masks) & ~sl::SliceLeaf::get(masks);
}
uint32_t rank_below(uint32_t mask, int c) {
  return uint32_t(std::popcount(mask & ((1u << c) - 1)));
}

/// Bytes of a leaf block with these counts, rounded up to 16 so that every
/// block starts 16-byte aligned.
uint64_t leaf_bytes(uint64_t nodes, uint64_t links, uint64_t voxels, uint64_t contours) {
  const uint64_t raw = nodes * sizeof(StreamNode) + links * 4 + voxels * 8 + contours * 4;
  return (raw + 15) & ~uint64_t(15);
}

/// What slice e adds to the leaf blocks while resident (its descriptors,
/// links, attributes and contours), with room for one block's rounding.
uint64_t block_bytes(const sl::SliceEntry& e) {
  return leaf_bytes(e.node_count, e.link_count, e.voxel_count, e.contour_count) + 16;
}

/// Trunk descriptors the load of slice e can add at most in a full-depth
/// octree (its region's levels above its children's region depth; each such
/// level has no more descriptors than the slice's level, every descriptor
/// having a descendant there). Variable-depth files can exceed it (voxels
/// outside every child slice also go to the trunk); it only sizes the arena
/// and load_all's check, the exact bytes are checked at every load.
uint64_t trunk_bound(const std::vector<sl::SliceEntry>& all, const sl::SliceEntry& e) {
  if (e.child_count == 0) return 0;
  const int k = all[e.first_child].region_depth;
  uint64_t n = 0;
  for (int l = e.region_depth; l < k; ++l)
    n += std::min<uint64_t>(e.node_count,
                            l - e.region_depth >= 21 ? ~0ull : 1ull << (3 * (l - e.region_depth)));
  return n;
}

/// A block in the arena (§7 "Storage in memory"): a leaf block -- one
/// subtree in depth-first order, corresponding to the next-level slice
/// `key` (or to `key` itself when that slice is resident and has no child
/// slices) -- or a trunk chunk of kTrunkSlots fixed-size descriptors.
struct Block {
  uint32_t key = 0;  // leaf: the slice; trunk chunk: its index in the trunk
  bool trunk = false;
  int stamp_level = -1;           // BlockRef::stamp_level: a leaf block's deepest level
  uint64_t offset = 0, size = 0;  // its extent in the arena
  uint32_t node_count = 0, link_count = 0, voxel_count = 0, contour_count = 0;
  std::span<StreamNode> nodes;
  std::span<uint32_t> links;     // per subdivided child: a node id or kAbsent | slice
  std::span<uint32_t> attrs;     // per child: color, normal
  std::span<uint32_t> contours;  // per contoured child
  /// Points the arrays at the extent starting at `base` (after a move, too).
  void place(std::byte* base) {
    std::byte* p = base;
    auto take = [&p]<class T>(std::span<T>& s, size_t n) {
      s = {reinterpret_cast<T*>(p), n};
      p += n * sizeof(T);
    };
    take(nodes, node_count);
    take(links, link_count);
    take(attrs, size_t(voxel_count) * 2);
    take(contours, contour_count);
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
  /// `limit` = capacity: a hard cap (a budget); larger: the arena grows
  /// (reallocated, every block repointed) up to it when the free bytes do not
  /// suffice (an unlimited budget, where the trunk's size is not known ahead).
  Arena(uint64_t capacity, uint64_t limit)
      : capacity_(capacity),
        limit_(std::max(limit, capacity)),
        memory_(new std::byte[std::max<uint64_t>(capacity, 16)]) {}
  uint64_t capacity() const { return capacity_; }
  /// Bytes an allocation may still take (growing, if allowed).
  uint64_t available() const { return limit_ - used_; }
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
    if (bytes > limit_ - used_)
      throw Error("streamed esvo arena: " + std::to_string(bytes) + " B asked for, " +
                  std::to_string(limit_ - used_) + " B free");
    if (bytes > capacity_ - used_)
      grow(std::min(limit_, std::max(capacity_ + capacity_ / 2, used_ + bytes + (1u << 16))),
           moved);
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
  template <class Moved>
  void grow(uint64_t capacity, const Moved& moved) {
    std::unique_ptr<std::byte[]> memory(new std::byte[capacity]);
    for (const auto& [off, ext] : extents_) std::memcpy(memory.get() + off, at(off), ext.second);
    memory_ = std::move(memory);
    capacity_ = capacity;
    for (const auto& [off, ext] : extents_) moved(ext.first, off);
  }
  uint64_t insert(uint64_t offset, uint32_t id, uint64_t bytes) {
    extents_.emplace(offset, std::make_pair(id, bytes));
    used_ += bytes;
    return offset;
  }
  uint64_t capacity_, limit_;
  std::unique_ptr<std::byte[]> memory_;  // not value-initialized: untouched pages stay virtual
  std::map<uint64_t, std::pair<uint32_t, uint64_t>> extents_;
  uint64_t used_ = 0, moved_bytes_ = 0, compactions_ = 0, full_bytes_ = 0;
};

/// Slice data checked against the directory (every descriptor word and
/// count), so that what merges into a block cannot send a ray out of bounds.
void check_slice(const SliceFile& file, uint32_t i, const std::vector<uint32_t>& words) {
  const sl::SliceEntry& e = file.slices()[i];
  auto bad = [&](const char* why) {
    return Error("slice file '" + file.path().string() + "': slice " + std::to_string(i) + ": " +
                 why);
  };
  const bool deepest = e.node_level + 1u >= file.header().levels;
  uint64_t voxels = 0, contours = 0, links = 0;
  if (words.size() < e.node_count) throw bad("counts disagree with the directory");
  for (uint32_t n = 0; n < e.node_count; ++n) {
    const uint32_t d = words[n];
    const uint32_t valid = sl::SliceValid::get(d), leaf = sl::SliceLeaf::get(d),
                   cm = sl::SliceContourMask::get(d);
    if ((d >> 24) != 0 || valid == 0 || (leaf & ~valid) != 0 || (cm & ~valid) != 0)
      throw bad("malformed descriptor");
    if (cm != 0 && !file.has_contours()) throw bad("contour in a file without contours");
    if (deepest && (valid & ~leaf) != 0) throw bad("subdivided voxel at the finest level");
    voxels += uint32_t(std::popcount(valid));
    contours += uint32_t(std::popcount(cm));
    links += uint32_t(std::popcount(valid & ~leaf));
  }
  if (voxels != e.voxel_count || contours != e.contour_count || links != e.link_count ||
      words.size() != size_t(e.node_count) + 2 * size_t(voxels) + contours)
    throw bad("counts disagree with the directory");
}

/// Descriptors in depth-first order with their levels and codes, copied out
/// of the blocks (or a slice) to be merged, split and written back: the
/// host-side step of §7 "Loading slices".
struct Tree {
  struct Node {
    uint32_t masks;
    int level;
    uint64_t code;
    uint32_t attr;     // first pair in attrs
    uint32_t contour;  // first value in contours
  };
  std::vector<Node> nodes;
  std::vector<uint32_t> attrs, contours;
  void add(uint32_t masks, int level, uint64_t code, const uint32_t* attr,
           const uint32_t* contour) {
    nodes.push_back({masks, level, code, uint32_t(attrs.size() / 2), uint32_t(contours.size())});
    attrs.insert(attrs.end(), attr, attr + 2 * std::popcount(sl::SliceValid::get(masks)));
    contours.insert(contours.end(), contour,
                    contour + std::popcount(sl::SliceContourMask::get(masks)));
  }
  /// Per node its parent's index (kNoNode for the first), checking that the
  /// order is depth-first.
  std::vector<uint32_t> parents() const {
    std::vector<uint32_t> parent(nodes.size(), kNoNode), stack;
    for (uint32_t j = 0; j < nodes.size(); ++j) {
      while (!stack.empty() && nodes[stack.back()].level >= nodes[j].level) stack.pop_back();
      if (!stack.empty()) parent[j] = stack.back();
      stack.push_back(j);
    }
    return parent;
  }
};

}  // namespace

struct StreamedEsvo::Impl {
  std::shared_ptr<const SliceFile> file;
  StreamOptions options;
  StreamSource source;
  std::vector<BlockRef> table = std::vector<BlockRef>(kMaxBlocks);
  std::vector<std::unique_ptr<Block>> blocks = std::vector<std::unique_ptr<Block>>(kMaxBlocks);
  std::unique_ptr<Arena> arena;  // every block's arrays
  std::set<uint32_t> free_ids;   // block ids, smallest first (deterministic)
  std::vector<State> state;
  /// Per slice: its leaf block (a block id, kEmptyBlock or kNoBlock). Every
  /// next-level slice (parent resident, itself not) has one; so has a
  /// resident slice without child slices; no other slice has one.
  std::vector<uint32_t> block_of;
  std::vector<uint32_t> resident_children;  // per slice
  uint32_t resident_count = 0;
  // The trunk: chunks (block ids, kNoBlock where freed) and its free
  // descriptor slots (chunk * kTrunkSlots + slot), smallest first.
  std::vector<uint32_t> trunk_chunks;
  std::set<uint32_t> trunk_free;
  uint64_t trunk_live = 0;
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
  std::string last_error;

  const sl::SliceEntry& entry(uint32_t i) const { return file->slices()[i]; }
  Error bad(uint32_t i, const std::string& why) const {
    return Error("slice file '" + file->path().string() + "': slice " + std::to_string(i) + ": " +
                 why);
  }

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

  // ---- Nodes and links ----
  const StreamNode& node(uint32_t id) const {
    return blocks[id >> kLocalBits]->nodes[id & kLocalMask];
  }
  uint32_t& link_of(uint32_t id, int c) {
    Block& b = *blocks[id >> kLocalBits];
    const StreamNode& d = b.nodes[id & kLocalMask];
    return b.links[d.link + rank_below(subdivided(d.masks), c)];
  }
  /// The node of the voxel at (level, code), walking down from the root;
  /// kNoNode when a link on the way is absent or the voxel is not subdivided.
  uint32_t find(int level, uint64_t code) const {
    uint32_t id = source.root;
    for (int l = 0; l < level; ++l) {
      const StreamNode& d = node(id);
      const int c = int(code >> (3 * (level - 1 - l)) & 7);
      if ((subdivided(d.masks) >> c & 1u) == 0) return kNoNode;
      const Block& b = *blocks[id >> kLocalBits];
      id = b.links[d.link + rank_below(subdivided(d.masks), c)];
      if (id & kAbsent) return kNoNode;
    }
    return id;
  }
  /// Where the link to the voxel (level, code) is: its parent node and slot
  /// (kNoNode: the root pointer). Its parent is a trunk descriptor.
  std::pair<uint32_t, int> parent_link(uint32_t i, int level, uint64_t code) const {
    if (level == 0) return {kNoNode, 0};
    const uint32_t p = find(level - 1, code >> 3);
    if (p == kNoNode || (subdivided(node(p).masks) >> (code & 7) & 1u) == 0)
      throw bad(i, "its region is not a subdivided voxel of the resident octree");
    return {p, int(code & 7)};
  }
  void set_link(std::pair<uint32_t, int> at, uint32_t value) {
    if (at.first == kNoNode)
      source.root = value;
    else
      link_of(at.first, at.second) = value;
  }

  /// Appends the resident subtree under node `id` (voxel (level, code)) to
  /// `t` in depth-first order, `where` getting each node's id; after each
  /// node, `after(t)` may append more (the load merges a slice's level so).
  template <class After>
  void gather(uint32_t id, int level, uint64_t code, Tree& t, std::vector<uint32_t>& where,
              const After& after) const {
    struct Item {
      uint32_t id;
      int level;
      uint64_t code;
    };
    std::vector<Item> stack{{id, level, code}};
    while (!stack.empty()) {
      const Item it = stack.back();
      stack.pop_back();
      const Block& b = *blocks[it.id >> kLocalBits];
      const StreamNode& d = b.nodes[it.id & kLocalMask];
      t.add(d.masks, it.level, it.code, b.attrs.data() + size_t(d.attr) * 2,
            b.contours.data() + d.contour);
      where.push_back(it.id);
      after(t);
      const uint32_t sub = subdivided(d.masks);
      for (int c = 7; c >= 0; --c) {
        if ((sub >> c & 1u) == 0) continue;
        const uint32_t l = b.links[d.link + rank_below(sub, c)];
        if ((l & kAbsent) == 0) stack.push_back({l, it.level + 1, it.code << 3 | uint64_t(c)});
      }
    }
  }

  // ---- Blocks, trunk slots ----
  uint32_t take_id() {
    const uint32_t id = *free_ids.begin();
    free_ids.erase(free_ids.begin());
    return id;
  }
  /// A block with these counts in the arena (compacting or growing if need
  /// be); its table entry is set.
  uint32_t allocate(uint32_t key, bool trunk, uint32_t nodes, uint32_t links, uint32_t voxels,
                    uint32_t contours, int stamp_level = -1) {
    const uint32_t id = take_id();
    auto b = std::make_unique<Block>();
    b->stamp_level = stamp_level;
    b->key = key;
    b->trunk = trunk;
    b->node_count = nodes, b->link_count = links, b->voxel_count = voxels,
    b->contour_count = contours;
    b->size = leaf_bytes(nodes, links, voxels, contours);
    blocks[id] = std::move(b);
    Block& nb = *blocks[id];
    nb.offset = arena->allocate(id, nb.size, [&](uint32_t moved, uint64_t to) {
      Block& m = *blocks[moved];
      m.offset = to;
      m.place(arena->at(to));
      table[moved] = {m.nodes.data(), m.links.data(), m.attrs.data(), m.contours.data(),
                      m.stamp_level};
    });
    nb.place(arena->at(nb.offset));
    // The rounding's padding zeroed: a block's bytes are a function of its contents.
    std::byte* end = reinterpret_cast<std::byte*>(nb.contours.data() + nb.contours.size());
    std::memset(end, 0, size_t(arena->at(nb.offset) + nb.size - end));
    table[id] = {nb.nodes.data(), nb.links.data(), nb.attrs.data(), nb.contours.data(),
                 nb.stamp_level};
    used[id].store(stamp, std::memory_order_relaxed);
    return id;
  }
  void release(uint32_t id) {
    arena->release(blocks[id]->offset);
    blocks[id].reset();
    table[id] = {};
    free_ids.insert(id);
  }
  /// A free trunk descriptor (a new chunk when none is free): its node id.
  uint32_t take_trunk_slot() {
    if (trunk_free.empty()) {
      const uint32_t chunk = uint32_t(trunk_chunks.size());
      trunk_chunks.push_back(kNoBlock);
      const uint32_t id =
          allocate(chunk, true, kTrunkSlots, 8 * kTrunkSlots, 8 * kTrunkSlots, 8 * kTrunkSlots);
      trunk_chunks[chunk] = id;
      for (uint32_t s = 0; s < kTrunkSlots; ++s) {
        blocks[id]->nodes[s] = {0, 8 * s, 8 * s, 8 * s};  // masks 0: free
        trunk_free.insert(chunk * kTrunkSlots + s);
      }
    }
    const uint32_t slot = *trunk_free.begin();
    trunk_free.erase(trunk_free.begin());
    ++trunk_live;
    return trunk_node(slot);
  }
  uint32_t trunk_node(uint32_t slot) const {
    return trunk_chunks[slot / kTrunkSlots] << kLocalBits | (slot % kTrunkSlots);
  }
  /// Marks a trunk descriptor free; compact_trunk() then closes the hole.
  void free_trunk_slot(uint32_t id) {
    Block& b = *blocks[id >> kLocalBits];
    b.nodes[id & kLocalMask].masks = 0;
    trunk_free.insert(b.key * kTrunkSlots + (id & kLocalMask));
    --trunk_live;
  }
  /// Keeps the trunk dense (its live descriptors in slots 0 .. live-1, so
  /// its chunk count depends only on what is resident): the highest live
  /// descriptors move into the holes (the one link to each is repointed,
  /// found in an index of the trunk's links built once per compaction: a
  /// search of the trunk per move made unloading quadratic in the holes),
  /// then the empty chunks at the end go.
  void compact_trunk() {
    std::unordered_map<uint32_t, uint32_t> link_at;  // linked node id -> index in its chunk's links
    std::unordered_map<uint32_t, uint32_t> link_chunk;  // ... and that chunk's block id
    auto index_links = [&](uint32_t block_id, uint32_t local) {
      Block& b = *blocks[block_id];
      const StreamNode& d = b.nodes[local];
      for (int r = 0; r < std::popcount(subdivided(d.masks)); ++r) {
        const uint32_t l = b.links[d.link + uint32_t(r)];
        if ((l & kAbsent) != 0) continue;
        link_at[l] = d.link + uint32_t(r);
        link_chunk[l] = block_id;
      }
    };
    if (!trunk_free.empty() && *trunk_free.begin() < trunk_live)
      for (uint32_t slot = 0; slot < trunk_chunks.size() * kTrunkSlots; ++slot)
        if (blocks[trunk_chunks[slot / kTrunkSlots]]->nodes[slot % kTrunkSlots].masks != 0)
          index_links(trunk_chunks[slot / kTrunkSlots], slot % kTrunkSlots);
    while (!trunk_free.empty() && *trunk_free.begin() < trunk_live) {
      const uint32_t hole = *trunk_free.begin();
      uint32_t top = uint32_t(trunk_chunks.size()) * kTrunkSlots - 1;
      while (trunk_free.count(top) != 0) --top;
      const uint32_t from = trunk_node(top), to = trunk_node(hole);
      Block& fb = *blocks[from >> kLocalBits];
      Block& tb = *blocks[to >> kLocalBits];
      const uint32_t f = from & kLocalMask, t = to & kLocalMask;
      tb.nodes[t] = {fb.nodes[f].masks, 8 * t, 8 * t, 8 * t};
      std::copy_n(&fb.attrs[16 * size_t(f)], 16, &tb.attrs[16 * size_t(t)]);
      std::copy_n(&fb.contours[8 * size_t(f)], 8, &tb.contours[8 * size_t(t)]);
      std::copy_n(&fb.links[8 * size_t(f)], 8, &tb.links[8 * size_t(t)]);
      fb.nodes[f].masks = 0;
      // The one link to it, then its own links' new place.
      if (source.root == from) {
        source.root = to;
      } else {
        const auto at = link_at.find(from);
        if (at == link_at.end())
          throw Error("streamed esvo: trunk descriptor " + std::to_string(from) +
                      " linked from nowhere");
        blocks[link_chunk.at(from)]->links[at->second] = to;
        link_at[to] = at->second;
        link_chunk[to] = link_chunk.at(from);
        link_at.erase(from);
        link_chunk.erase(from);
      }
      index_links(to >> kLocalBits, t);
      trunk_free.erase(hole);
      trunk_free.insert(top);
    }
    while (!trunk_chunks.empty() && trunk_live <= (trunk_chunks.size() - 1) * kTrunkSlots) {
      const uint32_t chunk = uint32_t(trunk_chunks.size()) - 1;
      for (uint32_t s = 0; s < kTrunkSlots; ++s) trunk_free.erase(chunk * kTrunkSlots + s);
      release(trunk_chunks.back());
      trunk_chunks.pop_back();
    }
  }
  uint64_t trunk_chunks_needed(uint64_t slots) const {
    return slots > trunk_free.size() ? (slots - trunk_free.size() + kTrunkSlots - 1) / kTrunkSlots
                                     : 0;
  }

  /// Writes the nodes of `t` at their ids (`ids`, leaf-block nodes of one
  /// block in depth-first order, from local index 0): descriptor, attributes,
  /// contours, and links -- to the child's id when the child is in `t`,
  /// otherwise `absent(level, code)` of the missing child voxel.
  template <class Absent>
  void write(const Tree& t, const std::vector<uint32_t>& ids, const Absent& absent) {
    std::map<uint32_t, std::array<uint32_t, 3>> run;  // leaf block -> attr, contour, link
    for (size_t j = 0; j < t.nodes.size(); ++j) {
      const Tree::Node& n = t.nodes[j];
      Block& b = *blocks[ids[j] >> kLocalBits];
      const uint32_t local = ids[j] & kLocalMask;
      StreamNode d{n.masks, 8 * local, 8 * local, 8 * local};
      if (!b.trunk) {
        std::array<uint32_t, 3>& r = run[ids[j] >> kLocalBits];
        d = {n.masks, r[0], r[1], r[2]};
        r[0] += uint32_t(std::popcount(sl::SliceValid::get(n.masks)));
        r[1] += uint32_t(std::popcount(sl::SliceContourMask::get(n.masks)));
        r[2] += uint32_t(std::popcount(subdivided(n.masks)));
      }
      b.nodes[local] = d;
      // data() + offset, not &v[offset]: a scene without contours has empty
      // contour arrays, and operator[] on an empty vector is undefined even
      // for a copy of 0 elements (UBSan: reference binding to null pointer).
      std::copy_n(t.attrs.data() + size_t(n.attr) * 2,
                  2 * std::popcount(sl::SliceValid::get(n.masks)),
                  b.attrs.data() + size_t(d.attr) * 2);
      std::copy_n(t.contours.data() + n.contour, std::popcount(sl::SliceContourMask::get(n.masks)),
                  b.contours.data() + d.contour);
      const uint32_t sub = subdivided(n.masks);
      for (int c = 0; c < 8; ++c)
        if (sub >> c & 1u)
          b.links[d.link + rank_below(sub, c)] = absent(n.level + 1, n.code << 3 | uint64_t(c));
    }
    const std::vector<uint32_t> parent = t.parents();
    for (size_t j = 0; j < t.nodes.size(); ++j)
      if (parent[j] != kNoNode) link_of(ids[parent[j]], int(t.nodes[j].code & 7)) = ids[j];
  }

  /// §7 "Loading slices", Figure 21: merges slice i (checked words) into its
  /// block, then keeps one block per child slice (each its region's subtree)
  /// and moves what is in none of them to the trunk. False (nothing changed)
  /// when the arena or the block ids cannot hold the result; throws (nothing
  /// changed) when the slice does not fit what the resident octree implies.
  bool merge(uint32_t i, const std::vector<uint32_t>& w) {
    const sl::SliceEntry& e = entry(i);
    const auto& all = file->slices();
    const int n = e.node_level, r = e.region_depth;
    const uint32_t own = block_of[i];
    if (own == kNoBlock) throw bad(i, "not a next-level slice");
    // 1. The block's subtree (levels r .. n-1 of the region) with the slice's
    // descriptors (level n) after their parents: depth-first still.
    Tree t;
    std::vector<uint32_t> where;
    uint32_t next = 0;
    size_t attr_at = e.node_count, contour_at = e.node_count + 2 * size_t(e.voxel_count);
    auto add_slice_node = [&](Tree& tree, uint64_t code) {
      if (next >= e.node_count) throw bad(i, "more voxels in the region than descriptors");
      const uint32_t d = w[next++];
      tree.add(d, n, code, &w[attr_at], &w[contour_at]);
      attr_at += 2 * size_t(std::popcount(sl::SliceValid::get(d)));
      contour_at += size_t(std::popcount(sl::SliceContourMask::get(d)));
    };
    if (own == kEmptyBlock) {
      if (r != n) throw bad(i, "the region above the slice is not resident");
      add_slice_node(t, e.region_code);
    } else {
      const Block& b = *blocks[own];
      gather(own << kLocalBits, r, e.region_code, t, where, [&](Tree& tree) {
        const Tree::Node last = tree.nodes.back();
        if (last.level != n - 1) return;
        const StreamNode& d = node(where.back());
        const uint32_t sub = subdivided(d.masks);
        for (int c = 0; c < 8; ++c) {
          if ((sub >> c & 1u) == 0) continue;
          if (b.links[d.link + rank_below(sub, c)] != (kAbsent | i))
            throw bad(i, "the parent's link disagrees");
          add_slice_node(tree, last.code << 3 | uint64_t(c));
        }
      });
      if (where.size() != b.node_count) throw bad(i, "its block is not one subtree");
    }
    if (next != e.node_count) throw bad(i, "fewer voxels in the region than descriptors");
    // 2. The split (planned by the slice, §7.1): its children share one region depth k.
    const uint32_t cc = e.child_count;
    const int k = cc != 0 ? all[e.first_child].region_depth : r;
    if (k < r || k > n + 1 || (k == r && cc > 1)) throw bad(i, "its child slices do not tile it");
    const auto first = all.begin() + e.first_child, last = first + cc;
    for (auto c = first; c != last; ++c)
      if (c->parent != i || c->region_depth != k) throw bad(i, "its child slices do not tile it");
    auto child_at = [&](uint64_t code_k) -> int {
      const auto it =
          std::lower_bound(first, last, code_k,
                           [](const sl::SliceEntry& s, uint64_t v) { return s.region_code < v; });
      return it != last && it->region_code == code_k ? int(it - first) : -1;
    };
    const std::vector<uint32_t> parent = t.parents();
    std::vector<uint8_t> present(t.nodes.size(), 0);
    for (size_t j = 1; j < t.nodes.size(); ++j) ++present[parent[j]];
    for (size_t j = 0; j < t.nodes.size(); ++j) {
      const Tree::Node& x = t.nodes[j];
      const uint32_t sub = subdivided(x.masks);
      if (x.level < n) {
        if (present[j] != std::popcount(sub)) throw bad(i, "its block is not one subtree");
        continue;
      }
      for (int c = 0; c < 8; ++c)
        if ((sub >> c & 1u) != 0 &&
            (cc == 0 || child_at((x.code << 3 | uint64_t(c)) >> (3 * (n + 1 - k))) < 0))
          throw bad(i, "subdivided voxel without a child slice");
    }
    // Owners: -1 the trunk, else the group (child slice, or the slice itself
    // when it has none).
    const uint32_t groups = std::max<uint32_t>(cc, 1);
    std::vector<int> owner(t.nodes.size(), 0);
    if (!(cc == 0 || k == r))
      for (size_t j = 0; j < t.nodes.size(); ++j)
        owner[j] =
            t.nodes[j].level >= k ? child_at(t.nodes[j].code >> (3 * (t.nodes[j].level - k))) : -1;
    struct Counts {
      uint32_t nodes = 0, links = 0, voxels = 0, contours = 0;
    };
    std::vector<Counts> count(groups);
    uint64_t trunk = 0;
    for (size_t j = 0; j < t.nodes.size(); ++j) {
      if (owner[j] < 0) {
        ++trunk;
        continue;
      }
      Counts& g = count[size_t(owner[j])];
      const uint32_t m = t.nodes[j].masks;
      ++g.nodes;
      g.links += uint32_t(std::popcount(subdivided(m)));
      g.voxels += uint32_t(std::popcount(sl::SliceValid::get(m)));
      g.contours += uint32_t(std::popcount(sl::SliceContourMask::get(m)));
    }
    // 3. Room: the arena and the block ids, counting what the old block frees.
    uint64_t need = 0, ids = 0;
    for (const Counts& g : count)
      if (g.nodes != 0) {
        if (g.nodes > sl::kMaxSliceNodes) throw bad(i, "its block would exceed 2^19 descriptors");
        need += leaf_bytes(g.nodes, g.links, g.voxels, g.contours);
        ++ids;
      }
    const uint64_t chunks = trunk_chunks_needed(trunk);
    need += chunks * kTrunkChunkBytes;
    ids += chunks;
    const bool had = own != kEmptyBlock;
    if (need > arena->available() + (had ? blocks[own]->size : 0) ||
        ids > free_ids.size() + (had ? 1 : 0))
      return false;
    const auto at = parent_link(i, r, e.region_code);
    // 4. Commit: the old block goes, the result blocks and trunk slots come.
    if (had) release(own);
    std::vector<uint32_t> ids_of(t.nodes.size());
    for (size_t j = 0; j < t.nodes.size(); ++j)
      if (owner[j] < 0) ids_of[j] = take_trunk_slot();
    std::vector<uint32_t> group_block(groups, kEmptyBlock), fill(groups, 0);
    for (uint32_t g = 0; g < groups; ++g)
      if (count[g].nodes != 0)
        group_block[g] = allocate(cc == 0 ? i : e.first_child + g, false, count[g].nodes,
                                  count[g].links, count[g].voxels, count[g].contours, n);
    for (size_t j = 0; j < t.nodes.size(); ++j)
      if (owner[j] >= 0)
        ids_of[j] = group_block[size_t(owner[j])] << kLocalBits | fill[size_t(owner[j])]++;
    write(t, ids_of, [&](int level, uint64_t code) {
      // Only level n + 1 voxels are missing (checked above): the child slice
      // covering it. (The others get their child's id right after.)
      if (level != n + 1) return kAbsent | i;
      return kAbsent | uint32_t(e.first_child + uint32_t(child_at(code >> (3 * (n + 1 - k)))));
    });
    set_link(at, ids_of[0]);
    block_of[i] = cc == 0 ? group_block[0] : kNoBlock;
    for (uint32_t g = 0; g < cc; ++g) block_of[e.first_child + g] = group_block[g];
    state[i] = State::kResident;
    ++resident_count;
    if (i != 0) ++resident_children[e.parent];
    return true;
  }

  /// The inverse of merge (a resident slice without resident children):
  /// gathers its region's subtree from the trunk and its children's blocks,
  /// drops the slice's level and writes back the one block it had. False
  /// (nothing changed) when the arena cannot hold it.
  bool unmerge(uint32_t i) {
    const sl::SliceEntry& e = entry(i);
    const int n = e.node_level, r = e.region_depth;
    const uint32_t top = find(r, e.region_code);
    if (top == kNoNode) throw Error("streamed esvo: slice " + std::to_string(i) + " has no region");
    Tree all_levels;
    std::vector<uint32_t> where;
    gather(top, r, e.region_code, all_levels, where, [](Tree&) {});
    Tree t;
    uint32_t links = 0, voxels = 0, contours = 0;
    for (const Tree::Node& x : all_levels.nodes) {
      if (x.level >= n) continue;
      t.add(x.masks, x.level, x.code, all_levels.attrs.data() + size_t(x.attr) * 2,
            all_levels.contours.data() + x.contour);
      links += uint32_t(std::popcount(subdivided(x.masks)));
      voxels += uint32_t(std::popcount(sl::SliceValid::get(x.masks)));
      contours += uint32_t(std::popcount(sl::SliceContourMask::get(x.masks)));
    }
    std::vector<uint32_t> freed;  // the blocks it gathered from
    if (e.child_count == 0) freed.push_back(block_of[i]);
    for (uint32_t g = 0; g < e.child_count; ++g)
      if (block_of[e.first_child + g] != kEmptyBlock) freed.push_back(block_of[e.first_child + g]);
    uint64_t have = arena->available();
    for (uint32_t id : freed) have += blocks[id]->size;
    if (!t.nodes.empty() && leaf_bytes(t.nodes.size(), links, voxels, contours) > have)
      return false;
    const auto at = parent_link(i, r, e.region_code);
    for (uint32_t id : where)
      if (blocks[id >> kLocalBits]->trunk) free_trunk_slot(id);
    for (uint32_t id : freed) release(id);
    if (e.child_count == 0) block_of[i] = kNoBlock;
    for (uint32_t g = 0; g < e.child_count; ++g) block_of[e.first_child + g] = kNoBlock;
    if (t.nodes.empty()) {
      block_of[i] = kEmptyBlock;
      set_link(at, kAbsent | i);
    } else {
      const uint32_t id =
          allocate(i, false, uint32_t(t.nodes.size()), links, voxels, contours, n - 1);
      std::vector<uint32_t> ids(t.nodes.size());
      for (uint32_t j = 0; j < ids.size(); ++j) ids[j] = id << kLocalBits | j;
      write(t, ids, [&](int, uint64_t) { return kAbsent | i; });
      block_of[i] = id;
      set_link(at, ids[0]);
    }
    compact_trunk();
    state[i] = State::kOnDisk;
    --resident_count;
    --resident_children[e.parent];
    return true;
  }

  /// Counts of the resident subtree under node `id` (voxel level `level`),
  /// split by `keep(level, id)`: [0] kept, [1] not; each nodes, links,
  /// voxels, contours. `below` stops the walk above that level.
  template <class Keep>
  std::array<std::array<uint64_t, 4>, 2> count_subtree(uint32_t id, int level, int below,
                                                       const Keep& keep) const {
    std::array<std::array<uint64_t, 4>, 2> out{};
    std::vector<std::pair<uint32_t, int>> stack{{id, level}};
    while (!stack.empty()) {
      const auto [at, l] = stack.back();
      stack.pop_back();
      const Block& b = *blocks[at >> kLocalBits];
      const StreamNode& d = b.nodes[at & kLocalMask];
      const uint32_t sub = subdivided(d.masks);
      auto& c = out[keep(l, at) ? 0 : 1];
      c[0] += 1;
      c[1] += uint32_t(std::popcount(sub));
      c[2] += uint32_t(std::popcount(sl::SliceValid::get(d.masks)));
      c[3] += uint32_t(std::popcount(sl::SliceContourMask::get(d.masks)));
      if (l + 1 >= below) continue;
      for (int r = 0; r < std::popcount(sub); ++r) {
        const uint32_t link = b.links[d.link + uint32_t(r)];
        if ((link & kAbsent) == 0) stack.push_back({link, l + 1});
      }
    }
    return out;
  }
  /// The planner's estimate of what loading next-level slice i adds to the
  /// arena: its level in the leaf blocks, less what of its block moves to
  /// the trunk, plus the trunk chunks that takes -- exact but for the result
  /// blocks' 16-byte rounding, which it leaves out (a lower bound, in a
  /// full-depth octree, so that a budget the result fits is never refused
  /// ahead; merge checks the exact bytes and a load that does not fit waits).
  uint64_t load_need(uint32_t i) const {
    const sl::SliceEntry& e = entry(i);
    const auto& all = file->slices();
    const int k = e.child_count != 0 ? all[e.first_child].region_depth : e.region_depth;
    const bool split = e.child_count > 1 || (e.child_count == 1 && k != e.region_depth);
    std::array<uint64_t, 4> moved{};
    if (split && block_of[i] != kEmptyBlock && block_of[i] != kNoBlock)
      moved = count_subtree(block_of[i] << kLocalBits, e.region_depth, k,
                            [](int, uint32_t) { return false; })[1];
    uint64_t trunk = moved[0];
    const bool level_to_trunk = split && k == e.node_level + 1;  // the slice's own level, too
    if (level_to_trunk) trunk += e.node_count;
    // The old block's bytes and the merged ones, unrounded.
    uint64_t raw = level_to_trunk
                       ? 0
                       : uint64_t(e.node_count) * sizeof(StreamNode) + uint64_t(e.link_count) * 4 +
                             uint64_t(e.voxel_count) * 8 + uint64_t(e.contour_count) * 4;
    uint64_t old = 0;
    if (block_of[i] != kEmptyBlock && block_of[i] != kNoBlock) {
      const Block& b = *blocks[block_of[i]];
      old = b.size;
      raw += uint64_t(b.node_count) * sizeof(StreamNode) + uint64_t(b.link_count) * 4 +
             uint64_t(b.voxel_count) * 8 + uint64_t(b.contour_count) * 4;
    }
    const uint64_t gone =
        moved[0] * sizeof(StreamNode) + moved[1] * 4 + moved[2] * 8 + moved[3] * 4;
    const uint64_t add = raw - std::min(raw, gone) + trunk_chunks_needed(trunk) * kTrunkChunkBytes;
    return add > old ? add - old : 0;
  }
  /// The bytes unloading slice i (resident, no resident children) frees:
  /// its children's blocks less the block it gets back, plus the trunk
  /// chunks the compaction then releases (exact for one unload).
  uint64_t unload_gain(uint32_t i) const {
    const sl::SliceEntry& e = entry(i);
    const uint32_t top = find(e.region_depth, e.region_code);
    if (top == kNoNode) return 0;
    const auto kept = count_subtree(top, e.region_depth, 1 << 30,
                                    [&](int l, uint32_t) { return l < e.node_level; })[0];
    uint64_t freed = 0;
    if (e.child_count == 0) freed += blocks[block_of[i]]->size;
    for (uint32_t g = 0; g < e.child_count; ++g)
      if (block_of[e.first_child + g] != kEmptyBlock)
        freed += blocks[block_of[e.first_child + g]]->size;
    const uint64_t back = kept[0] != 0 ? leaf_bytes(kept[0], kept[1], kept[2], kept[3]) : 0;
    const uint64_t in_trunk = count_subtree(top, e.region_depth, 1 << 30, [&](int, uint32_t id) {
      return blocks[id >> kLocalBits]->trunk;
    })[0][0];
    const uint64_t chunks_after = (trunk_live - in_trunk + kTrunkSlots - 1) / kTrunkSlots;
    freed += (trunk_chunks.size() - chunks_after) * kTrunkChunkBytes;
    return freed > back ? freed - back : 0;
  }

  /// Whether a ray of this frame used what slice i (resident, no resident
  /// children) added: entered one of the blocks holding its level, or --
  /// for a child whose block is empty (the level is in the trunk, where
  /// entering is not stamped) -- asked for that child in this pass.
  bool slice_used(uint32_t i, const std::vector<uint8_t>& requested) const {
    const sl::SliceEntry& e = entry(i);
    auto hit = [&](uint32_t b, uint32_t child) {
      return b == kEmptyBlock ? requested[child] != 0
                              : used[b].load(std::memory_order_relaxed) == stamp;
    };
    if (e.child_count == 0) return hit(block_of[i], i);
    for (uint32_t g = 0; g < e.child_count; ++g)
      if (hit(block_of[e.first_child + g], e.first_child + g)) return true;
    return false;
  }

  /// Reads and checks `list` on worker threads (several reads in flight),
  /// in batches, merging each batch in list order (deterministic). Returns
  /// loaded, refused, and those left for lack of room.
  std::array<uint64_t, 3> load(const std::vector<uint32_t>& list, uint64_t* bytes_read,
                               Progress* progress = nullptr) {
    std::array<uint64_t, 3> out{0, 0, 0};
    const size_t batch = size_t(std::max(1, options.io_threads)) * 4;
    for (size_t b0 = 0; b0 < list.size(); b0 += batch) {
      const size_t count = std::min(batch, list.size() - b0);
      std::vector<std::vector<uint32_t>> words(count);
      std::vector<std::string> errors(count);
      std::atomic<size_t> next{0};
      auto work = [&] {
        for (size_t k; (k = next.fetch_add(1)) < count;) {
          try {
            words[k] = file->read(list[b0 + k]);  // hash verified
            check_slice(*file, list[b0 + k], words[k]);
          } catch (const std::exception& ex) {
            errors[k] = ex.what();
          }
        }
      };
      const size_t threads = std::min<size_t>(count, size_t(std::max(1, options.io_threads)));
      std::vector<std::thread> pool;
      for (size_t th = 1; th < threads; ++th) pool.emplace_back(work);
      work();
      for (std::thread& th : pool) th.join();
      for (size_t k = 0; k < count; ++k) {
        const uint32_t i = list[b0 + k];
        if (errors[k].empty()) {
          try {
            if (merge(i, words[k])) {
              ++out[0];
              *bytes_read += entry(i).data_bytes;
            } else {
              ++out[2];
            }
            continue;
          } catch (const std::exception& ex) {
            errors[k] = ex.what();
          }
        }
        state[i] = State::kRefused;
        last_error = errors[k];
        ++out[1];
      }
      if (progress != nullptr)
        for (size_t k = 0; k < count; ++k) progress->advance(entry(list[b0 + k]).data_bytes);
    }
    return out;
  }
};

StreamedEsvo::StreamedEsvo(std::shared_ptr<const SliceFile> file, const StreamOptions& options)
    : file_(std::move(file)), impl_(std::make_unique<Impl>()) {
  if (!file_) throw Error("StreamedEsvo: no slice file");
  Impl& m = *impl_;
  m.file = file_;
  m.options = options;
  m.source = {file_->grid(), m.table.data(), m.used.data(), 0, 0};
  const auto& all = file_->slices();
  const size_t n = all.size();
  m.state.assign(n, State::kOnDisk);
  m.block_of.assign(n, kNoBlock);
  m.block_of[0] = kEmptyBlock;  // above the root slice: nothing yet
  m.resident_children.assign(n, 0);
  for (uint32_t id = 0; id < kMaxBlocks; ++id) m.free_ids.insert(id);
  const sl::SliceEntry& root = all[0];
  if (options.budget_bytes != 0 && block_bytes(root) > options.budget_bytes)
    throw Error("streaming budget " + std::to_string(options.budget_bytes) +
                " B is below the root slice's " + std::to_string(block_bytes(root)) + " B");
  // The arena: the budget (a hard cap), or what every slice needs (the
  // blocks, the trunk's bound) when that is less; unlimited: it may grow.
  uint64_t whole = 0, trunk = 0;
  for (const sl::SliceEntry& e : all) whole += block_bytes(e), trunk += trunk_bound(all, e);
  whole += (trunk / kTrunkSlots + 1) * kTrunkChunkBytes;
  const uint64_t budget = options.budget_bytes;
  m.arena = std::make_unique<Arena>(budget != 0 ? std::min(budget, whole) : whole,
                                    budget != 0 ? budget : ~uint64_t(0));
  // The root slice: merged like any other (a corrupt root is fatal).
  const std::vector<uint32_t> words = file_->read(0);
  check_slice(*file_, 0, words);
  if (!m.merge(0, words))
    throw Error("streaming budget " + std::to_string(budget) + " B cannot hold the root slice");
  stats_.loaded = 1;
  stats_.bytes_read = root.data_bytes;
  stats_.resident_bytes = stats_.peak_resident_bytes = m.arena->used();
  stats_.resident_slices = 1;
  refresh_stats();
}

void StreamedEsvo::refresh_stats() {
  const Impl& m = *impl_;
  stats_.resident_bytes = m.arena->used();
  stats_.peak_resident_bytes = std::max(stats_.peak_resident_bytes, stats_.resident_bytes);
  stats_.resident_slices = m.resident_count;
  stats_.compactions = m.arena->compactions();
  stats_.bytes_moved = m.arena->moved_bytes();
  stats_.full_compaction_bytes = m.arena->full_compaction_bytes();
  stats_.trunk_descriptors = m.trunk_live;
  stats_.trunk_chunks = uint32_t(std::count_if(m.trunk_chunks.begin(), m.trunk_chunks.end(),
                                               [](uint32_t c) { return c != kNoBlock; }));
  stats_.leaf_blocks = uint32_t(kMaxBlocks - m.free_ids.size()) - stats_.trunk_chunks;
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

void StreamedEsvo::beam_start(const BeamFrustum& beam, TraceContext& ctx, BeamStart* start) const {
  ::voxcast::detail::OctreeWorld<::voxcast::detail::StreamedEsvoNodes>(impl_->source)
      .beam_start(beam, ctx, start);
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
  std::vector<uint8_t> requested(all.size(), 0);
  for (const Request& r : requests) {
    if (r.kind != kRequestKind || r.key >= all.size()) continue;
    const uint32_t i = uint32_t(r.key);
    requested[i] = 1;
    if (i == 0 || m.state[i] != State::kOnDisk || m.state[all[i].parent] != State::kResident)
      continue;
    cand.push_back({m.score(i), i});
  }
  std::sort(cand.begin(), cand.end(), [](const auto& a, const auto& b) {
    return a.first != b.first ? a.first > b.first : a.second < b.second;
  });
  cand.erase(std::unique(cand.begin(), cand.end()), cand.end());

  // Plan within the budget: unload lower-scoring resident leaf slices (no
  // resident children, not a planned load's parent) while that improves the
  // total score, i.e. only for a candidate that scores higher. The sizes
  // are estimates (what a slice adds to the leaf blocks, the trunk chunks
  // its split may need); merge checks the exact bytes, and a load that does
  // not fit stays pending.
  const uint64_t budget = m.options.budget_bytes;
  std::vector<uint32_t> to_load, victims;
  std::vector<uint8_t> mark(all.size(), 0);  // 1 = victim, 2 = parent of a planned load
  uint64_t after = m.arena->used();
  uint64_t pending = 0;
  std::vector<std::pair<double, uint32_t>> leaves;  // resident leaf slices by score
  for (uint32_t i = 1; i < all.size(); ++i)
    if (m.state[i] == State::kResident && m.resident_children[i] == 0)
      leaves.push_back({m.slice_used(i, requested) ? m.score(i) : 0.0, i});
  std::sort(leaves.begin(), leaves.end());
  size_t next_leaf = 0;
  for (const auto& [score, i] : cand) {
    const uint32_t parent = all[i].parent;
    if (to_load.size() >= m.options.max_loads_per_pass || mark[parent] == 1) {
      ++pending;
      continue;
    }
    const uint64_t need = m.load_need(i);
    const uint8_t parent_mark = mark[parent];
    mark[parent] = 2;  // never its own parent's victim
    std::vector<uint32_t> take;
    uint64_t freed = 0;
    size_t scan = next_leaf;
    // The estimates are exact but for blocks' 16-byte rounding (and, in
    // variable-depth files, voxels a split moves to the trunk): within that,
    // the load is tried and merge's exact check decides.
    // (A copy: clang 14 cannot capture a structured binding in a lambda, P1091.)
    const uint64_t children = all[i].child_count;
    auto slack = [children](size_t victims) { return 16 * (children + victims + 1); };
    while (budget != 0 && after - freed + need > budget + slack(take.size())) {
      while (scan < leaves.size() && mark[leaves[scan].second] != 0) ++scan;
      if (scan >= leaves.size() || !(leaves[scan].first < score)) break;
      take.push_back(leaves[scan].second);
      freed += std::min(after - freed, m.unload_gain(leaves[scan].second));
      ++scan;
    }
    if (budget != 0 && after - freed + need > budget + slack(take.size())) {
      mark[parent] = parent_mark;
      ++pending;
      continue;
    }
    for (uint32_t v : take) mark[v] = 1, victims.push_back(v);
    next_leaf = scan;
    after = after - freed + need;
    to_load.push_back(i);
  }
  // A victim's slot in `leaves` is consumed; a parent left childless by a
  // victim becomes a leaf for later passes (not this one: keeps it simple
  // and the plan monotone).
  uint64_t unloaded = 0;
  for (uint32_t v : victims) unloaded += m.unmerge(v);
  const auto [loaded, refused, no_room] = m.load(to_load, &stats_.bytes_read);
  pending += no_room;

  stats_.loaded += loaded;
  stats_.unloaded += unloaded;
  stats_.refused += refused;
  stats_.pending = pending;
  refresh_stats();
  PassOutcome out;
  out.changed = loaded > 0;
  out.served = loaded + refused;
  out.pending = pending;
  return out;
}

bool StreamedEsvo::fits_whole() const {
  const auto& all = file_->slices();
  uint64_t total = 0, trunk = 0;
  for (const sl::SliceEntry& e : all) total += block_bytes(e), trunk += trunk_bound(all, e);
  total += (trunk / kTrunkSlots + 1) * kTrunkChunkBytes;
  return impl_->options.budget_bytes == 0 || total <= impl_->options.budget_bytes;
}

void StreamedEsvo::load_all(Progress* progress) {
  Impl& m = *impl_;
  const auto& all = file_->slices();
  if (progress != nullptr) {
    uint64_t bytes = 0;
    for (uint32_t i = 0; i < all.size(); ++i)
      if (m.state[i] != State::kResident) bytes += all[i].data_bytes;
    progress->add_units(bytes);
  }
  if (!fits_whole())
    throw Error("load_all: the slices need more than the budget of " +
                std::to_string(m.options.budget_bytes) + " B");
  while (true) {
    std::vector<uint32_t> list;
    for (uint32_t i = 1; i < all.size(); ++i)
      if (m.state[i] == State::kOnDisk && m.state[all[i].parent] == State::kResident)
        list.push_back(i);
    if (list.empty()) break;
    const auto [loaded, refused, no_room] = m.load(list, &stats_.bytes_read, progress);
    stats_.loaded += loaded;
    stats_.refused += refused;
    refresh_stats();
    if (no_room != 0)
      throw Error("load_all: the slices need more than the budget of " +
                  std::to_string(m.options.budget_bytes) + " B or the " +
                  std::to_string(kMaxBlocks) + " blocks");
  }
  refresh_stats();
}

bool StreamedEsvo::load_slice(uint32_t slice) {
  Impl& m = *impl_;
  const auto& all = file_->slices();
  if (slice == 0 || slice >= all.size() || m.state[slice] != State::kOnDisk ||
      m.state[all[slice].parent] != State::kResident)
    return false;
  const auto [loaded, refused, no_room] = m.load({slice}, &stats_.bytes_read);
  stats_.loaded += loaded;
  stats_.refused += refused;
  refresh_stats();
  return loaded != 0;
}

bool StreamedEsvo::unload_slice(uint32_t slice) {
  Impl& m = *impl_;
  if (slice == 0 || slice >= m.state.size() || m.state[slice] != State::kResident ||
      m.resident_children[slice] != 0 || !m.unmerge(slice))
    return false;
  ++stats_.unloaded;
  refresh_stats();
  return true;
}

/// Calls f(id, level, code) for every resident descriptor, depth-first from the root.
template <class F>
static void walk(const StreamedEsvo::Impl& m, const F& f) {
  struct Item {
    uint32_t id;
    int level;
    uint64_t code;
  };
  std::vector<Item> stack{{m.source.root, 0, 0}};
  while (!stack.empty()) {
    const Item it = stack.back();
    stack.pop_back();
    f(it.id, it.level, it.code);
    const Block& b = *m.blocks[it.id >> kLocalBits];
    const StreamNode& d = b.nodes[it.id & kLocalMask];
    const uint32_t sub = subdivided(d.masks);
    for (int c = 7; c >= 0; --c) {
      if ((sub >> c & 1u) == 0) continue;
      const uint32_t l = b.links[d.link + rank_below(sub, c)];
      if ((l & kAbsent) == 0) stack.push_back({l, it.level + 1, it.code << 3 | uint64_t(c)});
    }
  }
}

Aabb StreamedEsvo::occupied(Progress* progress) const {
  // The file's bounds (SliceFile::occupied_bounds: the top of the hierarchy
  // read from disk), not the resident voxels': the automatic camera frames
  // a slice file as its .vxc, whatever the budget lets in. Computed once.
  std::call_once(occupied_once_, [&] {
    if (progress != nullptr) progress->add_units(1);
    occupied_cache_ = file_->occupied_bounds();
    if (progress != nullptr) progress->advance(1);
  });
  return occupied_cache_;
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

std::vector<uint32_t> StreamedEsvo::memory_image() const {
  const Impl& m = *impl_;
  std::vector<uint32_t> out;
  // The leaf blocks by slice: their bytes as they are, links within the
  // block as local indices (block ids are allocation order, not state).
  for (uint32_t i = 0; i < m.block_of.size(); ++i) {
    const uint32_t id = m.block_of[i];
    if (id == kNoBlock) continue;
    out.push_back(i);
    if (id == kEmptyBlock) {
      out.push_back(0);
      continue;
    }
    const Block& b = *m.blocks[id];
    out.push_back(uint32_t(b.size));
    const uint32_t* words = reinterpret_cast<const uint32_t*>(m.arena->at(b.offset));
    const size_t link0 = b.node_count * sizeof(StreamNode) / 4;
    for (size_t w = 0; w < b.size / 4; ++w) {
      const bool link = w >= link0 && w < link0 + b.link_count;
      out.push_back(link && (words[w] & kAbsent) == 0 ? words[w] & kLocalMask : words[w]);
    }
  }
  // The trunk's descriptors, depth-first: contents and what they link to.
  walk(m, [&](uint32_t id, int level, uint64_t code) {
    const Block& b = *m.blocks[id >> kLocalBits];
    if (!b.trunk) return;
    const StreamNode& d = b.nodes[id & kLocalMask];
    out.insert(out.end(), {uint32_t(level), uint32_t(code), uint32_t(code >> 32), d.masks});
    const uint32_t* a = b.attrs.data() + size_t(d.attr) * 2;
    out.insert(out.end(), a, a + 2 * std::popcount(sl::SliceValid::get(d.masks)));
    const uint32_t* c = b.contours.data() + d.contour;
    out.insert(out.end(), c, c + std::popcount(sl::SliceContourMask::get(d.masks)));
    for (int r = 0; r < std::popcount(subdivided(d.masks)); ++r) {
      const uint32_t l = b.links[d.link + uint32_t(r)];
      const Block* to = (l & kAbsent) ? nullptr : m.blocks[l >> kLocalBits].get();
      out.push_back(to == nullptr ? l : to->trunk ? 0xFFFFFFFFu : to->key);
    }
  });
  return out;
}

void StreamedEsvo::check_invariants() const {
  const Impl& m = *impl_;
  const auto& all = file_->slices();
  auto fail = [](const std::string& why) { throw Error("streamed esvo invariant: " + why); };
  auto str = [](uint64_t v) { return std::to_string(v); };
  // The slices: parents resident; exactly one leaf block for every
  // next-level slice and every resident slice without child slices, none
  // for any other; no block shared.
  std::vector<uint32_t> children(all.size(), 0), slice_of(kMaxBlocks, kNoBlock);
  uint32_t count = 0;
  for (uint32_t i = 0; i < all.size(); ++i) {
    const bool res = m.state[i] == State::kResident;
    if (res) {
      ++count;
      if (i != 0 && m.state[all[i].parent] != State::kResident)
        fail("slice " + str(i) + " resident without its parent");
      if (i != 0) ++children[all[i].parent];
    }
    const bool next_level = !res && i != 0 && m.state[all[i].parent] == State::kResident;
    const bool should = next_level || (res && all[i].child_count == 0);
    const uint32_t b = m.block_of[i];
    if (should != (b != kNoBlock))
      fail("slice " + str(i) + (should ? " has no block" : " has a block"));
    if (b == kNoBlock || b == kEmptyBlock) continue;
    if (b >= kMaxBlocks || !m.blocks[b] || m.blocks[b]->trunk || m.blocks[b]->key != i)
      fail("block of slice " + str(i));
    if (slice_of[b] != kNoBlock) fail("block " + str(b) + " shared");
    slice_of[b] = i;
  }
  for (uint32_t i = 0; i < all.size(); ++i)
    if (children[i] != m.resident_children[i]) fail("resident child count of slice " + str(i));
  if (count != m.resident_count || count != stats_.resident_slices) fail("resident slice count");
  for (uint32_t id = 0; id < kMaxBlocks; ++id) {
    const Block* b = m.blocks[id].get();
    if ((b != nullptr) == (m.free_ids.count(id) != 0)) fail("free block id " + str(id));
    if (b != nullptr && !b->trunk && slice_of[id] == kNoBlock)
      fail("block " + str(id) + " of no slice");
    if (b != nullptr && b->trunk &&
        (b->key >= m.trunk_chunks.size() || m.trunk_chunks[b->key] != id))
      fail("trunk chunk " + str(id));
  }
  // The octree, depth-first from the root: leaf blocks hold one subtree of
  // their slice's region each, in depth-first order (the k-th node reached
  // is the block's k-th); trunk descriptors link only to trunk descriptors
  // and to the roots of resident blocks; every absent link names the
  // next-level slice that covers its voxel.
  std::vector<uint32_t> seen(kMaxBlocks, 0);
  std::vector<uint8_t> named(all.size(), 0);
  uint64_t trunk_nodes = 0;
  walk(m, [&](uint32_t id, int level, uint64_t code) {
    const uint32_t bid = id >> kLocalBits, local = id & kLocalMask;
    const Block* b = bid < kMaxBlocks ? m.blocks[bid].get() : nullptr;
    if (b == nullptr || local >= b->node_count) fail("link to a missing node " + str(id));
    const StreamNode& d = b->nodes[local];
    const uint32_t valid = sl::SliceValid::get(d.masks), sub = subdivided(d.masks);
    if (valid == 0) fail("link to a free descriptor " + str(id));
    if (d.attr + uint64_t(std::popcount(valid)) > b->voxel_count ||
        d.contour + uint64_t(std::popcount(sl::SliceContourMask::get(d.masks))) >
            b->contour_count ||
        d.link + uint64_t(std::popcount(sub)) > b->link_count)
      fail("descriptor " + str(id) + " outside its block");
    if (b->trunk) {
      ++trunk_nodes;
      if (m.trunk_free.count(b->key * kTrunkSlots + local) != 0) fail("free trunk slot in use");
      if (d.attr != 8 * local || d.contour != 8 * local || d.link != 8 * local)
        fail("trunk descriptor " + str(id) + " not in its slot");
    } else {
      const sl::SliceEntry& e = all[b->key];
      const bool complete = m.state[b->key] == State::kResident;
      const int deepest = e.node_level - (complete ? 0 : 1);
      if (seen[bid] != local) fail("block " + str(bid) + " not depth-first at " + str(local));
      if (level < e.region_depth || level > deepest ||
          code >> (3 * (level - e.region_depth)) != e.region_code ||
          (local == 0 && level != e.region_depth))
        fail("descriptor " + str(id) + " outside its block's region or levels");
    }
    ++seen[bid];
    for (int c = 0; c < 8; ++c) {
      if ((sub >> c & 1u) == 0) continue;
      const uint32_t l = b->links[d.link + rank_below(sub, c)];
      const uint64_t child = code << 3 | uint64_t(c);
      if (l & kAbsent) {
        const uint32_t s = l & ~kAbsent;
        if (s >= all.size() || m.state[s] == State::kResident ||
            m.state[all[s].parent] != State::kResident || all[s].node_level != level + 1 ||
            child >> (3 * (level + 1 - all[s].region_depth)) != all[s].region_code ||
            (!b->trunk && s != b->key))
          fail("absent link of descriptor " + str(id) + " slot " + str(c));
        named[s] = 1;
        continue;
      }
      const Block* to = (l >> kLocalBits) < kMaxBlocks ? m.blocks[l >> kLocalBits].get() : nullptr;
      if (to == nullptr) fail("link into no block from " + str(id));
      if (b->trunk && !to->trunk && (l & kLocalMask) != 0)
        fail("trunk link into the middle of block " + str(l >> kLocalBits));
      if (!b->trunk && (l >> kLocalBits) != bid) fail("leaf block link out of its block");
    }
  });
  for (uint32_t id = 0; id < kMaxBlocks; ++id)
    if (m.blocks[id] && !m.blocks[id]->trunk && seen[id] != m.blocks[id]->node_count)
      fail("block " + str(id) + ": " + str(seen[id]) + " of " + str(m.blocks[id]->node_count) +
           " descriptors reached");
  for (uint32_t i = 0; i < all.size(); ++i)
    if (m.block_of[i] == kEmptyBlock && !named[i] && i != 0)
      fail("slice " + str(i) + " with an empty block is linked from nowhere");
  if (trunk_nodes != m.trunk_live || trunk_nodes != stats_.trunk_descriptors)
    fail("trunk descriptors " + str(trunk_nodes) + " reached, " + str(m.trunk_live) + " live");
  // The bytes: the arena's, within the budget; one extent per block, in
  // order, without overlaps, where the block and the caster's table say.
  const Arena& a = *m.arena;
  const uint64_t bytes = a.used();
  if (bytes != stats_.resident_bytes) fail("resident bytes");
  if (m.options.budget_bytes != 0 &&
      (bytes > m.options.budget_bytes || a.capacity() > m.options.budget_bytes))
    fail("over the budget");
  uint64_t end = 0, sum = 0, extents = 0;
  for (const auto& [off, ext] : a.extents()) {
    const auto [id, size] = ext;
    if (off < end || off + size > a.capacity()) fail("arena extent at " + str(off));
    const Block* b = id < kMaxBlocks ? m.blocks[id].get() : nullptr;
    if (b == nullptr || b->offset != off || b->size != size ||
        reinterpret_cast<const std::byte*>(b->nodes.data()) != a.at(off) ||
        m.table[id].nodes != b->nodes.data() || m.table[id].links != b->links.data() ||
        m.table[id].attrs != b->attrs.data() || m.table[id].contours != b->contours.data())
      fail("arena extent at " + str(off) + " of block " + str(id));
    end = off + size;
    sum += size;
    ++extents;
  }
  if (extents != kMaxBlocks - m.free_ids.size() || sum != bytes) fail("arena bytes");
}

}  // namespace voxcast::esvo
