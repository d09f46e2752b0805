#include "master/server/lease_table.h"

#include <fmt/format.h>

#include <algorithm>
#include <chrono>

#include "common/check.h"
#include "common/log.h"

namespace epr {

int64_t unix_ms() {
  return std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::system_clock::now().time_since_epoch())
      .count();
}

LeaseTable::LeaseTable(std::string job_id, size_t tiles, LeasePolicy policy, MillisClock clock, JobCounters* counters)
    : job_id_(std::move(job_id)), policy_(policy), clock_(std::move(clock)), counters_(counters), slots_(tiles) {
  EPR_CHECK(counters_ != nullptr);
}

void LeaseTable::open_round(uint32_t round, const std::vector<uint32_t>& order) {
  round_ = round;
  tile_of_.clear();
  slots_.assign(slots_.size(), Slot{});
  pending_.assign(order.begin(), order.end());
  round_tiles_ = order.size();
  committed_ = 0;
  for (uint32_t t : order) {
    EPR_CHECK(t < slots_.size());
    slots_[t].state = Slot::State::kPending;
  }
}

std::optional<LeaseTable::Grant> LeaseTable::lease(const std::string& worker, uint64_t lease) {
  EPR_CHECK(!blocked(worker));
  const int64_t now = clock_();
  std::optional<uint32_t> speculative;
  if (pending_.empty() && !(speculative = speculative_tile(worker, now))) return std::nullopt;
  if (lost_tile_) return std::nullopt;  // the job is failing: no tile goes out again
  const uint32_t t = speculative ? *speculative : pending_.front();
  if (!speculative) pending_.pop_front();
  Slot& slot = slots_[t];
  slot.state = Slot::State::kLeased;
  slot.issued.insert(lease);
  slot.holds[lease] = {worker, now, now + policy_.lease_timeout_ms, now};
  tile_of_[lease] = t;
  last_lease_ = lease;
  ++counters_->tiles_leased;
  if (speculative) {
    slot.speculated = true;
    ++counters_->tiles_speculative;
    logger("master")->info("job {} round {} tile {}: lease runs long, speculative copy to worker {}", job_id_, round_,
                           t, worker);
  } else if (slot.re_leased) {
    ++counters_->tiles_re_leased;
  }
  return Grant{t, now + policy_.lease_timeout_ms, speculative.has_value()};
}

std::optional<uint32_t> LeaseTable::speculative_tile(const std::string& worker, int64_t now) const {
  // Nothing to compare with before the first commit (of this round or the previous one).
  if (policy_.speculative_factor <= 0 || tile_ms_.empty()) return std::nullopt;
  // A dead holder's tile comes back when its lease expires, not as a copy.
  const int64_t alive_ms = int64_t(policy_.heartbeat_interval_ms) * 3 / 2;
  std::optional<uint32_t> best;
  int64_t best_age = -1;
  for (uint32_t t = 0; t < slots_.size(); ++t) {
    const Slot& slot = slots_[t];
    if (slot.state != Slot::State::kLeased || slot.speculated || slot.holds.empty()) continue;
    int64_t since = now;
    bool own = false, alive = false;
    for (const auto& [id, h] : slot.holds) {
      since = std::min(since, h.since_ms);
      own |= h.worker == worker;
      alive |= now - h.seen_ms <= alive_ms;
    }
    if (!own && alive && now - since > best_age) {
      best = t;
      best_age = now - since;
    }
  }
  if (!best || best_age <= policy_.speculative_floor_ms) return std::nullopt;
  std::vector<int64_t> times = tile_ms_;
  std::nth_element(times.begin(), times.begin() + ptrdiff_t(times.size() / 2), times.end());
  const double median = double(times[times.size() / 2]);
  if (double(best_age) <= policy_.speculative_factor * median) return std::nullopt;
  return best;
}

std::optional<int64_t> LeaseTable::extend(uint64_t lease) {
  auto it = tile_of_.find(lease);
  if (it == tile_of_.end()) return std::nullopt;
  Hold& h = slots_[it->second].holds.at(lease);
  const int64_t now = clock_();
  h.deadline_ms = now + policy_.lease_timeout_ms;
  h.seen_ms = now;
  return h.deadline_ms;
}

bool LeaseTable::issued(uint32_t tile, uint64_t lease) const {
  return tile < slots_.size() && slots_[tile].issued.count(lease) > 0;
}

