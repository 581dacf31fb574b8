// The "esvo-sliced" entry of the format registry (format_registry.hpp):
// slice files (esvo §7, include/voxcast/esvo_slices.hpp) opened by
// load_scene() as a StreamedEsvo, so that every reader of scenes (render,
// info, view, Python voxcast.load) reads them the way it reads containers.
// A slice file is a file type of its own (its magic, not a container): the
// format has sniff and open_file, and no build, save or load (the files are
// written by `build --slices`: write_slices / build_slices).
#include <fmt/printf.h>

#include <memory>
#include <nlohmann/json.hpp>
#include <string>

#include "voxcast/error.hpp"
#include "voxcast/esvo_slices.hpp"
#include "voxcast/format_registry.hpp"
#include "voxcast/progress.hpp"
#include "voxcast/scene_file.hpp"

namespace voxcast::esvo {

namespace {

const StreamedEsvo& streamed_of(const Structure& s) {
  const auto* e = dynamic_cast<const StreamedEsvo*>(&s);
  if (e == nullptr) throw Error("esvo-sliced format: the structure is not a streamed ESVO");
  return *e;
}

uint64_t all_resident_bytes(const SliceFile& file) {
  uint64_t bytes = 0;
  for (const slice_layout::SliceEntry& e : file.slices()) bytes += StreamedEsvo::block_bytes(e);
  return bytes;
}

// Share of a whole-file open's time spent reading, hashing, checking and
// merging the slices (the rest: the walk for the occupied bounds).
constexpr double kOpenReadWeight = 0.9;

LoadedStructure open(const std::filesystem::path& path, const SceneLoadOptions& options,
                     SceneInfo* info) {
  const std::shared_ptr<SliceFile> file = SliceFile::open(path);
  StreamOptions so;
  so.budget_bytes = options.stream_budget;
  auto s = std::make_unique<StreamedEsvo>(file, so);
  if (options.load_all && s->fits_whole()) {
    // The in-core equivalent, and as strict as a container's loader: every
    // slice read, hashed and linked, a damaged one refuses the file. On a
    // terminal: a bar over the read and the bounds walk (cached for
    // load_scene's occupied()).
    Progress* progress = options.progress;
    if (progress != nullptr) {
      progress->set_phases({{"read", kOpenReadWeight}, {"bounds", 1 - kOpenReadWeight}});
      progress->start_phase(0, 0);
    }
    s->load_all(progress);
    if (s->stats().refused != 0) throw Error(s->last_refusal());
    if (progress != nullptr) progress->start_phase(1, 0);
    s->occupied(progress);
    if (progress != nullptr) progress->finish();
  }
  if (info != nullptr) {
    // A slice file records no source (esvo_slices.hpp: header and directory only).
    *info = SceneInfo{};
    info->voxelization = "unrecorded";
  }
  return s;
}

SceneDescription describe(const Structure& structure, const DescribeStyle& style) {
  const StreamedEsvo& s = streamed_of(structure);
  const SliceFile& file = s.file();
  const slice_layout::FileHeader& h = file.header();
  const uint64_t whole = all_resident_bytes(file);
  nlohmann::json j;
  j["slices"] = file.slices().size();
  j["slice_bytes"] = h.slice_bytes;
  j["descriptors"] = h.total_nodes;
  j["voxels"] = h.total_voxels;
  j["contours"] = file.has_contours();
  j["attributes"] = file.compressed() ? "compressed" : "raw";
  j["resident_bytes_all"] = whole;
  j["resident_bytes"] = s.stats().resident_bytes;
  j["resident_slices"] = s.stats().resident_slices;
  SceneDescription d;
  d.grid = file.grid();
  d.json = j.dump();
  d.summary =
      fmt::sprintf("structure   esvo-sliced, %zu slices on disk (esvo 7), streamed blocks\n",
                   file.slices().size());
  d.summary += fmt::sprintf("contours    %s\n", file.has_contours() ? "yes" : "no");
  d.summary += fmt::sprintf("attributes  %s\n",
                            file.compressed()
                                ? "compressed on disk (esvo 5.5 blocks per slice), raw in memory"
                                : "raw (esvo 5.4)");
  d.voxels = fmt::sprintf("%llu below the root in all levels, %llu descriptors",
                          (unsigned long long)h.total_voxels, (unsigned long long)h.total_nodes);
  d.details = file.describe();
  d.details += "all slices resident (streamed blocks): " + style.bytes(double(whole)) + "\n";
  d.details += fmt::sprintf("resident at open: %u slices, %s\n", s.stats().resident_slices,
                            style.bytes(double(s.stats().resident_bytes)));
  return d;
}

}  // namespace

void register_sliced_format(FormatRegistry& registry) {
  SceneFormat f;
  f.name = "esvo-sliced";
  f.description = "ESVO slices on disk, streamed (esvo 7; written by build --slices)";
  f.extensions = {".vxs"};
  f.contours = true;
  f.sniff = [](const std::filesystem::path& path) { return is_slice_file(path); };
  f.open_file = open;
  f.occupied = [](const Structure& s) { return streamed_of(s).occupied(); };
  f.describe = describe;
  f.memory_bytes = [](const Structure& s) { return streamed_of(s).stats().resident_bytes; };
  f.stream_counters = [](const Structure& structure) {
    const StreamStats& st = streamed_of(structure).stats();
    StreamCounters c;
    c.loaded = st.loaded;
    c.unloaded = st.unloaded;
    c.refused = st.refused;
    c.pending = st.pending;
    c.bytes_read = st.bytes_read;
    c.resident_parts = st.resident_slices;
    c.resident_bytes = st.resident_bytes;
    c.peak_resident_bytes = st.peak_resident_bytes;
    return c;
  };
  registry.add(std::move(f));
}

}  // namespace voxcast::esvo
