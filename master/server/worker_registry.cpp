#include "master/server/worker_registry.h"

#include <fmt/format.h>

#include <algorithm>

#include "common/log.h"

namespace epr {

std::string WorkerRegistry::add(const std::string& name, uint32_t threads, std::set<std::string> cached_scenes,
                                int64_t now_ms) {
  Worker w;
  w.id = fmt::format("w{}-{:04x}", next_++, uint32_t(now_ms) & 0xffff);
  w.name = name;
  w.threads = std::max(1u, threads);
  w.last_seen_ms = now_ms;
  w.cached_scenes = std::move(cached_scenes);
  const std::string id = w.id;
  logger("master")->info("worker {} ({}, {} threads) registered", id, name, threads);
  workers_[id] = std::move(w);
  return id;
}

WorkerRegistry::Worker* WorkerRegistry::touch(const std::string& id, int64_t now_ms) {
  Worker* w = find(id);
  if (w) w->last_seen_ms = now_ms;
  return w;
}

WorkerRegistry::Worker* WorkerRegistry::find(const std::string& id) {
  auto it = workers_.find(id);
  return it == workers_.end() ? nullptr : &it->second;
}

void WorkerRegistry::drop_lease(uint64_t lease) {
  for (auto& [id, w] : workers_) w.leases.erase(lease);
}

std::vector<std::string> WorkerRegistry::forget_silent(int64_t now_ms, int timeout_ms) {
  std::vector<std::string> gone;
  for (auto it = workers_.begin(); it != workers_.end();) {
    if (now_ms - it->second.last_seen_ms > timeout_ms) {
      logger("master")->warn("worker {} silent for {} ms: forgotten", it->first, now_ms - it->second.last_seen_ms);
      gone.push_back(it->first);
      it = workers_.erase(it);
    } else {
      ++it;
    }
  }
  return gone;
}

void WorkerRegistry::credit(const std::string& id, uint64_t paths, double seconds_tracing) {
  if (Worker* w = find(id)) {
    ++w->tiles_committed;
    w->paths += paths;
    w->seconds_tracing += seconds_tracing;
  }
}

std::vector<std::string> WorkerRegistry::ids() const {
  std::vector<std::string> out;
  for (const auto& [id, w] : workers_) out.push_back(id);
  return out;
}

size_t WorkerRegistry::busy() const {
  return size_t(
      std::count_if(workers_.begin(), workers_.end(), [](const auto& kv) { return !kv.second.leases.empty(); }));
}

std::vector<WorkerSnapshot> WorkerRegistry::snapshot(int64_t now_ms) const {
  std::vector<WorkerSnapshot> out;
  for (const auto& [id, w] : workers_) {
    WorkerSnapshot s;
    s.id = id;
    s.name = w.name;
    s.threads = w.threads;
    s.heartbeat_age_seconds = double(now_ms - w.last_seen_ms) / 1000.0;
    s.tiles_committed = w.tiles_committed;
    s.paths_traced = w.paths;
    s.paths_per_second = w.seconds_tracing > 0 ? double(w.paths) / w.seconds_tracing : 0.0;
    s.leases_held = w.leases.size();
    out.push_back(s);
  }
  return out;
}

}  // namespace epr
