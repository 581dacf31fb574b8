// Registers the built-in scene formats before any test runs, as the CLI's
// main() does. Linked into every test executable as an object file: in the
// static support library an unreferenced initializer would be dropped.
#include "voxcast/format_registry.hpp"

namespace {
const bool registered = (voxcast::register_builtin_formats(), true);
}  // namespace
