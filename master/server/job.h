// A job as the master holds it, and the copy of it that status calls, watchers and the monitoring
// endpoint see (JobSnapshot). A Job holds what more than one thread touches, each field guarded by
// its JobManager's mutex (job_lock.h) or set before the job is published; what only the reprojection
// thread touches (the job's scene, camera and RoundDriver) is that thread's (reprojection_worker.h).
#pragma once

#include <chrono>
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "common/camera.h"
#include "common/check.h"
#include "common/job_state.h"
#include "common/render_options.h"
#include "common/scene.h"
#include "common/tile.h"
#include "master/frame_state.h"
#include "master/round_driver.h"
#include "master/server/job_counters.h"
#include "master/server/job_lock.h"
#include "master/server/lease_table.h"
#include "master/server/preview_state.h"
#include "master/server/tile_outcomes.h"
#include "wire/scene_bundle.h"

namespace epr {

struct JobProgressRecord;

/// The frame sequence a job belongs to (JobSpec.batch_id, client/batch.h). An empty id: the job is
/// not part of a batch. With a frame window (window > 0) the master renders the frames numbered
/// window_first..window_last of the batch together (window_run.h, DESIGN.md "Frame windows").
struct BatchMembership {
  std::string id, name;
  std::optional<uint32_t> frame;
  uint32_t frames = 0;  // of the whole batch
  uint32_t window = 0, window_first = 0, window_last = 0;
  // The distance in frames at which a neighbour's reprojected sample counts half of the frame's own
  // (window_sample_weight); 0: all count alike.
  float window_halving = 0;
};

struct WindowRun;

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
  // A window job's window as rendered once its run started (WindowRun::fed_by): the first and last
  // frame whose vertices feed it; 0, 0 before.
  uint32_t fed_by_first = 0, fed_by_last = 0;
};

struct Job {
  Job(std::string id_, uint64_t seq_, JobRequest request_, std::string scene_hash_,
      std::shared_ptr<const SceneBundleData> bundle_, int64_t submitted_ms_)
      : id(std::move(id_)),
        seq(seq_),
        request(std::move(request_)),
        scene_hash(std::move(scene_hash_)),
        bundle(std::move(bundle_)),
        tiles(make_tiles(request.options)),
        submitted_ms(submitted_ms_) {}

  // The job's identity: fixed at construction, read by any thread without the lock.
  const std::string id;
  const uint64_t seq;  // submission order
  const JobRequest request;
  const std::string scene_hash;
  const std::shared_ptr<const SceneBundleData> bundle;
  const std::vector<TileRect> tiles;
  const int64_t submitted_ms;

  // Everything else is its manager's (job_lock.h): the analysis rejects a touch without its mutex.
  JobState state EPR_GUARDED_BY(job_fields) = JobState::kQueued;
  std::string error EPR_GUARDED_BY(job_fields);
  uint64_t triangles EPR_GUARDED_BY(job_fields) = 0;
  Bounds3 codec_bounds EPR_GUARDED_BY(job_fields);
  // Started: its first round opened in this master (a fresh job's round 0 before its frame is built,
  // so a job's seconds include that build); a resumed job keeps its first start.
  int64_t started_ms EPR_GUARDED_BY(job_fields) = 0;
  int64_t finished_ms EPR_GUARDED_BY(job_fields) = 0;
  FrameProgress progress EPR_GUARDED_BY(job_fields);
  ReprojectionCounts counts EPR_GUARDED_BY(job_fields);
  JobCounters counters EPR_GUARDED_BY(job_fields);
  TileDrops drops EPR_GUARDED_BY(job_fields);  // counters.tiles_dropped by reason, in this master's run
  bool budget_exhausted EPR_GUARDED_BY(job_fields) = false;
  uint64_t version EPR_GUARDED_BY(job_fields) = 0;

  // The current round, while running.
  std::unique_ptr<LeaseTable> leases EPR_GUARDED_BY(job_fields);
  RoundPlan plan EPR_GUARDED_BY(job_fields);
  uint32_t round EPR_GUARDED_BY(job_fields) = 0;
  uint32_t remaining EPR_GUARDED_BY(job_fields) = 0;  // tiles of the round not yet applied by the reprojection thread
  bool round_open EPR_GUARDED_BY(job_fields) = false;
  int64_t round_opened_ms EPR_GUARDED_BY(job_fields) = 0;            // for the round duration histogram
  double reprojecting_at_round_open EPR_GUARDED_BY(job_fields) = 0;  // seconds_reprojecting when the round opened
  std::chrono::steady_clock::time_point last_commit_at EPR_GUARDED_BY(job_fields);
  double seconds_round_backlog EPR_GUARDED_BY(job_fields) = 0;
  double seconds_round_closing EPR_GUARDED_BY(job_fields) = 0;
  double seconds_writing_results EPR_GUARDED_BY(job_fields) = 0;
  // This master's start of the job: loading its scene (before the job runs), and building its frame
  // (a fresh job's round 0 is traced meanwhile; a resumed job's frame is built before it runs).
  double seconds_scene_load EPR_GUARDED_BY(job_fields) = 0;
  double seconds_frame_build EPR_GUARDED_BY(job_fields) = 0;

  // Round checkpoints (MasterOptions::checkpoint_interval_s): when the last was taken (0: none yet in
  // this master's run) and what it cost, copy + write, seconds.
  int64_t last_checkpoint_ms EPR_GUARDED_BY(job_fields) = 0;
  double checkpoint_cost_s EPR_GUARDED_BY(job_fields) = 0;
  uint32_t round_checkpoints EPR_GUARDED_BY(job_fields) = 0;
  // Set when the job was running when the master stopped: it continues from this record.
  std::shared_ptr<const JobProgressRecord> resume EPR_GUARDED_BY(job_fields);

  PreviewState preview EPR_GUARDED_BY(job_fields);
  // A window job's run (window_run.h), from its start on: the frames started with it, itself included.
  std::shared_ptr<const WindowRun> run EPR_GUARDED_BY(job_fields);
  // Its window as rendered, set with `run` (WindowRun::fed_by, shares_of): the first and last frame
  // whose vertices feed it (0, 0 before), and its view's share with the frames before and after it
  // (-1: none).
  uint32_t fed_by_first EPR_GUARDED_BY(job_fields) = 0, fed_by_last EPR_GUARDED_BY(job_fields) = 0;
  double view_share_previous EPR_GUARDED_BY(job_fields) = -1, view_share_next EPR_GUARDED_BY(job_fields) = -1;

  /// The terminal transition, made once: false (and nothing changes) if the job had ended already.
  bool end(JobState final_state, std::string why, int64_t now_ms) EPR_REQUIRES(job_fields);
  /// The job's state as a snapshot; `workers_active` is the caller's to fill in.
  JobSnapshot snapshot(int64_t now_ms) const EPR_REQUIRES(job_fields);
  /// Adds the job's settings and counters (`c`: as of the round the statistics describe) to the
  /// statistics file that FrameState::statistics() began.
  void add_statistics(nlohmann::json* stats, const JobCounters& c, int64_t now_ms) const EPR_REQUIRES(job_fields);
};

}  // namespace epr
