// JobManager's graceful stop (job_manager.h, drain_and_checkpoint): epr-master drains on SIGTERM
// before it shuts down. A checkpoint holds a job's frame after a closed round, and the live frame of
// a round in progress mixes two rounds, so the drain lets the open rounds finish (their tiles are
// still leased, traced and applied), opens no further round and starts no queued job, and checkpoints
// each job as its round closes, whatever the checkpoint interval. A restarted master resumes from there.
#include <algorithm>
#include <chrono>

#include "common/log.h"
#include "master/server/checkpoint.h"
#include "master/server/checkpointer.h"
#include "master/server/job_manager.h"
#include "master/server/reprojection_worker.h"

namespace epr {

bool JobManager::drain_and_checkpoint(std::chrono::milliseconds timeout, const std::function<bool()>& give_up) {
  auto log = logger("master");
  if (!checkpointer_) {
    log->info("draining: checkpoints are off (no --state-dir, or --no-checkpoints): nothing to keep");
    return true;
  }
  const auto start = std::chrono::steady_clock::now();
  const auto deadline = start + timeout;
  std::vector<std::string> waiting;
  std::string why;
  {
    JobLock lock(mu_);
    draining_ = true;
    for (bool first = true;; first = false) {
      waiting.clear();
      for (const auto& [id, job] : jobs_.all())
        if (job->state == JobState::kRunning && std::find(drained_.begin(), drained_.end(), id) == drained_.end())
          waiting.push_back(id + " (round " + std::to_string(job->round) + ")");
      if (waiting.empty()) break;
      if (first)
        log->info(
            "draining: {} running job(s) finish their open round, are checkpointed, and open no other; at most "
            "{:.0f} s",
            waiting.size(), std::chrono::duration<double>(timeout).count());
      // With no worker left and no committed tile still to apply, no round can close any more.
      if (workers_.empty() && tasks_.empty())
        why = "no worker is left to trace";
      else if (std::chrono::steady_clock::now() >= deadline)
        why = "out of time";
      else if (give_up && give_up())
        why = "given up";
      if (!why.empty()) break;
      work_cv_.wait_for(lock, std::chrono::milliseconds(100));
    }
  }
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (waiting.empty()) {
    log->info("drained in {:.2f} s: every running job is checkpointed after its last closed round", s);
    return true;
  }
  std::string list;
  for (const auto& w : waiting) list += (list.empty() ? "" : ", ") + w;
  log->warn("drain ended after {:.2f} s ({}): {} resume from their last checkpoint", s, why, list);
  return false;
}

bool ReprojectionWorker::checkpoint_for_drain(const std::shared_ptr<Job>& job, JobProgressRecord* record) {
  uint32_t round;  // the round that closed; a restart resumes with the next one
  {
    JobLock lock(m_.mu_);
    if (!m_.draining_) return false;
    if (job->run && !drain_stops(*job, job->round)) return false;  // its window run stops at a later round
    job->last_checkpoint_ms = 0;  // taken whatever the interval: the state a restart resumes from
    round = job->round;
  }
  save_round_checkpoint(job, std::move(*record));
  {
    JobLock lock(m_.mu_);
    m_.drained_.push_back(job->id);
  }
  logger("master")->info("job {}: draining: round {} closed and checkpointed; no further round opens", job->id, round);
  m_.work_cv_.notify_all();
  return true;
}

}  // namespace epr
