// Writes the master's job checkpoints on a thread of its own: a queue with at most one item per
// job, a newer item replacing a pending older one. An item is a record to write (the small ones:
// finished jobs, no frame) or a round checkpoint whose file the reprojection thread has already
// written straight from the live frame (CheckpointStore::write_progress_file: nothing copied) and
// that this thread fsyncs and puts in place (commit_progress). A job's state is read and its item
// queued in one step under the queue's lock, so the last item queued is the job's last state.
#pragma once

#include <condition_variable>
#include <deque>
#include <filesystem>
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
  /// Queues the progress file `written` (CheckpointStore::write_progress_file) to be committed if
  /// `accept`, called under the queue's lock, returns true; otherwise, or if a newer item replaces it
  /// before it is committed, the file is removed.
  void queue_written(const std::string& job_id, std::filesystem::path written, const std::function<bool()>& accept)
      EPR_EXCLUDES(mu_);
  /// As queue(), then waits until the job's record is on disk (or the writer has stopped): for a
  /// state that must be durable before anyone hears of it.
  void queue_and_wait(const std::string& job_id, const std::function<std::optional<JobProgressRecord>()>& make)
      EPR_EXCLUDES(mu_);
  /// Writes what is queued and stops the thread (idempotent).
  void stop() EPR_EXCLUDES(mu_);

 private:
  struct Item {
    std::shared_ptr<const JobProgressRecord> record;  // to write, or
    std::filesystem::path written;                    // written, to commit
  };
  void loop() EPR_EXCLUDES(mu_);
  void push(const std::string& job_id, Item item) EPR_REQUIRES(mu_);

  CheckpointStore& store_;
  std::function<void(const std::string&, double)> written_;
  Mutex mu_;
  std::condition_variable_any cv_;
  std::deque<std::pair<std::string, Item>> queue_ EPR_GUARDED_BY(mu_);
  bool stopping_ EPR_GUARDED_BY(mu_) = false;
  bool stopped_ EPR_GUARDED_BY(mu_) = false;  // the thread has written everything and returned
  std::string writing_ EPR_GUARDED_BY(mu_);   // the job whose item the thread is writing, if any
  std::thread thread_;
};

}  // namespace epr
