// The one main() of voxcast_microbench (every bench/*.cpp links into it).
#include <benchmark/benchmark.h>

BENCHMARK_MAIN();
