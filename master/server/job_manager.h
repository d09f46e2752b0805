// The master's domain logic: it ties the parts together and runs the threads.
//   job_registry.h    the jobs, their queue order, idempotency keys and watchers
//   worker_registry.h the workers, their heartbeats and leases
//   lease_table.h     a running job's leases: order, expiry, speculative copies, failures, blocklist
//   lease_parking.h   LeaseTile calls kept waiting until a tile may be there
//   job_scheduling.cpp which jobs run at once and which running job a lease comes from (below)
//   round_driver.h    the round loop around FrameState (shared with the single-process render)
//   checkpointer.h    the thread that writes checkpoints (checkpoint.h: their format and folder)
//   previews.h        preview PNGs; result_files.h the finished job's files (job_results.cpp serves both)
//   job_lock.h        what the analysis checks Job fields against: this manager's mutex (JobLock)
//   reprojection_worker.h, reaper.h: the two threads' own objects (below)
// gRPC services (job_service.h, worker_service.h) only translate between the wire and this class.
//
// Threads:
//  - gRPC handlers call the public methods; each takes the manager's mutex briefly and never waits
//    for tracing or reprojection work.
//  - One reprojection thread, a ReprojectionWorker on its stack, owns the OSMesa context and every
//    running job's scene, camera and RoundDriver (each with its own reprojector and GL buffers in
//    that one context): it starts jobs (a fresh job's round 0 opens before its deep framebuffer is
//    built, a resumed job's round after its frame is restored), applies committed tiles per (job,
//    round) in commit order, closes rounds (M', skip mask), opens the next round and writes results.
//  - A reaper thread (Reaper) expires leases past their deadline and forgets silent workers.
// What more than one thread touches -- the registries, parking, the commit queue and every shared Job
// field -- is EPR_GUARDED_BY the manager's mutex (Job's fields by job_fields, job_lock.h), so clang's
// analysis (scripts/check_thread_safety.py) rejects a touch without it.
//  - The checkpointer's thread writes checkpoints.
// Several jobs at once: queued jobs start, in next_queued() order (resumed ones first, then priority,
// then submission), while the memory estimates (master/memory_estimate.h) of the running jobs and
// the next one, with one commit queue between them, fit memory_budget_bytes, and fewer than
// max_running_jobs run; the first running job always starts (a job over the budget alone is refused
// at submission). No budget (0): one job at a time. A queued job that does not fit waits for running
// ones to end; smaller jobs behind it do not pass it.
// Leasing across running jobs: a worker gets a tile of the highest-priority running job that has one
// to hand out (waiting, or a speculative copy); among equal priorities, of the job with the fewest
// leases out, then of the one leased from least recently (round robin), so that equal jobs share the
// workers evenly. A job whose round is closing has none to hand out: its workers trace the other
// jobs' tiles meanwhile.
// Back-pressure: committed tiles of every job wait in one queue bounded in vertices; while it is over
// its bound, LeaseTile answers Wait, so a fast worker cannot grow the master's memory.
// Exactly once: a tile is committed by the first complete result for (job, round, tile); later or
// duplicate results are dropped and counted. Commits of one round touch disjoint pixels, and rounds
// are applied in order, so M and the path sums do not depend on arrival order.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <variant>
#include <vector>

#include "common/check.h"
#include "common/job_state.h"
#include "common/limits.h"
#include "common/render_options.h"
#include "common/result_kinds.h"
#include "master/server/duration_histogram.h"
#include "master/server/job.h"
#include "master/server/job_registry.h"
#include "master/server/lease_parking.h"
#include "master/server/lease_table.h"
#include "master/server/tile_outcomes.h"
#include "master/server/worker_registry.h"
#include "wire/scene_bundle.h"
#include "wire/tile_result_stream.h"

