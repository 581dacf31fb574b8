// Saving brickmap edits without loss: the edit journal, its replay and the
// checkpoint (layout and rules: include/voxcast/brickmap_file.hpp).
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include <xxhash.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <mutex>
#include <optional>
#include <set>
#include <string>

#include "brickmap/codec.hpp"
#include "voxcast/brickmap_file.hpp"
#include "voxcast/container.hpp"
#include "voxcast/error.hpp"
#include "voxcast/system.hpp"

namespace voxcast::brickmap {
namespace {

using namespace codec;

constexpr char kMagic[8] = {'V', 'X', 'B', 'M', 'J', 'R', 'N', '3'};
constexpr char kMagicV2[8] = {'V', 'X', 'B', 'M', 'J', 'R', 'N', '2'};
constexpr char kMagicV1[8] = {'V', 'X', 'B', 'M', 'J', 'R', 'N', '1'};
constexpr size_t kFileHead = 32, kRecordHead = 40, kCellBits = kChunkCells / 8;
constexpr uint32_t kRecordMagic = fourcc("JREC");
constexpr uint32_t kChunkRecord = 1, kHeaderRecord = 2, kCommitRecord = 3, kRebaseRecord = 4,
                   kCarvedRecord = 5;

std::mutex hook_mutex;
std::function<void(const char*)> save_hook;

void step(const char* name) {
  std::function<void(const char*)> h;
  {
    std::lock_guard<std::mutex> lock(hook_mutex);
    h = save_hook;
  }
  if (h) h(name);
}

[[noreturn]] void io_fail(const std::string& what, const std::filesystem::path& p, int err) {
  throw Error("journal '" + p.string() + "': " + what + ": " + std::strerror(err));
}

class Fd {
 public:
  Fd(const std::filesystem::path& p, int flags) : path_(p), fd_(::open(p.c_str(), flags, 0644)) {
    if (fd_ < 0) io_fail("cannot open", p, errno);
  }
  ~Fd() {
    if (fd_ >= 0) ::close(fd_);
  }
  Fd(const Fd&) = delete;
  Fd& operator=(const Fd&) = delete;
  void write_all(const uint8_t* data, size_t n) {
    while (n > 0) {
      const ssize_t k = ::write(fd_, data, n);
      if (k < 0 && errno == EINTR) continue;
      if (k <= 0) io_fail("write failed", path_, errno);
      data += k, n -= size_t(k);
    }
  }
  void sync() {
    if (::fsync(fd_) != 0) io_fail("fsync failed", path_, errno);
  }
  void truncate(uint64_t size) {
    if (::ftruncate(fd_, off_t(size)) != 0) io_fail("truncate failed", path_, errno);
  }
  void seek_end() {
    if (::lseek(fd_, 0, SEEK_END) < 0) io_fail("seek failed", path_, errno);
  }
  int fd() const { return fd_; }

 private:
  std::filesystem::path path_;
  int fd_;
};

void sync_directory(const std::filesystem::path& file) {
  const std::filesystem::path dir = file.has_parent_path() ? file.parent_path() : ".";
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY);
  if (fd < 0) io_fail("cannot open its directory", file, errno);
  const int r = ::fsync(fd);
  const int err = errno;
  ::close(fd);
  if (r != 0) io_fail("directory fsync failed", file, err);
}

// The journal's bytes. Opened without blocking and checked on the open file
// descriptor: a FIFO in the journal's place would block the open (and every
// reader of the world: info, render, edit) until a writer appears, a device
// such as /dev/zero would never end, a directory is no journal.
std::vector<uint8_t> read_file(const std::filesystem::path& p) {
  Fd f(p, O_RDONLY | O_NONBLOCK | O_CLOEXEC);
  struct stat st;
  if (::fstat(f.fd(), &st) != 0) io_fail("cannot stat", p, errno);
  if (!S_ISREG(st.st_mode))
    throw Error("journal '" + p.string() + "' is " + file_type_name(uint32_t(st.st_mode)) +
                ", not a regular file");
  std::vector<uint8_t> bytes(size_t(st.st_size));
  size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t k = ::read(f.fd(), bytes.data() + done, bytes.size() - done);
    if (k < 0 && errno == EINTR) continue;
    if (k < 0) io_fail("read failed", p, errno);
    if (k == 0) break;  // shortened while being read: what is there
    done += size_t(k);
  }
  bytes.resize(done);
  return bytes;
}

