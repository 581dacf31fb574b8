#pragma once
// What every subcommand shares about the command line's files and numbers:
// usage errors (exit 2) versus runtime errors (exit 1), printable messages,
// input files that cannot hang the process, and outputs that cannot destroy
// data (OutputSet).
#include <sys/types.h>

#include <CLI/CLI.hpp>
#include <cstdint>
#include <filesystem>
#include <initializer_list>
#include <map>
#include <string>
#include <string_view>
#include <unordered_map>
#include <utility>
#include <vector>

#include "voxcast/camera.hpp"
#include "voxcast/error.hpp"

namespace voxcast::cli {

/// The command line cannot be run as given: an unknown option, a value out of
/// range, an output path that is refused before any work starts. main() exits
/// with 2 for these and 1 for every other voxcast::Error.
class UsageError : public Error {
 public:
  using Error::Error;
};

/// `s` as one printable line: valid UTF-8 is kept, invalid bytes and control
/// characters become \xNN, runs of whitespace one space, JSON-library tags
/// such as "[json.exception.parse_error.101] " are dropped.
std::string printable(std::string_view s);
/// printable(path) in single quotes, for messages.
std::string in_quotes(const std::filesystem::path& path);

/// Refuses (voxcast::Error, exit 1) an input that does not exist or is not a
/// regular file: opening a FIFO blocks until a writer appears, a device never
/// ends, a directory is no file. Symlinks are followed.
void require_regular_input(const std::string& path, const char* what);

/// Process CPU time (user + system) in seconds: frame costs that can be read
/// for an idle machine when the wall clock is shared.
double cpu_seconds();

/// For unsigned options: CLI11 would read "-1" as 2^N-1.
const CLI::Validator& not_negative();

/// `value` must be finite and within [lo, hi]; else a UsageError naming
/// `option` and the range. Integers are checked through double (exact to 2^53).
void require_range(const char* option, double value, double lo, double hi);
/// A power of two within [lo, hi].
void require_power_of_two(const char* option, uint64_t value, uint64_t lo, uint64_t hi);

/// --camera ex,ey,ez,tx,ty,tz,ux,uy,uz,fovy (Camera::parse) as a usage error.
Camera parse_camera_option(const std::string& text);

/// --memory-budget: "512M", "8G", ... (parse_byte_size), refused when above
/// the machine's physical memory (a budget that large protects nothing).
/// `option` names the option in the usage error (e.g. "--budget").
uint64_t parse_memory_budget(const std::string& text, const char* option = "--memory-budget");

/// Every file a command writes. Register all outputs before any work
/// (add() checks each right away), write each to staging(path), then commit()
/// renames all of them into place; if the command fails before commit(), the
/// destructor removes what was staged, so either every output is written or
/// none is touched.
///
/// Rules (each a UsageError): the extension must be one of the given ones;
/// an output must not be an existing non-regular file (directory, FIFO,
/// device, socket); it must not be the same file as an input (same device
/// and inode: hard links, "./x" vs "x", symlinks included); no two outputs
/// may be the same file. A symlink is written through: its target (which may
/// not exist yet) is replaced, the link itself stays.
class OutputSet {
 public:
  /// `inputs`: the files the command reads (checked against every output).
  explicit OutputSet(std::vector<std::string> inputs);
  ~OutputSet();
  OutputSet(const OutputSet&) = delete;
  OutputSet& operator=(const OutputSet&) = delete;

  /// `option` names the output in messages ("-o", "--depth");
  /// `extensions` are lower-case with the dot (".png").
  void add(const char* option, const std::string& path,
           std::initializer_list<const char*> extensions);
  /// Where to write the output registered as `path` (a hidden file in its
  /// target's directory, with the same extension).
  std::filesystem::path staging(const std::string& path) const;
  /// Calls `writer(staging(path))`; a failure is reported under the user's
  /// name for the file, not the staging name.
  template <class Writer>
  void write(const std::string& path, Writer&& writer) {
    const std::filesystem::path stage = staging(path);
    try {
      writer(stage);
    } catch (const Error& e) {
      throw Error(rename_in_message(e.what(), stage, path));
    }
  }
  /// Renames every staged output into place. If one rename fails, the ones
  /// already done are undone (previous contents restored from hard-link
  /// backups) before the error is thrown.
  ///
  /// Signals: SIGINT, SIGTERM or SIGHUP before commit() remove every staged
  /// file (and its writer's temporary) and end the process with that signal,
  /// so no output is touched; one that arrives during commit() takes effect
  /// when it returns or throws, so the outputs are all new or all as before.
  void commit();

 private:
  void commit_all();
  static std::string rename_in_message(std::string message, const std::filesystem::path& stage,
                                       const std::string& path);
  struct Output {
    std::string option, path;
    std::filesystem::path target, stage, backup;
    bool target_existed = false;
    bool staged_registered = false;
  };
  struct FileId {
    dev_t dev;
    ino_t ino;
    std::string name;
  };
  std::vector<FileId> inputs_;
  std::vector<Output> outputs_;
  // Indices into outputs_ (a --path render adds one output per frame: no
  // scan of the earlier ones per add): by the path as given, by the
  // canonical target, and by the existing target's device and inode.
  std::unordered_map<std::string, size_t> by_path_, by_key_;
  std::map<std::pair<dev_t, ino_t>, size_t> by_id_;
  bool committed_ = false;
};

}  // namespace voxcast::cli
