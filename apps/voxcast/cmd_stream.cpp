// voxcast render WORLD --stream (stream_render.hpp).
#include <cstdio>

#include "cli_io.hpp"
#include "commands.hpp"
#include "stream_render.hpp"
#include "voxcast/brickmap_stream.hpp"
#include "voxcast/container.hpp"
#include "voxcast/error.hpp"
#include "voxcast/image.hpp"
#include "voxcast/scene_file.hpp"

namespace voxcast::cli {

void add_stream_options(CLI::App* cmd, StreamArgs& a) {
  cmd->add_flag("--stream", a.enabled,
                "Brickmap worlds: stream the bricks the rays ask for from the file within "
                "--budget, over --frames frames (per-frame Mrays/s and uploads printed)");
  cmd->add_option("--frames", a.frames,
                  "With --stream or a slice file: frames to render (the last is written)")
      ->capture_default_str();
  cmd->add_option("--budget", a.budget,
                  "With --stream: RAM for resident bricks and the chunk cache (half each; default "
                  "512M); slice files: memory for resident slices (default unlimited)");
  cmd->add_option("--uploads", a.uploads, "With --stream: bricks uploaded per pass at most")
      ->capture_default_str();
  cmd->add_option("--passes", a.passes,
                  "With --stream: passes per frame (1 = LOD colors until the bricks arrive in "
                  "later frames)")
      ->capture_default_str();
  cmd->add_flag("--no-hidden-removal", a.no_hidden_removal,
                "With --stream: upload voxels enclosed by solid neighbours too");
  cmd->add_flag("--dxt1", a.dxt1,
                "With --stream: keep the uploaded bricks' colors as DXT1 blocks (0.5 B per voxel "
                "instead of 4)");
}

int render_stream(const StreamArgs& a, const std::string& world, const std::string& output,
                  RenderOptions opt, const std::vector<Camera>& path,
                  const std::function<Camera(const Aabb&, int, int)>& auto_camera) {
  require_range("--frames", a.frames, 1, 1000000);
  require_range("--uploads", a.uploads, 1, 1 << 24);
  require_range("--passes", a.passes, 1, 1000);
  brickmap::StreamOptions so;
  so.budget_bytes =
      parse_memory_budget(a.budget.empty() ? std::string("512M") : a.budget, "--budget");
  so.uploads_per_pass = uint32_t(a.uploads);
  so.hidden_voxel_removal = !a.no_hidden_removal;
  so.dxt1 = a.dxt1;
  OutputSet outputs({world});
  outputs.add("-o", output, {".png", ".pfm"});
  require_regular_input(world, "world");
  // Another scene format is not a damaged world: the option does not apply.
  std::string format;
  try {
    format = scene_format(ContainerReader::open(world));
  } catch (const Error&) {
    // (damaged, or not a container: the world's own open below says which)
  }
  if (!format.empty() && format != "brickmap")
    throw UsageError("--stream: '" + printable(world) + "' is a scene of format " + format +
                     "; --stream renders brickmap worlds (ESVO slice files stream with --budget)");
  brickmap::StreamingWorld s(world, so);
  const Aabb occupied = s.world().occupied_bounds();
  opt.max_passes = a.passes;
  RenderResult last;
  uint64_t uploaded = 0;
  for (int k = 0; k < a.frames; ++k) {
    opt.camera = path.empty()
                     ? auto_camera(occupied, opt.width, opt.height)
                     : path[std::min(path.size() - 1, size_t(k) * path.size() / size_t(a.frames))];
    opt.frame = uint32_t(k);
    last = render(s, opt);
    const brickmap::StreamStats& st = s.stats();
    std::printf(
        "frame %d: %.2f Mrays/s, %llu bricks uploaded (%d pass%s), %llu resident (%s), %llu "
        "missing, chunk cache %s\n",
        k, double(last.rays) / last.seconds * 1e-6, (unsigned long long)(st.uploaded - uploaded),
        last.passes, last.passes == 1 ? "" : "es", (unsigned long long)(st.uploaded - st.evicted),
        format_bytes(double(st.resident_bytes)).c_str(), (unsigned long long)s.missing(),
        format_bytes(double(st.cache_bytes)).c_str());
    uploaded = st.uploaded;
  }
  const brickmap::StreamStats& st = s.stats();
  for (const brickmap::ChunkFailure& f : st.refused)
    std::fprintf(stderr, "voxcast: warning: %s refused: %s\n", printable(world).c_str(),
                 printable(f.reason).c_str());
  std::printf(
      "stream: %llu uploads, %llu evictions, %llu chunk loads, %llu hidden voxels dropped, peak "
      "resident %s of %s, peak cache %s of %s; chunk decode %s in %.3f s (%.2f GB/s; %.3f s "
      "of CPU time, %.2f GB/s)\n",
      (unsigned long long)st.uploaded, (unsigned long long)st.evicted,
      (unsigned long long)st.chunk_loads, (unsigned long long)st.hidden_voxels,
      format_bytes(double(st.peak_resident_bytes)).c_str(),
      format_bytes(double(s.brick_budget())).c_str(),
      format_bytes(double(st.peak_cache_bytes)).c_str(),
      format_bytes(double(s.cache_budget())).c_str(),
      format_bytes(double(st.decoded_bytes)).c_str(), st.decode_seconds,
      st.decode_seconds > 0 ? double(st.decoded_bytes) / st.decode_seconds * 1e-9 : 0.0,
      st.decode_cpu_seconds,
      st.decode_cpu_seconds > 0 ? double(st.decoded_bytes) / st.decode_cpu_seconds * 1e-9 : 0.0);
  outputs.write(output, [&](const std::filesystem::path& to) { write_image(to, last.color); });
  outputs.commit();
  return 0;
}

}  // namespace voxcast::cli
