// Frame windows (DESIGN.md "Frame windows"): the frames window_first..window_last of a batch that
// one master renders together, a "run". A run starts once all its frames are queued (or after
// MasterOptions::window_run_wait_ms with those that are: the reason is logged), as one unit of the
// memory budget; every vertex traced for frame f is also reprojected into the run's frames g with
// |g - f| <= K, and each frame closes its own rounds: round r once its own tiles of r and its
// neighbours' of r - 1 are applied (reprojection_window.cpp), so its M' after round r counts its own
// rounds 0..r and its neighbours' 0..r-1. A frame that ends (done, cancelled, failed) leaves its run;
// the others go on.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "master/server/job.h"

namespace epr {
namespace v1 {
class JobSpec;
}

/// The frames of one run as started together, in frame order (their Job::run).
struct WindowRun {
  std::vector<std::shared_ptr<Job>> frames;
  uint32_t window = 0;  // K
  // Cuts (DESIGN.md "Frame windows"): the run's frames this master has (ended ones too), in frame
  // order; per pair of neighbours among them (measured[i], measured[i + 1]) how much their views
  // share (view_overlap.h) and whether that is a cut. Empty: not measured, no cut.
  std::vector<uint32_t> measured;
  std::vector<double> share;
  std::vector<uint8_t> cut;
  /// The frames of the run within K frames of `frame` (number), other than it, with no cut between.
  std::vector<std::shared_ptr<Job>> neighbours(uint32_t frame) const;
  /// The first and last frame number of `frame`'s window as it is rendered: `frame` and its
  /// neighbours() (frames that ended later included).
  std::pair<uint32_t, uint32_t> fed_by(uint32_t frame) const;
  /// True if a cut lies between frames a and b.
  bool cut_between(uint32_t a, uint32_t b) const;
  /// The shares of `frame`'s views with the measured frames before and after it; -1 where there is none.
  std::pair<double, double> shares_of(uint32_t frame) const;
};

/// The batch fields of a JobSpec (batch_id, batch_name, frame, batch_frames, frame_window,
/// window_first, window_last) and back.
BatchMembership batch_from_spec(const v1::JobSpec& spec);
void batch_to_spec(const BatchMembership& batch, v1::JobSpec* spec);

/// A window frame's M' counts its own reprojected samples kWindowUnit each and a sample traced for
/// the frame `distance` frames away round(kWindowUnit 2^(-distance / halving)), at least 1 (halving
/// 0: kWindowUnit, all alike): integers, so M' and the skip decisions stay exact whatever the order
/// samples arrive in (DESIGN.md "Frame windows").
inline constexpr uint32_t kWindowUnit = 16;
uint32_t window_sample_weight(uint32_t distance, float halving);
/// The count unit of a job's frame (FrameState::set_count_unit): kWindowUnit for a window that
/// weighs its neighbours' samples, else 1.
inline uint32_t window_count_unit(const BatchMembership& b) {
  return b.window > 0 && b.window_halving > 0 ? kWindowUnit : 1;
}

/// True if the job asks for a frame window.
inline bool windowed(const BatchMembership& b) { return b.window > 0; }
/// Frames in the run of a window job: window_last - window_first + 1.
inline uint32_t run_length(const BatchMembership& b) { return b.window_last - b.window_first + 1; }
/// True if both are window jobs of the same run (batch id, K, first and last frame).
bool same_run(const BatchMembership& a, const BatchMembership& b);

/// The checks of a request's window fields by themselves (the reason, or nullopt): a window needs a
/// batch frame inside window_first..window_last, K within limits::kFrameWindow, a run of at most
/// limits::kWindowRunFrames frames, and a mode that reprojects by the deep framebuffer (not pt, not
/// exact). Without a window, the window fields must be 0.
std::optional<std::string> window_error(const JobRequest& request);

/// Why `request` (scene `scene_hash`) cannot join the run of `member`, already on this master: the
/// first field in which their settings differ (everything but the camera must agree), or the same
/// frame twice. Nullopt if it can.
std::optional<std::string> run_mismatch(const JobRequest& request, const std::string& scene_hash, const Job& member);

}  // namespace epr
