#pragma once
// Each subcommand registers itself on the CLI11 app and returns the callback
// that runs it once the command line has been parsed.
#include <CLI/CLI.hpp>
#include <functional>
#include <string>

#include "voxcast/math.hpp"

namespace voxcast::cli {

using Runner = std::function<int()>;

Runner add_build(CLI::App& app);
Runner add_render(CLI::App& app);
Runner add_info(CLI::App& app);
Runner add_bench(CLI::App& app);
Runner add_generate(CLI::App& app);
Runner add_view(CLI::App& app);
Runner add_volume(CLI::App& app);  // cmd_volume.cpp: voxcast volume render
Runner add_convert(CLI::App& app);
Runner add_edit(CLI::App& app);

/// "x,y,z" -> Vec3; throws voxcast::Error.
Vec3 parse_vec3(const std::string& text, const char* what);
/// "WxH" -> width, height (1..16384 each); throws a UsageError naming
/// `what` (the option).
void parse_size(const std::string& text, int* width, int* height, const char* what = "--size");
/// n decimal integers separated by 'x' or 'X' ("640x480", "64x64x16", "300"),
/// nothing else (no sign, space or other text); false when the text is not
/// that or a value is out of [lo, hi] (never wrapped).
bool parse_dims(const std::string& text, int n, int64_t lo, int64_t hi, int64_t* out);
/// Human-readable byte count ("12.3 MiB").
std::string format_bytes(double bytes);
/// Limits TBB to `threads` workers for the lifetime of the returned object (0 = all cores).
struct ThreadLimit {
  explicit ThreadLimit(int threads);
  ~ThreadLimit();
  struct Impl;
  Impl* impl = nullptr;
};

}  // namespace voxcast::cli
