// What the reprojection thread (reprojection_worker.h) does next, decided under the manager's mutex,
// and the manager's side of what it does: opening a round, ending a job, its final checkpoint.
#include <algorithm>
#include <set>

#include "master/server/checkpoint.h"
#include "master/server/checkpointer.h"
#include "master/server/job_manager.h"
#include "master/server/window_run.h"

namespace epr {

std::shared_ptr<Job> JobManager::ended_job() const {
  for (const auto& job : running_)
    if (job->state == JobState::kCancelled || job->state == JobState::kFailed) return job;
  return nullptr;
}

std::vector<std::shared_ptr<Job>> JobManager::startable_jobs() const {
  if (draining_) return {};  // drain_and_checkpoint(): nothing new starts
  // Window runs still waiting for frames are passed over: the jobs behind them may start.
  std::vector<std::shared_ptr<Job>> passed = running_;
  while (auto next = jobs_.next_queued(passed)) {
    std::vector<std::shared_ptr<Job>> start{next};
    if (windowed(next->request.batch)) {
      start = startable_run(next);
      if (start.empty()) {
        for (const auto& [id, j] : jobs_.all())
          if (j->state == JobState::kQueued && same_run(j->request.batch, next->request.batch)) passed.push_back(j);
        continue;
      }
    }
    return admits(start) ? start : std::vector<std::shared_ptr<Job>>{};
  }
  return {};
}

std::vector<std::shared_ptr<Job>> JobManager::startable_run(const std::shared_ptr<Job>& job) const {
  const BatchMembership& b = job->request.batch;
  std::vector<std::shared_ptr<Job>> queued;
  std::set<uint32_t> here;  // frames of the run on this master, ended ones included (they left it)
  int64_t oldest = job->submitted_ms;
  for (const auto& [id, j] : jobs_.all()) {
    if (!same_run(j->request.batch, b)) continue;
    if (j->state == JobState::kRunning || std::find(running_.begin(), running_.end(), j) != running_.end())
      return {job};  // the run has started: a frame that comes late runs alone
    here.insert(j->request.batch.frame.value_or(0));
    if (j->state != JobState::kQueued) continue;
    queued.push_back(j);
    oldest = std::min(oldest, j->submitted_ms);
  }
  if (here.size() < run_length(b) && clock_() - oldest < options_.window_run_wait_ms) return {};
  std::sort(queued.begin(), queued.end(), [](const std::shared_ptr<Job>& x, const std::shared_ptr<Job>& y) {
    return x->request.batch.frame < y->request.batch.frame;
  });
  return queued;
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
  } else if (!(work.start = startable_jobs()).empty()) {
    // Before the queued commits: a fresh job's round 0 opens at once, so that workers have its
    // tiles while its frame is built. A window run's frames start together.
    work.kind = Kind::kStart;
    work.job = work.start.front();
    running_.insert(running_.end(), work.start.begin(), work.start.end());
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

void JobManager::end_job(const std::shared_ptr<Job>& job, JobState state, const std::string& error) {
  bool ended;
  {
    JobLock lock(mu_);
    ended = job->end(state, error, clock_());
  }
  work_cv_.notify_all();
  if (ended) save_final_checkpoint(job);
  notify(job);
}

void JobManager::open_round(Job& job, RoundPlan plan, double reprojecting) {
  job.plan = std::move(plan);
  job.leases->open_round(job.round, job.plan.order);
  job.remaining = uint32_t(job.plan.order.size());
  job.round_open = true;
  job.round_opened_ms = clock_();
  // Without a frame yet (round 0 of a fresh job) the build's end sets it (ReprojectionWorker::start_job).
  job.reprojecting_at_round_open = reprojecting;
  ++job.version;
}

void JobManager::save_final_checkpoint(const std::shared_ptr<Job>& job) {
  if (!checkpointer_) return;
  checkpointer_->queue(job->id, [&]() -> std::optional<JobProgressRecord> {
    JobLock lock(mu_);
    return progress_record(*job);
  });
}

}  // namespace epr
