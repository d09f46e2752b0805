// JobManager's scheduling across the running jobs (job_manager.h, "Several jobs at once"): which
// queued job may start beside the running ones (the memory budget), which running job a worker's
// lease comes from (priority, then fewest leases out, then round robin), which parked lease calls are
// answered first, and the tiles waiting that /metrics exports.
#include <algorithm>
#include <map>
#include <set>

#include "master/memory_estimate.h"
#include "master/server/job_manager.h"
#include "master/server/window_run.h"

namespace epr {

uint64_t JobManager::tiles_waiting() const {
  JobLock lock(mu_);
  uint64_t n = 0;
  for (const auto& [id, job] : jobs_.all()) {
    if (job->state == JobState::kQueued)
      n += job->tiles.size();
    else if (job->state == JobState::kRunning && job->leases)
      n += job->leases->uncommitted();
  }
  return n;
}

bool JobManager::admits(const std::vector<std::shared_ptr<Job>>& next) const {
  if (running_.empty()) return true;
  if (options_.memory_budget_bytes == 0 ||
      running_.size() + next.size() > size_t(std::max(1, options_.max_running_jobs)))
    return false;
  // The commit queue is one for every job: counted once.
  const bool checkpoints = options_.checkpoints && !options_.state_dir.empty();
  auto own = [&](const Job& j) {
    const MemoryEstimate e = estimate_job_memory(j.request.options, checkpoints);
    return e.total() - e.queue_bytes;
  };
  uint64_t need = kCommitQueueBytes;
  for (const auto& j : next) need += own(*j);
  for (const auto& j : running_) need += own(*j);
  return need <= options_.memory_budget_bytes;
}

void JobManager::stop_running(const std::shared_ptr<Job>& job) {
  {
    JobLock lock(mu_);
    running_.erase(std::remove(running_.begin(), running_.end(), job), running_.end());
  }
  work_cv_.notify_all();  // a queued job may fit now
}

// *parkable: the answer is a short Wait that a tile may end soon (see lease_tile_or_park).
LeaseDecision JobManager::decide_lease(const std::string& worker, bool* parkable) {
  *parkable = false;
  WorkerRegistry::Worker* w = workers_.touch(worker, clock_());
  if (!w) return UnknownWorker{};
  if (stopping_) return LeaseWait{1000};
  // Back-pressure: the reprojection thread is behind.
  if (queued_vertices_ > options_.max_queued_vertices) return LeaseWait{20};
  // The running jobs this worker may trace, in the order they are offered (job_manager.h):
  // priority, then the fewest leases out, then the one served least recently.
  std::vector<Job*> offer;
  bool blocked = false, closing = false;
  for (const auto& job : running_) {
    if (job->state != JobState::kRunning) continue;
    // A worker that failed too many of a job's tiles gets none of its tiles.
    if (job->leases->blocked(worker)) {
      blocked = true;
      continue;
    }
    if (!job->round_open) {
      closing = true;
      continue;
    }
    offer.push_back(job.get());
  }
  // A window frame's rounds behind the furthest of its run's running frames: those behind first, so
  // that the frames whose rounds the others' closes wait for are traced first.
  std::map<const Job*, uint32_t> behind;
  for (const Job* job : offer)
    if (job->run) {
      uint32_t top = job->round;
      for (const auto& g : job->run->frames)
        if (g->state == JobState::kRunning) top = std::max(top, g->round);
      behind[job] = top - job->round;
    }
  std::sort(offer.begin(), offer.end(), [&behind](const Job* a, const Job* b) EPR_REQUIRES(job_fields) {
    if (a->request.priority != b->request.priority) return a->request.priority > b->request.priority;
    const auto lag = [&](const Job* j) {
      auto it = behind.find(j);
      return it == behind.end() ? 0u : it->second;
    };
    if (lag(a) != lag(b)) return lag(a) > lag(b);
    if (a->leases->out() != b->leases->out()) return a->leases->out() < b->leases->out();
    return a->leases->last_lease() < b->leases->last_lease();
  });
  for (Job* job : offer) {
    const uint64_t lease = next_lease_;
    auto g = job->leases->lease(worker, lease);
    if (!g) continue;
    ++next_lease_;
    w->leases.insert(lease);
    return grant(*job, worker, *g, lease);
  }
  // Blocked for every running job: wait for the next job.
  if (blocked && offer.empty() && !closing) return LeaseWait{500};
  // No job: poll slowly. A round closing: the next opens within milliseconds; every tile out: one may
  // come back (or a speculative copy become due) any moment.
  *parkable = true;
  if (!offer.empty()) return LeaseWait{5};
  return LeaseWait{closing ? 20u : 200u};
}

void JobManager::wake_parked(bool all) {
  // Workers that hold a running job's scene first: they start tracing without fetching it.
  std::set<std::string> scenes;
  for (const auto& job : running_)
    if (job->state == JobState::kRunning && job->round_open) scenes.insert(job->scene_hash);
  parking_.wake(
      all, clock_(),
      // Both called by wake(), with mu_ held.
      [this](const std::string& worker, bool* parkable)
          EPR_REQUIRES(mu_, job_fields) { return decide_lease(worker, parkable); },
      [this, &scenes](const std::string& worker) EPR_REQUIRES(mu_) {
        const WorkerRegistry::Worker* w = workers_.find(worker);
        if (!w) return false;
        for (const auto& scene : scenes)
          if (w->cached_scenes.count(scene)) return true;
        return false;
      });
}

}  // namespace epr
