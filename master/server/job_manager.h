// The master's domain logic: job queue, per-job round state machine, tile lease table, worker
// registry and the commit pipeline into the reprojection thread (DESIGN.md section 2).
//
// Threads:
//  - gRPC handlers call the public methods; each takes the manager's mutex briefly and never waits
//    for tracing or reprojection work.
//  - One reprojection thread owns the OSMesa context and every job's FrameState: it starts jobs
//    (deep framebuffer), applies committed tiles in commit order, closes rounds (M', skip mask),
//    opens the next round and writes results.
//  - A reaper thread re-queues tiles whose lease deadline passed and forgets silent workers.
// Slow and failing workers: once a round has no unleased tile, an idle worker gets a speculative copy
// of the tile whose lease runs longest (MasterOptions::speculative_factor); the first complete result
// wins and the other lease is told "not wanted". Leases that expire, results refused as invalid and
// failures workers report count per worker and job; past max_worker_failures the worker gets no more
// tiles of the job, and a job every registered worker is blocked for fails with the last reason.
// Back-pressure: committed tiles wait in a queue bounded in vertices; while it is over its bound,
// LeaseTile answers Wait, so a fast worker cannot grow the master's memory (at most the bound plus
// the tiles already leased).
// Exactly once: a tile is committed by the first complete result for (job, round, tile); later or
// duplicate results are dropped and counted. Commits of one round touch disjoint pixels, and rounds
// are applied in order, so M and the path sums do not depend on arrival order.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <variant>
#include <vector>

#include <nlohmann/json.hpp>

#include "common/render_options.h"
#include "master/frame_state.h"
#include "master/server/duration_histogram.h"
#include "wire/scene_bundle.h"
#include "wire/tile_result_stream.h"
#include "worker/tile_renderer.h"

