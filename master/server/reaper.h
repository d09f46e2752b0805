// The JobManager's reaper thread (job_manager.h): every 200 ms (or when the manager's work_cv_ wakes
// it), under the manager's mutex, it expires the running jobs' leases past their deadline, forgets
// workers silent for MasterOptions::worker_timeout_ms, fails a job that lost a tile too often or whose
// every worker is blocked (JobManager::fail_if_stuck), and answers parked lease requests that a tile
// came back for or whose time is up; then, without the mutex, it answers them, checkpoints the failed
// jobs' final state and tells their watchers. It owns nothing: it touches the manager's registries,
// leases and jobs under the mutex only, and lives on its thread's stack.
#pragma once

#include <chrono>

#include "common/check.h"
#include "master/server/job_manager.h"

namespace epr {

class Reaper {
 public:
  explicit Reaper(JobManager& manager) : m_(manager) {}
  Reaper(const Reaper&) = delete;
  Reaper& operator=(const Reaper&) = delete;
  /// The thread's loop, until JobManager::shutdown().
  void run() EPR_EXCLUDES(m_.mu_);

  static constexpr std::chrono::milliseconds kPeriod{200};

 private:
  /// One pass, with the mutex held; the jobs it failed go to `failed`.
  void reap(std::vector<std::shared_ptr<Job>>* failed) EPR_REQUIRES(m_.mu_, job_fields);

  JobManager& m_;
};

}  // namespace epr
