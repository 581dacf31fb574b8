// The one list of built-in scene formats (format_registry.hpp). A new
// structure module adds its register_format() call here and nowhere else;
// this module, not src/io, is the one that links every structure.
#include <mutex>

#include "voxcast/brickmap.hpp"
#include "voxcast/dag_format.hpp"
#include "voxcast/esvo_format.hpp"
#include "voxcast/esvo_slices.hpp"
#include "voxcast/format_registry.hpp"

namespace voxcast {

void register_builtin_formats() {
  static std::once_flag once;
  std::call_once(once, [] {
    FormatRegistry& r = format_registry();
    esvo::register_format(r);
    dag::register_format(r);
    brickmap::register_format(r);
    esvo::register_sliced_format(r);  // slice files (a file type of their own)
  });
}

}  // namespace voxcast
