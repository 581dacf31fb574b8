#pragma once
// Brickmap worlds on disk (van Wingerden 2015 §4.5) and saving edits without
// loss (issue 11 item 5).
//
// A world is its scene file WORLD.vxc (src/brickmap/format.cpp: META, the
// LZ4-compressed brickgrid header BMGH, the chunk offset table BMCT and the
// chunks BMCK, 16^3 brickmaps each, every chunk LZ4-compressed on its own
// with its own xxh64) plus, once edited in place, its edit journal
// WORLD.vxc.journal: a write-ahead log of whole-chunk images.
//
// Saving edits (commit_edits): the chunks holding the edited cells are
// encoded anew and appended to the journal as one transaction (chunk
// records, the new brickgrid header, a commit record), each record with its
// own checksum, and fsync'ed; when commit_edits returns, the edit is
// acknowledged: it survives a crash. The scene file itself is never written
// in place. checkpoint_world() folds the journal in: the whole world to a
// temporary file WORLD.vxc.checkpoint (fsync), a rebase record naming that
// file's identity appended to the journal (fsync), the rename over
// WORLD.vxc, then the journal removed.
//
// The journal is bound to the exact world file it was written against: its
// head holds that file's identity, the xxh64 of the container's header (a
// version-2 container's header holds the xxh64 of its directory, which holds
// every chunk's xxh64; of a version-1 container, the header and its section
// table with every section's xxh64), read from the file's first bytes alone.
// A journal whose head names another file (WORLD.vxc replaced by another
// world of the same grid size, or rewritten) is refused, not replayed, by
// everything that opens the world, unless its last rebase record names the
// file: then the checkpoint that wrote the file was cut off before it
// removed the journal, whose transactions (up to that record) the file
// holds; commit_edits then starts the journal anew. Writing a world whole
// over WORLD.vxc otherwise (save_scene, the CLI's outputs) removes the
// journal after the rename: a crash in between leaves a refused journal,
// never a silently replayed one.
//
// Opening (open_world, and load_scene through the format's load_file hook):
// the scene file, then every transaction of the journal whose commit record
// is intact, in order; a torn tail (a save cut off by a crash) is ignored.
// Chunk records are whole images, so a transaction replayed onto a file
// that holds it already changes nothing: every chunk is the old or the new
// state, never a mix.
//
// ---- Journal layout (little-endian) ----
//   +0  char[8] "VXBMJRN3" (format 3: format 2, "VXBMJRN2", and the carved
//                records; a format-2 journal is read alike. A format-1
//                journal "VXBMJRN1", bound by the cell count alone, is
//                refused: fold it in with the voxcast that wrote it, or
//                remove it)
//   +8  u64     brickgrid cells of the world
//   +16 u64     identity of the world file it was written against (above)
//   +24 u64     xxh64 of bytes 0..23
//   then records from byte 32, each a 40-byte head and a payload:
//     +0  u32 'JREC'   +4 u32 type (1 chunk, 2 header, 3 commit, 4 rebase,
//                      5 carved)
//     +8  u64 transaction number (ascending from 1)
//     +16 u64 payload bytes P   +24 u64 xxh64 of the payload
//     +32 u64 xxh64 of head bytes 0..31
//   chunk  payload: u64 chunk index, 512 bytes of cell bits (bit p set: the
//          chunk's cell at position p, x fastest, is non-empty), u32 raw
//          size, u32 LZ4 size, the LZ4 block of the chunk's raw bytes
//          (codec.hpp encode_chunk);
//   carved payload (a generated terrain's world only, World::carved; after
//          each chunk record of its transaction): u64 chunk index, u32
//          count N, N times u32 cell position in the chunk (ascending) and
//          the cell's u64[8] carved-voxel mask (never all zero): the chunk's
//          carved voxels, replaced whole like its bricks;
//   header payload: u64 bricks, u64 voxels, the BMGH bytes (codec.hpp);
//   commit payload: u64 records in the transaction before this one;
//   rebase payload: u64 identity of the file a checkpoint wrote, holding
//          every transaction before it (a record of its own, its own
//          transaction number, no commit record).
#include <cstdint>
#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "voxcast/brickmap.hpp"

