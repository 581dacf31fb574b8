#include "cli_io.hpp"

#include <fcntl.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <set>
#include <string>

#include "commands.hpp"
#include "voxcast/brickmap_file.hpp"
#include "voxcast/system.hpp"

namespace voxcast::cli {

// Here, not in main.cpp, so the Python module (which links this file and
// pipeline.cpp, not main.cpp) has it too.
std::string format_bytes(double bytes) {
  const char* units[] = {"B", "KiB", "MiB", "GiB", "TiB"};
  int u = 0;
  while (bytes >= 1024 && u < 4) bytes /= 1024, ++u;
  char buf[64];
  std::snprintf(buf, sizeof buf, u == 0 ? "%.0f %s" : "%.2f %s", bytes, units[u]);
  return buf;
}

namespace fs = std::filesystem;

// ------------------------------------------------------------ messages

namespace {

// Length of the valid UTF-8 sequence starting at s[i], 0 if there is none
// (overlong forms, surrogates and code points above U+10FFFF are invalid).
size_t utf8_sequence(std::string_view s, size_t i) {
  const auto b = [&](size_t k) { return static_cast<unsigned char>(s[i + k]); };
  const unsigned char c = b(0);
  size_t n = 0;
  uint32_t cp = 0;
  if (c < 0x80) return 1;
  if ((c & 0xE0) == 0xC0) {
    n = 2;
    cp = c & 0x1F;
  } else if ((c & 0xF0) == 0xE0) {
    n = 3;
    cp = c & 0x0F;
  } else if ((c & 0xF8) == 0xF0) {
    n = 4;
    cp = c & 0x07;
  } else {
    return 0;
  }
  if (i + n > s.size()) return 0;
  for (size_t k = 1; k < n; ++k) {
    if ((b(k) & 0xC0) != 0x80) return 0;
    cp = (cp << 6) | (b(k) & 0x3F);
  }
  static const uint32_t kMin[5] = {0, 0, 0x80, 0x800, 0x10000};
  if (cp < kMin[n] || cp > 0x10FFFF || (cp >= 0xD800 && cp <= 0xDFFF)) return 0;
  return n;
}

}  // namespace

std::string printable(std::string_view s) {
  // nlohmann::json parse errors go on, after "parse error at line L, column
  // C:", in the parser's terms ("syntax error while parsing object key -
  // invalid literal; last read: ..."): the position is what a user can use.
  std::string trimmed;
  if (const size_t at = s.find("parse error at line "); at != std::string_view::npos) {
    if (const size_t colon = s.find(':', at); colon != std::string_view::npos) {
      trimmed = std::string(s.substr(0, colon));
      s = trimmed;
    }
  }
  std::string out;
  out.reserve(s.size());
  bool space = false;
  for (size_t i = 0; i < s.size();) {
    const unsigned char c = static_cast<unsigned char>(s[i]);
    // nlohmann::json prefixes its messages with "[json.exception.<kind>.<id>] ".
    if (c == '[' && s.substr(i).rfind("[json.exception.", 0) == 0) {
      const size_t close = s.find("] ", i);
      if (close != std::string_view::npos) {
        i = close + 2;
        continue;
      }
    }
    if (c == ' ' || c == '\n' || c == '\r' || c == '\t') {
      space = !out.empty();
      ++i;
      continue;
    }
    if (space) out.push_back(' ');
    space = false;
    const size_t n = utf8_sequence(s, i);
    if (n == 0 || c < 0x20 || c == 0x7F) {
      char hex[8];
      std::snprintf(hex, sizeof hex, "\\x%02X", unsigned(c));
      out += hex;
      ++i;
      continue;
    }
    out.append(s.substr(i, n));
    i += n;
  }
  return out;
}

std::string in_quotes(const fs::path& path) {
  return "'" + printable(path.string()) + "'";
}

// ------------------------------------------------------------ numbers

double cpu_seconds() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return double(u.ru_utime.tv_sec + u.ru_stime.tv_sec) +
         1e-6 * double(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

const CLI::Validator& not_negative() {
  static const CLI::Validator v(
      [](std::string& text) -> std::string {
        const size_t first = text.find_first_not_of(" \t");
        if (first != std::string::npos && text[first] == '-')
          return printable(text) + " is negative; expected a whole number >= 0";
        return {};
      },
      "", "NOT_NEGATIVE");
  return v;
}

void require_range(const char* option, double value, double lo, double hi) {
  if (std::isfinite(value) && value >= lo && value <= hi) return;
  auto num = [](double v) {
    char buf[64];
    std::snprintf(buf, sizeof buf, "%.10g", v);
    return std::string(buf);
  };
  throw UsageError(std::string(option) + ": " + num(value) + " is not a number in " + num(lo) +
                   " .. " + num(hi));
}

void require_power_of_two(const char* option, uint64_t value, uint64_t lo, uint64_t hi) {
  if (value >= lo && value <= hi && (value & (value - 1)) == 0) return;
  throw UsageError(std::string(option) + ": " + std::to_string(value) +
                   " is not a power of two in " + std::to_string(lo) + " .. " + std::to_string(hi));
}

Camera parse_camera_option(const std::string& text) {
  try {
    return Camera::parse(text);
  } catch (const Error& e) {
    std::string why = e.what();
    if (why.rfind("camera: ", 0) == 0) why.erase(0, 8);
    throw UsageError("--camera: " + why);
  }
}

uint64_t parse_memory_budget(const std::string& text, const char* option) {
  uint64_t bytes = 0;
  try {
    bytes = parse_byte_size(text.c_str());
  } catch (const Error& e) {
    throw UsageError(std::string(option) + ": " + e.what());
  }
  const uint64_t physical = physical_memory_bytes();
  if (physical > 0 && bytes > physical)
    throw UsageError(std::string(option) + ": " + printable(text) + " is more than the " +
                     format_bytes(double(physical)) + " of physical memory of this machine");
  return bytes;
}

// ------------------------------------------------------------ files

namespace {

const char* file_kind(mode_t mode) {
  return file_type_name(uint32_t(mode));
}

// The file a write to `path` lands in: symlinks in the last component are
// followed (relative targets are relative to the link's directory), so that
// renaming onto the result replaces the target's contents, not the link.
fs::path follow_links(const fs::path& path, const char* option) {
  fs::path p = path;
  for (int hops = 0;; ++hops) {
    std::error_code ec;
    if (!fs::is_symlink(fs::symlink_status(p, ec))) return p;
    if (hops == 40)
      throw UsageError(std::string(option) + " " + in_quotes(path) +
                       ": too many levels of symlinks");
    const fs::path t = fs::read_symlink(p, ec);
    if (ec)
      throw Error(std::string(option) + " " + in_quotes(path) +
                  ": cannot read symlink: " + ec.message());
    p = t.is_absolute() ? t : p.parent_path() / t;
  }
}

// Staged files, for the signal handler: a Ctrl-C during a long render must
// not leave hidden temporaries behind. Fixed storage, because a handler may
// only call async-signal-safe functions (unlink, signal, raise).
constexpr int kMaxStaged = 32;
char g_staged[kMaxStaged][4096];
volatile std::sig_atomic_t g_staged_count = 0;
// While commit() renames the staged files into place, a signal is held back
// (recorded here and re-raised once every rename is done or undone): dying
// halfway would leave some outputs new and some old, and backups behind. The
// handler may run on any thread (TBB's workers do not block signals), so it
// cannot rely on the committing thread's signal mask.
volatile std::sig_atomic_t g_committing = 0;
volatile std::sig_atomic_t g_pending_signal = 0;

void remove_staged() {
  for (int i = 0; i < g_staged_count; ++i) ::unlink(g_staged[i]);
}

extern "C" void remove_staged_and_die(int sig) {
  if (g_committing) {
    g_pending_signal = sig;
    return;
  }
  remove_staged();
  std::signal(sig, SIG_DFL);
  std::raise(sig);
}

void register_staged(const std::string& path) {
  if (g_staged_count >= kMaxStaged || path.size() >= sizeof g_staged[0]) return;
  std::memcpy(g_staged[g_staged_count], path.c_str(), path.size() + 1);
  g_staged_count = g_staged_count + 1;
  static bool installed = false;
  if (!installed) {
    installed = true;
    for (int sig : {SIGINT, SIGTERM, SIGHUP}) std::signal(sig, remove_staged_and_die);
  }
}

// Ends commit()'s window: a signal that came during it now takes effect,
// after the staged files that are still registered are removed (none once
// every rename succeeded).
void end_commit_window() {
  g_committing = 0;
  if (const int sig = g_pending_signal) {
    remove_staged();
    std::signal(sig, SIG_DFL);
    std::raise(sig);
  }
}

void unregister_staged_all() {
  g_staged_count = 0;
}

std::string lower_extension(const fs::path& path) {
  std::string ext = path.extension().string();
  for (char& c : ext) c = char(std::tolower(static_cast<unsigned char>(c)));
  return ext;
}

}  // namespace

void require_regular_input(const std::string& path, const char* what) {
  struct stat st;
  if (::stat(path.c_str(), &st) != 0)
    throw Error(std::string("cannot open ") + what + " " + in_quotes(path) + ": " +
                std::strerror(errno));
  if (!S_ISREG(st.st_mode))
    throw Error(std::string(what) + " " + in_quotes(path) + " is " + file_kind(st.st_mode) +
                ", not a regular file");
}

OutputSet::OutputSet(std::vector<std::string> inputs) {
  for (std::string& name : inputs) {
    struct stat st;
    // An input that does not exist is reported by its reader; it cannot be
    // the same file as an output either.
    if (::stat(name.c_str(), &st) == 0) inputs_.push_back({st.st_dev, st.st_ino, std::move(name)});
  }
}

OutputSet::~OutputSet() {
  if (committed_) return;
  for (const Output& o : outputs_) {
    std::error_code ec;
    if (!o.stage.empty()) fs::remove(o.stage, ec);
  }
  unregister_staged_all();
}

void OutputSet::add(const char* option, const std::string& path,
                    std::initializer_list<const char*> extensions) {
  const std::string where = std::string(option) + " " + in_quotes(path);
  if (path.empty()) throw UsageError(std::string(option) + ": empty file name");
  const std::string ext = lower_extension(path);
  if (std::none_of(extensions.begin(), extensions.end(), [&](const char* e) { return ext == e; })) {
    std::string list;
    for (const char* e : extensions) list += std::string(list.empty() ? "" : " or ") + e;
    throw UsageError(where + " must end in " + list);
  }
  Output o;
  o.option = option;
  o.path = path;
  o.target = follow_links(path, option);
  struct stat st;
  if (::stat(o.target.c_str(), &st) == 0) {
    if (!S_ISREG(st.st_mode))
      throw UsageError(where + " is " + file_kind(st.st_mode) + "; outputs must be regular files");
    for (const FileId& in : inputs_)
      if (in.dev == st.st_dev && in.ino == st.st_ino)
        throw UsageError(where + " is the same file as the input " + in_quotes(in.name));
    const auto [at, fresh] = by_id_.try_emplace({st.st_dev, st.st_ino}, outputs_.size());
    if (!fresh) {
      const Output& prev = outputs_[at->second];
      throw UsageError(where + " and " + prev.option + " " + in_quotes(prev.path) +
                       " are the same file");
    }
    o.target_existed = true;
  } else {
    const fs::path dir = o.target.parent_path().empty() ? fs::path(".") : o.target.parent_path();
    struct stat ds;
    if (::stat(dir.c_str(), &ds) != 0 || !S_ISDIR(ds.st_mode))
      throw UsageError(where + ": the directory " + in_quotes(dir) + " does not exist");
  }
  // Not-yet-existing outputs: the same name twice (after resolving ".",
  // ".." and symlinked directories).
  std::error_code ec;
  const fs::path key = fs::weakly_canonical(fs::absolute(o.target, ec), ec);
  if (const auto at = by_key_.find(key.string()); at != by_key_.end()) {
    const Output& prev = outputs_[at->second];
    throw UsageError(where + " and " + prev.option + " " + in_quotes(prev.path) +
                     " are the same file");
  }
  const fs::path dir = o.target.parent_path().empty() ? fs::path(".") : o.target.parent_path();
  if (::access(dir.c_str(), W_OK) != 0)
    throw Error("cannot write " + where + ": the directory " + in_quotes(dir) +
                " is not writable (" + std::strerror(errno) + ")");
  // Hidden, same directory (so the final rename stays on one file system),
  // same extension (writers pick the format from it).
  o.stage = dir / ("." + o.target.filename().string() + ".voxcast-" + std::to_string(::getpid()) +
                   "-" + std::to_string(outputs_.size()) + ext);
  by_key_.emplace(key.string(), outputs_.size());
  by_path_.emplace(o.path, outputs_.size());  // (the same path twice has the same key)
  outputs_.push_back(std::move(o));
}

fs::path OutputSet::staging(const std::string& path) const {
  const auto at = by_path_.find(path);
  if (at == by_path_.end())
    throw Error("internal: output " + in_quotes(path) + " was not registered");
  const Output& o = outputs_[at->second];
  // Registered lazily: only once a writer is about to create it. The
  // writer's own temporary (write_file_atomic) is renamed onto it.
  register_staged(o.stage.string());
  register_staged(o.stage.string() + ".tmp." + std::to_string(::getpid()));
  return o.stage;
}

std::string OutputSet::rename_in_message(std::string message, const fs::path& stage,
                                         const std::string& path) {
  // The writer's own temporary first (it starts with the staging name).
  for (const std::string& from :
       {stage.string() + ".tmp." + std::to_string(::getpid()), stage.string()})
    for (size_t at; (at = message.find(from)) != std::string::npos;)
      message.replace(at, from.size(), path);
  return message;
}

void OutputSet::commit() {
  g_committing = 1;
  try {
    commit_all();
  } catch (...) {
    end_commit_window();
    throw;
  }
  committed_ = true;
  unregister_staged_all();
  end_commit_window();
}

void OutputSet::commit_all() {
  // Backups keep the previous contents reachable until every rename has
  // succeeded; a hard link costs no copy.
  for (size_t i = 0; i < outputs_.size(); ++i) {
    Output& o = outputs_[i];
    std::error_code ec;
    if (!fs::exists(o.stage, ec))
      throw Error("internal: output " + in_quotes(o.path) + " was never written");
    if (o.target_existed) {
      o.backup = o.stage.string() + ".old";
      if (::link(o.target.c_str(), o.backup.c_str()) != 0) o.backup.clear();
    }
  }
  for (size_t i = 0; i < outputs_.size(); ++i) {
    Output& o = outputs_[i];
    if (::rename(o.stage.c_str(), o.target.c_str()) == 0) continue;
    const int err = errno;
    for (size_t j = 0; j < i; ++j) {  // undo
      const Output& d = outputs_[j];
      if (!d.backup.empty())
        ::rename(d.backup.c_str(), d.target.c_str());
      else if (!d.target_existed)
        ::unlink(d.target.c_str());
    }
    for (const Output& d : outputs_) {
      if (!d.backup.empty()) ::unlink(d.backup.c_str());
    }
    throw Error("cannot write " + o.option + " " + in_quotes(o.path) + ": rename failed (" +
                std::strerror(err) + "); no output was changed");
  }
  std::set<fs::path> dirs;
  for (const Output& o : outputs_) {
    if (!o.backup.empty()) ::unlink(o.backup.c_str());
    // A brickmap world replaced whole: the edit journal beside it was
    // written against the old file (brickmap_file.hpp); it goes too (a
    // crash before this leaves it refused, never replayed).
    brickmap::remove_journal(o.target);
    dirs.insert(o.target.parent_path().empty() ? fs::path(".") : o.target.parent_path());
  }
  // Persist the renames (each directory once); a failure here does not undo them.
  for (const fs::path& dir : dirs) {
    const int dfd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (dfd >= 0) {
      ::fsync(dfd);
      ::close(dfd);
    }
  }
}

}  // namespace voxcast::cli
