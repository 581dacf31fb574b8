// voxcast render SLICES.vxs --budget 512M --frames K [--path camera.json]:
// a streamed scene (the streamed ESVO of a slice file, esvo §7, opened by
// load_scene through the format registry) rendered frame by frame, one pass
// per frame, with a line per frame of what the streaming did.
#include "cmd_render_sliced.hpp"

#include <sys/resource.h>

#include <chrono>
#include <cstdio>
#include <optional>

#include "cli_io.hpp"
#include "commands.hpp"
#include "view/camera_path.hpp"
#include "voxcast/error.hpp"
#include "voxcast/format_registry.hpp"
#include "voxcast/scene_file.hpp"
#include "voxcast/system.hpp"

namespace voxcast::cli {

namespace {
// Peak resident set of the process (getrusage: kilobytes on Linux).
double peak_rss_bytes() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return double(u.ru_maxrss) * 1024.0;
}
}  // namespace

int render_sliced(const SlicedRender& a, RenderOptions opt) {
  if (a.frames < 1 || a.frames > 1000000) throw UsageError("--frames must be in 1..1000000");
  SceneLoadOptions lo;
  lo.load_all = false;  // the root only: the frames stream the rest
  if (!a.budget.empty()) {
    try {
      lo.stream_budget = parse_byte_size(a.budget.c_str());
    } catch (const Error& e) {
      throw UsageError(std::string("--budget: ") + e.what());
    }
  }
  OutputSet outputs(a.path.empty() ? std::vector<std::string>{a.input}
                                   : std::vector<std::string>{a.input, a.path});
  outputs.add("-o", a.output, {".png", ".pfm"});
  for (const std::string& f : a.frame_files) outputs.add("--write-frames", f, {".png", ".pfm"});
  require_regular_input(a.input, "scene");
  std::optional<view::CameraPath> path;
  if (!a.path.empty()) {
    require_regular_input(a.path, "camera path");
    path = view::CameraPath::load(a.path);
  }
  // Through the format registry (format_registry.hpp): the format that
  // recognizes the file opens it and reports its streaming.
  LoadedScene loaded = load_scene(a.input, lo);
  const SceneFormat& format = format_registry().get(loaded.format);
  if (!format.stream_counters)
    throw UsageError("--budget and --frames apply to slice files (build --slices) and to --stream");
  Structure& scene = *loaded.structure;
  const auto counters = [&] { return format.stream_counters(scene); };
  // The automatic camera frames the file's occupied bounds (read from the
  // top of the slice hierarchy, whatever the budget lets in), as render of
  // the same scene opened whole or as a .vxc does.
  bool derived = false;
  const Camera fixed =
      path ? Camera{}
           : resolve_camera(*a.camera, format.occupied(scene), opt.width, opt.height, &derived);
  if (derived) std::printf("camera: %s\n", fixed.to_string().c_str());
  std::printf("streaming %s: %s, budget %s\n", printable(a.input).c_str(), loaded.format.c_str(),
              lo.stream_budget ? format_bytes(double(lo.stream_budget)).c_str() : "unlimited");
  RenderResult result;
  const auto start = std::chrono::steady_clock::now();
  for (int f = 0; f < a.frames; ++f) {
    if (path) {
      const double t = a.frames == 1 ? path->end()
                                     : path->start() + (path->end() - path->start()) * double(f) /
                                                           double(a.frames - 1);
      opt.camera = path->at(t);
    } else {
      opt.camera = fixed;
    }
    const StreamCounters before = counters();
    const auto t0 = std::chrono::steady_clock::now();
    result = render(scene, opt);
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const StreamCounters s = counters();
    std::printf(
        "frame %d: loaded %llu, unloaded %llu, refused %llu, pending %llu, resident %u slices "
        "%.2f MiB, read %.2f MiB, %.2f Mrays/s, %.1f ms\n",
        f, (unsigned long long)(s.loaded - before.loaded),
        (unsigned long long)(s.unloaded - before.unloaded),
        (unsigned long long)(s.refused - before.refused), (unsigned long long)s.pending,
        (unsigned)s.resident_parts, double(s.resident_bytes) / 1048576.0,
        double(s.bytes_read - before.bytes_read) / 1048576.0,
        double(result.rays) / result.seconds * 1e-6, seconds * 1e3);
    if (!a.frame_files.empty())
      outputs.write(a.frame_files[size_t(f)],
                    [&](const std::filesystem::path& to) { write_image(to, result.color); });
  }
  const double total =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const StreamCounters s = counters();
  std::printf(
      "total: %d frames in %.2f s (%.2f frames/s), %.2f MiB read (%.2f MiB/s), peak resident "
      "%.2f MiB, peak RSS %s\n",
      a.frames, total, double(a.frames) / total, double(s.bytes_read) / 1048576.0,
      double(s.bytes_read) / 1048576.0 / total, double(s.peak_resident_bytes) / 1048576.0,
      format_bytes(peak_rss_bytes()).c_str());
  outputs.write(a.output, [&](const std::filesystem::path& to) { write_image(to, result.color); });
  outputs.commit();
  return 0;
}

}  // namespace voxcast::cli
