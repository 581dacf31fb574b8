// The command and machine lines of the benchmark reports (bench_machine.hpp).
#include "bench_machine.hpp"

#include <cstdio>
#include <fstream>
#include <iterator>
#include <thread>

#include "cli_io.hpp"

namespace voxcast::cli {
namespace {

// The value of the first line of a /proc file that starts with `key`
// ("key<TAB>: value"), or the whole first line for an empty key.
std::string first_line_of(const char* path, const std::string& key) {
  std::ifstream in(path);
  std::string line;
  while (std::getline(in, line)) {
    if (key.empty()) return line;
    if (line.rfind(key, 0) != 0) continue;
    const size_t colon = line.find(':');
    const size_t v = colon == std::string::npos ? colon : line.find_first_not_of(" \t", colon + 1);
    return v == std::string::npos ? std::string() : line.substr(v);
  }
  return "unknown";
}

}  // namespace

// The command line as the kernel has it (arguments NUL-separated).
std::string command_line() {
  std::ifstream in("/proc/self/cmdline", std::ios::binary);
  std::string all((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>()), out;
  for (char c : all) out += c ? c : ' ';
  while (!out.empty() && out.back() == ' ') out.pop_back();
  return out;
}

std::string cpu_description() {
  // "AMD EPYC" alone does not tell Zen generations apart: add family/model.
  return first_line_of("/proc/cpuinfo", "model name") + " (family " +
         first_line_of("/proc/cpuinfo", "cpu family") + ", model " +
         first_line_of("/proc/cpuinfo", "model\t") + ")";
}

std::string load_average() {
  std::string load = first_line_of("/proc/loadavg", "");  // the 1, 5, 15 min averages
  for (int spaces = 0, i = 0; i < int(load.size()); ++i)
    if (load[size_t(i)] == ' ' && ++spaces == 3) load.resize(size_t(i));
  return load;
}

std::string machine_line() {
  return cpu_description() + ", " + std::to_string(std::thread::hardware_concurrency()) +
         " logical CPUs, load average " + load_average();
}

void print_bench_header() {
  std::printf("command     %s\n", printable(command_line()).c_str());
  std::printf("machine     %s\n", machine_line().c_str());
}

}  // namespace voxcast::cli
