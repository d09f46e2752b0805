// What the monitoring endpoint says, as pure functions of JobManager snapshots (the same snapshots
// that feed the gRPC WatchJob stream, so the dashboard and `epr watch` cannot disagree):
//  - the JSON documents of /api/v1/jobs and /api/v1/jobs/{id},
//  - the Prometheus text exposition (format 0.0.4) of /metrics.
//
// Metric conventions (https://prometheus.io/docs/practices/naming/): prefix `epr_`, base units
// (seconds), counters end in `_total`, the round and reprojection durations are histograms.
// Cardinality stays bounded: farm-wide counters have no job label; per-job series (label `job`) exist
// only for queued and running jobs and the last kRecentFinishedJobs finished ones; per-worker series
// (label `worker`) only for registered workers.
#pragma once

#include <map>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "common/check.h"
#include "master/server/duration_histogram.h"
#include "master/server/job_manager.h"

namespace epr {

/// A job's progress and statistics. Counts are exact integers; times are seconds; percentages are
/// 0..100; `eta_seconds` is null while unknown.
nlohmann::json to_json(const JobSnapshot& s);
/// A worker with its heartbeat age (seconds) and throughput (paths per second of tracing time).
nlohmann::json to_json(const WorkerSnapshot& w);

/// Counters summed over every job the master has held.
struct FarmTotals {
  uint64_t jobs = 0, rounds = 0, paths_traced = 0, paths_skipped = 0;
  JobCounters counters;
  TileDrops drops;
  ReprojectionCounts counts;

  static FarmTotals of(const JobSnapshot& s);
  FarmTotals& operator+=(const FarmTotals& o);
};

/// Keeps FarmTotals monotone although the JobManager forgets its oldest finished jobs: a job that
/// disappears from the list keeps contributing the values it had when last seen. Thread-safe.
class FarmTotalsTracker {
 public:
  FarmTotals update(const std::vector<JobSnapshot>& jobs) EPR_EXCLUDES(mu_);

 private:
  Mutex mu_;
  std::map<std::string, FarmTotals> live_ EPR_GUARDED_BY(mu_);
  FarmTotals retired_ EPR_GUARDED_BY(mu_);
};

struct MetricsInput {
  std::vector<JobSnapshot> jobs;
  std::vector<WorkerSnapshot> workers;
  DurationHistograms histograms;
  FarmTotals totals;
  bool gl_ready = false;
  uint64_t tiles_waiting = 0;  // JobManager::tiles_waiting()
};

inline constexpr size_t kRecentFinishedJobs = 10;

/// The /metrics body.
std::string prometheus_text(const MetricsInput& in);

}  // namespace epr
