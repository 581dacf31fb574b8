// The format-neutral half of scene files: META's "format", the registry, and
// the one loader every subcommand uses. The formats themselves live with
// their structures (src/esvo/format.cpp, src/dag/format.cpp).
#include "voxcast/scene_file.hpp"

#include <algorithm>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>

#include "io/meta_json.hpp"
#include "voxcast/error.hpp"
#include "voxcast/format_registry.hpp"
#include "voxcast/progress.hpp"

namespace voxcast {

std::string scene_format(const ContainerReader& reader) {
  const nlohmann::json meta = meta::parse(reader);
  try {
    return meta::get_string(meta, "format");
  } catch (const nlohmann::json::exception& e) {
    throw Error(std::string("corrupt scene: META section: ") + e.what());
  }
}

std::string scene_format(const Container& c) {
  return scene_format(ContainerReader::from_bytes(c.serialize()));
}

void FormatRegistry::add(SceneFormat format) {
  if (format.name.empty()) throw Error("scene format without a name");
  if (find(format.name)) throw Error("scene format '" + format.name + "' registered twice");
  if (!format.occupied || !format.describe)
    throw Error("scene format '" + format.name + "' lacks an occupied or describe function");
  if (format.sniff || format.open_file) {
    // A file type of its own: opened by path, never built into a container.
    if (!format.sniff || !format.open_file || format.build || format.save || format.load)
      throw Error("scene format '" + format.name +
                  "' of its own files needs sniff and open_file and no build, save or load");
  } else if (!format.build || !format.save || !format.load || !format.build_summary) {
    throw Error("scene format '" + format.name + "' lacks a build, save, load, occupied, " +
                "describe or build_summary function");
  }
  formats_.push_back(std::move(format));
}

const SceneFormat* FormatRegistry::find(std::string_view name) const {
  for (const SceneFormat& f : formats_)
    if (f.name == name) return &f;
  return nullptr;
}

const SceneFormat* FormatRegistry::recognize(const std::filesystem::path& path) const {
  for (const SceneFormat& f : formats_)
    if (f.sniff && f.sniff(path)) return &f;
  return nullptr;
}

std::vector<std::string> FormatRegistry::names() const {
  std::vector<std::string> n;
  for (const SceneFormat& f : formats_) n.push_back(f.name);
  return n;
}

const SceneFormat& FormatRegistry::get(std::string_view name) const {
  if (const SceneFormat* f = find(name)) return *f;
  std::string known;
  for (const SceneFormat& f : formats_) known += (known.empty() ? "" : ", ") + f.name;
  if (known.empty()) known = "none registered: call voxcast::register_builtin_formats()";
  // The name comes from a file: keep the message one printable line.
  std::string shown;
  for (const char c : name.substr(0, 64)) shown += (c >= 0x20 && c < 0x7F) ? c : '?';
  throw Error("unknown scene format '" + shown + "' (known: " + known + ")");
}

FormatRegistry& format_registry() {
  static FormatRegistry registry;
  return registry;
}

void save_scene(const std::filesystem::path& path, const std::string& format,
                const Structure& structure, const SceneInfo& info) {
  const SceneFormat& f = format_registry().get(format);
  if (!f.save)
    throw Error("scene format '" + f.name + "' is not saved as a scene container (its files " +
                "are written by its own builder)");
  ContainerWriter writer(path);
  // A bar on a terminal: the bytes written against the structure's memory
  // (the file holds about that much: the words and the attributes).
  // (Named by the stage: the CLI writes to a temporary name, then renames.)
  Progress progress("write scene", f.memory_bytes ? f.memory_bytes(structure) : 0);
  writer.set_progress(&progress);
  f.save(writer, structure, info);
  writer.commit();
  progress.finish();
}

namespace {
LoadedScene load_from(const ContainerReader& reader, const std::filesystem::path* path,
                      Progress* progress);
}  // namespace

LoadedScene load_scene(const std::filesystem::path& path, const SceneLoadOptions& options) {
  try {
    // A file type of its own (SceneFormat::sniff), else a container. Only
    // a regular file is sniffed (reading a FIFO's first bytes would block;
    // the container's open refuses the rest with its own message).
    std::error_code ec;
    const SceneFormat* f =
        std::filesystem::is_regular_file(path, ec) ? format_registry().recognize(path) : nullptr;
    if (f != nullptr) {
      LoadedScene out;
      out.format = f->name;
      // A bar on a terminal for a format that reports one (the caller's, or
      // one of its own).
      std::optional<Progress> own;
      SceneLoadOptions with_bar = options;
      if (with_bar.progress == nullptr)
        with_bar.progress = &own.emplace("load scene", std::vector<Progress::Phase>{{"", 1}});
      out.structure = f->open_file(path, with_bar, &out.info);
      out.occupied = f->occupied(*out.structure);
      return out;
    }
    // A bar on a terminal (the caller's, or one of its own).
    std::optional<Progress> own;
    Progress* progress = options.progress;
    if (progress == nullptr)
      progress = &own.emplace("load scene", std::vector<Progress::Phase>{{"", 1}});
    return load_from(ContainerReader::open(path), &path, progress);
  } catch (const Error& e) {
    // One line naming the file and what is wrong (the container's own
    // open/read errors already name it).
    const std::string what = e.what(), name = "'" + path.string() + "'";
    if (what.find(name) != std::string::npos) throw;
    throw Error("scene " + name + ": " + what);
  }
}

LoadedScene load_scene(const ContainerReader& reader) {
  return load_from(reader, nullptr, nullptr);
}

namespace {
// Share of the load's time spent reading, hashing and validating (the rest:
// the occupied bounds).
constexpr double kLoadReadWeight = 0.9;

LoadedScene load_from(const ContainerReader& reader, const std::filesystem::path* path,
                      Progress* progress) {
  // The one gate between a file and every reader (render, info): the
  // format's full validator, then every chunk it did not read (so a file
  // with a damaged extra section is refused as before, when the whole file
  // was hashed up front), then the walks done here, so every subcommand
  // accepts or refuses exactly the same files.
  LoadedScene out;
  out.format = scene_format(reader);
  const SceneFormat& f = format_registry().get(out.format);
  out.sections = reader.section_ids();
  // The bar: the bytes read and hashed against the file's size (the
  // format's validation walk runs between its reads), then the occupied
  // bounds (a walk of the whole structure, one unit).
  struct Detach {  // the reader may outlive the bar
    const ContainerReader& r;
    ~Detach() { r.set_progress(nullptr); }
  } detach{reader};
  if (progress) {
    progress->set_phases({{"read", kLoadReadWeight}, {"bounds", 1 - kLoadReadWeight}});
    progress->start_phase(0, reader.file_bytes());
    progress->set_done(reader.bytes_read());
    reader.set_progress(progress);
  }
  out.structure =
      path && f.load_file ? f.load_file(*path, reader, &out.info) : f.load(reader, &out.info);
  reader.verify_all();
  reader.set_progress(nullptr);
  if (progress) progress->start_phase(1, 1);
  out.occupied = f.occupied(*out.structure);
  if (progress) {
    progress->advance();
    progress->finish();
  }
  return out;
}
}  // namespace

LoadedScene load_scene(const Container& c) {
  return load_scene(ContainerReader::from_bytes(c.serialize()));
}

}  // namespace voxcast