// The identity of a scene file's exact content, from its first bytes alone
// (brickmap_file.hpp, "the world file's identity"): a version-2 container's
// header holds the xxh64 of its directory, which holds every chunk's xxh64;
// a version-1 container's directory holds every section's.
uint64_t world_file_id(const std::filesystem::path& p) {
  namespace cl = container_layout;
  Fd f(p, O_RDONLY | O_NONBLOCK | O_CLOEXEC);
  const auto read_at = [&](uint64_t offset, size_t n) {
    std::vector<uint8_t> b(n);
    size_t done = 0;
    while (done < n) {
      const ssize_t k = ::pread(f.fd(), b.data() + done, n - done, off_t(offset + done));
      if (k < 0 && errno == EINTR) continue;
      if (k <= 0) throw Error("'" + p.string() + "': cannot read its container header");
      done += size_t(k);
    }
    return b;
  };
  std::vector<uint8_t> h = read_at(0, sizeof(cl::FileHeaderV1));
  const uint32_t version = load_le<uint32_t>(h.data() + 8);
  if (version == 1) {
    const uint64_t n = load_le<uint32_t>(h.data() + 12);
    if (n > (1u << 20)) throw Error("'" + p.string() + "': section table too large");
    const std::vector<uint8_t> t =
        read_at(sizeof(cl::FileHeaderV1), size_t(n) * sizeof(cl::SectionEntryV1));
    h.insert(h.end(), t.begin(), t.end());
  } else {
    h = read_at(0, sizeof(cl::FileHeader));
  }
  return XXH64(h.data(), h.size(), 0);
}

// 'journal ...' refused: what the CLI prints as its one line.
[[noreturn]] void foreign_journal(const std::string& p) {
  throw Error("journal '" + p +
              "' belongs to another version of the world (the world file was replaced or "
              "rewritten since its edits were saved); remove the journal to open the world file "
              "as it is");
}

std::vector<uint8_t> file_head(const World& w, uint64_t base) {
  std::vector<uint8_t> h(kMagic, kMagic + 8);
  put_le<uint64_t>(h, w.cells().size());
  put_le<uint64_t>(h, base);
  put_le<uint64_t>(h, XXH64(h.data(), h.size(), 0));
  return h;
}

struct Record {
  uint32_t type = 0;
  uint64_t txn = 0;
  const uint8_t* payload = nullptr;
  uint64_t size = 0;
};

std::vector<uint8_t> record_head(uint32_t type, uint64_t txn, const std::vector<uint8_t>& payload) {
  std::vector<uint8_t> h;
  put_le<uint32_t>(h, kRecordMagic);
  put_le<uint32_t>(h, type);
  put_le<uint64_t>(h, txn);
  put_le<uint64_t>(h, payload.size());
  put_le<uint64_t>(h, XXH64(payload.data(), payload.size(), 0));
  put_le<uint64_t>(h, XXH64(h.data(), h.size(), 0));
  return h;
}

// The journal's committed transactions, in order; `end`: the byte after the
// last intact commit (or rebase) record (what a writer keeps).
struct Parsed {
  std::vector<std::vector<Record>> txns;  // each without its commit record
  uint64_t end = 0;
  uint64_t last_txn = 0;
  uint64_t base = 0;  // the head's world file identity
  // The last rebase record: the identity of the file its checkpoint wrote,
  // holding txns[0, rebased_txns).
  bool rebased = false;
  uint64_t rebase_id = 0;
  size_t rebased_txns = 0;
  // Which transactions belong to the world file of identity `id`: the first
  // of them (txns from there on), or refused.
  size_t first_for(uint64_t id, const std::string& p) const {
    if (id == base) return 0;
    if (rebased && id == rebase_id) return rebased_txns;
    foreign_journal(p);
  }
};

