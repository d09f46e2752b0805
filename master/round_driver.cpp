#include "master/round_driver.h"

#include <algorithm>

#include "wire/tile_result_stream.h"

namespace epr {

RoundDriver::RoundDriver(const RenderOptions& opts, const Camera& camera, const Scene& scene, GlContext* gl)
    : frame_(opts, camera, scene, gl) {}

RoundPlan RoundDriver::open(const std::vector<TileRect>& tiles) const {
  RoundPlan plan;
  plan.round = uint32_t(frame_.round());
  plan.paths_per_pixel = frame_.next_paths_per_pixel();
  plan.skip.resize(tiles.size());
  plan.first_sample.resize(tiles.size());
  std::vector<size_t> active(tiles.size(), 0);
  for (uint32_t t = 0; t < tiles.size(); ++t) {
    const TileRect& r = tiles[t];
    if (frame_.tile_idle(r.x0, r.y0, r.x1, r.y1)) continue;
    frame_.tile_inputs(r.x0, r.y0, r.x1, r.y1, &plan.skip[t], &plan.first_sample[t]);
    active[t] = size_t(std::count(plan.skip[t].begin(), plan.skip[t].end(), uint8_t(0)));
    plan.order.push_back(t);
  }
  // Every active pixel of a round traces the same number of paths, so a tile costs about its active
  // pixels. The results do not depend on the order: each pixel's samples are keyed by (pixel, sample).
  std::stable_sort(plan.order.begin(), plan.order.end(), [&](uint32_t a, uint32_t b) { return active[a] > active[b]; });
  return plan;
}

void RoundDriver::apply(const TileResult& r) {
  frame_.add_paths(r.rect.x0, r.rect.y0, r.rect.x1, r.rect.y1, r.path_sum, r.path_count);
  frame_.reproject(r.vertices);
  frame_.reproject_packed(r.packed_vertices);
  if (r.visible.empty()) return;
  std::vector<ExactSample> exact(r.visible.size());
  for (size_t i = 0; i < exact.size(); ++i) exact[i] = {r.visible[i].subpixel, r.visible[i].radiance};
  frame_.add_exact(exact);
}

void RoundDriver::apply(const AssembledTile& t) {
  frame_.add_paths(int(t.x0), int(t.y0), int(t.x1), int(t.y1), t.path_sum, t.path_count);
  frame_.reproject(t.vertices);
  frame_.reproject_packed(t.packed_vertices);
  if (t.exact_samples.empty()) return;
  std::vector<ExactSample> exact(t.exact_samples.size());
  for (size_t i = 0; i < exact.size(); ++i) exact[i] = {t.exact_samples[i].first, t.exact_samples[i].second};
  frame_.add_exact(exact);
}

}  // namespace epr
