// CPU time of the calling thread and of the whole process, in seconds. Nanosecond clocks: per-tile
// deltas are microseconds, below getrusage's tick granularity on some kernels.
#pragma once

#include <time.h>

namespace epr {

inline double thread_cpu_seconds() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

inline double process_cpu_seconds() {
  timespec ts{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

}  // namespace epr
