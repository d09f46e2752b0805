// The reprojection thread: reprojection_worker.h.
#include "master/server/reprojection_worker.h"

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
#include "master/server/previews.h"
#include "master/server/window_run.h"
#include "wire/scene_shelf.h"

namespace epr {
namespace fs = std::filesystem;
namespace {

double seconds_since(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

}  // namespace

// ---- the reprojection thread ----------------------------------------------------------------------

ReprojectionWorker::ReprojectionWorker(JobManager& manager) : m_(manager) {}
ReprojectionWorker::~ReprojectionWorker() = default;

void ReprojectionWorker::run() {
  set_thread_name("epr-reproject");
  auto log = logger("master");
  if (m_.options_.reproject_backend_override != "cpu") {
    try {
      gl_ = std::make_unique<GlContext>();
      log->info("reprojection context: {} / {}", gl_->renderer(), gl_->version());
    } catch (const std::exception& e) {
      log->warn("no OSMesa context ({}); jobs asking for GL reprojection will use the CPU reprojector", e.what());
    }
  }
  {
    JobLock lock(m_.mu_);
    m_.gl_ready_ = gl_ != nullptr;
  }
  for (;;) {
    RenderWork work;
    {
      JobLock lock(m_.mu_);
      // Woken at least every second: a window run waiting for its frames may start after a time.
      // With nothing else to do, a window frame whose round 0 is open is built.
      while ((work = m_.next_work()).kind == RenderWork::Kind::kWait && unbuilt_.empty())
        m_.work_cv_.wait_for(lock, std::chrono::seconds(1));
    }
    if (work.kind == RenderWork::Kind::kStop) break;
    if (work.kind == RenderWork::Kind::kWait) {
      build_unbuilt();
      continue;
    }
    do_work(work);
  }
  unbuilt_.clear();
  renders_.clear();  // the drivers' GL buffers go before the context
  gl_.reset();
}

RoundDriver* ReprojectionWorker::driver(const Job& job) {
  auto it = renders_.find(job.id);
  return it == renders_.end() ? nullptr : it->second.driver.get();
}

void ReprojectionWorker::do_work(RenderWork& work) {
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
        if (driver(*job)) take_preview_copy(job, work.counters);
      } catch (const std::exception& e) {
        log->error("job {}: cannot take a preview copy: {}", job->id, e.what());
      }
      {
        JobLock lock(m_.mu_);
        job->preview.copy = PreviewState::Copy::kIdle;
      }
      m_.copy_cv_.notify_all();
      return;
    case RenderWork::Kind::kStart:
      if (windowed(job->request.batch)) return start_run(work.start);
      return start_or_fail(job);
    case RenderWork::Kind::kApply:
      // A window frame's first commits come up before its frame is built: it is built now.
      if (!driver(*job)) build_unbuilt(job);
      try {
        apply_commits(std::make_shared<const Batch>(std::move(work.batch)));
      } catch (const std::exception& e) {
        log->error("job {}: commit failed: {}", job->id, e.what());
        m_.end_job(job, JobState::kFailed, e.what());
      }
      return;
  }
}

void ReprojectionWorker::start_or_fail(const std::shared_ptr<Job>& job) {
  try {
    start_job(job);
  } catch (const std::exception& e) {
    fail_start(job, e.what());
  }
}

void ReprojectionWorker::fail_start(const std::shared_ptr<Job>& job, const std::string& why) {
  // A fresh job's round 0 may be open by now: ending the job closes it (its leases are no longer
  // wanted, its queued commits are dropped unapplied).
  logger("master")->error("job {} failed to start: {}", job->id, why);
  m_.stop_running(job);
  m_.end_job(job, JobState::kFailed, why);
  renders_.erase(job->id);
}

