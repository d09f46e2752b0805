#include "worker/master_targets.h"

namespace epr {

const char* to_string(MasterState s) {
  switch (s) {
    case MasterState::kConnecting:
      return "connecting";
    case MasterState::kConnected:
      return "connected";
    case MasterState::kBackingOff:
      return "backing off";
    case MasterState::kRefused:
      return "refused";
    case MasterState::kLeaving:
      return "leaving";
  }
  return "?";
}

}  // namespace epr
