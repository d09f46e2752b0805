// The JobManager's reprojection thread (job_manager.h), for every running job: it starts queued jobs
// as the memory budget admits them (scene; a fresh job's round 0 opens, then its deep framebuffer is
// built; a resumed job's frame is restored first), applies committed tiles per (job, round) in commit
// order through the job's RoundDriver, closes rounds and opens the next, writes finished jobs'
// results, drops cancelled and failed ones, and takes round checkpoints. Each step serves one job;
// the commit queue interleaves jobs, and a batch never spans two (job, round) pairs. Each step is
// decided under the manager's mutex (JobManager::next_work) and done without it (do_work).
//
// The worker lives on the thread's stack (JobManager starts the thread with run()), so what it owns
// -- the OSMesa context and each running job's scene, camera and RoundDriver -- no other thread can
// reach; every Job field it shares it touches under the manager's mutex (job_lock.h).
#pragma once

#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "common/camera.h"
#include "common/check.h"
#include "common/scene.h"
#include "master/round_driver.h"
#include "master/server/checkpoint.h"
#include "master/server/job_manager.h"
#include "master/server/window_run.h"

namespace epr {

class GlContext;

class ReprojectionWorker {
 public:
  explicit ReprojectionWorker(JobManager& manager);
  ~ReprojectionWorker();
  ReprojectionWorker(const ReprojectionWorker&) = delete;
  ReprojectionWorker& operator=(const ReprojectionWorker&) = delete;
  /// The thread's loop, until JobManager::shutdown().
  void run() EPR_EXCLUDES(m_.mu_);

 private:
  using RenderWork = JobManager::RenderWork;
  using Task = JobManager::Task;
  using Batch = std::vector<std::unique_ptr<Task>>;
  /// What end_round() leaves for the next round's opening: the round's checkpoint record, the
  /// counters as of its close, and whether a preview copy is wanted.
  struct ClosedRound {
    JobProgressRecord checkpoint;
    JobCounters at_close;
    bool want_preview = false;
  };
  /// A window neighbour's committed tiles of `round`, to be reprojected into this frame (with
  /// `units` per sample) once the frame has closed that round (reprojection_window.cpp).
  struct Deferred {
    uint32_t round = 0, from_frame = 0, units = 1;
    std::shared_ptr<const Batch> batch;
  };
  /// What only this thread touches of a running job.
  struct Render {
    std::shared_ptr<const Scene> scene;  // shared with the process's other users (wire/scene_shelf.h)
    std::unique_ptr<Camera> camera;
    std::unique_ptr<RoundDriver> driver;  // null until the job's frame is built
    int64_t counts_ms = 0;                // when the job's `counts` were last refreshed from the reprojector
    // A window frame (reprojection_window.cpp): its neighbours' tiles of rounds it has not closed
    // yet; a closed round whose next round a drain keeps shut until its neighbours' tiles of it are
    // in (`held`); and the record of a checkpoint after round `checkpoint_round` waiting for them,
    // the next round open meanwhile and its own tiles waiting to be applied (`own`).
    std::vector<Deferred> deferred;
    std::optional<ClosedRound> held;
    std::optional<JobProgressRecord> checkpoint;
    uint32_t checkpoint_round = 0;
    std::vector<std::shared_ptr<const Batch>> own;
  };
  /// A window run's decisions that its frames, closing their rounds one by one, share: the rounds
  /// after which they checkpoint, the highest round closed so far, and where a drain stops them.
  struct RunRounds {
    std::set<uint32_t> checkpoint;
    int64_t closed = -1;
    std::optional<uint32_t> drain;
  };

  void do_work(RenderWork& work) EPR_EXCLUDES(m_.mu_);
  /// The job's driver, null if its frame is not built (or the job is not this thread's any more).
  RoundDriver* driver(const Job& job);
  /// start_job(), failing the job if it throws.
  void start_or_fail(const std::shared_ptr<Job>& job) EPR_EXCLUDES(m_.mu_);
  void start_job(const std::shared_ptr<Job>& job) EPR_EXCLUDES(m_.mu_);
  /// Fails a job that could not start (`why`), closing its round 0 if open.
  void fail_start(const std::shared_ptr<Job>& job, const std::string& why) EPR_EXCLUDES(m_.mu_);
  /// start_job()'s first part: the job's Render with its scene and camera; returns its checkpoint
  /// (taken from Job::resume), null for a fresh job.
  std::shared_ptr<const JobProgressRecord> prepare_job(const std::shared_ptr<Job>& job) EPR_EXCLUDES(m_.mu_);
  /// Builds the job's frame (RoundDriver: deep framebuffer, accumulation) after prepare_job().
  void build_frame(const std::shared_ptr<Job>& job) EPR_EXCLUDES(m_.mu_);
  /// A starting job runs (unless it was cancelled meanwhile): its leases and its first round in this
  /// master open (round 0 of a fresh job, before its frame exists; the next round of a resumed one,
  /// from its restored frame and `resume`, its checkpoint or null), and parked workers hear of it.
  /// False if it was cancelled meanwhile.
  bool begin_running(const std::shared_ptr<Job>& job, const JobProgressRecord* resume) EPR_EXCLUDES(m_.mu_);
  /// Applies queued commits of one job and round, in commit order (RoundDriver::apply of a span).
  void apply_commits(std::shared_ptr<const Batch> batch) EPR_EXCLUDES(m_.mu_);
  /// end_round(), then open_next_round() with the job's own checkpoint interval.
  void close_round(const std::shared_ptr<Job>& job) EPR_EXCLUDES(m_.mu_);
  /// Closes the job's round (M', skip mask, progress); finishes the job if no round is left or its
  /// time budget is over (then nullopt).
  std::optional<ClosedRound> end_round(const std::shared_ptr<Job>& job) EPR_EXCLUDES(m_.mu_);
  /// After end_round(): a draining master's checkpoint instead (`may_drain`), or the next round opens;
  /// then the preview copy and the round's checkpoint (`checkpoint`: whether it is due, decided for a
  /// whole window run; unset: the job's own checkpoint interval decides).
  void open_next_round(const std::shared_ptr<Job>& job, ClosedRound closed, std::optional<bool> checkpoint,
                       bool may_drain = true) EPR_EXCLUDES(m_.mu_);
  void finish_job(const std::shared_ptr<Job>& job, bool budget_exhausted) EPR_EXCLUDES(m_.mu_);
  void drop_job(const std::shared_ptr<Job>& job) EPR_EXCLUDES(m_.mu_);
  /// Replaces the job's preview copy with one of its frame as it stands, with `counters`' statistics.
  void take_preview_copy(const std::shared_ptr<Job>& job, const JobCounters& counters) EPR_EXCLUDES(m_.mu_);
  void save_round_checkpoint(const std::shared_ptr<Job>& job, JobProgressRecord record, std::optional<bool> due = {})
      EPR_EXCLUDES(m_.mu_);
  /// Whether the job's checkpoint interval has passed since its last round checkpoint.
  bool checkpoint_due(const Job& job) const EPR_REQUIRES(job_fields);