namespace epr {

struct CameraAnimation;

class GlContext;
class CheckpointStore;
class Checkpointer;
struct JobProgressRecord;

struct MasterOptions {
  // The prefix of this master's job ids (NAME.j000123-abcd, master/master_name.h); empty: ids without
  // one (j000123-abcd).
  std::string name;
  std::string state_dir;  // results, scenes and checkpoints (checkpoint.h); empty: a temp folder of
                          // this manager's, removed with it (results must be fetched before)
  // Checkpoint every job after its rounds (and its spec at submit) so that a restarted master on
  // the same state_dir resumes it. Only with an explicit state_dir: a temp folder is never reopened.
  bool checkpoints = true;
  // Seconds at least between a job's round checkpoints (the first round is always checkpointed).
  // < 0, the default: automatic, kAutoCheckpointFactor x what the job's last checkpoint cost (the
  // reprojection thread's write from the live frame plus the fsync and rename), so that checkpoints take
  // at most ~5 % of the master's time however large the image; 0: after every round.
  double checkpoint_interval_s = -1;
  static constexpr double kAutoCheckpointFactor = 20;
  std::string reproject_backend_override;   // "cpu" forces the CPU reprojector (no OSMesa)
  int worker_timeout_ms = 10000;            // a worker silent this long is forgotten
  uint64_t max_queued_vertices = 8u << 20;  // back-pressure bound of the commit queue
  // The reprojection thread applies the queued commits of one job and round together, up to this
  // many records per reprojector call (0: one call per tile, as before; for comparisons).
  uint64_t reproject_batch_records = uint64_t(1) << 20;
  size_t max_scene_bytes = 256u << 20;
  // Jobs whose estimated master memory (master/memory_estimate.h) exceeds this are refused at
  // submission (INVALID_ARGUMENT, naming what they need); 0: no limit. epr-master's --memory-budget
  // defaults to 80 % of the machine's physical memory.
  uint64_t memory_budget_bytes = 0;
  // Jobs running at once, at most (the budget decides below that; no budget: one).
  int max_running_jobs = 8;
  int max_image_side = limits::kImageSide.hi;
  int max_spp = limits::kSpp.hi;  // target samples per pixel of one job
  int max_jobs = 1000;            // jobs kept (finished ones are forgotten oldest first)
  // Leases: timeout (a lease not extended by a heartbeat for this long expires), the heartbeat
  // interval asked of workers, speculative copies and the failures that block a worker (lease_table.h).
  int lease_timeout_ms = 20000;
  int heartbeat_interval_ms = 1000;
  double speculative_factor = 2.0;
  int speculative_floor_ms = 1000;
  int max_worker_failures = 3;
  int max_tile_losses = 3;
  // A running job holds a copy of its images (32 bytes per pixel) only while someone asks for its
  // previews or partial results: for this long after the last ask (Job::preview.images).
  int preview_interest_ms = 10000;
  // A window run (window_run.h) starts once all its frames are queued, or once its oldest queued
  // frame has waited this long: then with the frames that are here (the log says which are missing).
  int window_run_wait_ms = 60000;
  // A window never spans a cut (DESIGN.md "Frame windows"): where two neighbouring frames' views
  // share less than this (view_overlap.h, the smaller of the two fractions), no frame on one side
  // exchanges vertices with a frame on the other. 0: no cuts.
  double window_cut_share = 0.1;

  // Called on the reprojection thread just before a job's frame is built (a fresh job's round 0 is
  // open by then, a resumed job's not yet), with the job's id; what it throws fails the job as a
  // failed build would. For tests: to hold the build while tiles are committed, or to fail it.
  std::function<void(const std::string& job_id)> before_frame_build;
  // Called on the reprojection thread once a round's last tile is applied, before the round closes,
  // with the job's id and round. For tests: to hold a round's close while other jobs lease.
  std::function<void(const std::string& job_id, uint32_t round)> before_round_close;

  LeasePolicy lease_policy() const {
    return {lease_timeout_ms,     heartbeat_interval_ms, speculative_factor,
            speculative_floor_ms, max_worker_failures,   max_tile_losses};
  }
};

class JobManager {
 public:
  /// `clock`: Unix milliseconds (tests may inject their own).
  explicit JobManager(MasterOptions options, MillisClock clock = unix_ms);
  ~JobManager();
  JobManager(const JobManager&) = delete;
  JobManager& operator=(const JobManager&) = delete;

