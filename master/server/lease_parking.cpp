#include "master/server/lease_parking.h"

namespace epr {

uint64_t LeaseParking::park(const std::string& worker, int64_t deadline_ms, Answer answer) {
  const uint64_t handle = next_++;
  parked_[handle] = {worker, deadline_ms, std::move(answer)};
  return handle;
}

void LeaseParking::stop() {
  stopped_ = true;
  // No tile is handed out now whose result could not come back.
  for (auto& [handle, p] : parked_) due_.emplace_back(std::move(p.answer), LeaseWait{1000});
  parked_.clear();
}

void LeaseParking::wake(bool all, int64_t now_ms, const Decide& decide,
                        const std::function<bool(const std::string&)>& prefer) {
  std::vector<uint64_t> order, later;
  for (const auto& [handle, p] : parked_) (prefer && prefer(p.worker) ? order : later).push_back(handle);
  order.insert(order.end(), later.begin(), later.end());
  for (uint64_t handle : order) {
    auto it = parked_.find(handle);
    bool parkable = false;
    LeaseDecision d = decide(it->second.worker, &parkable);
    if (parkable && !all && now_ms < it->second.deadline_ms) continue;
    if (parkable) d = LeaseWait{1};  // out of time: ask again at once (a job may start any moment)
    due_.emplace_back(std::move(it->second.answer), std::move(d));
    parked_.erase(it);
  }
}

}  // namespace epr
