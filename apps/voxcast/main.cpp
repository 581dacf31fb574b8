// voxcast: mesh -> sparse voxel structures -> CPU ray-cast images.
#include <embree3/rtcore_config.h>
#include <oneapi/tbb/global_control.h>

#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <new>
#include <sstream>
#include <vector>

#include "cli_io.hpp"
#include "commands.hpp"
#include "view/panel.hpp"
#include "voxcast/error.hpp"
#include "voxcast/format_registry.hpp"
#include "voxcast/progress.hpp"
#include "voxcast/version.hpp"

namespace voxcast::cli {

Vec3 parse_vec3(const std::string& text, const char* what) {
  std::vector<float> v;
  std::stringstream ss(text);
  std::string item;
  while (std::getline(ss, item, ',')) {
    char* end = nullptr;
    float f = std::strtof(item.c_str(), &end);
    if (item.empty() || end == item.c_str() || *end != 0 || !std::isfinite(f))
      throw UsageError(std::string(what) + ": '" + printable(text) +
                       "' is not x,y,z (three finite numbers)");
    v.push_back(f);
  }
  if (v.size() != 3 || (!text.empty() && text.back() == ','))
    throw UsageError(std::string(what) + ": '" + printable(text) +
                     "' is not x,y,z (three finite numbers)");
  return {v[0], v[1], v[2]};
}

bool parse_dims(const std::string& text, int n, int64_t lo, int64_t hi, int64_t* out) {
  const char* p = text.data();
  const char* const end = p + text.size();
  for (int i = 0; i < n; ++i) {
    if (i > 0) {
      if (p == end || (*p != 'x' && *p != 'X')) return false;
      ++p;
    }
    if (p == end || *p < '0' || *p > '9') return false;  // (from_chars would take a '-')
    int64_t v = 0;
    const auto [q, ec] = std::from_chars(p, end, v);
    if (ec != std::errc() || v < lo || v > hi) return false;  // out of range: not wrapped
    out[i] = v;
    p = q;
  }
  return p == end;
}

void parse_size(const std::string& text, int* width, int* height, const char* what) {
  int64_t v[2];
  if (!parse_dims(text, 2, 1, 16384, v))
    throw UsageError(std::string(what) + ": '" + printable(text) +
                     "' is not WxH with 1 <= W, H <= 16384");
  *width = int(v[0]);
  *height = int(v[1]);
}

struct ThreadLimit::Impl {
  tbb::global_control control;
};
ThreadLimit::ThreadLimit(int threads) {
  require_range("--threads", threads, 0, 4096);
  if (threads > 0)
    impl = new Impl{tbb::global_control(tbb::global_control::max_allowed_parallelism, threads)};
}
ThreadLimit::~ThreadLimit() {
  delete impl;
}

}  // namespace voxcast::cli

int main(int argc, char** argv) {
  using namespace voxcast::cli;
  // Every scene format before any option is declared (`build --format` lists them).
  voxcast::register_builtin_formats();
  CLI::App app{
      "voxcast: voxelize triangle meshes into sparse voxel octrees and ray cast them on the CPU"};
  app.require_subcommand(1);
  // Version, build type, ISA (baseline and the dispatched kernels') and the
  // libraries linked in.
  app.set_version_flag("--version", [] {
    return voxcast::build_description() + voxcast::io_library_versions() +
           voxcast::view::view_library_versions() +
           "stb_image (Debian's libstb-dev header, compiled in)\nEmbree " + RTC_VERSION_STRING +
           " (oracle: bench only)\nCLI11 " + CLI11_VERSION;
  });
  app.get_formatter()->column_width(36);
  std::vector<std::pair<CLI::App*, Runner>> commands;
  // --quiet on every subcommand (and sub-subcommand): no progress bars and
  // no warnings; errors and the command's own output stay.
  std::function<void(CLI::App*)> add_quiet = [&](CLI::App* sub) {
    sub->add_flag_callback(
        "-q,--quiet", [] { voxcast::Progress::set_quiet(true); },
        "No progress bars or warnings on stderr (errors and results stay)");
    for (CLI::App* child : sub->get_subcommands({})) add_quiet(child);
  };
  auto add = [&](Runner (*fn)(CLI::App&)) {
    size_t before = app.get_subcommands({}).size();
    Runner r = fn(app);
    CLI::App* sub = app.get_subcommands({})[before];
    add_quiet(sub);
    commands.emplace_back(sub, std::move(r));
  };
  add(add_build);
  add(add_render);
  add(add_info);
  add(add_bench);
  add(add_generate);
  add(add_view);
  add(add_volume);
  add(add_convert);
  add(add_edit);
  // One convention (README "Command line"): a usage error is one line and
  // exit 2, a runtime error one line and exit 1; --help prints the help.
  auto error_line = [](const std::string& message) {
    // A message quoting a huge value (a 2 MB batch line) keeps its start and
    // end: one line a terminal can show, cut between UTF-8 characters.
    std::string line = printable(message);
    constexpr size_t kHead = 400, kTail = 100;
    if (line.size() > kHead + kTail + 40) {
      size_t head = kHead, tail = line.size() - kTail;
      while (head > 0 && (static_cast<unsigned char>(line[head]) & 0xC0) == 0x80) --head;
      while (tail < line.size() && (static_cast<unsigned char>(line[tail]) & 0xC0) == 0x80) ++tail;
      line = line.substr(0, head) + " [... " + std::to_string(tail - head) + " bytes ...] " +
             line.substr(tail);
    }
    std::fprintf(stderr, "voxcast: error: %s\n", line.c_str());
  };
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    // The message and where to read more, not the whole help text: the
    // mistake would scroll out of sight.
    CLI::App* which = nullptr;
    for (auto& [sub, run] : commands)
      if (sub->parsed()) which = sub;
    std::string message = e.what();
    if (!which && app.get_subcommands().empty() && message.find("subcommand") != std::string::npos)
      message =
          "a subcommand is required: build, render, info, bench, generate, view, volume or convert";
    error_line(message + " (see 'voxcast" + (which ? " " + which->get_name() : std::string()) +
               " --help')");
    return 2;
  }
  try {
    for (auto& [sub, run] : commands)
      if (sub->parsed()) return run();
  } catch (const UsageError& e) {
    error_line(e.what());
    return 2;
  } catch (const voxcast::Error& e) {
    error_line(e.what());
    return 1;
  } catch (const std::bad_alloc&) {
    error_line("out of memory (lower --resolution or --size)");
    return 1;
  } catch (const std::exception& e) {
    error_line(e.what());
    return 1;
  }
  return 2;
}