  // ---- clients -----------------------------------------------------------------------------------
  struct SubmitResult {
    std::string id;          // the new (or, for a repeated request_id, the earlier) job
    std::string error;       // non-empty: why the request is invalid (INVALID_ARGUMENT)
    std::string scene_hash;  // the request's scene
    bool unstored = false;   // the error: the state folder could not store the job (RESOURCE_EXHAUSTED)
  };
  SubmitResult submit(JobRequest request) EPR_EXCLUDES(mu_);
  std::optional<JobSnapshot> get(const std::string& id) const EPR_EXCLUDES(mu_);
  std::vector<JobSnapshot> list() const EPR_EXCLUDES(mu_);
  /// False if no such job.
  bool cancel(const std::string& id) EPR_EXCLUDES(mu_);
  /// Calls `listener` (from any thread, without the manager's mutex) whenever the job changes;
  /// returns a handle for unwatch(), or 0 if no such job.
  uint64_t watch(const std::string& id, std::function<void(const JobSnapshot&)> listener) EPR_EXCLUDES(mu_);
  void unwatch(uint64_t handle) EPR_EXCLUDES(mu_);
  /// Path of a finished job's result file, if it exists.
  std::optional<std::string> result_path(const std::string& id, ResultKind kind) const EPR_EXCLUDES(mu_);
  /// One result file of a job, as FetchResult serves it.
  struct ResultFile {
    enum class Error { kNone, kNoJob, kNotReady, kNotProduced, kFailed };
    Error error = Error::kNone;
    std::string why;  // with an error: the reason, for the client
    std::string bytes;
    int round = 0;         // the closed round the file reflects
    bool partial = false;  // the job is not done
  };
  /// A done job's file; a cancelled or failed job's last preview copy (partial); with
  /// `allow_partial`, a running job's latest preview copy (partial: taken when a round closed, at most
  /// about a second after the one before, or on this ask, waiting up to kPartialWaitMs for it),
  /// encoded on the calling thread.
  ResultFile result_file(const std::string& id, ResultKind kind, bool allow_partial) const EPR_EXCLUDES(mu_);
  /// Bytes of the running jobs' preview copies (Job::preview.images).
  size_t preview_copy_bytes() const EPR_EXCLUDES(mu_);
  /// PNG of a preview layer (previews.h) of the job's preview copy (encoded on demand, on the calling
  /// thread; a first ask waits up to kPreviewWaitMs for the copy), or of the finished job's results.
  std::optional<std::vector<unsigned char>> preview_png(const std::string& id, const std::string& layer) const
      EPR_EXCLUDES(mu_);
  /// The size and shape checks of a job request (dimensions, sample counts, camera, scene bundle)
  /// against the MasterOptions limits; the reason if it is invalid. submit() applies them too.
  std::optional<std::string> validate(const JobRequest& request) const;
  /// Every check of a request before submit(), the reason (for INVALID_ARGUMENT) if it is refused:
  /// the name, the batch fields, validate(), the memory budget, and check_scene() (a refusal from then
  /// on discards the checked scene again). Without `has_camera` the request takes the scene's own
  /// camera (at each of `frames`, if any: its animation's; each must be valid).
  std::optional<std::string> admit(JobRequest* request, bool has_camera, const std::vector<uint32_t>& frames = {})
      EPR_EXCLUDES(mu_);
  /// Stores an uploaded scene under its content hash.
  std::string add_scene(SceneBundleData bundle) EPR_EXCLUDES(mu_);
  /// Loads the scene to check it; the reason (naming file and line inside the bundle) if it is bad.
  /// `scene_camera`, if given, receives the scene's own camera, `animation` its camera keyframes.
  std::optional<std::string> check_scene(const SceneBundleData& bundle, CameraSpec* scene_camera = nullptr,
                                         CameraAnimation* animation = nullptr, const Lighting& lighting = {}) const
      EPR_EXCLUDES(mu_);
  /// The scene check_scene() loaded last stays loaded for the job's start (one load per submission):
  /// kept until a scene is checked after it, its check is discarded, or a job of it starts with no
  /// other job of it queued. Lets go of it here if `content_hash` is that scene and none is queued.
  void release_checked_scene(const std::string& content_hash) EPR_EXCLUDES(mu_);
  /// Removes what check_scene() left in the scene cache (scenes/HASH) for a submission that was
  /// refused, unless a job or another check still uses it. Built-in scenes are never cached.
  void discard_checked_scene(const std::string& content_hash) EPR_EXCLUDES(mu_);
  /// The scene files of a hash, for FetchScene.
  std::shared_ptr<const SceneBundleData> scene(const std::string& hash) const EPR_EXCLUDES(mu_);