void ReprojectionWorker::drop_job(const std::shared_ptr<Job>& job) {
  // Cancelled or failed: the last preview copy, or else the frame as it stands, becomes the job's
  // (partial) result files and PNG previews; the image copy goes once they are written (until then it
  // serves both).
  std::shared_ptr<const FrameImages> images;
  nlohmann::json stats;
  std::string dir;
  bool from_frame;
  JobCounters counters;
  {
    JobLock lock(m_.mu_);
    images = job->preview.images;
    from_frame = job->preview.partial_pending && !images && driver(*job);
    counters = job->counters;
    dir = m_.job_dir(*job);
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
    JobLock lock(m_.mu_);
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
    JobLock lock(m_.mu_);
    job->preview.pngs = std::move(pngs);
    job->preview.images.reset();
  }
  {
    JobLock lock(m_.mu_);
    job->preview.partial_pending = false;
  }
  m_.copy_cv_.notify_all();
  renders_.erase(job->id);
  m_.notify(job);
  // A frame that leaves its window run may be the one the others' rounds waited for.
  std::shared_ptr<const WindowRun> run;
  {
    JobLock lock(m_.mu_);
    run = job->run;
  }
  if (run) advance_run(run);
}

void ReprojectionWorker::start_job(const std::shared_ptr<Job>& job) {
  std::shared_ptr<const JobProgressRecord> resume = prepare_job(job);
  // A fresh job's round 0 traces every pixel from sample 0, which needs no frame: its leases open
  // now, and the frame (deep framebuffer, accumulation) is built while workers trace them. Their
  // commits wait in the commit queue (bounded as ever) and are applied once the frame exists. A
  // resumed job's round has skip masks: its frame is restored before the round opens.
  if (!resume) {
    if (begin_running(job, nullptr)) build_frame(job);  // else cancelled meanwhile
    return;  // the commits queued meanwhile are applied next (reprojection_loop)
  }
  build_frame(job);
  try {
    renders_.at(job->id).driver->frame().restore(*resume->frame);
  } catch (const std::exception& e) {
    logger("master")->error("job {}: its checkpoint does not fit ({}); starting it again from round 0", job->id,
                            e.what());
    resume.reset();
  }
  begin_running(job, resume.get());
}

std::shared_ptr<const JobProgressRecord> ReprojectionWorker::prepare_job(const std::shared_ptr<Job>& job) {
  Render& render = renders_[job->id];
  render = Render{};
  const auto setup = std::chrono::steady_clock::now();
  render.scene = share_bundle_scene(*job->bundle, job->scene_hash, m_.cache_dir(), job->request.options.lighting);
  m_.release_checked_scene(job->scene_hash);  // the admission's load, taken from the shelf just now
  const double scene_s = seconds_since(setup);
  render.camera =
      std::make_unique<Camera>(job->request.camera, job->request.options.width, job->request.options.height);
  JobLock lock(m_.mu_);
  job->triangles = render.scene->triangle_count();
  job->codec_bounds = render.scene->bounds();
  job->seconds_scene_load = scene_s;
  return std::move(job->resume);
}

void ReprojectionWorker::build_frame(const std::shared_ptr<Job>& job) {
  RenderOptions opts = job->request.options;
  if (m_.options_.reproject_backend_override == "cpu" || !gl_)
    if (opts.reproject == ReprojectMethod::kGl) opts.reproject = ReprojectMethod::kCpu;
  Render& render = renders_.at(job->id);
  if (m_.options_.before_frame_build) m_.options_.before_frame_build(job->id);
  const auto build = std::chrono::steady_clock::now();
  // The edge pixels' rays use the scene's BVH on the shelf: one build for every frame of the scene.
  render.driver =
      std::make_unique<RoundDriver>(opts, *render.camera, *render.scene, gl_.get(), shelved_bvh(render.scene).get());
  render.driver->frame().set_count_unit(window_count_unit(job->request.batch));
  const double build_s = seconds_since(build);
  FrameState& frame = render.driver->frame();
  uint64_t committed_meanwhile = 0;
  bool fresh;
  double scene_s;
  {
    JobLock lock(m_.mu_);
    job->seconds_frame_build = build_s;
    scene_s = job->seconds_scene_load;
    fresh = job->state == JobState::kRunning;  // its round 0 open meanwhile; a resumed job is still queued
    if (fresh) {
      // The round's reprojection time (its histogram) leaves the build out.
      job->reprojecting_at_round_open = frame.seconds_reprojecting();
      committed_meanwhile = job->counters.tiles_committed;
    }
  }
  const FrameState::BuildSeconds& parts = frame.build_seconds();
  logger("master")->info(
      "job {} set up in {:.2f} s: scene {:.2f} s, frame state {:.2f} s (deep framebuffer into the plane grid {:.2f} s, "
      "edge pixels {:.2f} s, reprojector {:.2f} s){}",
      job->id, scene_s + build_s, scene_s, build_s, parts.grid, parts.edge_pixels, parts.reprojector,
      fresh ? fmt::format(" (round 0 open meanwhile: {} tiles committed)", committed_meanwhile) : std::string());
}

