// A job as the master holds it, and the copy of it that status calls, watchers and the monitoring
// endpoint see (JobSnapshot). The JobManager guards every Job field with its mutex except those
// marked "reprojection thread", which only that thread touches.
#pragma once

#include <chrono>
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "common/camera.h"
#include "common/job_state.h"
#include "common/render_options.h"
#include "common/scene.h"
#include "common/tile.h"
#include "master/frame_state.h"
#include "master/round_driver.h"
#include "master/server/job_counters.h"
#include "master/server/lease_table.h"
#include "master/server/preview_state.h"
#include "master/server/tile_outcomes.h"
#include "wire/scene_bundle.h"

namespace epr {

struct JobProgressRecord;

/// The frame sequence a job belongs to (JobSpec.batch_id, client/batch.h): the master stores and
/// shows it, nothing else. An empty id: the job is not part of a batch.
struct BatchMembership {
  std::string id, name;
  std::optional<uint32_t> frame;
  uint32_t frames = 0;  // of the whole batch
};

struct JobRequest {
  RenderOptions options;  // scene field unused: the bundle is the scene
  CameraSpec camera;
  SceneBundleData bundle;
  std::string name;
  int priority = 0;
  std::optional<double> time_budget_seconds;
  std::string request_id;  // idempotency key: a retried submit returns the first job
  BatchMembership batch;
};

/// A consistent copy of a job's progress.
struct JobSnapshot {
  std::string id, name, error;
  uint64_t seq = 0;  // submission order
  JobState state = JobState::kQueued;
  int priority = 0;
  RenderOptions options;
  CameraSpec camera;
  std::string scene_hash, scene_builtin;
  uint64_t scene_bytes = 0, triangles = 0;
  FrameProgress progress;
  ReprojectionCounts counts;
  JobCounters counters;
  TileDrops drops;
  int rounds_planned = 0;
  uint32_t workers_active = 0;
  uint32_t workers_blocked = 0;  // workers given no more tiles of this job
  int64_t submitted_ms = 0, started_ms = 0, finished_ms = 0;
  double seconds_elapsed = 0, eta_seconds = -1;
  // Between rounds, summed over the rounds closed so far: from a round's last result arriving to the
  // reprojection thread having applied it (the commit queue's backlog), and from there to the next
  // round being open (M', skip mask, previews and the next round's tile inputs).
  double seconds_round_backlog = 0, seconds_round_closing = 0;
  double seconds_writing_results = 0;  // the finished job's output files, before it is done
  uint32_t round_checkpoints = 0;      // rounds whose state was checkpointed (MasterOptions::checkpoint_interval_s)
  bool budget_exhausted = false;
  uint64_t version = 0;  // increases with every change
  BatchMembership batch;
};

struct Job {
  std::string id;
  uint64_t seq = 0;  // submission order
  JobRequest request;
  JobState state = JobState::kQueued;
  std::string error;
  std::string scene_hash;
  std::shared_ptr<const SceneBundleData> bundle;
  uint64_t triangles = 0;
  Bounds3 codec_bounds;
  std::vector<TileRect> tiles;
  // Started: its first round opened in this master (a fresh job's round 0 before its frame is built,
  // so a job's seconds include that build); a resumed job keeps its first start.
  int64_t submitted_ms = 0, started_ms = 0, finished_ms = 0;
  FrameProgress progress;
  ReprojectionCounts counts;
  JobCounters counters;
  TileDrops drops;  // counters.tiles_dropped by reason, in this master's run
  bool budget_exhausted = false;
  uint64_t version = 0;

  // The current round, while running.
  std::unique_ptr<LeaseTable> leases;
  RoundPlan plan;
  uint32_t round = 0;
  uint32_t remaining = 0;  // tiles of the round not yet applied by the reprojection thread
  bool round_open = false;
  int64_t round_opened_ms = 0;            // for the round duration histogram
  double reprojecting_at_round_open = 0;  // seconds_reprojecting when the round opened
  std::chrono::steady_clock::time_point last_commit_at;
  double seconds_round_backlog = 0, seconds_round_closing = 0, seconds_writing_results = 0;
  // This master's start of the job: loading its scene (before the job runs), and building its frame
  // (a fresh job's round 0 is traced meanwhile; a resumed job's frame is built before it runs).
  double seconds_scene_load = 0, seconds_frame_build = 0;

  // Round checkpoints (MasterOptions::checkpoint_interval_s): when the last was taken (0: none yet in
  // this master's run) and what it cost, copy + write, seconds.
  int64_t last_checkpoint_ms = 0;
  double checkpoint_cost_s = 0;
  uint32_t round_checkpoints = 0;
  // Set when the job was running when the master stopped: it continues from this record.
  std::shared_ptr<const JobProgressRecord> resume;

  PreviewState preview;

  // Reprojection thread.
  int64_t counts_ms = 0;               // when `counts` was last refreshed from the reprojector
  std::shared_ptr<const Scene> scene;  // shared with the process's other users (wire/scene_shelf.h)
  std::unique_ptr<Camera> camera;
  std::unique_ptr<RoundDriver> driver;

  /// The terminal transition, made once: false (and nothing changes) if the job had ended already.
  bool end(JobState final_state, std::string why, int64_t now_ms);
  /// The job's state as a snapshot; `workers_active` is the caller's to fill in.
  JobSnapshot snapshot(int64_t now_ms) const;
  /// Adds the job's settings and counters (`c`: as of the round the statistics describe) to the
  /// statistics file that FrameState::statistics() began.
  void add_statistics(nlohmann::json* stats, const JobCounters& c, int64_t now_ms) const;
};

}  // namespace epr
