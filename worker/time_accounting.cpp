#include "worker/time_accounting.h"

#include "common/cpu_time.h"

namespace epr {

void TimeAccounting::add_cpu(Activity a, double seconds) {
  MutexLock lock(mu_);
  cpu_[int(a)] += seconds;
}

WorkerTimeSplit TimeAccounting::cpu() {
  MutexLock lock(mu_);
  return to_split(cpu_);
}

std::pair<WorkerTimeSplit, WorkerTimeSplit> TimeAccounting::split() {
  MutexLock lock(mu_);
  advance();
  double with[kActivities], without[kActivities];
  for (int a = 0; a < kActivities; ++a) {
    with[a] = seconds_[a][1];
    without[a] = seconds_[a][0];
  }
  return {to_split(with), to_split(without)};
}

WorkerTimeSplit TimeAccounting::to_split(const double (&by)[kActivities]) {
  WorkerTimeSplit t;
  t.other = by[int(Activity::kOther)];
  t.tracing = by[int(Activity::kTracing)];
  t.leasing = by[int(Activity::kLeasing)];
  t.waiting = by[int(Activity::kWaiting)];
  t.submitting = by[int(Activity::kSubmitting)];
  return t;
}

void TimeAccounting::change(const Activity* from, const Activity* to) {
  MutexLock lock(mu_);
  advance();
  if (from) --threads_in_[int(*from)];
  if (to) ++threads_in_[int(*to)];
}

void TimeAccounting::advance() {
  const auto now = Clock::now();
  const double dt = std::chrono::duration<double>(now - last_).count();
  last_ = now;
  const int tracing = threads_in_[int(Activity::kTracing)];
  for (int a = 0; a < kActivities; ++a) {
    // A tracing thread sees another one tracing if there are two; any other thread if there is one.
    const bool others = a == int(Activity::kTracing) ? tracing > 1 : tracing > 0;
    seconds_[a][others ? 1 : 0] += double(threads_in_[a]) * dt;
  }
}

ThreadActivity::ThreadActivity(TimeAccounting& t) : t_(t) {
  if (t_.cpu_clock()) cpu_ = thread_cpu_seconds();
  t_.enter(current_);
}

ThreadActivity::~ThreadActivity() {
  if (t_.cpu_clock()) t_.add_cpu(current_, thread_cpu_seconds() - cpu_);
  t_.leave(current_);
}

void ThreadActivity::set(Activity a) {
  if (a == current_) return;
  if (t_.cpu_clock()) {
    const double cpu = thread_cpu_seconds();
    t_.add_cpu(current_, cpu - cpu_);
    cpu_ = cpu;
  }
  t_.move(current_, a);
  current_ = a;
}

}  // namespace epr