bool ReprojectionWorker::begin_running(const std::shared_ptr<Job>& job, const JobProgressRecord* resume) {
  // A fresh job has no frame yet (its round 0 is traced while the frame is built); a resumed one's
  // frame is restored (`resume`: its checkpoint, null if the checkpoint did not fit).
  Render& render = renders_.at(job->id);
  FrameState* frame = render.driver ? &render.driver->frame() : nullptr;
  {
    JobLock lock(m_.mu_);
    if (job->state != JobState::kQueued) return false;  // cancelled meanwhile
    job->state = JobState::kRunning;
    job->started_ms = resume ? resume->started_ms : m_.clock_();
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
        std::make_unique<LeaseTable>(job->id, job->tiles.size(), m_.options_.lease_policy(), m_.clock_, &job->counters);
    m_.open_round(*job,
                  frame ? render.driver->open(job->tiles) : RoundDriver::first_plan(job->request.options, job->tiles),
                  frame ? frame->seconds_reprojecting() : 0);
    m_.wake_parked(/*all=*/false);
  }
  m_.answer_due();
  if (frame)
    logger("master")->info("job {} running from round {}: {} triangles, {} tiles", job->id, frame->round(),
                           render.scene->triangle_count(), job->tiles.size());
  else
    logger("master")->info("job {} running: {} triangles, {} tiles; round 0 is traced while its frame is built",
                           job->id, render.scene->triangle_count(), job->tiles.size());
  m_.notify(job);
  return true;
}

void ReprojectionWorker::apply_commits(std::shared_ptr<const Batch> shared) {
  // One job and round (reprojection_loop), every tile of them still to apply: the round closes after
  // the batch that holds its last tile.
  const Batch& batch = *shared;
  Job& job = *batch.front()->job;
  {
    JobLock lock(m_.mu_);
    if (job.state != JobState::kRunning || job.round != batch.front()->round) return;
  }
  Render& render = renders_.at(job.id);
  std::vector<const AssembledTile*> tiles;
  tiles.reserve(batch.size());
  for (const auto& t : batch) tiles.push_back(&t->tile);
  // A window frame whose checkpoint waits for its neighbours' round keeps its own next round's tiles
  // until it is written (reprojection_window.cpp).
  if (render.checkpoint)
    render.own.push_back(shared);
  else
    render.driver->apply(tiles);
  reproject_into_neighbours(job, batch.front()->round, shared);
  ++batches_applied_;
  tiles_applied_ += tiles.size();
  // The counts at most every 100 ms (and at the round's close): GL's counters are read back, which
  // waits for the dispatches in flight.
  const int64_t now = m_.clock_();
  const bool refresh = now - render.counts_ms >= 100;
  ReprojectionCounts counts;
  if (refresh) {
    counts = render.driver->frame().counts();
    render.counts_ms = now;
  }
  bool round_done;
  std::shared_ptr<const WindowRun> run;
  {
    JobLock lock(m_.mu_);
    run = job.run;
    if (refresh) job.counts = counts;
    job.counters.seconds_reprojecting = render.driver->frame().seconds_reprojecting();
    EPR_CHECK(batch.size() <= job.remaining);
    job.remaining -= uint32_t(batch.size());
    round_done = job.remaining == 0;
  }
  if (!round_done) return;
  if (run) return advance_run(run);  // by the rule of its run
  if (m_.options_.before_round_close) m_.options_.before_round_close(job.id, batch.front()->round);
  close_round(batch.front()->job);
}

