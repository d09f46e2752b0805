// The leases of one running job: which tiles of the current round wait, which are out and with whom,
// speculative copies of tiles whose lease runs long, expiry, and the failures counted against
// workers (with the blocklist they lead to).
//
// Policy:
//  - Tiles are leased in the order the round gives (most active pixels first); a tile given back or
//    expired goes to the front.
//  - Every lease has its own deadline, lease_timeout_ms after it was granted or last extended.
//  - Once no tile waits, an idle worker gets a copy of the tile whose lease has run longest, if that
//    is longer than speculative_floor_ms and speculative_factor x the median lease-to-commit time of
//    the round (of the previous round while none of this one is committed), its holder is alive (a
//    heartbeat within 1.5 heartbeat intervals) and the asker does not hold it. One copy per tile and
//    round; the first complete result wins and the other leases lose.
//  - A lease that expires, a result refused as invalid and a failure a worker reports count against
//    the worker; at max_worker_failures it gets no more tiles of the job.
//  - A lease that expires (its worker vanished: crashed, killed or cut off; a worker that stops
//    gracefully gives its leases back instead) counts against the tile, across rounds: at
//    max_tile_losses the tile is handed out no more and lost_tile() names it (the JobManager fails
//    the job), so a tile that crashes every worker taking it does not take the farm with it.
// Not thread-safe: the JobManager calls it under its mutex. Time comes from an injected clock, so the
// policy is tested without gRPC and without sleeping.
#pragma once

#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <unordered_map>
#include <vector>

#include "master/server/job_counters.h"

namespace epr {

/// Milliseconds on some fixed scale (the system clock's Unix time in the master).
using MillisClock = std::function<int64_t()>;
int64_t unix_ms();

/// Why a worker gives a lease back (ReturnLeaseRequest.failure).
enum class LeaseFailure { kNone, kScene, kTile, kInvalidResult, kExpired };

struct LeasePolicy {
  int lease_timeout_ms = 20000;
  int heartbeat_interval_ms = 1000;
  double speculative_factor = 2.0;  // <= 0: no speculative copies
  int speculative_floor_ms = 1000;
  int max_worker_failures = 3;  // <= 0: never block
  int max_tile_losses = 3;      // <= 0: never give a tile up
};

class LeaseTable {
 public:
  /// `counters` (the job's) receives tiles_leased, tiles_re_leased, tiles_speculative and
  /// worker_failures; it must outlive the table. `job_id` names the job in log lines.
  LeaseTable(std::string job_id, size_t tiles, LeasePolicy policy, MillisClock clock, JobCounters* counters);

  /// Starts round `round`: `order` lists the tiles that trace, in leasing order; the rest are idle.
  void open_round(uint32_t round, const std::vector<uint32_t>& order);
  uint32_t round() const { return round_; }
  size_t tile_count() const { return slots_.size(); }
  size_t waiting() const { return pending_.size(); }
  /// Leases out (speculative copies included): the job's share of the workers right now.
  size_t out() const { return tile_of_.size(); }
  /// Tiles of the round not yet committed (waiting or out).
  size_t uncommitted() const { return round_tiles_ - committed_; }
  /// Distinct workers holding a lease of this job.
  size_t holders() const;
  /// The id of the last lease granted (0: none yet); lease ids grow, so the job served least recently
  /// has the smallest.
  uint64_t last_lease() const { return last_lease_; }

  struct Grant {
    uint32_t tile = 0;
    int64_t deadline_ms = 0;
    bool speculative = false;
  };
  /// A tile for `worker` under the new lease id `lease`: the first waiting tile, else a speculative
  /// copy (see the policy); nullopt if there is none. Call only for workers not blocked().
  std::optional<Grant> lease(const std::string& worker, uint64_t lease);
  bool blocked(const std::string& worker) const { return blocked_.count(worker) > 0; }
  size_t blocked_count() const { return blocked_.size(); }

  /// Extends a lease that is out; its new deadline, or nullopt if it is not (lost, committed, expired).
  std::optional<int64_t> extend(uint64_t lease);
  /// True if `lease` was granted for `tile` in this round (a result must name one).
  bool issued(uint32_t tile, uint64_t lease) const;

  enum class CommitOutcome { kCommitted, kDuplicate };
  /// The result of `lease` for `tile`: the first wins; every other lease of the tile loses and is
  /// appended to `losers` (their holders are told "not wanted"). Idle or already committed: duplicate.
  CommitOutcome commit(uint32_t tile, uint64_t lease, std::vector<uint64_t>* losers);

  /// Gives `lease` back (a no-op if it is not out). With a failure, it counts against `worker` if the
  /// lease is the worker's own. True if the lease was out.
  bool release(uint64_t lease, const std::string& worker, LeaseFailure failure, const std::string& reason);

  struct Expired {
    uint32_t tile = 0;
    uint64_t lease = 0;
    std::string worker;
  };
  /// Releases every lease past its deadline and counts a failure against its holder.
  std::vector<Expired> expire();

  /// A tile whose leases expired max_tile_losses times (the first such tile), and that count.
  struct LostTile {
    uint32_t tile = 0;
    int losses = 0;
  };
  std::optional<LostTile> lost_tile() const { return lost_tile_; }

  /// The reason the job cannot go on if every one of `workers` is blocked for it, else nullopt.
  std::optional<std::string> all_blocked(const std::vector<std::string>& workers) const;

 private:
  struct Hold {
    std::string worker;
    int64_t since_ms = 0, deadline_ms = 0;
    int64_t seen_ms = 0;  // granted or last extended
  };
  struct Slot {
    enum class State { kIdle, kPending, kLeased, kCommitted } state = State::kIdle;
    std::map<uint64_t, Hold> holds;  // the leases out for this tile
    std::set<uint64_t> issued;       // every lease of the tile this round
    bool re_leased = false;          // given back or expired once this round
    bool speculated = false;         // a speculative copy went out this round
  };

  std::optional<uint32_t> speculative_tile(const std::string& worker, int64_t now) const;
  void drop_hold(uint32_t tile, uint64_t lease);  // back to waiting once no lease is out
  void count_failure(const std::string& worker, LeaseFailure failure, const std::string& reason);

  std::string job_id_;
  LeasePolicy policy_;
  MillisClock clock_;
  JobCounters* counters_;
  uint32_t round_ = 0;
  std::vector<Slot> slots_;
  std::deque<uint32_t> pending_;
  size_t round_tiles_ = 0, committed_ = 0;  // tiles tracing this round, and committed of them
  uint64_t last_lease_ = 0;
  std::unordered_map<uint64_t, uint32_t> tile_of_;  // leases out -> tile
  // Lease-to-commit times (ms) of round tile_ms_round_: drive the speculative threshold.
  uint32_t tile_ms_round_ = 0;
  std::vector<int64_t> tile_ms_;
  std::map<std::string, int> failures_;  // worker -> failed leases of this job
  std::set<std::string> blocked_, scene_failed_;
  std::string last_failure_;
  std::map<uint32_t, int> losses_;  // tile -> leases of it that expired, over every round
  std::optional<LostTile> lost_tile_;
};

}  // namespace epr
