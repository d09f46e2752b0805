// The workers a master knows: registration, when each was last heard from, the leases each holds and
// what it has done. A worker silent for longer than the worker timeout is forgotten (its leases then
// expire in their jobs' lease tables). Not thread-safe: the JobManager calls it under its mutex.
#pragma once

#include <cstdint>
#include <map>
#include <set>
#include <string>
#include <vector>

namespace epr {

struct WorkerSnapshot {
  std::string id, name;
  uint32_t threads = 0;
  double heartbeat_age_seconds = 0;
  uint64_t tiles_committed = 0, paths_traced = 0;
  double paths_per_second = 0;  // over its committed tiles' tracing time
  size_t leases_held = 0;
};

class WorkerRegistry {
 public:
  struct Worker {
    std::string id, name;
    uint32_t threads = 1;
    int64_t last_seen_ms = 0;
    std::set<uint64_t> leases;
    std::set<std::string> cached_scenes;  // scene hashes the worker holds (WorkerInfo.cached_scenes)
    uint64_t tiles_committed = 0, paths = 0;
    double seconds_tracing = 0;
  };

  /// A new worker's id.
  std::string add(const std::string& name, uint32_t threads, std::set<std::string> cached_scenes, int64_t now_ms);
  void remove(const std::string& id) { workers_.erase(id); }
  /// The worker, seen now; nullptr if unknown.
  Worker* touch(const std::string& id, int64_t now_ms);
  Worker* find(const std::string& id);
  /// Drops `lease` from whoever holds it.
  void drop_lease(uint64_t lease);
  /// Forgets the workers silent for more than `timeout_ms`; their ids.
  std::vector<std::string> forget_silent(int64_t now_ms, int timeout_ms);
  /// Counts a committed tile of `id` (if it is still known).
  void credit(const std::string& id, uint64_t paths, double seconds_tracing);

  std::vector<std::string> ids() const;
  bool empty() const { return workers_.empty(); }
  /// Workers holding at least one lease.
  size_t busy() const;
  std::vector<WorkerSnapshot> snapshot(int64_t now_ms) const;

 private:
  std::map<std::string, Worker> workers_;
  uint64_t next_ = 1;
};

}  // namespace epr
