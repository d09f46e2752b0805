// JobManager's reprojection thread (job_manager.h), for every running job: it starts queued jobs
// as the memory budget admits them (scene; a fresh job's round 0 opens, then its deep framebuffer is
// built; a resumed job's frame is restored first), applies committed tiles per (job, round) in commit
// order through the job's RoundDriver, closes rounds and opens the next, writes finished jobs'
// results, drops cancelled and failed ones, and takes round checkpoints. Each step serves one job;
// the commit queue interleaves jobs, and a batch never spans two (job, round) pairs.
// It alone touches a job's driver, scene and camera; every other Job field under the manager's mutex.
#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <filesystem>

#include "common/log.h"
#include "common/scene_loader.h"
#include "common/thread_name.h"
#include "common/tile.h"
#include "master/gl_context.h"
#include "master/result_files.h"
#include "master/server/checkpoint.h"
#include "master/server/checkpointer.h"
#include "master/server/job_manager.h"
#include "master/server/previews.h"

namespace epr {
namespace fs = std::filesystem;
namespace {

double seconds_since(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

}  // namespace

// ---- the reprojection thread ----------------------------------------------------------------------

void JobManager::reprojection_loop() {
  set_thread_name("epr-reproject");
  auto log = logger("master");
  std::unique_ptr<GlContext> gl;
  if (options_.reproject_backend_override != "cpu") {
    try {
      gl = std::make_unique<GlContext>();
      log->info("reprojection context: {} / {}", gl->renderer(), gl->version());
    } catch (const std::exception& e) {
      log->warn("no OSMesa context ({}); jobs asking for GL reprojection will use the CPU reprojector", e.what());
    }
  }
  {
    MutexLock lock(mu_);
    gl_ready_ = gl != nullptr;
  }
  for (;;) {
    RenderWork work;
    {
      MutexLock lock(mu_);
      while ((work = next_work()).kind == RenderWork::Kind::kWait) work_cv_.wait(lock);
    }
    if (work.kind == RenderWork::Kind::kStop) break;
    do_work(work, gl.get());
  }
  MutexLock lock(mu_);
  for (const auto& [id, job] : jobs_.all()) job->driver.reset();
}

std::shared_ptr<Job> JobManager::ended_job() const {
  for (const auto& job : running_)
    if (job->state == JobState::kCancelled || job->state == JobState::kFailed) return job;
  return nullptr;
}

std::shared_ptr<Job> JobManager::startable_job() const {
  if (draining_) return nullptr;  // drain_and_checkpoint(): nothing new starts
  auto next = jobs_.next_queued(running_);
  return next && admits(*next) ? next : nullptr;
}

std::shared_ptr<Job> JobManager::copy_asked_job() const {
  for (const auto& job : running_)
    if (job->preview.copy == PreviewState::Copy::kRequested && job->state == JobState::kRunning) return job;
  return nullptr;
}

JobManager::RenderWork JobManager::next_work() {
  using Kind = RenderWork::Kind;
  RenderWork work;
  if (stopping_) {
    work.kind = Kind::kStop;
  } else if ((work.job = ended_job())) {
    work.kind = Kind::kDrop;
    running_.erase(std::find(running_.begin(), running_.end(), work.job));
  } else if ((work.job = startable_job())) {
    // Before the queued commits: a fresh job's round 0 opens at once, so that workers have its
    // tiles while its frame is built.
    work.kind = Kind::kStart;
    running_.push_back(work.job);
  } else if ((work.job = copy_asked_job())) {
    // Between batches: the frame as it stands (its closed rounds and the tiles of the open one
    // applied so far).
    work.kind = Kind::kCopy;
    work.job->preview.copy = PreviewState::Copy::kTaking;  // for those waiting on copy_cv_
    work.counters = work.job->counters;
  } else if (!tasks_.empty()) {
    // The queued commits of the front one's job and round, in commit order, up to
    // reproject_batch_records records: one reprojector call for all of them (parallel where
    // one tile's call would stay serial), the same sums as one call per tile.
    work.kind = Kind::kApply;
    size_t records = 0;
    while (!tasks_.empty()) {
      Task& next = *tasks_.front();
      const size_t n = next.tile.vertex_count() + next.tile.exact_samples.size();
      if (!work.batch.empty() && (next.job != work.batch.front()->job || next.round != work.batch.front()->round ||
                                  records + n > options_.reproject_batch_records))
        break;
      records += n;
      queued_vertices_ -= n;
      work.batch.push_back(std::move(tasks_.front()));
      tasks_.pop_front();
    }
    work.job = work.batch.front()->job;
  }
  return work;
}

void JobManager::do_work(RenderWork& work, GlContext* gl) {
  auto log = logger("master");
  const std::shared_ptr<Job>& job = work.job;
  switch (work.kind) {
    case RenderWork::Kind::kWait:
    case RenderWork::Kind::kStop:
      return;
    case RenderWork::Kind::kDrop:
      return drop_job(job);
    case RenderWork::Kind::kCopy:
      try {
        if (job->driver) take_preview_copy(job, work.counters);
      } catch (const std::exception& e) {
        log->error("job {}: cannot take a preview copy: {}", job->id, e.what());
      }
      {
        MutexLock lock(mu_);
        job->preview.copy = PreviewState::Copy::kIdle;
      }
      copy_cv_.notify_all();
      return;
    case RenderWork::Kind::kStart:
      try {
        start_job(job, gl);
      } catch (const std::exception& e) {
        // A fresh job's round 0 may be open by now: ending the job closes it (its leases are no
        // longer wanted, its queued commits are dropped unapplied).
        log->error("job {} failed to start: {}", job->id, e.what());
        stop_running(job);
        end_job(job, JobState::kFailed, e.what());
        job->driver.reset();
        job->scene.reset();
      }
      return;
    case RenderWork::Kind::kApply:
      try {
        apply_commits(work.batch);
      } catch (const std::exception& e) {
        log->error("job {}: commit failed: {}", job->id, e.what());
        end_job(job, JobState::kFailed, e.what());
      }
      return;
  }
}

void JobManager::end_job(const std::shared_ptr<Job>& job, JobState state, const std::string& error) {
  bool ended;
  {
    MutexLock lock(mu_);
    ended = job->end(state, error, clock_());
  }
  work_cv_.notify_all();
  if (ended) save_final_checkpoint(job);
  notify(job);
}

void JobManager::drop_job(const std::shared_ptr<Job>& job) {
  // Cancelled or failed: the last preview copy, or else the frame as it stands, becomes the job's
  // (partial) result files and PNG previews; the image copy goes once they are written (until then it
  // serves both).
  std::shared_ptr<const FrameImages> images;
  nlohmann::json stats;
  std::string dir;
  bool from_frame;
  JobCounters counters;
  {
    MutexLock lock(mu_);
    images = job->preview.images;
    from_frame = job->preview.partial_pending && !images && job->driver;
    counters = job->counters;
    dir = job_dir(*job);
  }
  if (from_frame) {
    try {
      take_preview_copy(job, counters);
    } catch (const std::exception& e) {
      logger("master")->error("job {}: cannot copy its frame for its partial results: {}", job->id, e.what());
    }
  }
  bool reprojects;
  {
    MutexLock lock(mu_);
    images = job->preview.images;
    reprojects = job->preview.reprojects;  // written with the copy, under the mutex
    if (job->preview.stats) stats = *job->preview.stats;
    stats.update({{"partial", true}, {"state", to_string(job->state)}});
  }
  if (images) {
    try {
      fs::create_directories(dir);
      write_results(*images, reprojects, stats,
                    [&](const ResultKindInfo& k) { return (fs::path(dir) / k.stored_as).string(); });
    } catch (const std::exception& e) {
      logger("master")->error("job {}: cannot store its partial results: {}", job->id, e.what());
    }
    std::map<std::string, std::vector<unsigned char>> pngs;
    for (std::string_view layer : kPreviewLayers)
      if (auto png = encode_preview(*images, reprojects, layer)) pngs[std::string(layer)] = std::move(*png);
    MutexLock lock(mu_);
    job->preview.pngs = std::move(pngs);
    job->preview.images.reset();
  }
  {
    MutexLock lock(mu_);
    job->preview.partial_pending = false;
  }
  copy_cv_.notify_all();
  job->driver.reset();
  job->scene.reset();
  notify(job);
}

void JobManager::start_job(const std::shared_ptr<Job>& job, GlContext* gl) {
  RenderOptions opts = job->request.options;
  if (options_.reproject_backend_override == "cpu" || !gl)
    if (opts.reproject == ReprojectMethod::kGl) opts.reproject = ReprojectMethod::kCpu;
  job->driver.reset();
  const auto setup = std::chrono::steady_clock::now();
  job->scene = share_bundle_scene(*job->bundle, job->scene_hash, cache_dir(), job->request.options.lighting);
  const double scene_s = seconds_since(setup);
  job->camera = std::make_unique<Camera>(job->request.camera, opts.width, opts.height);
  std::shared_ptr<const JobProgressRecord> resume;
  {
    MutexLock lock(mu_);
    resume = std::move(job->resume);
    job->triangles = job->scene->triangle_count();
    job->codec_bounds = job->scene->bounds();
    job->seconds_scene_load = scene_s;
  }
  const bool had_checkpoint = resume != nullptr;
  // A fresh job's round 0 traces every pixel from sample 0, which needs no frame: its leases open
  // now, and the frame (deep framebuffer, accumulation) is built while workers trace them. Their
  // commits wait in the commit queue (bounded as ever) and are applied once the frame exists. A
  // resumed job's round has skip masks: its frame is restored before the round opens.
  if (!had_checkpoint && !begin_running(job, nullptr)) return;  // cancelled meanwhile
  if (options_.before_frame_build) options_.before_frame_build(job->id);
  const auto build = std::chrono::steady_clock::now();
  job->driver = std::make_unique<RoundDriver>(opts, *job->camera, *job->scene, gl);
  const double build_s = seconds_since(build);
  FrameState& frame = job->driver->frame();
  uint64_t committed_meanwhile = 0;
  {
    MutexLock lock(mu_);
    job->seconds_frame_build = build_s;
    // The round's reprojection time (its histogram) leaves the build out.
    job->reprojecting_at_round_open = frame.seconds_reprojecting();
    committed_meanwhile = job->counters.tiles_committed;
  }
  logger("master")->info(
      "job {} set up in {:.2f} s: scene {:.2f} s, frame state (deep framebuffer, accumulation) {:.2f} s{}", job->id,
      scene_s + build_s, scene_s, build_s,
      had_checkpoint ? std::string()
                     : fmt::format(" (round 0 open meanwhile: {} tiles committed)", committed_meanwhile));
  if (!had_checkpoint) return;  // the commits queued meanwhile are applied next (reprojection_loop)
  try {
    frame.restore(*resume->frame);
  } catch (const std::exception& e) {
    logger("master")->error("job {}: its checkpoint does not fit ({}); starting it again from round 0", job->id,
                            e.what());
    resume.reset();
  }
  begin_running(job, resume.get());
}

bool JobManager::begin_running(const std::shared_ptr<Job>& job, const JobProgressRecord* resume) {
  // A fresh job has no frame yet (its round 0 is traced while the frame is built); a resumed one's
  // frame is restored (`resume`: its checkpoint, null if the checkpoint did not fit).
  FrameState* frame = job->driver ? &job->driver->frame() : nullptr;
  {
    MutexLock lock(mu_);
    if (job->state != JobState::kQueued) return false;  // cancelled meanwhile
    job->state = JobState::kRunning;
    job->started_ms = resume ? resume->started_ms : clock_();
    job->round = 0;
    if (frame) {
      // The counters go on from the checkpoint's; a checkpoint that did not fit starts them again.
      job->counters = resume ? resume->counters : JobCounters{};
      job->progress = frame->progress();
      job->counts = frame->counts();
      job->round = uint32_t(frame->round());
      job->counters.seconds_reprojecting = frame->seconds_reprojecting();
    }
    job->leases =
        std::make_unique<LeaseTable>(job->id, job->tiles.size(), options_.lease_policy(), clock_, &job->counters);
    open_round(*job, frame ? job->driver->open(job->tiles) : RoundDriver::first_plan(job->request.options, job->tiles));
    wake_parked(/*all=*/false);
  }
  answer_due();
  if (frame)
    logger("master")->info("job {} running from round {}: {} triangles, {} tiles", job->id, frame->round(),
                           job->scene->triangle_count(), job->tiles.size());
  else
    logger("master")->info("job {} running: {} triangles, {} tiles; round 0 is traced while its frame is built",
                           job->id, job->scene->triangle_count(), job->tiles.size());
  notify(job);
  return true;
}

void JobManager::open_round(Job& job, RoundPlan plan) {
  job.plan = std::move(plan);
  job.leases->open_round(job.round, job.plan.order);
  job.remaining = uint32_t(job.plan.order.size());
  job.round_open = true;
  job.round_opened_ms = clock_();
  // Without a frame yet (round 0 of a fresh job) the build's end sets it (start_job).
  job.reprojecting_at_round_open = job.driver ? job.driver->frame().seconds_reprojecting() : 0;
  ++job.version;
}

void JobManager::apply_commits(const std::vector<std::unique_ptr<Task>>& batch) {
  // One job and round (reprojection_loop), every tile of them still to apply: the round closes after
  // the batch that holds its last tile.
  Job& job = *batch.front()->job;
  {
    MutexLock lock(mu_);
    if (job.state != JobState::kRunning || job.round != batch.front()->round) return;
  }
  std::vector<const AssembledTile*> tiles;
  tiles.reserve(batch.size());
  for (const auto& t : batch) tiles.push_back(&t->tile);
  job.driver->apply(tiles);
  ++batches_applied_;
  tiles_applied_ += tiles.size();
  // The counts at most every 100 ms (and at the round's close): GL's counters are read back, which
  // waits for the dispatches in flight.
  const int64_t now = clock_();
  const bool refresh = now - job.counts_ms >= 100;
  ReprojectionCounts counts;
  if (refresh) {
    counts = job.driver->frame().counts();
    job.counts_ms = now;
  }
  bool round_done;
  {
    MutexLock lock(mu_);
    if (refresh) job.counts = counts;
    job.counters.seconds_reprojecting = job.driver->frame().seconds_reprojecting();
    EPR_CHECK(batch.size() <= job.remaining);
    job.remaining -= uint32_t(batch.size());
    round_done = job.remaining == 0;
  }
  if (!round_done) return;
  if (options_.before_round_close) options_.before_round_close(job.id, batch.front()->round);
  close_round(batch.front()->job);
}

void JobManager::close_round(const std::shared_ptr<Job>& job) {
  const auto closing = std::chrono::steady_clock::now();
  FrameState& frame = job->driver->frame();
  const bool more = job->driver->close();
  bool budget_over = false, want_preview;
  JobProgressRecord checkpoint;
  JobCounters at_close;
  {
    MutexLock lock(mu_);
    job->seconds_round_backlog += std::chrono::duration<double>(closing - job->last_commit_at).count();
    job->progress = frame.progress();
    job->counts = frame.counts();
    job->counters.seconds_reprojecting = frame.seconds_reprojecting();
    job->round_open = false;
    const int64_t now = clock_();
    histograms_.round.observe(double(now - job->round_opened_ms) / 1000.0);
    histograms_.reprojection.observe(job->counters.seconds_reprojecting - job->reprojecting_at_round_open);
    if (job->request.time_budget_seconds)
      budget_over = double(now - job->started_ms) / 1000.0 >= *job->request.time_budget_seconds;
    // Renewed while someone asks (at most once a second); dropped once nobody has for a while.
    const bool watched = job->preview.asked_ms >= 0 && now - job->preview.asked_ms <= options_.preview_interest_ms;
    want_preview = watched && now - job->preview.last_ms >= 1000;
    if (!watched) job->preview.images.reset();
    checkpoint = progress_record(*job);  // the counters as of the round's end
    at_close = job->counters;
  }
  if (!more || budget_over) {
    finish_job(job, budget_over && more);
    return;
  }
  if (checkpoint_for_drain(job, &checkpoint)) return;  // draining: no further round opens (job_drain.cpp)
  {
    MutexLock lock(mu_);
    if (job->state != JobState::kRunning) return;
    ++job->round;
    open_round(*job, job->driver->open(job->tiles));
    job->seconds_round_closing += seconds_since(closing);
    wake_parked(/*all=*/false);
  }
  answer_due();
  notify(job);  // watchers (`epr watch`) hear of the round now, not after the copy below
  // The preview copy after the next round opened (workers trace meanwhile): the frame still holds the
  // closed round's state, since only this thread applies the next round's results.
  // The copy costs the reprojection thread 32 bytes per pixel of work (seconds at 3840 x 2160 on a
  // loaded 2-core machine, during which no tile is applied): the next one waits at least ten times
  // as long as this one took (at least the second), so copies take at most ~10 % of the thread. The
  // previews (downscaled, previews.h) and `epr get --partial` serve the latest copy; they say which
  // round it reflects.
  if (want_preview) take_preview_copy(job, at_close);
  save_round_checkpoint(job, std::move(checkpoint));  // the next round's tiles are being traced meanwhile
}

void JobManager::take_preview_copy(const std::shared_ptr<Job>& job, const JobCounters& counters) {
  FrameState& frame = job->driver->frame();
  const int64_t copy_started = clock_();
  {
    // The old copy goes first, so that the job never holds two (32 bytes per pixel each); the PNGs
    // encoded from it keep serving previews meanwhile.
    MutexLock lock(mu_);
    job->preview.images.reset();
    job->preview.copy = PreviewState::Copy::kTaking;
  }
  auto images = std::make_shared<const FrameImages>(frame.images(/*preview=*/true));
  nlohmann::json stats = frame.statistics(job->request.options, counters.worker_culled);
  MutexLock lock(mu_);
  job->add_statistics(&stats, counters, clock_());
  job->preview.images = std::move(images);
  job->preview.copy = PreviewState::Copy::kIdle;
  job->preview.stats = std::make_shared<const nlohmann::json>(std::move(stats));
  job->preview.round = frame.round();
  job->preview.reprojects = frame.reprojects();
  job->preview.pngs.clear();
  const int64_t now = clock_();
  job->preview.last_ms = now + std::max<int64_t>(0, 10 * (now - copy_started) - 1000);
  copy_cv_.notify_all();
}

void JobManager::finish_job(const std::shared_ptr<Job>& job, bool budget_exhausted) {
  const auto start = std::chrono::steady_clock::now();
  const std::string dir = job_dir(*job);
  fs::create_directories(dir);
  FrameImages images;
  bool reprojects;
  nlohmann::json stats;
  {
    // The result files replace the preview copy: it goes before the final images are made, so that
    // the job's peak holds one set of images. Its PNGs serve previews until the files exist.
    MutexLock lock(mu_);
    job->preview.images.reset();
    job->preview.copy = PreviewState::Copy::kTaking;
  }
  {
    FrameState& frame = job->driver->frame();
    images = frame.release_images();
    reprojects = frame.reprojects();
    uint64_t worker_culled;
    {
      MutexLock lock(mu_);
      worker_culled = job->counters.worker_culled;  // every tile is applied: no commit changes it now
    }
    stats = frame.statistics(job->request.options, worker_culled);
    MutexLock lock(mu_);
    job->progress = frame.progress();
    job->counts = frame.counts();
    job->counters.seconds_reprojecting = frame.seconds_reprojecting();
    job->budget_exhausted = budget_exhausted;
  }
  const double images_s = seconds_since(start);
  // Everything the images came from -- the frame state (accumulation, deep framebuffer, per-pixel
  // arrays) and the scene -- goes before the result files are written, for the same reason.
  job->driver.reset();
  job->scene.reset();
  const double freed_s = seconds_since(start);
  auto stored = [&](const ResultKindInfo& k) { return (fs::path(dir) / k.stored_as).string(); };
  // The images first; the statistics, which include the time they took, after.
  write_results(images, reprojects, {},
                [&](const ResultKindInfo& k) { return k.kind == ResultKind::kJson ? std::string() : stored(k); });
  {
    MutexLock lock(mu_);
    job->add_statistics(&stats, job->counters, clock_());
    stats["partial"] = false;
  }
  write_results(images, reprojects, stats,
                [&](const ResultKindInfo& k) { return k.kind == ResultKind::kJson ? stored(k) : std::string(); });
  {
    // Done once every file is in place.
    MutexLock lock(mu_);
    job->seconds_writing_results = seconds_since(start);
    job->preview.pngs.clear();  // from now on made from the result files
    job->preview.copy = PreviewState::Copy::kIdle;
  }
  // The finished state is on disk before anyone hears of it (after the results: it promises them),
  // so that a master killed after a client saw DONE comes back with the job done.
  int64_t finished_ms = 0;
  if (checkpointer_)
    checkpointer_->queue_and_wait(job->id, [&]() -> std::optional<JobProgressRecord> {
      MutexLock lock(mu_);
      if (is_terminal(job->state)) return std::nullopt;  // cancelled meanwhile: that state is saved
      JobProgressRecord r = progress_record(*job);
      r.state = JobState::kDone;
      r.error.clear();
      r.finished_ms = finished_ms = clock_();
      return r;
    });
  {
    MutexLock lock(mu_);
    job->end(JobState::kDone, "", finished_ms ? finished_ms : clock_());
    running_.erase(std::remove(running_.begin(), running_.end(), job), running_.end());
  }
  const double results_s = seconds_since(start);
  logger("master")->info(
      "job {} done: images {:.2f} s, freeing the frame {:.2f} s, result files {:.2f} s; {} tiles applied in {} batches "
      "(this master so far)",
      job->id, images_s, freed_s - images_s, results_s - freed_s, tiles_applied_, batches_applied_);
  std::optional<std::string> nonfinite;
  {
    MutexLock lock(mu_);
    nonfinite = nonfinite_warning(job->counters.non_finite + job->counts.invalid, job->progress.paths_traced);
  }
  if (nonfinite) logger("master")->warn("job {}: {}", job->id, *nonfinite);
  work_cv_.notify_all();
  notify(job);
}

// ---- round checkpoints ---------------------------------------------------------------------------

void JobManager::save_round_checkpoint(const std::shared_ptr<Job>& job, JobProgressRecord record) {
  if (!checkpointer_) return;
  {
    // Not every round: a 512 x 512 frame is ~80 MB to write (see checkpoint_interval_s).
    MutexLock lock(mu_);
    const double gap = options_.checkpoint_interval_s >= 0
                           ? options_.checkpoint_interval_s
                           : MasterOptions::kAutoCheckpointFactor * job->checkpoint_cost_s;
    if (job->last_checkpoint_ms && double(clock_() - job->last_checkpoint_ms) < 1000 * gap) return;
    job->last_checkpoint_ms = clock_();
  }
  // Written here, straight from the live frame -- the state after the closed round: nothing of the next
  // one is applied yet, and only this thread applies it -- a few MiB at a time, the accumulation
  // visited in place (GL: one band mapped at a time): no copy of the frame, whatever its size. The
  // checkpointer thread then fsyncs the file and puts it in place. The write's time counts towards
  // the interval (checkpoint_cost_s), so that checkpoints stay a small share of the job's time.
  const auto start = std::chrono::steady_clock::now();
  fs::path written;
  try {
    const FrameView view = job->driver->frame().view();
    written = store_->write_progress_file(job->id, record, &view);
  } catch (const std::exception& e) {
    logger("master")->error("job {}: cannot write its checkpoint after round {}: {}", job->id, record.progress.round,
                            e.what());
    return;
  }
  const double write_s = seconds_since(start);
  logger("master")->debug("job {}: frame after round {} written for its checkpoint in {:.1f} ms", job->id,
                          record.progress.round, 1e3 * write_s);
  checkpointer_->queue_written(job->id, std::move(written), [&] {
    MutexLock lock(mu_);
    if (job->state != JobState::kRunning) return false;  // ended meanwhile: its final record is queued instead
    job->checkpoint_cost_s = write_s;                    // the commit's time is added when it is committed
    ++job->round_checkpoints;
    return true;
  });
}

void JobManager::save_final_checkpoint(const std::shared_ptr<Job>& job) {
  if (!checkpointer_) return;
  checkpointer_->queue(job->id, [&]() -> std::optional<JobProgressRecord> {
    MutexLock lock(mu_);
    return progress_record(*job);
  });
}

}  // namespace epr
