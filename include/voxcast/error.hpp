#pragma once
// Every failure a user can cause (bad files, bad options, exhausted budgets)
// is reported as voxcast::Error with a one-line, human-readable message.
#include <stdexcept>
#include <string>

namespace voxcast {

class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

}  // namespace voxcast
