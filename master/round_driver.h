// The progressive round loop around a FrameState, one for the single-process render
// (client/local_render.cpp) and the master (master/server/job_manager.cpp), so that both plan,
// apply and close rounds the same way:
//   open()   the next round's inputs per tile, and the order to trace them in (most active pixels
//            first: the round ends on small tiles); first_plan() the same for round 0, frame or not;
//   apply()  a tile's result: path sums, then its vertices or exact samples (any order within a
//            round; commits of one round touch disjoint pixels); or several tiles of one round in
//            one go (one reprojector call for all their vertices, the same state as one by one);
//   close()  M', skip mask and progress; false once no round is left;
//   images() / statistics()  the render's results.
// Threading as FrameState: with the GL back-end, every call on the thread whose context is current.
#pragma once

#include <cstdint>
#include <memory>
#include <nlohmann/json.hpp>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "common/camera.h"
#include "common/render_options.h"
#include "common/scene.h"
#include "common/tile.h"
#include "master/frame_state.h"

namespace epr {

class GlContext;
struct AssembledTile;

struct RoundPlan {
  uint32_t round = 0;  // rounds finished before this one
  int paths_per_pixel = 1;
  std::vector<std::vector<uint8_t>> skip;  // per tile, per tile pixel (empty: idle tile)
  // Per tile: per tile pixel, one entry for every pixel of the tile, or empty for 0 (TileRequest).
  std::vector<std::vector<uint32_t>> first_sample;
  // Per tile: per tile pixel, its paths (FrameState::path_budget()), or empty for paths_per_pixel each.
  std::vector<std::vector<uint32_t>> paths;
  std::vector<uint32_t> order;  // the tiles that trace, most active pixels first
};

class RoundDriver {
 public:
  /// `gl`: the context for the "gl" reprojector; `bvh`: the scene's shared BVH, if any (see FrameState).
  RoundDriver(const RenderOptions& opts, const Camera& camera, const Scene& scene, GlContext* gl,
              const SceneBvh* bvh = nullptr);

  bool done() const { return frame_.done(); }
  RoundPlan open(const std::vector<TileRect>& tiles) const;
  /// The plan open() gives for round 0 of a new frame (every pixel traces, from sample 0), without
  /// a frame: the master opens a fresh job's round 0 while its frame is being built.
  static RoundPlan first_plan(const RenderOptions& opts, const std::vector<TileRect>& tiles);
  void apply(const TileResult& result);
  void apply(const AssembledTile& tile);
  /// The tiles of one round in the order given, with the same result as apply() of each in turn, bit
  /// for bit: their path sums, then their vertices concatenated in that order and reprojected in one
  /// call (the reprojector adds in input order; one large call runs on every core where per-tile
  /// calls stay serial). Runs of tiles whose vertices are of one kind (decoded, packed or exact) go
  /// together; a tile with several kinds is applied alone, so that the order stays apply()'s.
  void apply(std::span<const AssembledTile* const> tiles);
  /// Records per apply(span) call the master aims for (its reprojection thread drains the commit
  /// queue up to this many): large enough for the parallel CPU path, small enough to copy cheaply.
  static constexpr size_t kBatchRecords = size_t(1) << 20;
  /// Only the vertices of `tiles` (decoded and packed; traced for another frame of the same scene,
  /// DESIGN.md "Frame windows"), reprojected into this frame in the order given: no path sums, no
  /// exact samples; each accepted one adding `sample_weight` count units (FrameState::set_count_unit).
  void reproject(std::span<const AssembledTile* const> tiles, uint32_t sample_weight);
  /// Ends the round; true if another is needed.
  bool close() { return frame_.finish_round(); }

  FrameState& frame() { return frame_; }
  const FrameState& frame() const { return frame_; }

 private:
  FrameState frame_;
  std::vector<std::string_view> packed_parts_;  // apply(span)'s packed vertices, tile by tile
  std::vector<VertexRecord> vertex_batch_;      // ... decoded vertices
  std::vector<ExactSample> exact_batch_;        // ... exact samples
};

}  // namespace epr