// The head checked (its magic, checksum and the world's cell count; the
// world file's identity is Parsed::first_for's), then the records.
Parsed parse_journal(const std::vector<uint8_t>& j, const World& w, const std::string& p) {
  if (j.size() >= 8 && std::equal(kMagicV1, kMagicV1 + 8, j.begin()))
    throw Error("journal '" + p +
                "' has the format of an older voxcast, not bound to its world file: fold it in "
                "with that version (voxcast edit --checkpoint) or remove it");
  if (j.size() < kFileHead ||
      (!std::equal(kMagic, kMagic + 8, j.begin()) &&
       !std::equal(kMagicV2, kMagicV2 + 8, j.begin())) ||
      XXH64(j.data(), kFileHead - 8, 0) != load_le<uint64_t>(&j[kFileHead - 8]))
    throw Error("journal '" + p + "': not an edit journal (or its head is damaged)");
  if (load_le<uint64_t>(&j[8]) != w.cells().size()) foreign_journal(p);
  Parsed out;
  out.base = load_le<uint64_t>(&j[16]);
  out.end = kFileHead;
  std::vector<Record> pending;
  size_t at = kFileHead;
  while (j.size() - at >= kRecordHead) {
    const uint8_t* h = &j[at];
    if (load_le<uint32_t>(h) != kRecordMagic || XXH64(h, 32, 0) != load_le<uint64_t>(h + 32)) break;
    Record r;
    r.type = load_le<uint32_t>(h + 4);
    r.txn = load_le<uint64_t>(h + 8);
    r.size = load_le<uint64_t>(h + 16);
    if (r.size > j.size() - at - kRecordHead) break;  // cut off
    r.payload = h + kRecordHead;
    if (XXH64(r.payload, size_t(r.size), 0) != load_le<uint64_t>(h + 24)) break;
    if (r.txn <= out.last_txn) break;  // out of order: not written by commit_edits
    at += kRecordHead + size_t(r.size);
    if (!pending.empty() && pending.front().txn != r.txn) pending.clear();  // never committed
    if (r.type == kCommitRecord) {
      if (r.size != 8 || load_le<uint64_t>(r.payload) != pending.size()) break;
      out.txns.push_back(std::move(pending));
      pending.clear();
      out.end = at;
      out.last_txn = r.txn;
    } else if (r.type == kRebaseRecord) {
      if (r.size != 8 || !pending.empty()) break;
      out.rebased = true;
      out.rebase_id = load_le<uint64_t>(r.payload);
      out.rebased_txns = out.txns.size();
      out.end = at;
      out.last_txn = r.txn;
    } else if (r.type == kChunkRecord || r.type == kHeaderRecord || r.type == kCarvedRecord) {
      pending.push_back(r);
    } else {
      break;
    }
  }
  return out;
}

// A chunk record's fields (payload: u64 chunk, the cells' presence bits,
// u32 raw size, u32 LZ4 size, the LZ4 block), validated.
struct ChunkRecord {
  uint64_t chunk = 0;
  const uint8_t* bits = nullptr;
  const uint8_t* z = nullptr;
  size_t z_size = 0, raw = 0;
};
ChunkRecord chunk_record(const Record& r, const ChunkGrid& cg, const std::string& name) {
  if (r.size < 8 + kCellBits + 8) corrupt(name + ": short chunk record");
  ChunkRecord c;
  c.chunk = load_le<uint64_t>(r.payload);
  if (c.chunk >= cg.count()) corrupt(name + ": chunk index out of range");
  c.bits = r.payload + 8;
  const uint64_t rs = load_le<uint32_t>(r.payload + 8 + kCellBits);
  const uint64_t zs = load_le<uint32_t>(r.payload + 12 + kCellBits);
  if (zs != r.size - (16 + kCellBits) || rs > kMaxChunkRaw) corrupt(name + ": bad chunk sizes");
  c.z = r.payload + 16 + kCellBits, c.z_size = size_t(zs), c.raw = size_t(rs);
  return c;
}

