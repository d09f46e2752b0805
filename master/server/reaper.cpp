#include "master/server/reaper.h"

#include "common/thread_name.h"

namespace epr {

void Reaper::run() {
  set_thread_name("epr-reaper");
  JobLock lock(m_.mu_);
  while (!m_.stopping_) {
    m_.work_cv_.wait_for(lock, kPeriod);
    if (m_.stopping_) break;
    std::vector<std::shared_ptr<Job>> failed;
    reap(&failed);
    lock.unlock();
    m_.answer_due();
    if (!failed.empty()) m_.work_cv_.notify_all();
    for (const auto& job : failed) {
      m_.save_final_checkpoint(job);  // a restart must not run it again
      m_.notify(job);
    }
    lock.lock();
  }
}

void Reaper::reap(std::vector<std::shared_ptr<Job>>* failed) {
  for (const auto& job : m_.running_) {
    if (job->state != JobState::kRunning) continue;
    const auto expired = job->leases->expire();
    for (const auto& e : expired) {
      if (WorkerRegistry::Worker* w = m_.workers_.find(e.worker)) w->leases.erase(e.lease);
      ++job->version;
    }
    if (!expired.empty()) m_.fail_if_stuck(job, failed);
  }
  m_.workers_.forget_silent(m_.clock_(), m_.options_.worker_timeout_ms);
  // The workers that were not blocked may have left.
  for (const auto& job : m_.running_) m_.fail_if_stuck(job, failed);
  // Parked lease requests: tiles that came back, speculative copies, and the ones out of time.
  m_.wake_parked(/*all=*/false);
}

}  // namespace epr
