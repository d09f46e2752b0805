// The programs the cluster tests run (paths compiled in by tests/CMakeLists.txt) and their argv type.
#pragma once

#include <string>
#include <vector>

namespace epr::testing {

using Args = std::vector<std::string>;

inline const std::string kEpr = EPR_CLIENT_BIN;
inline const std::string kMaster = EPR_MASTER_BIN;
inline const std::string kWorker = EPR_WORKER_BIN;

}  // namespace epr::testing