// A carved record (payload: u64 chunk, u32 count N, N times u32 position in
// the chunk (ascending) and the cell's u64[8] carved mask, never all zero):
// the carved voxels of the chunk's cells, validated, as (cell, mask).
std::pair<uint64_t, std::vector<std::pair<uint64_t, VoxelMask>>> carved_record(
    const Record& r, const World& w, const ChunkGrid& cg, const std::string& name) {
  if (!w.terrain()) corrupt(name + ": carved voxels in a world that is no generated terrain");
  if (r.size < 12) corrupt(name + ": short carved record");
  const uint64_t chunk = load_le<uint64_t>(r.payload);
  if (chunk >= cg.count()) corrupt(name + ": chunk index out of range");
  const uint64_t n = load_le<uint32_t>(r.payload + 8);
  if (n > kChunkCells || r.size != 12 + 68 * n) corrupt(name + ": bad carved record size");
  std::vector<uint64_t> cells(kChunkCells, UINT64_MAX);  // position -> cell (UINT64_MAX: none)
  for_chunk_cells(w, cg, chunk, [&](uint64_t ci, uint32_t pos) { cells[pos] = ci; });
  std::vector<std::pair<uint64_t, VoxelMask>> out;
  int64_t last = -1;
  for (uint64_t e = 0; e < n; ++e) {
    const uint8_t* p = r.payload + 12 + 68 * e;
    const uint32_t pos = load_le<uint32_t>(p);
    if (pos >= kChunkCells || int64_t(pos) <= last || cells[pos] == UINT64_MAX)
      corrupt(name + ": carved cell positions out of range or not ascending");
    VoxelMask m;
    for (size_t q = 0; q < 8; ++q) m[q] = load_le<uint64_t>(p + 4 + 8 * q);
    if (m == VoxelMask{}) corrupt(name + ": a carved cell without carved voxels");
    out.push_back({cells[pos], m});
    last = pos;
  }
  return {chunk, std::move(out)};
}

// The brickgrid header of a transaction's header record.
std::vector<uint32_t> header_record(const Record* header, const World& w) {
  if (header == nullptr) corrupt("journal transaction without a brickgrid header");
  if (header->size < 16) corrupt("journal: short header record");
  return decode_grid_header(header->payload + 16, size_t(header->size - 16), w.cells().size(),
                            "journal header");
}

// One transaction into the world (the header checked against the chunks
// it replaces); returns the chunks it replaced.
std::vector<uint64_t> apply(World& w, const std::vector<Record>& txn, SceneInfo* si) {
  const ChunkGrid cg = chunk_grid(w.dims());
  std::vector<uint64_t> chunks;
  // The occupancy, pyramid and clearances are updated once for all the cells
  // touched, also when a damaged record throws half way (the world then
  // holds the records applied so far, consistently).
  std::vector<uint64_t> touched;
  const Record* header = nullptr;
  try {
    for (const Record& r : txn) {
      if (r.type == kHeaderRecord) {
        header = &r;
        continue;
      }
      const std::string name = "journal transaction " + std::to_string(r.txn);
      if (r.type == kCarvedRecord) {
        // The chunk's carved voxels replaced whole, as its bricks are.
        const auto [chunk, carved] = carved_record(r, w, cg, name);
        for_chunk_cells(w, cg, chunk, [&](uint64_t ci, uint32_t) { w.set_carved(ci, {}); });
        for (const auto& [cell, mask] : carved) w.set_carved(cell, mask);
        continue;
      }
      const ChunkRecord cr = chunk_record(r, cg, name);
      const uint64_t chunk = cr.chunk;
      const uint8_t* bits = cr.bits;
      const std::vector<uint8_t> raw =
          cr.raw ? decompress(cr.z, cr.z_size, cr.raw, name) : std::vector<uint8_t>{};
      const auto present = [&](uint64_t, uint32_t pos) {
        return (bits[pos >> 3] >> (pos & 7)) & 1;
      };
      std::vector<ChunkBrick> got =
          decode_chunk(w, cg, chunk, raw, name + " " + chunk_name(cg, chunk), present);
      for_chunk_cells(w, cg, chunk, [&](uint64_t ci, uint32_t pos) {
        if (!present(ci, pos) && w.cell(ci) != 0) {
          w.set_brick(ci, std::array<uint64_t, 8>{}.data(), nullptr, nullptr, 0, nullptr, false);
          touched.push_back(ci);
        }
      });
      for (const ChunkBrick& b : got) {
        w.set_brick(b.cell, b.mask, b.colors.data(), b.normals.data(), 0, nullptr, false);
        touched.push_back(b.cell);
      }
      chunks.push_back(chunk);
    }
  } catch (...) {
    w.update_occupancy(touched);
    throw;
  }
  w.update_occupancy(touched);
  const std::vector<uint32_t> cells = header_record(header, w);
  for (uint64_t chunk : chunks)
    for_chunk_cells(w, cg, chunk, [&](uint64_t ci, uint32_t) {
      const uint32_t c = w.cell(ci);
      const bool ok = c == 0 ? cells[ci] == 0
                             : cells[ci] != 0 && CellPayload::get(w.brick(cell_brick(c)).lod) ==
                                                     CellPayload::get(cells[ci]);
      if (!ok)
        corrupt("journal: a replayed chunk disagrees with its transaction's brickgrid header");
    });
  if (si) si->leaf_voxels = load_le<uint64_t>(header->payload + 8);
  return chunks;
}

}  // namespace

