// A job's running totals, one struct for its progress, its checkpoints and the monitoring endpoint.
// Checkpoints encode it field by field (checkpoint.cpp); the wire and monitoring read it from
// JobSnapshot::counters.
#pragma once

#include <cstdint>

namespace epr {

struct JobCounters {
  uint64_t rays = 0;               // rays traced by workers (camera, bounce, shadow, exact visibility)
  uint64_t vertices_received = 0;  // vertex records and exact samples committed
  uint64_t non_finite = 0;         // samples dropped as NaN or infinite (workers and master)
  uint64_t worker_culled = 0;      // culled by workers before sending (frustum, facing, glossy, exact occluded)
  uint64_t tiles_leased = 0, tiles_committed = 0, tiles_re_leased = 0, tiles_dropped = 0;
  uint64_t tiles_speculative = 0;  // speculative copies handed out (MasterOptions::speculative_factor)
  uint64_t worker_failures = 0;    // failed leases counted against workers
  double seconds_tracing = 0;      // summed over the committed tiles
  double seconds_reprojecting = 0;

  JobCounters& operator+=(const JobCounters& o) {
    rays += o.rays;
    vertices_received += o.vertices_received;
    non_finite += o.non_finite;
    worker_culled += o.worker_culled;
    tiles_leased += o.tiles_leased;
    tiles_committed += o.tiles_committed;
    tiles_re_leased += o.tiles_re_leased;
    tiles_dropped += o.tiles_dropped;
    tiles_speculative += o.tiles_speculative;
    worker_failures += o.worker_failures;
    seconds_tracing += o.seconds_tracing;
    seconds_reprojecting += o.seconds_reprojecting;
    return *this;
  }
  bool operator==(const JobCounters&) const = default;

  /// Visits the integer fields in a fixed order (the checkpoint encoding's), then the seconds.
  template <class Self, class Int, class Real>
  static void visit(Self& c, Int&& integer, Real&& real) {
    for (auto* v : {&c.rays, &c.vertices_received, &c.non_finite, &c.worker_culled, &c.tiles_leased, &c.tiles_committed,
                    &c.tiles_re_leased, &c.tiles_dropped, &c.tiles_speculative, &c.worker_failures})
      integer(*v);
    real(c.seconds_tracing);
    real(c.seconds_reprojecting);
  }
};

}  // namespace epr