  // Frame windows (window_run.h), in reprojection_window.cpp.
  /// Starts a window run's frames (`frames`, in frame order) together: they continue from one round
  /// (their checkpoints agree) or all start again from round 0. Fresh frames' rounds 0 all open
  /// before any frame is built; their builds wait in `unbuilt_` (build_unbuilt).
  void start_run(const std::vector<std::shared_ptr<Job>>& frames) EPR_EXCLUDES(m_.mu_);
  /// Builds a run's frame whose round 0 is open (from `unbuilt_`): `job`'s, or with null the first
  /// still running. Failing the frame if the build throws. False if none was left to build.
  bool build_unbuilt(const std::shared_ptr<Job>& job = nullptr) EPR_EXCLUDES(m_.mu_);
  /// `run`'s cuts (WindowRun::measured, share, cut): the views of each pair of neighbouring frames
  /// of the run (`first`'s) that this master has, against MasterOptions::window_cut_share. Returns
  /// the scene it loaded (null if it measured nothing).
  std::shared_ptr<const Scene> measure_cuts(const std::shared_ptr<Job>& first, WindowRun* run) EPR_EXCLUDES(m_.mu_);
  /// Reprojects the vertices of `batch`, committed for `job`'s round `round`, into the frames of its
  /// run within its window that have closed that round; defers them for the others.
  void reproject_into_neighbours(const Job& job, uint32_t round, const std::shared_ptr<const Batch>& batch)
      EPR_EXCLUDES(m_.mu_);
  /// Reprojects `render`'s deferred tiles of rounds up to `through` into its frame, in (round, frame)
  /// order, and lets go of them.
  void flush_deferred(Render& render, int64_t through);
  /// Closes every round of `run`'s frames that may close (the rule in reprojection_window.cpp), and
  /// lets the rounds held for a checkpoint go on, until none can.
  void advance_run(const std::shared_ptr<const WindowRun>& run) EPR_EXCLUDES(m_.mu_);
  /// True if every running neighbour of `g` in `run` has applied its tiles of rounds up to `round`.
  bool neighbours_through(const WindowRun& run, const Job& g, int64_t round) const EPR_REQUIRES(job_fields);
  /// One step of advance_run() for frame `g`; false if it can take none.
  bool advance_frame(const std::shared_ptr<const WindowRun>& run, const std::shared_ptr<Job>& g) EPR_EXCLUDES(m_.mu_);
  /// True if a draining master stops `job`'s run after `round`: the highest round any running frame of
  /// the run had open when the drain began (the first call that finds the master draining sets it).
  bool drain_stops(const Job& job, uint32_t round) EPR_REQUIRES(m_.mu_, job_fields);
  /// close_round() of a job whose round closed while draining: checkpoints it (true) instead of
  /// letting the next round open (false: not draining). In job_drain.cpp.
  bool checkpoint_for_drain(const std::shared_ptr<Job>& job, JobProgressRecord* record) EPR_EXCLUDES(m_.mu_);

  JobManager& m_;
  std::unique_ptr<GlContext> gl_;
  std::map<std::string, Render> renders_;       // by job id: the jobs this thread started and has not let go
  std::map<const WindowRun*, RunRounds> runs_;  // the window runs started, by their WindowRun
  // Window frames running without a frame yet, in the order their runs started them (frame order):
  // each is built when a batch of its commits comes up, or when the thread has nothing else to do.
  std::deque<std::shared_ptr<Job>> unbuilt_;
  // apply_commits() calls and the tiles they applied (for the log).
  uint64_t batches_applied_ = 0, tiles_applied_ = 0;
};

}  // namespace epr
