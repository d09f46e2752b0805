// Compiled by clang with -Wthread-safety only (ctest job_fields_need_the_lock, tests/CMakeLists.txt),
// never linked: the analysis must reject the unlocked touches of a Job's shared fields below
// (master/server/job_lock.h) and accept the locked ones.
#include "master/server/job.h"

namespace epr {

void read_unlocked(const Job& job, bool* reprojects) {
  *reprojects = job.preview.reprojects;  // expected: "reading variable 'preview' requires holding mutex 'job_fields'"
}

void write_unlocked(Job& job) {
  ++job.version;  // expected: "writing variable 'version' requires holding mutex 'job_fields' exclusively"
}

void locked(Mutex& manager_mu, Job& job) {
  JobLock lock(manager_mu);
  ++job.version;
  job.end(JobState::kCancelled, "", 0);
}

}  // namespace epr