void ReprojectionWorker::close_round(const std::shared_ptr<Job>& job) {
  if (auto closed = end_round(job)) open_next_round(job, std::move(*closed), std::nullopt);
}

std::optional<ReprojectionWorker::ClosedRound> ReprojectionWorker::end_round(const std::shared_ptr<Job>& job) {
  const auto closing = std::chrono::steady_clock::now();
  RoundDriver& driver = *renders_.at(job->id).driver;
  FrameState& frame = driver.frame();
  const bool more = driver.close();
  bool budget_over = false;
  ClosedRound closed;
  {
    JobLock lock(m_.mu_);
    job->seconds_round_backlog += std::chrono::duration<double>(closing - job->last_commit_at).count();
    job->progress = frame.progress();
    job->counts = frame.counts();
    job->counters.seconds_reprojecting = frame.seconds_reprojecting();
    job->round_open = false;
    const int64_t now = m_.clock_();
    m_.histograms_.round.observe(double(now - job->round_opened_ms) / 1000.0);
    m_.histograms_.reprojection.observe(job->counters.seconds_reprojecting - job->reprojecting_at_round_open);
    if (job->request.time_budget_seconds)
      budget_over = double(now - job->started_ms) / 1000.0 >= *job->request.time_budget_seconds;
    // Renewed while someone asks (at most once a second); dropped once nobody has for a while.
    const bool watched = job->preview.asked_ms >= 0 && now - job->preview.asked_ms <= m_.options_.preview_interest_ms;
    closed.want_preview = watched && now - job->preview.last_ms >= 1000;
    if (!watched) job->preview.images.reset();
    closed.checkpoint = progress_record(*job);  // the counters as of the round's end
    closed.at_close = job->counters;
    job->seconds_round_closing += seconds_since(closing);
  }
  if (!more || budget_over) {
    finish_job(job, budget_over && more);
    return std::nullopt;
  }
  return closed;
}

void ReprojectionWorker::open_next_round(const std::shared_ptr<Job>& job, ClosedRound closed,
                                         std::optional<bool> checkpoint_due, bool may_drain) {
  // Draining: no further round opens (job_drain.cpp).
  if (may_drain && checkpoint_for_drain(job, &closed.checkpoint)) return;
  const auto opening = std::chrono::steady_clock::now();
  RoundDriver& driver = *renders_.at(job->id).driver;
  FrameState& frame = driver.frame();
  {
    JobLock lock(m_.mu_);
    if (job->state != JobState::kRunning) return;
    ++job->round;
    m_.open_round(*job, driver.open(job->tiles), frame.seconds_reprojecting());
    job->seconds_round_closing += seconds_since(opening);
    m_.wake_parked(/*all=*/false);
  }
  m_.answer_due();
  m_.notify(job);  // watchers (`epr watch`) hear of the round now, not after the copy below
  // The preview copy after the next round opened (workers trace meanwhile): the frame still holds the
  // closed round's state, since only this thread applies the next round's results.
  // The copy costs the reprojection thread 32 bytes per pixel of work (seconds at 3840 x 2160 on a
  // loaded 2-core machine, during which no tile is applied): the next one waits at least ten times
  // as long as this one took (at least the second), so copies take at most ~10 % of the thread. The
  // previews (downscaled, previews.h) and `epr get --partial` serve the latest copy; they say which
  // round it reflects.
  if (closed.want_preview) take_preview_copy(job, closed.at_close);
  save_round_checkpoint(job, std::move(closed.checkpoint),
                        checkpoint_due);  // the next round's tiles are traced meanwhile
}

