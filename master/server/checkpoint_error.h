// The error of a state file that cannot be used (checkpoint.h).
#pragma once

#include <stdexcept>

namespace epr {

/// A state file that is missing, torn, corrupt or of another format version.
class CheckpointError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

}  // namespace epr