JournalChunks codec::read_journal_chunks(const std::filesystem::path& path, const World& w) {
  JournalChunks out;
  const std::filesystem::path jp = journal_path(path);
  std::error_code ec;
  if (!std::filesystem::exists(jp, ec)) return out;
  const std::vector<uint8_t> bytes = read_file(jp);
  const Parsed parsed = parse_journal(bytes, w, jp.string());
  const size_t first = parsed.first_for(world_file_id(path), jp.string());
  const ChunkGrid cg = chunk_grid(w.dims());
  for (size_t t = first; t < parsed.txns.size(); ++t) {
    const std::vector<Record>& txn = parsed.txns[t];
    const Record* header = nullptr;
    for (const Record& r : txn) {
      if (r.type == kHeaderRecord) {
        header = &r;
        continue;
      }
      if (r.type == kCarvedRecord)
        continue;  // the solid set behind the stored voxels: not rendered
      const ChunkRecord c = chunk_record(r, cg, "journal transaction " + std::to_string(r.txn));
      out.chunks[c.chunk] = {uint32_t(c.raw), std::vector<uint8_t>(c.z, c.z + c.z_size)};
    }
    out.header = header_record(header, w);
    ++out.transactions;
  }
  return out;
}

std::filesystem::path journal_path(const std::filesystem::path& world) {
  std::filesystem::path p = world;
  p += ".journal";
  return p;
}

void set_save_step_hook(std::function<void(const char*)> hook) {
  std::lock_guard<std::mutex> lock(hook_mutex);
  save_hook = std::move(hook);
}

void replay_journal(const std::filesystem::path& path, World& w, SceneInfo* si,
                    OpenReport* report) {
  const std::filesystem::path jp = journal_path(path);
  std::error_code ec;
  if (!std::filesystem::exists(jp, ec)) return;
  const std::vector<uint8_t> bytes = read_file(jp);
  replay_journal_bytes(bytes, w, si, report, jp.string(), world_file_id(path));
}

void replay_journal_bytes(const std::vector<uint8_t>& bytes, World& w, SceneInfo* si,
                          OpenReport* report, const std::string& name,
                          std::optional<uint64_t> base) {
  const Parsed parsed = parse_journal(bytes, w, name);
  const size_t first = base ? parsed.first_for(*base, name) : 0;
  for (size_t t = first; t < parsed.txns.size(); ++t) {
    const std::vector<uint64_t> chunks = apply(w, parsed.txns[t], si);
    if (report) {
      ++report->transactions;
      report->chunk_records += chunks.size();
      // A chunk replayed whole replaces a refused one.
      std::erase_if(report->refused, [&](const ChunkFailure& f) {
        return std::find(chunks.begin(), chunks.end(), f.chunk) != chunks.end();
      });
    }
  }
  if (report) report->ignored_bytes = bytes.size() - parsed.end;
}

