// Frame sequences: a batch is a client-side grouping of ordinary jobs, one per frame, that carry the
// same JobSpec.batch_id and their frame number (proto/epr/v1/job_service.proto). The client picks
// the batch id, evaluates each frame's camera from the scene's keyframes (common/camera_animation.h)
// and puts it in the frame's spec, so a master needs nothing but the fields to show and filter by.
// The scene is bundled once and sent once to each master (uploaded by content hash); submitting a
// batch to several masters is submitting each frame's spec to one of them (scene_for, then submit).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "client/job_client.h"
#include "common/render_options.h"
#include "wire/scene_bundle.h"

namespace epr {

/// Frames in a batch at most.
constexpr size_t kMaxBatchFrames = 100'000;

/// "1-240" (both ends included), "1-240x2" (every second frame: 1, 3, ... 239), "1,5,9", or a
/// comma-separated mix ("1-10,20,30-40x5"). Frames are sorted and unique, from 0 to kMaxFrame.
/// Throws std::invalid_argument naming the bad part.
std::vector<uint32_t> parse_frame_list(const std::string& text);

/// A fresh batch id: "b-" and 12 random hex digits.
std::string new_batch_id();
/// True for an id of 1 to 64 of [A-Za-z0-9_-].
bool valid_batch_id(const std::string& id);

/// "NAME.0007": a frame's job name and its output prefix's tail; 4 digits, more when the frame
/// number has more.
std::string frame_file_name(const std::string& prefix, uint32_t frame);

/// The jobs of a batch, one spec per frame, without their scene (scene_for gives it, per master).
struct FrameBatch {
  std::string id, name;
  SceneBundleData bundle;          // the scene, bundled once
  std::vector<uint32_t> frames;    // ascending
  std::vector<v1::JobSpec> specs;  // specs[i] renders frames[i]; scene not set
};

/// A frame window (DESIGN.md "Frame windows"): each frame's vertices also feed the frames at most
/// `frame_window` (K) away that its master renders with it, in runs of at most `run` consecutive
/// frame numbers (a gap in the frame list ends a run). 0: every frame alone.
struct WindowOptions {
  uint32_t frame_window = 0;
  uint32_t run = kDefaultWindowRun;
  // The distance in frames at which a neighbour's samples count half of the frame's own (JobSpec
  // window_halving); 0: all alike.
  float halving = 0;
  static constexpr uint32_t kDefaultWindowRun = 16;
};

/// Plans `frames` of opts.scene: each frame's camera is the scene's camera animation at that frame
/// with opts' camera overrides applied (--fov keeps every frame's field of view, for example).
/// request_id of each frame: "<batch id>-<frame>", so a retried submission does not queue a frame
/// twice. batch_id empty: new_batch_id(). Job names are frame_file_name(name, frame); the batch's
/// name is submit.name, else the scene's file or built-in name. Throws SceneError for a broken scene
/// or an unusable frame camera (naming the file, key line and frame), std::invalid_argument for bad
/// frames or names. With a window, each frame's spec carries it (frame_window, window_first, window_last:
/// its run) and the seed opts.seed + frame, so that the frames of a run trace paths of their own; a
/// window is refused (std::invalid_argument) out of range or with --mode pt or --reproject exact.
FrameBatch plan_batch(const RenderOptions& opts, const SubmitOptions& submit, const std::vector<uint32_t>& frames,
                      std::string batch_id = "", const WindowOptions& window = {});

/// The scene as a job names it on `client`'s master: a built-in by name, a file scene uploaded
/// there and named by its content hash (a master that has the scene already answers at once).
v1::SceneBundle scene_for(JobClient& client, const SceneBundleData& bundle);

/// Submits every frame of `batch` to `client`'s master: the scene once, then one job per frame, in
/// frame order. The job ids, in frame order.
std::vector<std::string> submit_batch(JobClient& client, const FrameBatch& batch);

/// Every job of the batch on `client`'s master (ListJobsRequest.batch_id, also filtered here for
/// masters that do not know the field), in frame order.
std::vector<v1::JobStatus> list_batch(JobClient& client, const std::string& batch_id);

/// Where a batch stands, from its jobs' statuses (those of every master holding some of its frames).
struct BatchSummary {
  std::string id, name;
  uint32_t frames = 0;  // of the whole batch: the largest batch_frames seen, at least the jobs found
  uint32_t done = 0, running = 0, queued = 0, failed = 0, cancelled = 0;
  double progress = 0;  // 0..1: done frames count 1, running frames their progress, the rest 0
  bool finished() const { return done + failed + cancelled >= frames; }
};
BatchSummary summarize_batch(const std::vector<v1::JobStatus>& jobs);

/// A running job's progress, 0..1, as progress_line measures it (1 when DONE).
double job_progress(const v1::JobStatus& s);

}  // namespace epr