namespace epr {

class GlContext;
class CheckpointStore;
struct JobProgressRecord;

struct MasterOptions {
  std::string state_dir;  // results, scenes and checkpoints (checkpoint.h); empty: a temp folder of
                          // this manager's, removed with it (results must be fetched before)
  // Checkpoint every job after its rounds (and its spec at submit) so that a restarted master on
  // the same state_dir resumes it. Only with an explicit state_dir: a temp folder is never reopened.
  bool checkpoints = true;
  // Seconds at least between a job's round checkpoints (the first round is always checkpointed).
  // < 0, the default: automatic, kAutoCheckpointFactor x what the job's last checkpoint cost (the
  // frame copy on the reprojection thread plus encoding and writing it), so that checkpoints take
  // at most ~5 % of the master's time however large the image; 0: after every round.
  double checkpoint_interval_s = -1;
  static constexpr double kAutoCheckpointFactor = 20;
  std::string reproject_backend_override; // "cpu" forces the CPU reprojector (no OSMesa)
  int lease_timeout_ms = 20000;           // a lease not extended by a heartbeat for this long expires
  int heartbeat_interval_ms = 1000;       // asked of workers
  int worker_timeout_ms = 10000;          // a worker silent this long is forgotten
  uint64_t max_queued_vertices = 8u << 20;  // back-pressure bound of the commit queue
  size_t max_scene_bytes = 256u << 20;
  int max_image_side = 16384;
  int max_spp = 1000000;                  // target samples per pixel of one job
  int max_jobs = 1000;                    // jobs kept (finished ones are forgotten oldest first)
  // Speculative re-lease: once a round has no unleased tile left, an idle worker gets a copy of the
  // tile whose lease has run longest, if it has run longer than speculative_factor x the median tile
  // time of the round so far (of the previous round while none of this one is committed) and at least
  // speculative_floor_ms, and its holder is alive (a heartbeat extended the lease within 1.5 heartbeat
  // intervals; a dead worker's tile comes back by expiry). At most one copy per tile and round.
  // speculative_factor <= 0: never.
  double speculative_factor = 2.0;
  int speculative_floor_ms = 1000;
  // A worker that fails this many tiles of a job (lease expired without a result, result refused as
  // invalid, failure reported with ReturnLease) gets no more tiles of it; a job every registered worker
  // is blocked for fails. <= 0: never block.
  int max_worker_failures = 3;
};

enum class JobState { kQueued, kRunning, kDone, kFailed, kCancelled };
const char* to_string(JobState s);

struct JobRequest {
  RenderOptions options;  // scene field unused: the bundle is the scene
  CameraSpec camera;
  SceneBundleData bundle;
  std::string name;
  int priority = 0;
  std::optional<double> time_budget_seconds;
  std::string request_id;  // idempotency key: a retried submit returns the first job
};

/// A consistent copy of a job's progress for status calls, watchers and the monitoring endpoint.
struct JobSnapshot {
  std::string id, name, error;
  JobState state = JobState::kQueued;
  int priority = 0;
  RenderOptions options;
  CameraSpec camera;
  std::string scene_hash, scene_builtin;
  uint64_t scene_bytes = 0, triangles = 0;
  FrameProgress progress;
  ReprojectionCounts counts;
  int rounds_planned = 0;
  uint64_t rays_traced = 0, vertices_received = 0, non_finite_dropped = 0;
  uint64_t worker_culled = 0;  // culled by workers before sending (frustum, facing, glossy)
  uint64_t tiles_leased = 0, tiles_committed = 0, tiles_re_leased = 0, tiles_dropped = 0;
  uint64_t tiles_speculative = 0;  // speculative copies handed out (MasterOptions::speculative_factor)
  uint64_t worker_failures = 0;    // failed leases counted against workers
  uint32_t workers_active = 0;
  uint32_t workers_blocked = 0;    // workers given no more tiles of this job
  int64_t submitted_ms = 0, started_ms = 0, finished_ms = 0;
  double seconds_elapsed = 0, eta_seconds = -1, seconds_tracing = 0, seconds_reprojecting = 0;
  // Between rounds, summed over the rounds closed so far: from a round's last result arriving to the
  // reprojection thread having applied it (the commit queue's backlog), and from there to the next
  // round being open (M', skip mask, previews and the next round's tile inputs).
  double seconds_round_backlog = 0, seconds_round_closing = 0;
  double seconds_writing_results = 0;  // the finished job's output files, before it is done
  uint32_t round_checkpoints = 0;      // rounds whose state was checkpointed (MasterOptions::checkpoint_interval_s)
  bool budget_exhausted = false;
  uint64_t version = 0;  // increases with every change
};

struct TileLeaseInfo {
  uint64_t lease_id = 0;
  std::string job_id;
  uint32_t round = 0, tile_index = 0;
  TileRect rect;
  std::vector<uint8_t> skip;           // per tile pixel
  std::vector<uint32_t> first_sample;  // per tile pixel
  uint32_t paths_per_pixel = 1;
  uint64_t seed = 0;
  RenderOptions options;
  CameraSpec camera;
  Bounds3 codec_bounds;
  std::string scene_hash, scene_builtin;
  uint64_t scene_bytes = 0, triangles = 0;
  int64_t deadline_ms = 0;
};
struct LeaseWait {
  uint32_t retry_after_ms = 200;
};
struct UnknownWorker {};
using LeaseDecision = std::variant<TileLeaseInfo, LeaseWait, UnknownWorker>;

enum class CommitOutcome { kCommitted, kDuplicate, kStale };

/// Why a worker gives a lease back (ReturnLeaseRequest.failure).
enum class LeaseFailure { kNone, kScene, kTile, kInvalidResult, kExpired };

struct WorkerSnapshot {
  std::string id, name;
  uint32_t threads = 0;
  double heartbeat_age_seconds = 0;
  uint64_t tiles_committed = 0, paths_traced = 0;
  double paths_per_second = 0;  // over its committed tiles' tracing time
  size_t leases_held = 0;
};

class JobManager {
 public:
  explicit JobManager(MasterOptions options);
  ~JobManager();
  JobManager(const JobManager&) = delete;
  JobManager& operator=(const JobManager&) = delete;

  // ---- clients -----------------------------------------------------------------------------------
  struct SubmitResult {
    std::string id;     // the new (or, for a repeated request_id, the earlier) job
    std::string error;  // non-empty: why the request is invalid (INVALID_ARGUMENT)
  };
  SubmitResult submit(JobRequest request);
  std::optional<JobSnapshot> get(const std::string& id) const;
  std::vector<JobSnapshot> list() const;
  /// False if no such job.
  bool cancel(const std::string& id);
  /// Calls `listener` (from any thread, without the manager's mutex) whenever the job changes;
  /// returns a handle for unwatch(), or 0 if no such job.
  uint64_t watch(const std::string& id, std::function<void(const JobSnapshot&)> listener);
  void unwatch(uint64_t handle);
  /// Path of a finished result file ("exr", "png", "samples.png", "json", "pathtrace.exr",
  /// "reprojection.exr"), if it exists.
  std::optional<std::string> result_path(const std::string& id, const std::string& kind) const;
  /// PNG of a layer ("combined", "pathtrace", "reprojection", "samples") as of a round that closed
  /// at most a second after the previous preview (encoded on demand, on the calling thread), or of
  /// the finished job's results.
  std::optional<std::vector<unsigned char>> preview_png(const std::string& id, const std::string& layer) const;

