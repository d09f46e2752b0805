// What clang's thread-safety analysis (common/check.h) checks a Job's shared fields against.
// `job_fields` names "the mutex of the JobManager that holds the job is held": a job belongs to one
// manager, whose mutex guards it, taken with JobLock (which holds both the mutex and this name). A Job
// field marked EPR_GUARDED_BY(job_fields) is touched only under a JobLock, or in a function marked
// EPR_REQUIRES(job_fields); the analysis rejects any other access. `job_fields` is a name for the
// analysis only: nothing locks it.
#pragma once

#include "common/check.h"

namespace epr {

class EPR_CAPABILITY("mutex") JobFields {};
inline JobFields job_fields;

/// Holds a JobManager's mutex, and with it every field of its jobs, for its scope; unlock()/lock() let
/// a condition_variable_any wait on it.
class EPR_SCOPED_CAPABILITY JobLock {
 public:
  explicit JobLock(Mutex& mu) EPR_ACQUIRE(mu, job_fields) : lock_(mu) {}
  ~JobLock() EPR_RELEASE() {}
  JobLock(const JobLock&) = delete;
  JobLock& operator=(const JobLock&) = delete;
  void lock() EPR_ACQUIRE() { lock_.lock(); }
  void unlock() EPR_RELEASE() { lock_.unlock(); }

 private:
  MutexLock lock_;
};

}  // namespace epr
