#include "support/cli_runner.hpp"

#include <sys/wait.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <stdexcept>

namespace voxcast::testing {

namespace {
CliResult run_command(const std::string& cmd) {
  CliResult r;
  FILE* p = popen(cmd.c_str(), "r");
  if (!p) throw std::runtime_error("popen failed");
  char buf[4096];
  size_t n;
  while ((n = fread(buf, 1, sizeof buf, p)) > 0) r.output.append(buf, n);
  int status = pclose(p);
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  return r;
}
}  // namespace

CliResult run_cli(const std::string& args) {
  return run_command(std::string("'") + VOXCAST_CLI_PATH + "' " + args + " 2>&1 </dev/null");
}

CliResult run_cli_split(const std::string& args, int timeout_seconds) {
  TempDir dir;
  const std::string err = dir.file("stderr");
  CliResult r = run_command("timeout -k 5 " + std::to_string(timeout_seconds) + " '" +
                            VOXCAST_CLI_PATH + "' " + args + " 2>'" + err + "' </dev/null");
  r.errors = read_text(err);
  return r;
}

TempDir::TempDir() {
  std::random_device rd;
  auto base = std::filesystem::temp_directory_path();
  for (int i = 0; i < 100; ++i) {
    auto p = base / ("voxcast-test-" + std::to_string(rd()));
    if (std::filesystem::create_directory(p)) {
      path = p.string();
      return;
    }
  }
  throw std::runtime_error("cannot create a temporary directory");
}

TempDir::~TempDir() {
  std::error_code ec;
  std::filesystem::remove_all(path, ec);
}

std::string read_text(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

void write_text(const std::string& path, const std::string& text) {
  std::ofstream f(path, std::ios::binary);
  f << text;
}

}  // namespace voxcast::testing