void ReprojectionWorker::take_preview_copy(const std::shared_ptr<Job>& job, const JobCounters& counters) {
  FrameState& frame = driver(*job)->frame();
  const int64_t copy_started = m_.clock_();
  {
    // The old copy goes first, so that the job never holds two (32 bytes per pixel each); the PNGs
    // encoded from it keep serving previews meanwhile.
    JobLock lock(m_.mu_);
    job->preview.images.reset();
    job->preview.copy = PreviewState::Copy::kTaking;
  }
  auto images = std::make_shared<const FrameImages>(frame.images(/*preview=*/true));
  nlohmann::json stats = frame.statistics(job->request.options, counters.worker_culled);
  JobLock lock(m_.mu_);
  job->add_statistics(&stats, counters, m_.clock_());
  job->preview.images = std::move(images);
  job->preview.copy = PreviewState::Copy::kIdle;
  job->preview.stats = std::make_shared<const nlohmann::json>(std::move(stats));
  job->preview.round = frame.round();
  job->preview.reprojects = frame.reprojects();
  job->preview.pngs.clear();
  const int64_t now = m_.clock_();
  job->preview.last_ms = now + std::max<int64_t>(0, 10 * (now - copy_started) - 1000);
  m_.copy_cv_.notify_all();
}

void ReprojectionWorker::finish_job(const std::shared_ptr<Job>& job, bool budget_exhausted) {
  const auto start = std::chrono::steady_clock::now();
  const std::string dir = m_.job_dir(*job);
  fs::create_directories(dir);
  FrameImages images;
  bool reprojects;
  nlohmann::json stats;
  {
    // The result files replace the preview copy: it goes before the final images are made, so that
    // the job's peak holds one set of images. Its PNGs serve previews until the files exist.
    JobLock lock(m_.mu_);
    job->preview.images.reset();
    job->preview.copy = PreviewState::Copy::kTaking;
  }
  {
    FrameState& frame = driver(*job)->frame();
    images = frame.release_images();
    reprojects = frame.reprojects();
    uint64_t worker_culled;
    {
      JobLock lock(m_.mu_);
      worker_culled = job->counters.worker_culled;  // every tile is applied: no commit changes it now
    }
    stats = frame.statistics(job->request.options, worker_culled);
    JobLock lock(m_.mu_);
    job->progress = frame.progress();
    job->counts = frame.counts();
    job->counters.seconds_reprojecting = frame.seconds_reprojecting();
    job->budget_exhausted = budget_exhausted;
  }
  const double images_s = seconds_since(start);
  // Everything the images came from -- the frame state (accumulation, deep framebuffer, per-pixel
  // arrays) and the scene -- goes before the result files are written, for the same reason.
  renders_.erase(job->id);
  const double freed_s = seconds_since(start);
  auto stored = [&](const ResultKindInfo& k) { return (fs::path(dir) / k.stored_as).string(); };
  // The images first; the statistics, which include the time they took, after.
  write_results(images, reprojects, {},
                [&](const ResultKindInfo& k) { return k.kind == ResultKind::kJson ? std::string() : stored(k); });
  {
    JobLock lock(m_.mu_);
    job->add_statistics(&stats, job->counters, m_.clock_());
    stats["partial"] = false;
  }
  write_results(images, reprojects, stats,
                [&](const ResultKindInfo& k) { return k.kind == ResultKind::kJson ? stored(k) : std::string(); });
  {
    // Done once every file is in place.
    JobLock lock(m_.mu_);
    job->seconds_writing_results = seconds_since(start);
    job->preview.pngs.clear();  // from now on made from the result files
    job->preview.copy = PreviewState::Copy::kIdle;
  }
  // The finished state is on disk before anyone hears of it (after the results: it promises them),
  // so that a master killed after a client saw DONE comes back with the job done.
  int64_t finished_ms = 0;
  if (m_.checkpointer_)
    m_.checkpointer_->queue_and_wait(job->id, [&]() -> std::optional<JobProgressRecord> {
      JobLock lock(m_.mu_);
      if (is_terminal(job->state)) return std::nullopt;  // cancelled meanwhile: that state is saved
      JobProgressRecord r = progress_record(*job);
      r.state = JobState::kDone;
      r.error.clear();
      r.finished_ms = finished_ms = m_.clock_();
      return r;
    });
  {
    JobLock lock(m_.mu_);
    job->end(JobState::kDone, "", finished_ms ? finished_ms : m_.clock_());
    m_.running_.erase(std::remove(m_.running_.begin(), m_.running_.end(), job), m_.running_.end());
  }
  const double results_s = seconds_since(start);
  logger("master")->info(
      "job {} done: images {:.2f} s, freeing the frame {:.2f} s, result files {:.2f} s; {} tiles applied in {} batches "
      "(this master so far)",
      job->id, images_s, freed_s - images_s, results_s - freed_s, tiles_applied_, batches_applied_);
  std::optional<std::string> nonfinite;
  {
    JobLock lock(m_.mu_);
    nonfinite = nonfinite_warning(job->counters.non_finite + job->counts.invalid, job->progress.paths_traced);
  }
  if (nonfinite) logger("master")->warn("job {}: {}", job->id, *nonfinite);
  m_.work_cv_.notify_all();
  m_.notify(job);
}

