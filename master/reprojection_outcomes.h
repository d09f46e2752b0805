// What became of the vertices offered for reprojection, whether the master decided (ReprojectionCounts)
// or a worker culled them before sending: the one definition of the accepted / occluded / culled
// figures and percentages that the render statistics, the job status and the monitoring endpoint show.
#pragma once

#include <cstdint>

#include "master/reprojector.h"

namespace epr {

struct ReprojectionOutcomes {
  uint64_t accepted = 0;           // reprojected: accepted by the depth test, plus exact samples
  uint64_t occluded = 0;           // includes backfacing
  uint64_t culled = 0;             // by the master (outside the image, behind the camera) and by the workers
  uint64_t culled_by_workers = 0;  // the workers' part of `culled` (frustum, facing, glossy, exact occluded)
  uint64_t not_diffuse = 0;        // glossy vertices the master skipped
  uint64_t invalid = 0;            // non-finite values; exact samples outside the grid
  uint64_t considered = 0;         // every vertex above: the base of the percentages

  /// `worker_culled`: vertices the workers culled before sending (JobCounters::worker_culled).
  static ReprojectionOutcomes of(const ReprojectionCounts& c, uint64_t worker_culled) {
    ReprojectionOutcomes o;
    o.accepted = c.accepted + c.exact;
    o.occluded = c.occluded;
    o.culled = c.culled + worker_culled;
    o.culled_by_workers = worker_culled;
    o.not_diffuse = c.not_diffuse;
    o.invalid = c.invalid;
    o.considered = o.accepted + o.occluded + o.culled + o.not_diffuse + o.invalid;
    return o;
  }
  /// `part` as a percentage of `considered` (0 when nothing was considered).
  double percent(uint64_t part) const { return considered ? 100.0 * double(part) / double(considered) : 0.0; }
  double accepted_percent() const { return percent(accepted); }
  double occluded_percent() const { return percent(occluded); }
  double culled_percent() const { return percent(culled); }
};

}  // namespace epr