World open_world(const std::filesystem::path& path, SceneInfo* info, OpenReport* report,
                 bool tolerant) {
  OpenReport local;
  OpenReport* rep = report ? report : &local;
  *rep = OpenReport{};
  const ContainerReader reader = ContainerReader::open(path);
  SceneInfo si;
  World w = read_world(reader, &si, tolerant ? &rep->refused : nullptr, &path);
  if (!tolerant) reader.verify_all();
  replay_journal(path, w, &si, rep);
  if (info) *info = std::move(si);
  return w;
}

uint64_t commit_edits(const std::filesystem::path& path, const World& w,
                      const std::vector<uint64_t>& cells) {
  const ChunkGrid cg = chunk_grid(w.dims());
  std::set<uint64_t> chunks;
  for (uint64_t ci : cells) {
    if (ci >= w.cells().size()) throw Error("brickmap: commit_edits: cell index out of range");
    chunks.insert(chunk_of(w, ci));
  }
  const std::filesystem::path jp = journal_path(path);
  const uint64_t base = world_file_id(path);
  std::error_code ec;
  uint64_t txn = 1;
  bool fresh = !std::filesystem::exists(jp, ec);
  if (!fresh) {
    const std::vector<uint8_t> bytes = read_file(jp);
    const Parsed parsed = parse_journal(bytes, w, jp.string());
    // A journal whose transactions are all in the file (a checkpoint cut
    // off before it removed the journal) is started anew.
    fresh = parsed.first_for(base, jp.string()) == parsed.txns.size() && parsed.base != base;
    txn = parsed.last_txn + 1;
    if (!fresh && std::equal(kMagicV2, kMagicV2 + 8, bytes.begin())) {
      // A format-2 journal gets format 3's head before records of this
      // version (carved voxels) follow: an older voxcast would stop reading
      // at the first record type it does not know and open the world
      // without the edits after it; now it refuses the journal instead.
      // Rewritten whole under a temporary name and renamed, as a new
      // journal is created; an unacknowledged tail is left out.
      std::vector<uint8_t> head(bytes.begin(), bytes.begin() + (kFileHead - 8));
      std::copy(kMagic, kMagic + 8, head.begin());
      put_le<uint64_t>(head, XXH64(head.data(), head.size(), 0));
      std::filesystem::path tmp = jp;
      tmp += ".tmp";
      {
        Fd f(tmp, O_WRONLY | O_CREAT | O_TRUNC);
        f.write_all(head.data(), head.size());
        f.write_all(bytes.data() + kFileHead, parsed.end - kFileHead);
        f.sync();
      }
      std::filesystem::rename(tmp, jp);
      sync_directory(jp);
      step("journal upgraded");
    } else if (!fresh && parsed.end != bytes.size()) {
      // An unacknowledged save cut off by a crash: not part of the world.
      Fd f(jp, O_WRONLY);
      f.truncate(parsed.end);
      f.sync();
      step("journal tail cut");
    }
  }
  if (fresh) {
    // Created whole under a temporary name, renamed over any folded-in
    // journal: a journal file always has its head.
    txn = 1;
    std::filesystem::path tmp = jp;
    tmp += ".tmp";
    {
      Fd f(tmp, O_WRONLY | O_CREAT | O_TRUNC);
      const std::vector<uint8_t> head = file_head(w, base);
      f.write_all(head.data(), head.size());
      f.sync();
    }
    step("journal created");
    std::filesystem::rename(tmp, jp);
    sync_directory(jp);
    step("journal renamed");
  }
  Fd f(jp, O_WRONLY);
  f.seek_end();
  uint64_t records = 0;
  const auto put = [&](uint32_t type, const std::vector<uint8_t>& payload) {
    const std::vector<uint8_t> head = record_head(type, txn, payload);
    f.write_all(head.data(), head.size());
    step("record head written");
    f.write_all(payload.data(), payload.size());
    step("record written");
    ++records;
  };
  std::vector<uint8_t> raw;
  for (uint64_t chunk : chunks) {
    encode_chunk(w, cg, chunk, &raw);
    std::vector<uint8_t> p;
    put_le<uint64_t>(p, chunk);
    std::vector<uint8_t> bits(kCellBits, 0);
    for_chunk_cells(w, cg, chunk, [&](uint64_t ci, uint32_t pos) {
      if (w.cell(ci) != 0) bits[pos >> 3] |= uint8_t(1u << (pos & 7));
    });
    p.insert(p.end(), bits.begin(), bits.end());
    const std::vector<uint8_t> z =
        raw.empty() ? std::vector<uint8_t>{} : compress(raw.data(), raw.size());
    put_le<uint32_t>(p, uint32_t(raw.size()));
    put_le<uint32_t>(p, uint32_t(z.size()));
    p.insert(p.end(), z.begin(), z.end());
    put(kChunkRecord, p);
    if (w.terrain()) {
      // The chunk's carved voxels (World::carved), whole: what refills the
      // terrain's interior correctly after a reload.
      std::vector<uint8_t> cv;
      put_le<uint64_t>(cv, chunk);
      put_le<uint32_t>(cv, 0);
      uint32_t n = 0;
      for_chunk_cells(w, cg, chunk, [&](uint64_t ci, uint32_t pos) {
        const auto it = w.carved().find(ci);
        if (it == w.carved().end()) return;
        put_le<uint32_t>(cv, pos);
        for (uint64_t m : it->second) put_le<uint64_t>(cv, m);
        ++n;
      });
      std::memcpy(&cv[8], &n, 4);
      put(kCarvedRecord, cv);
    }
  }
  const WorldStats st = w.stats();
  std::vector<uint8_t> h;
  put_le<uint64_t>(h, st.bricks);
  put_le<uint64_t>(h, st.voxels);
  const std::vector<uint8_t> gh = encode_grid_header(w);
  h.insert(h.end(), gh.begin(), gh.end());
  put(kHeaderRecord, h);
  std::vector<uint8_t> c;
  put_le<uint64_t>(c, records);
  const std::vector<uint8_t> head = record_head(kCommitRecord, txn, c);
  f.write_all(head.data(), head.size());
  step("commit head written");
  f.write_all(c.data(), c.size());
  step("commit written");
  f.sync();
  step("journal synced");  // acknowledged from here on
  return std::filesystem::file_size(jp);
}