// ---- round checkpoints ---------------------------------------------------------------------------

bool ReprojectionWorker::checkpoint_due(const Job& job) const {
  // Not every round: a 512 x 512 frame is ~80 MB to write (see checkpoint_interval_s).
  const double gap = m_.options_.checkpoint_interval_s >= 0
                         ? m_.options_.checkpoint_interval_s
                         : MasterOptions::kAutoCheckpointFactor * job.checkpoint_cost_s;
  return !job.last_checkpoint_ms || double(m_.clock_() - job.last_checkpoint_ms) >= 1000 * gap;
}

void ReprojectionWorker::save_round_checkpoint(const std::shared_ptr<Job>& job, JobProgressRecord record,
                                               std::optional<bool> due) {
  if (!m_.checkpointer_) return;
  {
    JobLock lock(m_.mu_);
    if (!due.value_or(checkpoint_due(*job))) return;
    job->last_checkpoint_ms = m_.clock_();
  }
  // Written here, straight from the live frame -- the state after the closed round: nothing of the next
  // one is applied yet, and only this thread applies it -- a few MiB at a time, the accumulation
  // visited in place (GL: one band mapped at a time): no copy of the frame, whatever its size. The
  // checkpointer thread then fsyncs the file and puts it in place. The write's time counts towards
  // the interval (checkpoint_cost_s), so that checkpoints stay a small share of the job's time.
  const auto start = std::chrono::steady_clock::now();
  fs::path written;
  try {
    const FrameView view = driver(*job)->frame().view();
    written = m_.store_->write_progress_file(job->id, record, &view);
  } catch (const std::exception& e) {
    logger("master")->error("job {}: cannot write its checkpoint after round {}: {}", job->id, record.progress.round,
                            e.what());
    return;
  }
  const double write_s = seconds_since(start);
  logger("master")->debug("job {}: frame after round {} written for its checkpoint in {:.1f} ms", job->id,
                          record.progress.round, 1e3 * write_s);
  m_.checkpointer_->queue_written(job->id, std::move(written), [&] {
    JobLock lock(m_.mu_);
    if (job->state != JobState::kRunning) return false;  // ended meanwhile: its final record is queued instead
    job->checkpoint_cost_s = write_s;                    // the commit's time is added when it is committed
    ++job->round_checkpoints;
    return true;
  });
}

}  // namespace epr
