#include "master/round_driver.h"

#include <algorithm>
#include <bit>
#include <optional>

#include "common/check.h"
#include "wire/tile_result_stream.h"

namespace epr {

RoundDriver::RoundDriver(const RenderOptions& opts, const Camera& camera, const Scene& scene, GlContext* gl,
                         const SceneBvh* bvh)
    : frame_(opts, camera, scene, gl, bvh) {}

namespace {

// The tiles with active pixels, most first. Every active pixel of a round traces the same number of
// paths, so a tile costs about its active pixels. The results do not depend on the order: each
// pixel's samples are keyed by (pixel, sample).
std::vector<uint32_t> busiest_first(const std::vector<size_t>& active) {
  std::vector<uint32_t> order;
  for (uint32_t t = 0; t < active.size(); ++t)
    if (active[t] > 0) order.push_back(t);
  std::stable_sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) { return active[a] > active[b]; });
  return order;
}

}  // namespace

RoundPlan RoundDriver::open(const std::vector<TileRect>& tiles) const {
  RoundPlan plan;
  plan.round = uint32_t(frame_.round());
  plan.paths_per_pixel = frame_.next_paths_per_pixel();
  plan.skip.resize(tiles.size());
  plan.first_sample.resize(tiles.size());
  plan.paths.resize(tiles.size());
  std::vector<size_t> active(tiles.size(), 0);
  for (uint32_t t = 0; t < tiles.size(); ++t) {
    const TileRect& r = tiles[t];
    if (frame_.tile_idle(r.x0, r.y0, r.x1, r.y1)) continue;
    frame_.tile_paths(r.x0, r.y0, r.x1, r.y1, &plan.paths[t]);
    std::vector<uint32_t>& first = plan.first_sample[t];
    const std::vector<uint8_t>& skip = plan.skip[t];
    frame_.tile_inputs(r.x0, r.y0, r.x1, r.y1, &plan.skip[t], &first);
    EPR_CHECK_EQ(skip.size(), size_t(r.x1 - r.x0) * size_t(r.y1 - r.y0));
    EPR_CHECK_EQ(first.size(), skip.size());
    active[t] = size_t(std::count(skip.begin(), skip.end(), uint8_t(0)));
    // One entry (none for 0) when every tracing pixel starts at the same sample (the usual case: active
    // pixels have all traced the same paths); skipped pixels' entries are never read.
    std::optional<uint32_t> common;
    bool uniform = true;
    for (size_t i = 0; i < first.size() && uniform; ++i) {
      if (skip[i]) continue;
      if (!common) common = first[i];
      uniform = first[i] == *common;
    }
    if (uniform) first = common.value_or(0) == 0 ? std::vector<uint32_t>() : std::vector<uint32_t>{*common};
  }
  plan.order = busiest_first(active);
  EPR_DCHECK_GT(plan.paths_per_pixel, 0);  // a round is opened only while the frame is not done
  return plan;
}

RoundPlan RoundDriver::first_plan(const RenderOptions& opts, const std::vector<TileRect>& tiles) {
  RoundPlan plan;
  plan.round = 0;
  plan.paths_per_pixel = round_paths(opts, 0);
  EPR_CHECK_GT(plan.paths_per_pixel, 0);  // RenderOptions::validate refuses spp < 1
  plan.skip.resize(tiles.size());
  plan.first_sample.resize(tiles.size());
  plan.paths.resize(tiles.size());  // empty: every pixel traces paths_per_pixel
  std::vector<size_t> active(tiles.size(), 0);
  for (uint32_t t = 0; t < tiles.size(); ++t) {
    const TileRect& r = tiles[t];
    if (r.x1 <= r.x0 || r.y1 <= r.y0) continue;
    active[t] = size_t(r.x1 - r.x0) * size_t(r.y1 - r.y0);
    plan.skip[t].assign(active[t], 0);  // first_sample[t] stays empty: every pixel starts at 0
  }
  plan.order = busiest_first(active);
  return plan;
}

void RoundDriver::apply(const TileResult& r) {
  frame_.add_paths(r.rect.x0, r.rect.y0, r.rect.x1, r.rect.y1, r.path_sum, r.path_count, r.glossy_sum);
  frame_.reproject(r.vertices);
  frame_.reproject_packed(r.packed_vertices);
  if (r.visible.empty()) return;
  std::vector<ExactSample> exact(r.visible.size());
  for (size_t i = 0; i < exact.size(); ++i) exact[i] = {r.visible[i].subpixel, r.visible[i].radiance};
  frame_.add_exact(exact);
}