  // ---- workers -----------------------------------------------------------------------------------
  /// `cached_scenes`: hashes of the scenes the worker holds; parked lease requests of workers that
  /// hold the running job's scene are answered first.
  std::string register_worker(const std::string& name, uint32_t threads, std::vector<std::string> cached_scenes = {})
      EPR_EXCLUDES(mu_);
  /// Extends the listed leases; returns per lease whether it is still wanted and its deadline.
  /// Nullopt for an unknown worker.
  std::optional<std::vector<std::pair<bool, int64_t>>> heartbeat(const std::string& worker,
                                                                 const std::vector<uint64_t>& leases) EPR_EXCLUDES(mu_);
  LeaseDecision lease_tile(const std::string& worker) EPR_EXCLUDES(mu_);
  /// Like lease_tile, but a worker that would be told to wait briefly (the round is closing, every
  /// tile of the round is out, or no job has started yet) is kept waiting instead, for up to
  /// max_wait_ms (at most kMaxParkMs): then `answer` is called later, exactly once, from another thread
  /// and without the manager's mutex, as soon as a tile may be there or when the time is up -- unless
  /// cancel_parked(*handle) returned true first. Returns the decision if it is made now (`answer` is
  /// then never called).
  std::optional<LeaseDecision> lease_tile_or_park(const std::string& worker, int max_wait_ms,
                                                  std::function<void(LeaseDecision)> answer, uint64_t* handle)
      EPR_EXCLUDES(mu_);
  /// True if the parked request was still waiting (its `answer` will not be called).
  bool cancel_parked(uint64_t handle) EPR_EXCLUDES(mu_);
  /// Answers every parked request with a Wait now and parks no more (before the server shuts down).
  void stop_parking() EPR_EXCLUDES(mu_);
  /// LeaseTile requests being held (for tests and monitoring).
  size_t parked_requests() const EPR_EXCLUDES(mu_);
  static constexpr int kMaxParkMs = 2000;
  /// How long preview_png() and result_file() wait for a copy they asked for.
  static constexpr int kPreviewWaitMs = 5000, kPartialWaitMs = 30000;
  void return_leases(const std::string& worker, const std::vector<uint64_t>& leases) EPR_EXCLUDES(mu_);
  void unregister_worker(const std::string& worker) EPR_EXCLUDES(mu_);
  /// Gives leases back; with a failure other than kNone, also counts one failure of `worker` for the
  /// job of each lease (blocking the worker past max_worker_failures, failing the job once every
  /// registered worker is blocked). `reason` is kept for the job's error message.
  void fail_leases(const std::string& worker, const std::vector<uint64_t>& leases, LeaseFailure failure,
                   const std::string& reason) EPR_EXCLUDES(mu_);
  std::vector<WorkerSnapshot> workers() const EPR_EXCLUDES(mu_);

  /// The verdict on a SubmitTile stream whose header names this lease, job, round and tile: what it must contain, or
  /// why it is refused or drained as stale.
  TileCheck expect(const TileResultIdentity& result) const EPR_EXCLUDES(mu_);
  /// Counts a complete result of a still-known job as dropped for `reason` (a stale verdict of expect()).
  void count_dropped(const std::string& job_id, DropReason reason) EPR_EXCLUDES(mu_);
  /// Commits a complete, checked tile result (never blocks on reprojection).
  CommitOutcome commit(const std::string& job_id, uint32_t round, uint32_t tile_index, AssembledTile tile)
      EPR_EXCLUDES(mu_);

