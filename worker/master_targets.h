// The masters a worker serves (epr-worker --master, parsed and resolved by wire/rpc/master_list.h)
// and how the worker's status names each one's link.
#pragma once

#include <string>

#include "wire/rpc/master_list.h"

namespace epr {

/// A master's link as the status shows it.
enum class MasterState { kConnecting, kConnected, kBackingOff, kRefused, kLeaving };
const char* to_string(MasterState s);

struct MasterStatus {
  std::string name;  // MasterEndpoint::name
  MasterState state = MasterState::kConnecting;
  std::string worker_id;  // the id this master gave the worker at its last registration
  std::string detail;     // the last error, or the reason of a refusal
};

}  // namespace epr