  // ---- workers -----------------------------------------------------------------------------------
  std::string register_worker(const std::string& name, uint32_t threads);
  /// Extends the listed leases; returns per lease whether it is still wanted and its deadline.
  /// Nullopt for an unknown worker.
  std::optional<std::vector<std::pair<bool, int64_t>>> heartbeat(const std::string& worker,
                                                                  const std::vector<uint64_t>& leases);
  LeaseDecision lease_tile(const std::string& worker);
  /// Like lease_tile, but a worker that would be told to wait briefly (the round is closing, every
  /// tile of the round is out, or no job has started yet) is kept waiting instead, for up to
  /// max_wait_ms (at most kMaxParkMs): then `answer` is called later, exactly once, from another thread
  /// and without the manager's mutex, as soon as a tile may be there (a round opened, a tile came back)
  /// or when the time is up -- unless cancel_parked(*handle) returned true first. Returns the decision
  /// if it is made now (`answer` is then never called). A worker answered at once at a round barrier
  /// polled every few milliseconds; this answers it the moment the next round opens.
  std::optional<LeaseDecision> lease_tile_or_park(const std::string& worker, int max_wait_ms,
                                                  std::function<void(LeaseDecision)> answer, uint64_t* handle);
  /// True if the parked request was still waiting (its `answer` will not be called).
  bool cancel_parked(uint64_t handle);
  /// Answers every parked request with a Wait now and parks no more (before the server shuts down).
  void stop_parking();
  /// LeaseTile requests being held (for tests and monitoring).
  size_t parked_requests() const;
  static constexpr int kMaxParkMs = 2000;
  void return_leases(const std::string& worker, const std::vector<uint64_t>& leases);
  void unregister_worker(const std::string& worker);
  /// Gives leases back; with a failure other than kNone, also counts one failure of `worker` for the
  /// job of each lease (blocking the worker past max_worker_failures, failing the job once every
  /// registered worker is blocked). `reason` is kept for the job's error message.
  void fail_leases(const std::string& worker, const std::vector<uint64_t>& leases, LeaseFailure failure,
                   const std::string& reason);
  std::vector<WorkerSnapshot> workers() const;
  /// The size and shape checks of a job request (dimensions, sample counts, camera, scene bundle)
  /// against the MasterOptions limits; the reason if it is invalid. submit() applies them too.
  std::optional<std::string> validate(const JobRequest& request) const;
  /// Stores an uploaded scene under its content hash.
  std::string add_scene(SceneBundleData bundle);
  /// Loads the scene to check it; the reason (naming file and line inside the bundle) if it is bad.
  std::optional<std::string> check_scene(const SceneBundleData& bundle) const;
  /// The scene files of a hash, for FetchScene.
  std::shared_ptr<const SceneBundleData> scene(const std::string& hash) const;

  /// What a SubmitTile stream with this header must contain, or why it cannot be accepted
  /// (`stale` is set when the job or round moved on: the stream is drained and acknowledged as stale).
  std::variant<TileExpectation, std::string> expect(const v1::TileResultHeader& header, bool* stale) const;
  /// Counts a complete result that arrived for a closed round of a still-known job as dropped.
  void count_stale(const std::string& job_id);
  /// Commits a complete, checked tile result (never blocks on reprojection).
  CommitOutcome commit(const std::string& job_id, uint32_t round, uint32_t tile_index, AssembledTile tile);

  /// Stops the threads (idempotent); pending work is dropped.
  void shutdown();
  bool gl_ready() const;
  /// Round and reprojection durations of every round closed so far (for /metrics).
  DurationHistograms histograms() const;
  const MasterOptions& options() const { return options_; }
  /// This run's number in the state directory (1 for a new one). Lease ids carry it above bit
  /// kLeaseEpochShift, so a lease of an earlier run is never mistaken for one of this run.
  uint64_t epoch() const { return epoch_; }
  static constexpr int kLeaseEpochShift = 40;

 private:
  struct Job;
  struct Worker;
  struct Task;