void RoundDriver::apply(const AssembledTile& t) {
  frame_.add_paths(int(t.x0), int(t.y0), int(t.x1), int(t.y1), t.path_sum, t.path_counts(), t.glossy_sum);
  frame_.reproject(t.vertices);
  frame_.reproject_packed(t.packed_vertices);
  if (t.exact_samples.empty()) return;
  std::vector<ExactSample> exact(t.exact_samples.size());
  for (size_t i = 0; i < exact.size(); ++i) exact[i] = {t.exact_samples[i].first, t.exact_samples[i].second};
  frame_.add_exact(exact);
}

namespace {

// Which kinds of vertices a tile carries: bit 0 decoded, bit 1 packed, bit 2 exact samples.
unsigned kinds_of(const AssembledTile& t) {
  return (t.vertices.empty() ? 0u : 1u) | (t.packed_vertices.empty() ? 0u : 2u) | (t.exact_samples.empty() ? 0u : 4u);
}

}  // namespace

void RoundDriver::reproject(std::span<const AssembledTile* const> tiles, uint32_t sample_weight) {
  frame_.set_sample_weight(sample_weight);
  packed_parts_.clear();
  vertex_batch_.clear();
  for (const AssembledTile* t : tiles) {
    if (!t->packed_vertices.empty()) packed_parts_.push_back(t->packed_vertices);
    vertex_batch_.insert(vertex_batch_.end(), t->vertices.begin(), t->vertices.end());
  }
  if (!packed_parts_.empty()) frame_.reproject_packed(packed_parts_);
  if (!vertex_batch_.empty()) frame_.reproject(vertex_batch_);
  frame_.set_sample_weight(frame_.count_unit());
  if (vertex_batch_.capacity() > 4 * kBatchRecords) std::vector<VertexRecord>().swap(vertex_batch_);
}

void RoundDriver::apply(std::span<const AssembledTile* const> tiles) {
  size_t i = 0;
  while (i < tiles.size()) {
    // The longest run from i whose tiles together carry one kind of vertex at most: concatenating
    // them keeps every vertex in apply()'s order.
    unsigned kinds = kinds_of(*tiles[i]);
    if (std::popcount(kinds) > 1) {
      apply(*tiles[i++]);
      continue;
    }
    size_t end = i + 1;
    while (end < tiles.size()) {
      const unsigned k = kinds_of(*tiles[end]);
      if (k != 0 && kinds != 0 && k != kinds) break;
      if (std::popcount(k) > 1) break;
      kinds |= k;
      ++end;
    }
    if (end == i + 1) {
      apply(*tiles[i++]);
      continue;
    }
    size_t records = 0;
    for (size_t j = i; j < end; ++j) {
      const AssembledTile& t = *tiles[j];
      frame_.add_paths(int(t.x0), int(t.y0), int(t.x1), int(t.y1), t.path_sum, t.path_counts(), t.glossy_sum);
      records += t.vertices.size() + t.packed_vertices.size() + t.exact_samples.size();
    }
    if (kinds == 1) {
      vertex_batch_.clear();
      vertex_batch_.reserve(records);
      for (size_t j = i; j < end; ++j)
        vertex_batch_.insert(vertex_batch_.end(), tiles[j]->vertices.begin(), tiles[j]->vertices.end());
      frame_.reproject(vertex_batch_);
    } else if (kinds == 2) {
      packed_parts_.clear();
      for (size_t j = i; j < end; ++j) packed_parts_.push_back(tiles[j]->packed_vertices);
      frame_.reproject_packed(packed_parts_);
    } else if (kinds == 4) {
      exact_batch_.clear();
      exact_batch_.reserve(records);
      for (size_t j = i; j < end; ++j)
        for (const auto& [subpixel, radiance] : tiles[j]->exact_samples) exact_batch_.push_back({subpixel, radiance});
      frame_.add_exact(exact_batch_);
    }
    i = end;
  }
  // Large batches are not kept between calls.
  if (vertex_batch_.capacity() > 4 * kBatchRecords) std::vector<VertexRecord>().swap(vertex_batch_);
  if (exact_batch_.capacity() > 4 * kBatchRecords) std::vector<ExactSample>().swap(exact_batch_);
}

}  // namespace epr
