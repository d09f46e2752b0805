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
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "common/camera.h"
#include "common/check.h"
#include "common/scene.h"
#include "master/round_driver.h"
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
  /// What only this thread touches of a running job.
  struct Render {
    std::shared_ptr<const Scene> scene;  // shared with the process's other users (wire/scene_shelf.h)
    std::unique_ptr<Camera> camera;
    std::unique_ptr<RoundDriver> driver;  // null until the job's frame is built
    int64_t counts_ms = 0;                // when the job's `counts` were last refreshed from the reprojector
  };

  void do_work(RenderWork& work) EPR_EXCLUDES(m_.mu_);
  /// The job's driver, null if its frame is not built (or the job is not this thread's any more).
  RoundDriver* driver(const Job& job);
  /// start_job(), failing the job if it throws.
  void start_or_fail(const std::shared_ptr<Job>& job) EPR_EXCLUDES(m_.mu_);
  void start_job(const std::shared_ptr<Job>& job) EPR_EXCLUDES(m_.mu_);
  /// A starting job runs (unless it was cancelled meanwhile): its leases and its first round in this
  /// master open (round 0 of a fresh job, before its frame exists; the next round of a resumed one,
  /// from its restored frame and `resume`, its checkpoint or null), and parked workers hear of it.
  /// False if it was cancelled meanwhile.
  bool begin_running(const std::shared_ptr<Job>& job, const JobProgressRecord* resume) EPR_EXCLUDES(m_.mu_);
  /// Applies queued commits of one job and round, in commit order (RoundDriver::apply of a span).
  void apply_commits(const std::vector<std::unique_ptr<Task>>& batch) EPR_EXCLUDES(m_.mu_);
  /// `checkpoint`: whether the round's checkpoint is due (decided for a whole window run); unset: the
  /// job's own checkpoint interval decides.
  void close_round(const std::shared_ptr<Job>& job, std::optional<bool> checkpoint = {}) EPR_EXCLUDES(m_.mu_);
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
  /// (their checkpoints agree) or all start again from round 0.
  void start_run(const std::vector<std::shared_ptr<Job>>& frames) EPR_EXCLUDES(m_.mu_);
  /// `run`'s cuts (WindowRun::measured, share, cut): the views of each pair of neighbouring frames
  /// of the run (`first`'s) that this master has, against MasterOptions::window_cut_share. Returns
  /// the scene it loaded (null if it measured nothing).
  std::shared_ptr<const Scene> measure_cuts(const std::shared_ptr<Job>& first, WindowRun* run) EPR_EXCLUDES(m_.mu_);
  /// Reprojects the vertices of `tiles`, committed for `job`'s current round, into the frames of its
  /// run within its window that are in the same round.
  void reproject_into_neighbours(const Job& job, const std::vector<const AssembledTile*>& tiles) EPR_EXCLUDES(m_.mu_);
  /// Closes `round` of every running frame of `run` at once, if each has all its tiles of it applied.
  void close_in_step(const WindowRun& run, uint32_t round) EPR_EXCLUDES(m_.mu_);
  /// close_round() of a job whose round closed while draining: checkpoints it (true) instead of
  /// letting the next round open (false: not draining). In job_drain.cpp.
  bool checkpoint_for_drain(const std::shared_ptr<Job>& job, JobProgressRecord* record) EPR_EXCLUDES(m_.mu_);

  JobManager& m_;
  std::unique_ptr<GlContext> gl_;
  std::map<std::string, Render> renders_;  // by job id: the jobs this thread started and has not let go
  // apply_commits() calls and the tiles they applied (for the log).
  uint64_t batches_applied_ = 0, tiles_applied_ = 0;
};

}  // namespace epr