  LeaseDecision lease_tile_locked(const std::string& worker, bool* parkable);  // with mu_ held
  void wake_parked(bool all);  // with mu_ held: decides what can be decided (all: every request) into due_
  void answer_due();           // without mu_: calls the answers wake_parked decided
  void reprojection_loop();
  void reaper_loop();
  void start_job(const std::shared_ptr<Job>& job, GlContext* gl);
  void apply_commit(Task& task);
  void close_round(const std::shared_ptr<Job>& job);
  void open_round(Job& job);  // with mu_ held
  void finish_job(const std::shared_ptr<Job>& job, bool budget_exhausted);
  static std::optional<std::vector<unsigned char>> encode_preview(const FrameImages& images, bool reprojects,
                                                                  const std::string& layer);
  static std::optional<std::vector<unsigned char>> result_preview(const std::string& dir, const std::string& layer);
  void notify(const std::shared_ptr<Job>& job);
  JobSnapshot snapshot(const Job& job) const;  // with mu_ held
  std::shared_ptr<Job> next_job() const;        // with mu_ held
  std::string job_dir(const Job& job) const;
  // Failures and speculative leases (with mu_ held).
  void count_failure(const std::shared_ptr<Job>& job, const std::string& worker, LeaseFailure failure,
                     const std::string& reason, std::vector<std::shared_ptr<Job>>* failed);
  void fail_if_all_blocked(const std::shared_ptr<Job>& job, std::vector<std::shared_ptr<Job>>* failed);
  std::optional<uint32_t> speculative_tile(Job& job, const std::string& worker, int64_t now);
  void release_lease(Job& job, uint32_t tile, uint64_t lease);
  // Checkpoints (checkpoint.h): loading the state directory, and the records written after each
  // round, at the end of a job and when it is cancelled or fails.
  void load_state();
  JobProgressRecord progress_record(const Job& job) const;                                // with mu_ held
  void save_round_checkpoint(const std::shared_ptr<Job>& job, JobProgressRecord record);  // reprojection thread
  void save_final_checkpoint(const std::shared_ptr<Job>& job);
  void enqueue_checkpoint(const std::string& job_id, JobProgressRecord record);  // with checkpoint_mu_ held
  void checkpoint_loop();

  MasterOptions options_;
  mutable std::mutex mu_;
  std::condition_variable work_cv_;
  std::map<std::string, std::shared_ptr<Job>> jobs_;
  std::map<std::string, std::string> request_ids_;
  std::map<std::string, std::unique_ptr<Worker>> workers_;
  std::map<std::string, std::shared_ptr<const SceneBundleData>> scenes_;
  std::deque<std::unique_ptr<Task>> tasks_;
  uint64_t queued_vertices_ = 0;
  uint64_t next_job_seq_ = 1, next_lease_ = 1, next_worker_ = 1, next_watch_ = 1;
  std::map<uint64_t, std::pair<std::string, std::function<void(const JobSnapshot&)>>> watchers_;
  std::shared_ptr<Job> active_;  // the job whose tiles are being leased
  struct Parked {
    std::string worker;
    int64_t deadline_ms = 0;
    std::function<void(LeaseDecision)> answer;
  };
  std::map<uint64_t, Parked> parked_;  // LeaseTile requests kept waiting, oldest first
  uint64_t next_parked_ = 1;
  bool parking_stopped_ = false;
  std::vector<std::pair<std::function<void(LeaseDecision)>, LeaseDecision>> due_;  // decided, to be answered
  bool stopping_ = false;
  bool gl_ready_ = false;
  DurationHistograms histograms_;
  std::string state_dir_;
  std::unique_ptr<CheckpointStore> store_;
  // Checkpoints are written by their own thread (the reprojection thread only copies the frame):
  // a queue with at most one record per job, a newer record replacing a pending older one. A job's
  // state is read and its record queued under checkpoint_mu_, so its last record is its last state.
  std::mutex checkpoint_mu_;
  std::condition_variable checkpoint_cv_;
  std::deque<std::pair<std::string, std::shared_ptr<const JobProgressRecord>>> checkpoint_queue_;
  bool checkpoint_stopping_ = false;
  std::thread checkpoint_thread_;
  uint64_t epoch_ = 0;
  bool checkpointing_ = false;  // options_.checkpoints with an explicit state_dir
  std::thread reprojection_thread_, reaper_thread_;
};

}  // namespace epr
