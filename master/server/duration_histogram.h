// A fixed-bucket histogram of durations in seconds, in the shape Prometheus exposes (cumulative
// bucket counts, sum, count). The JobManager records round and per-round reprojection durations into
// two of them; the monitoring endpoint copies them out under the manager's mutex.
#pragma once

#include <array>
#include <cstdint>

namespace epr {

struct DurationHistogram {
  /// Upper bounds in seconds (the implicit last bucket is +Inf). From a 32x32 test round (~5 ms) to a
  /// 4K round on a small farm (minutes).
  static constexpr std::array<double, 14> kBounds = {0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5,
                                                     1,     2.5,  5,     10,   30,  60,   300};
  std::array<uint64_t, kBounds.size()> buckets{};  // per bound: observations <= bound (not cumulative)
  uint64_t count = 0;                              // all observations, including those above the last bound
  double sum = 0;                                  // seconds

  void observe(double seconds) {
    if (!(seconds >= 0)) seconds = 0;  // a clock step or NaN must not corrupt the sum
    for (size_t i = 0; i < kBounds.size(); ++i)
      if (seconds <= kBounds[i]) {
        ++buckets[i];
        break;
      }
    ++count;
    sum += seconds;
  }
};

/// What the JobManager has recorded over its lifetime (all jobs).
struct DurationHistograms {
  DurationHistogram round;         // wall time from opening a round to closing it
  DurationHistogram reprojection;  // the master's reprojection time within one round
};

}  // namespace epr
