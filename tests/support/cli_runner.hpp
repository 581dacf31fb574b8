#pragma once
// Runs the voxcast CLI as a user would and captures what it prints.
#include <string>

namespace voxcast::testing {

struct CliResult {
  int exit_code = -1;
  std::string output;  // stdout and stderr interleaved (run_cli_split: stdout only)
  std::string errors;  // run_cli_split only: stderr
};

/// Runs `voxcast <args>` (args are passed to /bin/sh, quote as needed).
CliResult run_cli(const std::string& args);
/// The same with stdout and stderr apart, killed after `timeout_seconds`
/// (exit code 124 then): for checks of what goes where and of hangs.
CliResult run_cli_split(const std::string& args, int timeout_seconds = 60);

/// A fresh, empty temporary directory removed by the destructor.
struct TempDir {
  TempDir();
  ~TempDir();
  std::string path;
  std::string file(const std::string& name) const { return path + "/" + name; }
};

std::string read_text(const std::string& path);
void write_text(const std::string& path, const std::string& text);

}  // namespace voxcast::testing