void checkpoint_world(const std::filesystem::path& path, const World& w, const SceneInfo& info) {
  step("checkpoint begins");
  const std::filesystem::path jp = journal_path(path);
  std::error_code ec;
  // The journal, refused before anything is written if it belongs to
  // another file.
  std::vector<uint8_t> bytes;
  Parsed parsed;
  const bool journaled = std::filesystem::exists(jp, ec);
  if (journaled) {
    bytes = read_file(jp);
    parsed = parse_journal(bytes, w, jp.string());
    (void)parsed.first_for(world_file_id(path), jp.string());
  }
  std::filesystem::path staged = path;
  staged += ".checkpoint";
  {
    ContainerWriter writer(staged);
    write_world(writer, w, info);
    step("checkpoint written");
    writer.commit();  // fsync, rename, directory fsync
  }
  step("checkpoint staged");
  if (journaled) {
    // The journal learns the new file's identity before the file is in
    // place: a crash between the rename below and the journal's removal
    // leaves a journal that the new file is known to hold.
    std::vector<uint8_t> p;
    put_le<uint64_t>(p, world_file_id(staged));
    Fd f(jp, O_WRONLY);
    if (parsed.end != bytes.size()) f.truncate(parsed.end);
    f.seek_end();
    const std::vector<uint8_t> head = record_head(kRebaseRecord, parsed.last_txn + 1, p);
    f.write_all(head.data(), head.size());
    f.write_all(p.data(), p.size());
    step("rebase written");
    f.sync();
    step("rebase synced");
  }
  std::filesystem::rename(staged, path);
  sync_directory(path);
  step("checkpoint renamed");
  if (remove_journal(path)) step("journal removed");
}

bool remove_journal(const std::filesystem::path& path) {
  const std::filesystem::path jp = journal_path(path);
  std::error_code ec;
  if (!std::filesystem::remove(jp, ec)) return false;
  sync_directory(jp);
  return true;
}

}  // namespace voxcast::brickmap