  /// Graceful stop (epr-master on SIGTERM, before shutdown(); job_drain.cpp): no queued job starts and
  /// no running job opens another round; the rounds open now are leased, traced and applied to their
  /// end, and each job's state after its round is checkpointed whatever checkpoint_interval_s says (a
  /// job whose last round closes finishes as usual). Waits until every running job is checkpointed or
  /// ended, at most `timeout`; less once no worker is registered and no committed tile waits to be
  /// applied, or once `give_up` (polled with the manager's mutex held) returns true. True when every
  /// running job was checkpointed or ended; a job whose round did not close resumes from its last
  /// checkpoint. Without checkpoints: true at once.
  bool drain_and_checkpoint(std::chrono::milliseconds timeout, const std::function<bool()>& give_up = {})
      EPR_EXCLUDES(mu_);
  /// Stops the threads (idempotent); pending work is dropped.
  void shutdown() EPR_EXCLUDES(mu_);
  bool gl_ready() const EPR_EXCLUDES(mu_);
  /// Round and reprojection durations of every round closed so far (for /metrics).
  DurationHistograms histograms() const EPR_EXCLUDES(mu_);
  /// Tiles not yet committed in the current round of every running job, plus the first round's tiles
  /// of every queued job (for a queued resumed job, all its tiles: an upper bound). /metrics
  /// epr_tiles_waiting: what an autoscaler sizes the workers by.
  uint64_t tiles_waiting() const EPR_EXCLUDES(mu_);
  const MasterOptions& options() const { return options_; }
  /// This run's number in the state directory (1 for a new one). Lease ids carry it above bit
  /// kLeaseEpochShift, so a lease of an earlier run is never mistaken for one of this run.
  uint64_t epoch() const { return epoch_; }
  static constexpr int kLeaseEpochShift = 40;

 private:
  struct Task {
    std::shared_ptr<Job> job;
    uint32_t round = 0, tile_index = 0;
    AssembledTile tile;
  };

  LeaseDecision decide_lease(const std::string& worker, bool* parkable) EPR_REQUIRES(mu_, job_fields);
  /// Whether `next` (one job, or a window run's frames as one unit) may start beside the running jobs
  /// (memory budget, max_running_jobs).
  bool admits(const std::vector<std::shared_ptr<Job>>& next) const EPR_REQUIRES(mu_, job_fields);
  /// The queued frames of `job`'s window run (window_run.h) if the run may start now: all its frames
  /// are here (or have ended), or its oldest queued frame has waited window_run_wait_ms; `job` alone if
  /// its run started already (a late frame). Empty while the run waits for frames.
  std::vector<std::shared_ptr<Job>> startable_run(const std::shared_ptr<Job>& job) const EPR_REQUIRES(mu_, job_fields);
  /// Removes `job` from running_ (it finished, failed or was cancelled).
  void stop_running(const std::shared_ptr<Job>& job) EPR_EXCLUDES(mu_);
  TileLeaseInfo grant(Job& job, const std::string& worker, const LeaseTable::Grant& g, uint64_t lease)
      EPR_REQUIRES(mu_, job_fields);
  void wake_parked(bool all) EPR_REQUIRES(mu_, job_fields);
  void answer_due() EPR_EXCLUDES(mu_);
  JobSnapshot snapshot(const Job& job) const EPR_REQUIRES(mu_, job_fields);
  void notify(const std::shared_ptr<Job>& job) EPR_EXCLUDES(mu_);
  /// Fails the running job if one of its tiles was given up (its leases expired max_tile_losses
  /// times: lease_table.h) or every registered worker is blocked for it.
  void fail_if_stuck(const std::shared_ptr<Job>& job, std::vector<std::shared_ptr<Job>>* failed)
      EPR_REQUIRES(mu_, job_fields);
  std::string job_dir(const Job& job) const;
  std::string cache_dir() const;