LeaseTable::CommitOutcome LeaseTable::commit(uint32_t tile, uint64_t lease, std::vector<uint64_t>* losers) {
  EPR_CHECK(tile < slots_.size());
  Slot& slot = slots_[tile];
  if (slot.state == Slot::State::kCommitted || slot.state == Slot::State::kIdle) return CommitOutcome::kDuplicate;
  // Its lease had expired and the tile went back to waiting: this result still wins.
  if (slot.state == Slot::State::kPending)
    pending_.erase(std::remove(pending_.begin(), pending_.end(), tile), pending_.end());
  if (auto h = slot.holds.find(lease); h != slot.holds.end()) {
    if (tile_ms_round_ != round_) tile_ms_.clear();
    tile_ms_round_ = round_;
    tile_ms_.push_back(clock_() - h->second.since_ms);
  }
  for (const auto& [id, h] : slot.holds) {
    tile_of_.erase(id);
    if (id != lease) losers->push_back(id);
  }
  slot.holds.clear();
  slot.state = Slot::State::kCommitted;
  ++committed_;
  return CommitOutcome::kCommitted;
}

size_t LeaseTable::holders() const {
  std::set<std::string> workers;
  for (const auto& [lease, tile] : tile_of_) workers.insert(slots_[tile].holds.at(lease).worker);
  return workers.size();
}

void LeaseTable::drop_hold(uint32_t t, uint64_t lease) {
  Slot& slot = slots_[t];
  slot.holds.erase(lease);
  tile_of_.erase(lease);
  if (slot.state == Slot::State::kLeased && slot.holds.empty()) {
    slot.state = Slot::State::kPending;
    slot.re_leased = true;
    pending_.push_front(t);
  }
}

bool LeaseTable::release(uint64_t lease, const std::string& worker, LeaseFailure failure, const std::string& reason) {
  auto it = tile_of_.find(lease);
  if (it == tile_of_.end()) return false;
  const uint32_t t = it->second;
  const bool own = slots_[t].holds.at(lease).worker == worker;
  drop_hold(t, lease);
  if (failure != LeaseFailure::kNone && own) count_failure(worker, failure, reason);
  return true;
}

std::vector<LeaseTable::Expired> LeaseTable::expire() {
  const int64_t now = clock_();
  std::vector<Expired> expired;
  for (uint32_t t = 0; t < slots_.size(); ++t)
    for (const auto& [id, h] : slots_[t].holds)
      if (h.deadline_ms < now) expired.push_back({t, id, h.worker});
  auto log = logger("master");
  for (const Expired& e : expired) {
    if (slots_[e.tile].holds.size() == 1)
      log->warn("job {} tile {}: lease expired, re-queued (lease {}, worker {})", job_id_, e.tile, e.lease, e.worker);
    else
      log->warn("job {} tile {}: lease {} of worker {} expired; another lease of the tile is still out", job_id_,
                e.tile, e.lease, e.worker);
    drop_hold(e.tile, e.lease);
    count_failure(e.worker, LeaseFailure::kExpired, fmt::format("lease of tile {} expired without a result", e.tile));
    const int losses = ++losses_[e.tile];
    if (policy_.max_tile_losses > 0 && losses >= policy_.max_tile_losses && !lost_tile_) {
      lost_tile_ = LostTile{e.tile, losses};
      log->error("job {} tile {}: its lease expired {} times (its workers vanished): the tile is given up", job_id_,
                 e.tile, losses);
    }
  }
  return expired;
}

void LeaseTable::count_failure(const std::string& worker, LeaseFailure failure, const std::string& reason) {
  const int n = ++failures_[worker];
  ++counters_->worker_failures;
  if (failure == LeaseFailure::kScene) scene_failed_.insert(worker);
  last_failure_ = reason;
  auto log = logger("master");
  log->warn("job {}: worker {} failed a tile ({} so far): {}", job_id_, worker, n, reason);
  if (policy_.max_worker_failures > 0 && n >= policy_.max_worker_failures && blocked_.insert(worker).second)
    log->warn("job {}: worker {} failed {} tiles and gets no more tiles of this job", job_id_, worker, n);
}

std::optional<std::string> LeaseTable::all_blocked(const std::vector<std::string>& workers) const {
  if (blocked_.empty() || workers.empty()) return std::nullopt;
  bool all_scene = true;
  for (const auto& id : workers) {
    if (!blocked_.count(id)) return std::nullopt;
    all_scene &= scene_failed_.count(id) > 0;
  }
  const int limit = policy_.max_worker_failures;
  if (all_scene)
    return fmt::format("no worker could load the job's scene ({} worker(s) tried {} times each); last error: {}",
                       workers.size(), limit, last_failure_);
  return fmt::format("every registered worker ({}) failed {} tiles of the job and is blocked for it; last failure: {}",
                     workers.size(), limit, last_failure_);
}

}  // namespace epr
