// The jobs a master knows: submitted, running and finished ones (the oldest finished forgotten past a
// limit), the idempotency keys of submissions, which queued job runs next, and who watches which job.
// Not thread-safe: the JobManager calls it under its mutex and calls the listeners without it.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "common/check.h"
#include "master/server/job.h"

namespace epr {

class JobRegistry {
 public:
  using Listener = std::function<void(const JobSnapshot&)>;

  uint64_t next_seq() { return next_seq_++; }
  /// Adds `job` (and its request id); forgets the oldest finished jobs beyond `max_jobs` and returns
  /// their ids.
  std::vector<std::string> add(std::shared_ptr<Job> job, size_t max_jobs) EPR_REQUIRES(job_fields);
  std::shared_ptr<Job> find(const std::string& id) const;
  /// The job an earlier submission with this idempotency key created, if any.
  std::shared_ptr<Job> find_request(const std::string& request_id) const;
  const std::map<std::string, std::shared_ptr<Job>>& all() const { return jobs_; }
  /// The queued job to run next, leaving out those in `starting` (started, not yet running): one that
  /// was running when the master stopped, else the highest priority, oldest first among equals.
  std::shared_ptr<Job> next_queued(const std::vector<std::shared_ptr<Job>>& starting = {}) const
      EPR_REQUIRES(job_fields);

  /// A handle for unwatch(), or 0 if no such job.
  uint64_t watch(const std::string& id, Listener listener);
  void unwatch(uint64_t handle) { watchers_.erase(handle); }
  std::vector<Listener> listeners(const std::string& id) const;

 private:
  std::map<std::string, std::shared_ptr<Job>> jobs_;
  std::map<std::string, std::string> request_ids_;
  std::map<uint64_t, std::pair<std::string, Listener>> watchers_;
  uint64_t next_seq_ = 1, next_watch_ = 1;
};

}  // namespace epr