  // The reprojection thread (reprojection_worker.h) and the reaper (reaper.h): each thread's own
  // object, which reaches the manager's shared state under mu_.
  friend class ReprojectionWorker;
  friend class Reaper;
  void start_threads();  // job_threads.cpp
  /// One step of the reprojection thread: decided under the mutex (next_work, which also takes what
  /// it decides on: a dropped job out of running_, a started one into it, a batch out of the commit
  /// queue), then done without it (ReprojectionWorker::do_work).
  struct RenderWork {
    // The first that applies: stop; drop a cancelled or failed job; start a queued one; take an
    // asked-for preview copy; apply a batch of queued commits. kWait: nothing to do yet.
    enum class Kind { kWait, kStop, kDrop, kStart, kCopy, kApply };
    Kind kind = Kind::kWait;
    std::shared_ptr<Job> job;
    JobCounters counters;                      // kCopy: the copy's statistics as of the decision
    std::vector<std::unique_ptr<Task>> batch;  // kApply: one job and round, in commit order
    std::vector<std::shared_ptr<Job>> start;   // kStart: the job, or a window run's frames (job: the first)
  };
  RenderWork next_work() EPR_REQUIRES(mu_, job_fields);
  std::shared_ptr<Job> ended_job() const EPR_REQUIRES(mu_, job_fields);
  std::vector<std::shared_ptr<Job>> startable_jobs() const EPR_REQUIRES(mu_, job_fields);
  std::shared_ptr<Job> copy_asked_job() const EPR_REQUIRES(mu_, job_fields);
  /// Opens job.round with `plan` (RoundDriver::open, or first_plan before a fresh job's frame exists);
  /// `reprojecting`: the job's seconds_reprojecting as the round opens (0 without a frame yet).
  void open_round(Job& job, RoundPlan plan, double reprojecting) EPR_REQUIRES(mu_, job_fields);
  void end_job(const std::shared_ptr<Job>& job, JobState state, const std::string& error) EPR_EXCLUDES(mu_);
  /// Notes an ask for a preview or partial results of a running job; true if a copy is coming (being
  /// taken, or requested now: the job has a closed round and no copy) and the caller may wait for it
  /// on copy_cv_.
  bool ask_for_copy(Job& job) const EPR_REQUIRES(mu_, job_fields);

  // Checkpoints: the state directory at start, and the records written after rounds and at the end.
  void load_state() EPR_EXCLUDES(mu_);
  void save_final_checkpoint(const std::shared_ptr<Job>& job) EPR_EXCLUDES(mu_);

  MasterOptions options_;
  MillisClock clock_;
  mutable Mutex mu_;
  mutable std::condition_variable_any work_cv_;
  mutable std::condition_variable_any copy_cv_;  // a preview copy was taken, or a job ended
  JobRegistry jobs_ EPR_GUARDED_BY(mu_);
  WorkerRegistry workers_ EPR_GUARDED_BY(mu_);
  LeaseParking parking_ EPR_GUARDED_BY(mu_);
  std::map<std::string, std::shared_ptr<const SceneBundleData>> scenes_ EPR_GUARDED_BY(mu_);
  mutable std::map<std::string, int> scene_checks_ EPR_GUARDED_BY(mu_);  // check_scene() calls under way, by hash
  // The scene check_scene() loaded last and its hash (release_checked_scene).
  mutable std::pair<std::string, std::shared_ptr<const Scene>> checked_scene_ EPR_GUARDED_BY(mu_);
  std::deque<std::unique_ptr<Task>> tasks_ EPR_GUARDED_BY(mu_);
  uint64_t queued_vertices_ EPR_GUARDED_BY(mu_) = 0;
  uint64_t next_lease_ EPR_GUARDED_BY(mu_) = 1;
  // Jobs started and not yet finished or dropped, in start order (a job being started is still kQueued).
  std::vector<std::shared_ptr<Job>> running_ EPR_GUARDED_BY(mu_);
  bool stopping_ EPR_GUARDED_BY(mu_) = false;
  bool gl_ready_ EPR_GUARDED_BY(mu_) = false;
  bool draining_ EPR_GUARDED_BY(mu_) = false;             // drain_and_checkpoint() was called
  std::vector<std::string> drained_ EPR_GUARDED_BY(mu_);  // jobs checkpointed by the drain
  DurationHistograms histograms_ EPR_GUARDED_BY(mu_);
  std::string state_dir_;
  std::unique_ptr<CheckpointStore> store_;
  std::unique_ptr<Checkpointer> checkpointer_;  // with options_.checkpoints and an explicit state_dir
  uint64_t epoch_ = 0;
  std::thread reprojection_thread_, reaper_thread_;
};

}  // namespace epr
