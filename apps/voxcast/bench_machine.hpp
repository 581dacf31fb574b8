#pragma once
// The first lines of every benchmark report (`voxcast bench`, `voxcast
// volume bench`): every figure below them depends on the command and the
// machine.
#include <string>

namespace voxcast::cli {

/// The command line as the kernel has it (arguments joined by spaces).
std::string command_line();
/// "CPU model (family F, model M)" from /proc/cpuinfo.
std::string cpu_description();
/// The 1, 5 and 15 minute load averages ("A B C").
std::string load_average();
/// "CPU model (family F, model M), N logical CPUs, load average A B C".
std::string machine_line();
/// Prints "command     ..." and "machine     ..." on stdout.
void print_bench_header();

}  // namespace voxcast::cli