namespace voxcast::brickmap {

/// A chunk the loader refused (its bytes failed a checksum or did not
/// decode); its cells are left empty.
struct ChunkFailure {
  uint64_t chunk = 0;  // index in the chunk grid, x fastest
  std::string reason;
};

/// The world of a scene file's container. refused == null: strict, any
/// damage refuses the world (load_scene's rule). Otherwise tolerant: a chunk
/// whose bytes fail the container's or its own checksum, or do not decode,
/// is refused and listed while the rest of the world loads (a damaged META,
/// header or table still refuses the world). `file` (tolerant only): the
/// reader's file, from which chunks are then read directly, so that each is
/// judged by its own checksum alone (without it, by the container chunks
/// holding it as well).
World read_world(const ContainerReader& reader, SceneInfo* info, std::vector<ChunkFailure>* refused,
                 const std::filesystem::path* file = nullptr);

/// WORLD.vxc -> WORLD.vxc.journal
std::filesystem::path journal_path(const std::filesystem::path& world);

struct OpenReport {
  uint64_t transactions = 0;          // committed journal transactions replayed
  uint64_t chunk_records = 0;         // chunk images replayed
  uint64_t ignored_bytes = 0;         // journal bytes after the last intact commit
  std::vector<ChunkFailure> refused;  // chunks of the scene file refused (tolerant opens)
};

/// The world as saved: the scene file, then its journal. `tolerant`: see
/// read_world (a chunk replayed from the journal replaces a refused one).
/// Throws voxcast::Error for a world (or journal header) that cannot be read.
World open_world(const std::filesystem::path& path, SceneInfo* info = nullptr,
                 OpenReport* report = nullptr, bool tolerant = false);

/// Replays the journal of `path` (if any) into `world`, which holds the
/// scene file's state (open_world and the format's load_file hook).
void replay_journal(const std::filesystem::path& path, World& world, SceneInfo* info,
                    OpenReport* report);
/// The same from the journal's bytes (`name` for messages): what the fuzz
/// target feeds. `base`: the identity of the world file (see above) the
/// journal must belong to (nullopt: not checked). Throws voxcast::Error for a
/// journal of another world or a committed transaction that does not decode;
/// a torn tail is ignored.
void replay_journal_bytes(const std::vector<uint8_t>& journal, World& world, SceneInfo* info,
                          OpenReport* report, const std::string& name = "journal",
                          std::optional<uint64_t> base = std::nullopt);

/// Appends the chunks holding `cells` (brickgrid cell indices, e.g. the
/// EditResult::cells of the edits since the last save) and the brickgrid
/// header to the journal of `path` as one transaction and fsyncs it: when it
/// returns, the edits are durable. A torn tail left by an earlier crash is
/// cut off first. Every non-empty cell of those chunks must be resident.
/// Returns the journal's size afterwards.
uint64_t commit_edits(const std::filesystem::path& path, const World& world,
                      const std::vector<uint64_t>& cells);

/// The world written whole to `path` (temporary file, fsync, rebase record,
/// rename), then its journal removed: the journal's transactions are in the
/// scene file.
void checkpoint_world(const std::filesystem::path& path, const World& world, const SceneInfo& info);

/// Removes the journal of `path` (if there is one) and fsyncs its directory:
/// what a writer that has just replaced `path` whole does (the journal was
/// written against the file replaced). Returns whether there was one.
bool remove_journal(const std::filesystem::path& path);

/// Crash tests only: called at every step of commit_edits and
/// checkpoint_world that a crash could separate from the next (before and
/// after each write, fsync, rename, removal), with the step's name. Null (the
/// default): nothing is called.
void set_save_step_hook(std::function<void(const char* step)> hook);

}  // namespace voxcast::brickmap
