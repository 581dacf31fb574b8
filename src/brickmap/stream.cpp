// Streaming a brickmap world from its scene file (brickmap_stream.hpp).
#include <sys/mman.h>
#include <time.h>
#include <xxhash.h>

#include <algorithm>
#include <chrono>
#include <fstream>
#include <new>

#include "brickmap/codec.hpp"
#include "io/meta_json.hpp"
#include "voxcast/brickmap_stream.hpp"
#include "voxcast/error.hpp"
#include "voxcast/integrator.hpp"

namespace voxcast::brickmap {

using namespace codec;

namespace {
constexpr uint32_t kHeaderSection = fourcc("BMGH");
constexpr uint32_t kTableSection = fourcc("BMCT");
constexpr uint32_t kChunkSection = fourcc("BMCK");
constexpr size_t kTablePrefix = 8, kEntryBytes = 24;

// A chunk's raw bytes in a buffer that is reused: kept when a chunk is
// evicted for the next one, whose decode then writes into pages already
// mapped. A new buffer is mapped with its pages populated in one system call
// (MAP_POPULATE): LZ4 would otherwise take a page fault per 4 KiB it writes,
// the larger part of the decode time on a loaded machine. Never zero-filled
// by us: LZ4 writes every byte.
struct Unmap {
  size_t bytes = 0;
  void operator()(uint8_t* p) const { ::munmap(p, bytes); }
};
struct RawBuffer {
  std::unique_ptr<uint8_t[], Unmap> data;
  size_t size = 0, capacity = 0;
  void resize(size_t n) {
    if (n > capacity) {
      data.reset();
      capacity = 0;
      void* p = ::mmap(nullptr, std::max<size_t>(n, 1), PROT_READ | PROT_WRITE,
                       MAP_PRIVATE | MAP_ANONYMOUS | MAP_POPULATE, -1, 0);
      if (p == MAP_FAILED) throw std::bad_alloc();
      data = std::unique_ptr<uint8_t[], Unmap>(static_cast<uint8_t*>(p),
                                               Unmap{std::max<size_t>(n, 1)});
      capacity = n;
    }
    size = n;
  }
};

// A chunk's LZ4 block of the file checked against its xxh64 and decoded to
// its `rs` raw bytes in `out` (the streamer's decode; measure_chunk_decode
// times it).
void decode_chunk_block(const uint8_t* z, size_t zs, size_t rs, uint64_t xxh,
                        const std::string& name, RawBuffer* out) {
  if (XXH64(z, zs, 0) != xxh) corrupt(name + " checksum mismatch");
  out->resize(rs);
  decompress_to(z, zs, out->data.get(), rs, name);
}

// The offset in `raw` of each present cell's brick (header cell non-zero),
// per position in the chunk (UINT32_MAX: none), validated as the loader does.
void index_chunk_bricks(const World& w, const ChunkGrid& cg, uint64_t index,
                        const std::vector<uint32_t>& header, const RawBuffer& raw,
                        std::vector<uint32_t>* offsets, const std::string& name) {
  offsets->assign(kChunkCells, UINT32_MAX);
  size_t at = 0;
  const size_t per = w.has_normals() ? 8 : 4;
  for_chunk_cells(w, cg, index, [&](uint64_t ci, uint32_t pos) {
    if (header[ci] == 0) return;
    if (raw.size - at < 64) corrupt(name + " ends inside a brick mask");
    uint64_t mask[8];
    std::memcpy(mask, &raw.data[at], 64);
    size_t count = 0;
    for (uint64_t m : mask) count += size_t(std::popcount(m));
    if (count == 0 || raw.size - at - 64 < count * per)
      corrupt(name + " holds a brick that is empty or cut short");
    (*offsets)[pos] = uint32_t(at);
    at += 64 + count * per;
  });
  if (at != raw.size) corrupt(name + " has bytes after its last brick");
}
// Seconds of CPU time this thread has run (user and system): the decode's
// own work, which a wall clock on a shared machine mixes with the time the
// thread waited for a core.
double thread_cpu_seconds() {
  timespec t;
  ::clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return double(t.tv_sec) + double(t.tv_nsec) * 1e-9;
}
}  // namespace

// A decoded chunk: its raw bytes and where each present cell's brick starts.
struct StreamingWorld::Chunk {
  RawBuffer raw;
  std::vector<uint32_t> at;  // per position in the chunk: offset in raw, or UINT32_MAX
  // The memory held: the buffer's capacity (a reused buffer may be larger
  // than the chunk).
  uint64_t bytes() const { return raw.capacity + at.size() * 4; }
  const uint64_t* mask(uint32_t pos) const {
    return at[pos] == UINT32_MAX ? nullptr : reinterpret_cast<const uint64_t*>(&raw.data[at[pos]]);
  }
};

StreamingWorld::StreamingWorld(const std::filesystem::path& path, const StreamOptions& options)
    : path_(path), options_(options) {
  brick_budget_ = options.budget_bytes / 2;
  cache_budget_ = options.budget_bytes - brick_budget_;
  const ContainerReader reader = ContainerReader::open(path);
  // META, header and table as the strict loader checks them, without the
  // chunks: the world of an empty chunk section (every brick not resident).
  const nlohmann::json meta = meta::parse(reader);
  GridTransform grid;
  bool normals = false;
  uint32_t height_cells = 0;
  try {
    using namespace meta;
    if (get_string(meta, "format") != kFormatName) bad("format is not 'brickmap'");
    grid = grid_from_json(meta, 0);
    height_cells = meta_height_cells(meta, grid);
    const nlohmann::json& nj = field(meta, "normals");
    if (!nj.is_boolean()) bad("'normals' is not a boolean");
    normals = nj.get<bool>();
  } catch (const nlohmann::json::exception& e) {
    throw Error("corrupt scene: META section: " + meta::json_error_text(e));
  }
  if (!grid.placement_is_valid()) meta::bad("'grid' is not a valid placement");
  world_ = std::make_shared<World>(grid, normals, height_cells);
  if (options.dxt1) world_->use_dxt1();
  const std::vector<uint8_t> gh = reader.read(kHeaderSection);
  header_ = decode_grid_header(gh.data(), gh.size(), world_->cells().size(), "BMGH section");
  const ChunkGrid cg = chunk_grid(world_->dims());
  table_ = reader.read(kTableSection);
  if (table_.size() != kTablePrefix + kEntryBytes * cg.count() ||
      load_le<uint32_t>(&table_[0]) != cg.count())
    corrupt("BMCT section is not a table of " + std::to_string(cg.count()) + " chunks");
  const SectionInfo& data = reader.section(kChunkSection);
  chunk_data_offset_ = data.offset, chunk_data_size_ = data.size;
  // The edit journal's committed transactions: their last header and the
  // latest image of each chunk they rewrote replace the file's.
  JournalChunks journal = read_journal_chunks(path, *world_);
  if (!journal.header.empty()) header_ = std::move(journal.header);
  journal_ = std::move(journal.chunks);
  std::vector<uint64_t> cells;  // occupancy, pyramid and clearances updated once for all
  for (uint64_t ci = 0; ci < header_.size(); ++ci)
    if (header_[ci] != 0) {
      world_->set_not_resident(ci, cell_lod_abgr(header_[ci]), 0, false);
      cells.push_back(ci);
    }
  world_->update_occupancy(cells);
  refused_chunk_.assign(size_t(cg.count()), 0);
  query_ = std::make_unique<BrickmapStructure>(world_, &seen_);
}

StreamingWorld::~StreamingWorld() = default;

uint64_t StreamingWorld::missing() const {
  uint64_t n = 0;
  for (uint32_t c : world_->cells()) n += cell_state(c) == kStateNotResident;
  return n;
}

void StreamingWorld::begin_frame(const FrameView& view) {
  frame_ = view.frame;
}

uint64_t StreamingWorld::brick_bytes(uint32_t voxels) const {
  // Per entry of the run's size class: a color (4 B, or DXT1's 8 B per 16)
  // and a normal.
  const uint64_t entries = ColorAllocator::class_size(voxels);
  return sizeof(Brick) + (world_->dxt1() ? entries / 2 : entries * 4) +
         (world_->has_normals() ? entries * 4 : 0);
}

void StreamingWorld::evict_chunks(uint64_t need) {
  // Least recently used chunks out until `need` more bytes fit; the last
  // one out is kept for its buffer (recycled_).
  while (stats_.cache_bytes + need > cache_budget_ && !lru_.empty()) {
    const uint64_t victim = lru_.back();
    lru_.pop_back();
    const auto v = cache_.find(victim);
    stats_.cache_bytes -= v->second.first->bytes();
    recycled_ = std::move(v->second.first);
    cache_.erase(v);
    ++stats_.chunk_evictions;
  }
}

const StreamingWorld::Chunk* StreamingWorld::chunk(uint64_t index) {
  if (refused_chunk_[size_t(index)]) return nullptr;
  const auto it = cache_.find(index);
  if (it != cache_.end()) {
    lru_.splice(lru_.begin(), lru_, it->second.second);
    return it->second.first.get();
  }
  const ChunkGrid cg = chunk_grid(world_->dims());
  const std::string name = "BMCK " + chunk_name(cg, index);
  const auto journaled = journal_.find(index);
  const uint64_t e = kTablePrefix + kEntryBytes * index;
  // Room for the chunk before it is decoded (its raw size is known from the
  // table or the journal), so that an evicted chunk's buffer takes it.
  const uint64_t rs =
      journaled != journal_.end() ? journaled->second.first : load_le<uint32_t>(&table_[e + 12]);
  evict_chunks(std::min<uint64_t>(rs, kMaxChunkRaw) + uint64_t(kChunkCells) * 4);
  std::unique_ptr<Chunk> c = recycled_ ? std::move(recycled_) : std::make_unique<Chunk>();
  try {
    auto t0 = std::chrono::steady_clock::now();
    double cpu0 = thread_cpu_seconds();
    if (journaled != journal_.end()) {
      // The journal's image (its record checksummed when the journal was read).
      c->raw.resize(journaled->second.first);
      if (journaled->second.first)
        decompress_to(journaled->second.second.data(), journaled->second.second.size(),
                      c->raw.data.get(), journaled->second.first, name + " (journal)");
    } else {
      const uint64_t offset = load_le<uint64_t>(&table_[e]);
      const uint64_t zs = load_le<uint32_t>(&table_[e + 8]);
      if (zs == 0 || offset > chunk_data_size_ || zs > chunk_data_size_ - offset ||
          rs > kMaxChunkRaw)
        corrupt(name + " lies outside the BMCK section");
      z_.resize(static_cast<size_t>(zs));
      if (!file_.is_open()) file_.open(path_, std::ios::binary);
      file_.clear();
      file_.seekg(std::streamoff(chunk_data_offset_ + offset));
      if (!file_.read(reinterpret_cast<char*>(z_.data()), std::streamsize(zs)))
        throw Error(name + " cannot be read from the file");
      t0 = std::chrono::steady_clock::now();
      cpu0 = thread_cpu_seconds();
      decode_chunk_block(z_.data(), z_.size(), size_t(rs), load_le<uint64_t>(&table_[e + 16]), name,
                         &c->raw);
    }
    index_chunk_bricks(*world_, cg, index, header_, c->raw, &c->at, name);
    stats_.decode_seconds +=
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    stats_.decode_cpu_seconds += thread_cpu_seconds() - cpu0;
    stats_.decoded_bytes += c->raw.size;
  } catch (const Error& err) {
    // Refused: its bricks will not come; the rest streams on.
    recycled_ = std::move(c);
    refused_chunk_[size_t(index)] = 1;
    stats_.refused.push_back({index, err.what()});
    std::vector<uint64_t> cells;
    for_chunk_cells(*world_, cg, index, [&](uint64_t ci, uint32_t) {
      if (cell_state(world_->cell(ci)) == kStateNotResident) {
        world_->set_brick(ci, std::array<uint64_t, 8>{}.data(), nullptr, nullptr, 0, nullptr,
                          false);
        cells.push_back(ci);
      }
    });
    world_->update_occupancy(cells);
    return nullptr;
  }
  ++stats_.chunk_loads;
  stats_.cache_bytes += c->bytes();
  lru_.push_front(index);
  const Chunk* out = c.get();
  cache_.emplace(index, std::make_pair(std::move(c), lru_.begin()));
  // A reused buffer larger than the chunk may still leave the cache over
  // its budget: out again, never the chunk just loaded.
  while (stats_.cache_bytes > cache_budget_ && lru_.size() > 1) {
    const uint64_t victim = lru_.back();
    lru_.pop_back();
    const auto v = cache_.find(victim);
    stats_.cache_bytes -= v->second.first->bytes();
    cache_.erase(v);
    ++stats_.chunk_evictions;
  }
  stats_.peak_cache_bytes = std::max(stats_.peak_cache_bytes, stats_.cache_bytes);
  return out;
}

bool StreamingWorld::upload(uint64_t cell) {
  const ChunkGrid cg = chunk_grid(world_->dims());
  const uint64_t ci = chunk_of(*world_, cell);
  const std::array<uint32_t, 3>& d = world_->dims();
  const uint32_t i = uint32_t(cell % d[0]), j = uint32_t(cell / d[0] % d[1]),
                 k = uint32_t(cell / d[0] / d[1]);
  const uint32_t x0 = i & (kChunkSide - 1), y0 = j & (kChunkSide - 1), z0 = k & (kChunkSide - 1);
  // Hidden-voxel removal across chunk borders: the masks of the neighbour
  // bricks in other chunks, copied before this brick's chunk is fetched
  // (loading a chunk may evict another; the brick's own chunk is fetched
  // last, so it stays).
  uint64_t across[6][8];
  bool has_across[6] = {false, false, false, false, false, false};
  if (options_.hidden_voxel_removal) {
    const int step[6][3] = {{-1, 0, 0}, {1, 0, 0}, {0, -1, 0}, {0, 1, 0}, {0, 0, -1}, {0, 0, 1}};
    for (int n = 0; n < 6; ++n) {
      const int64_t ni = int64_t(i) + step[n][0], nj = int64_t(j) + step[n][1],
                    nk = int64_t(k) + step[n][2];
      if (ni < 0 || nj < 0 || nk < 0 || ni >= d[0] || nj >= d[1] || nk >= d[2]) continue;
      const uint64_t ncell = world_->cell_index(uint32_t(ni), uint32_t(nj), uint32_t(nk));
      const uint64_t nci = chunk_of(*world_, ncell);
      if (nci == ci || header_[ncell] == 0) continue;
      const Chunk* nc = chunk(nci);
      const uint32_t npos = uint32_t(ni & (kChunkSide - 1)) +
                            kChunkSide * (uint32_t(nj & (kChunkSide - 1)) +
                                          kChunkSide * uint32_t(nk & (kChunkSide - 1)));
      if (const uint64_t* m = nc ? nc->mask(npos) : nullptr) {
        std::memcpy(across[n], m, 64);
        has_across[n] = true;
      }
    }
  }
  const Chunk* c = chunk(ci);
  if (!c) return true;  // refused: the cell was emptied
  const uint32_t pos = x0 + kChunkSide * (y0 + kChunkSide * z0);
  const uint64_t* mask = c->mask(pos);
  uint64_t keep[8];
  std::memcpy(keep, mask, 64);
  uint32_t count = 0;
  for (uint64_t m : keep) count += uint32_t(std::popcount(m));
  if (options_.hidden_voxel_removal) {
    // A voxel is hidden when its six neighbours are solid; neighbours in the
    // adjacent bricks come from their masks (of this chunk, or copied above
    // from the neighbour chunks), those outside the world or in refused
    // chunks count as empty.
    int side = 0;
    const auto neighbour = [&](int dx, int dy, int dz) -> const uint64_t* {
      const int n = side++;
      if (has_across[n]) return across[n];
      const int x = int(x0) + dx, y = int(y0) + dy, z = int(z0) + dz;
      if (x < 0 || y < 0 || z < 0 || x >= int(kChunkSide) || y >= int(kChunkSide) ||
          z >= int(kChunkSide))
        return nullptr;
      return c->mask(uint32_t(x) + kChunkSide * (uint32_t(y) + kChunkSide * uint32_t(z)));
    };
    const uint64_t* nb[6];
    nb[0] = neighbour(-1, 0, 0), nb[1] = neighbour(1, 0, 0), nb[2] = neighbour(0, -1, 0);
    nb[3] = neighbour(0, 1, 0), nb[4] = neighbour(0, 0, -1), nb[5] = neighbour(0, 0, 1);
    const auto solid = [&](int x, int y, int z) {
      const uint64_t* m = mask;
      if (x < 0)
        m = nb[0], x += 8;
      else if (x > 7)
        m = nb[1], x -= 8;
      else if (y < 0)
        m = nb[2], y += 8;
      else if (y > 7)
        m = nb[3], y -= 8;
      else if (z < 0)
        m = nb[4], z += 8;
      else if (z > 7)
        m = nb[5], z -= 8;
      return m != nullptr && ((m[z] >> voxel_bit(uint32_t(x), uint32_t(y), 0)) & 1);
    };
    uint64_t visible[8] = {};
    for (int z = 0; z < 8; ++z)
      for (uint64_t m = mask[z]; m != 0; m &= m - 1) {
        const int bit = std::countr_zero(m), x = bit & 7, y = bit >> 3;
        if (!(solid(x - 1, y, z) && solid(x + 1, y, z) && solid(x, y - 1, z) &&
              solid(x, y + 1, z) && solid(x, y, z - 1) && solid(x, y, z + 1)))
          visible[z] |= uint64_t(1) << bit;
      }
    uint32_t shown = 0;
    for (uint64_t m : visible) shown += uint32_t(std::popcount(m));
    if (shown > 0 && shown < count) {
      stats_.hidden_voxels += count - shown;
      std::memcpy(keep, visible, 64);
    }
  }
  // The kept voxels' colors (and normals), in bit order.
  const uint32_t* colors = reinterpret_cast<const uint32_t*>(&c->raw.data[c->at[pos] + 64]);
  const uint32_t* normals = colors + count;
  std::vector<uint32_t> kc, kn;
  uint32_t n = 0;
  for (int w = 0; w < 8; ++w)
    for (uint64_t m = mask[w]; m != 0; m &= m - 1, ++n)
      if ((keep[w] >> std::countr_zero(m)) & 1) {
        kc.push_back(colors[n]);
        kn.push_back(world_->has_normals() ? normals[n] : 0);
      }
  const uint64_t need = brick_bytes(uint32_t(kc.size()));
  if (stats_.resident_bytes + need > brick_budget_) {
    // Evict the least recently seen bricks, never one seen in this frame.
    std::vector<std::pair<uint32_t, uint64_t>> order;
    order.reserve(resident_.size());
    for (uint64_t r : resident_) order.push_back({seen_[cell_brick(world_->cell(r))], r});
    std::sort(order.begin(), order.end());
    std::vector<char> gone(resident_.size(), 0);
    size_t evicted = 0;
    for (const auto& [when, r] : order) {
      if (stats_.resident_bytes + need <= brick_budget_ || when >= frame_) break;
      const Brick& b = world_->brick(cell_brick(world_->cell(r)));
      stats_.resident_bytes -= brick_bytes(uint32_t(brick_popcount(b)));
      world_->set_not_resident(r, cell_lod_abgr(header_[r]));
      ++stats_.evicted, ++evicted;
    }
    if (evicted)
      std::erase_if(resident_,
                    [&](uint64_t r) { return cell_state(world_->cell(r)) != kStateResident; });
    if (stats_.resident_bytes + need > brick_budget_) return false;
  }
  const uint32_t lod = cell_lod_abgr(header_[cell]);
  world_->set_brick(cell, keep, kc.data(), kn.data(), 0, &lod);
  const uint32_t slot = cell_brick(world_->cell(cell));
  if (seen_.size() < world_->bricks().extent()) seen_.resize(world_->bricks().extent(), 0);
  seen_[slot] = frame_;
  resident_.push_back(cell);
  stats_.resident_bytes += need;
  stats_.peak_resident_bytes = std::max(stats_.peak_resident_bytes, stats_.resident_bytes);
  ++stats_.uploaded;
  (void)cg;
  return true;
}

PassOutcome StreamingWorld::end_pass(std::span<const Request> requests) {
  // The most urgent first (nearest, brickmap.hpp), ties by cell: the same
  // order whatever the thread count.
  std::vector<Request> want;
  for (const Request& r : requests)
    if (r.kind == BrickmapStructure::kRequestBrick && r.key < world_->cells().size() &&
        cell_state(world_->cell(r.key)) == kStateNotResident)
      want.push_back(r);
  std::sort(want.begin(), want.end(), [](const Request& a, const Request& b) {
    return a.priority != b.priority ? a.priority > b.priority : a.key < b.key;
  });
  PassOutcome out;
  for (const Request& r : want) {
    if (out.served >= options_.uploads_per_pass || !upload(r.key)) break;
    ++out.served;
  }
  out.pending = want.size() - out.served;
  out.changed = out.served > 0;
  return out;
}

ChunkDecodeRate measure_chunk_decode(const World& w, int rounds) {
  const ChunkGrid cg = chunk_grid(w.dims());
  // The chunks as the writer stores them (format.cpp): raw bytes, LZ4, xxh64.
  struct Stored {
    uint64_t index;
    std::vector<uint8_t> z;
    size_t raw;
    uint64_t xxh;
  };
  std::vector<Stored> stored;
  ChunkDecodeRate out;
  std::vector<uint8_t> raw;
  for (uint64_t index = 0; index < cg.count(); ++index) {
    encode_chunk(w, cg, index, &raw);
    if (raw.empty()) continue;
    Stored s{index, compress(raw.data(), raw.size()), raw.size(), 0};
    s.xxh = XXH64(s.z.data(), s.z.size(), 0);
    out.compressed_bytes += s.z.size();
    stored.push_back(std::move(s));
  }
  out.chunks = stored.size();
  // The source bricks, cell order within each chunk (for_chunk_cells).
  for (const Stored& s : stored)
    for_chunk_cells(w, cg, s.index, [&](uint64_t ci, uint32_t) {
      const uint32_t cell = w.cell(ci);
      if (cell == 0) return;
      const Brick& b = w.brick(cell_brick(cell));
      ++out.source_bricks;
      out.source_hash = XXH64(b.mask, 64, out.source_hash ^ ci);
    });
  const std::vector<uint32_t>& header = w.cells();
  std::vector<uint32_t> offsets;
  RawBuffer r;
  for (int round = 0; round < std::max(rounds, 1); ++round) {
    uint64_t bytes = 0, bricks = 0, hash = 0;
    double sec = 0;
    for (const Stored& s : stored) {
      const std::string name = "BMCK " + chunk_name(cg, s.index);
      const auto t0 = std::chrono::steady_clock::now();
      decode_chunk_block(s.z.data(), s.z.size(), s.raw, s.xxh, name, &r);
      index_chunk_bricks(w, cg, s.index, header, r, &offsets, name);
      sec += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      bytes += r.size;
      // Untimed: the decoded masks' hash, to compare with the source's.
      for_chunk_cells(w, cg, s.index, [&](uint64_t ci, uint32_t pos) {
        if (offsets[pos] == UINT32_MAX) return;
        ++bricks;
        hash = XXH64(&r.data[offsets[pos]], 64, hash ^ ci);
      });
    }
    if (round == 0 || sec < out.seconds) out.seconds = sec;
    out.raw_bytes = bytes, out.decoded_bricks = bricks, out.decoded_hash = hash;
  }
  return out;
}

}  // namespace voxcast::brickmap
