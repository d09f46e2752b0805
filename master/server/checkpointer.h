// Writes the master's job checkpoints on a thread of its own, so that the reprojection thread only
// copies the frame: a queue with at most one record per job, a newer record replacing a pending
// older one. A job's state is read and its record queued in one step under the queue's lock
// (queue()), so the last record queued is the job's last state.
#pragma once

#include <condition_variable>
#include <deque>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <utility>

#include "common/check.h"
#include "master/server/checkpoint.h"

namespace epr {

class Checkpointer {
 public:
  /// `written(job_id, seconds)` is called on the writer thread after each record with a frame.
  Checkpointer(CheckpointStore& store, std::function<void(const std::string&, double)> written);
  /// Writes what is queued, then stops.
  ~Checkpointer();
  Checkpointer(const Checkpointer&) = delete;
  Checkpointer& operator=(const Checkpointer&) = delete;

  /// Calls `make` under the queue's lock and queues the record it returns (none: nothing queued).
  void queue(const std::string& job_id, const std::function<std::optional<JobProgressRecord>()>& make)
      EPR_EXCLUDES(mu_);
  /// Writes what is queued and stops the thread (idempotent).
  void stop() EPR_EXCLUDES(mu_);

 private:
  void loop() EPR_EXCLUDES(mu_);

  CheckpointStore& store_;
  std::function<void(const std::string&, double)> written_;
  Mutex mu_;
  std::condition_variable_any cv_;
  std::deque<std::pair<std::string, std::shared_ptr<const JobProgressRecord>>> queue_ EPR_GUARDED_BY(mu_);
  bool stopping_ EPR_GUARDED_BY(mu_) = false;
  std::thread thread_;
};

}  // namespace epr
