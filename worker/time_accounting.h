// Where a worker's tracing threads spend their wall time (WorkerNodeStats::time_*, cpu): each thread
// is in one Activity at a time; at every change the elapsed time is credited to the activities of all
// threads, split by whether another thread was tracing meanwhile. A few changes per tile: one mutex is
// cheap enough. A ThreadActivity follows one thread; its Doing switches the activity for a scope.
//
// The threads' own CPU seconds by activity are read only when asked for (TimeAccounting(true)): reading
// a thread's CPU clock (clock_gettime(CLOCK_THREAD_CPUTIME_ID)) brings the kernel's accounting of the
// running thread up to date, and a thread whose time slice has run out loses its core right there
// instead of at the next tick. On a busy machine the reads at every change put those preemptions at the
// tiles' hand-offs (between a tile's end and its submission, before the next lease), where they delay
// the pipeline; docs/BENCHMARKS.md section 9.
#pragma once

#include <chrono>
#include <utility>

#include "common/check.h"

namespace epr {

/// Where the tracing threads' wall time went, in thread-seconds summed over the threads (one row of
/// WorkerNodeStats: while another tracing thread of the node traced, or while none did).
struct WorkerTimeSplit {
  double tracing = 0;     // inside render_leased_tile (tracing, culling, encoding the vertices)
  double leasing = 0;     // waiting for a LeaseTile answer (the one asked for ahead, or a synchronous one)
  double waiting = 0;     // sleeping on the master's Wait (a round barrier, no job, back-pressure)
  double submitting = 0;  // waiting for the thread's previous tile submission to end
  double other = 0;       // the rest: preparing a job (scene, BVH), returning leases, starting calls
  double total() const { return tracing + leasing + waiting + submitting + other; }
  WorkerTimeSplit& operator+=(const WorkerTimeSplit& o) {
    tracing += o.tracing;
    leasing += o.leasing;
    waiting += o.waiting;
    submitting += o.submitting;
    other += o.other;
    return *this;
  }
  WorkerTimeSplit& operator-=(const WorkerTimeSplit& o) {
    tracing -= o.tracing;
    leasing -= o.leasing;
    waiting -= o.waiting;
    submitting -= o.submitting;
    other -= o.other;
    return *this;
  }
};

enum class Activity { kOther, kTracing, kLeasing, kWaiting, kSubmitting };

class TimeAccounting {
 public:
  /// `cpu`: also split the threads' CPU seconds by activity (cpu()); otherwise cpu() stays zero.
  explicit TimeAccounting(bool cpu = false) : cpu_clock_(cpu) {}
  bool cpu_clock() const { return cpu_clock_; }
  void enter(Activity a) EPR_EXCLUDES(mu_) { change(nullptr, &a); }
  void leave(Activity a) EPR_EXCLUDES(mu_) { change(&a, nullptr); }
  void move(Activity from, Activity to) EPR_EXCLUDES(mu_) { change(&from, &to); }
  void add_cpu(Activity a, double seconds) EPR_EXCLUDES(mu_);
  /// The threads' own CPU seconds by activity (up to their last change); zero unless constructed with cpu.
  WorkerTimeSplit cpu() EPR_EXCLUDES(mu_);
  /// {while another thread traced, while none did}, up to now.
  std::pair<WorkerTimeSplit, WorkerTimeSplit> split() EPR_EXCLUDES(mu_);

  static constexpr int kActivities = 5;

 private:
  using Clock = std::chrono::steady_clock;
  static WorkerTimeSplit to_split(const double (&by)[kActivities]);
  void change(const Activity* from, const Activity* to) EPR_EXCLUDES(mu_);
  void advance() EPR_REQUIRES(mu_);  // credits the time since the last change

  const bool cpu_clock_;
  Mutex mu_;
  Clock::time_point last_ EPR_GUARDED_BY(mu_) = Clock::now();
  int threads_in_[kActivities] EPR_GUARDED_BY(mu_) = {};
  double seconds_[kActivities][2] EPR_GUARDED_BY(mu_) = {};  // [activity][another thread traced]
  double cpu_[kActivities] EPR_GUARDED_BY(mu_) = {};         // thread CPU seconds
};

/// The activity of one tracing thread, kOther from construction to destruction unless a Doing says
/// otherwise.
class ThreadActivity {
 public:
  explicit ThreadActivity(TimeAccounting& t);
  ~ThreadActivity();
  ThreadActivity(const ThreadActivity&) = delete;
  ThreadActivity& operator=(const ThreadActivity&) = delete;

  /// Switches the thread to `what` for its scope and back after. A null ThreadActivity: nothing.
  class Doing {
   public:
    Doing(ThreadActivity* a, Activity what) : a_(a) {
      if (!a_) return;
      before_ = a_->current_;
      a_->set(what);
    }
    ~Doing() {
      if (a_) a_->set(before_);
    }
    Doing(const Doing&) = delete;
    Doing& operator=(const Doing&) = delete;

   private:
    ThreadActivity* a_;
    Activity before_ = Activity::kOther;
  };

 private:
  void set(Activity a);
  TimeAccounting& t_;
  Activity current_ = Activity::kOther;
  double cpu_ = 0;  // thread CPU seconds at the last change (with TimeAccounting::cpu_clock())
};

}  // namespace epr
