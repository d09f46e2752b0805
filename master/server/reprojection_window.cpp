// The reprojection thread's side of frame windows (window_run.h, DESIGN.md "Frame windows"): a
// run's frames start together, every committed tile's vertices go into the frames of its window as
// well as its own, and a round closes for every frame of the run at once, once all their tiles of it
// are applied -- so each frame's M' and skip mask after round r count the vertices of round r of all
// its neighbours, whatever the order tiles arrived in.
#include <fmt/format.h>

#include <algorithm>
#include <set>

#include "common/log.h"
#include "master/server/checkpoint.h"
#include "master/server/reprojection_worker.h"

namespace epr {

void ReprojectionWorker::start_run(const std::vector<std::shared_ptr<Job>>& frames) {
  auto log = logger("master");
  const BatchMembership& b = frames.front()->request.batch;
  auto run = std::make_shared<WindowRun>();
  run->frames = frames;
  run->window = b.window;
  std::string frame_list;
  for (const auto& j : frames)
    frame_list += fmt::format("{}{}", frame_list.empty() ? "" : ",", *j->request.batch.frame);
  std::set<int> rounds;
  {
    JobLock lock(m_.mu_);
    for (const auto& j : frames) rounds.insert(j->resume ? j->resume->progress.round : -1);
    if (rounds.size() > 1)
      // Rounds go in step: frames checkpointed after different rounds (a master stopped between
      // their checkpoints) cannot continue together. They start again; the counts come out the same.
      for (const auto& j : frames) {
        j->resume.reset();
        j->counters = {};
        j->progress = {};
        j->counts = {};
        j->round = 0;
      }
    for (const auto& j : frames) j->run = run;
  }
  if (frames.size() < run_length(b))
    log->warn(
        "window run {}..{} of batch {} starts with {} of its {} frames ({}): the others ended or did not "
        "come within {} s",
        b.window_first, b.window_last, b.id, frames.size(), run_length(b), frame_list,
        m_.options_.window_run_wait_ms / 1000.0);
  if (rounds.size() > 1)
    log->warn("window run {}..{} of batch {}: its frames were checkpointed after different rounds; they start again",
              b.window_first, b.window_last, b.id);
  log->info("window run {}..{} of batch {} (K = {}) starting: frames {}", b.window_first, b.window_last, b.id, b.window,
            frame_list);
  for (const auto& j : frames) start_or_fail(j);
}

void ReprojectionWorker::reproject_into_neighbours(const Job& job, const std::vector<const AssembledTile*>& tiles) {
  std::vector<std::shared_ptr<Job>> into;
  const uint32_t frame = job.request.batch.frame.value_or(0);
  {
    JobLock lock(m_.mu_);
    if (!job.run) return;
    for (auto& g : job.run->neighbours(frame))
      if (g->state == JobState::kRunning && g->round == job.round && g->round_open) into.push_back(std::move(g));
  }
  for (const auto& g : into)
    if (RoundDriver* d = driver(*g)) {
      const uint32_t other = g->request.batch.frame.value_or(0);
      const uint32_t units =
          window_count_unit(g->request.batch) == 1
              ? 1
              : window_sample_weight(other > frame ? other - frame : frame - other, g->request.batch.window_halving);
      d->reproject(tiles, units);
      const double s = d->frame().seconds_reprojecting();
      JobLock lock(m_.mu_);
      g->counters.seconds_reprojecting = s;
    }
}

void ReprojectionWorker::close_in_step(const WindowRun& run, uint32_t round) {
  std::vector<std::shared_ptr<Job>> closing;
  bool due = false;
  {
    JobLock lock(m_.mu_);
    for (const auto& g : run.frames) {
      // A frame that ended left the run; one in another round (its checkpoint did not fit) goes alone.
      if (g->state != JobState::kRunning || g->round != round || !g->round_open) continue;
      if (g->remaining > 0 || !driver(*g)) return;  // its tiles of the round are still to come
      closing.push_back(g);
    }
    // One decision for the run, so that its frames' checkpoints are of one round.
    for (const auto& g : closing) due = due || checkpoint_due(*g);
  }
  for (const auto& g : closing) {
    if (m_.options_.before_round_close) m_.options_.before_round_close(g->id, round);
    close_round(g, due);
  }
}

}  // namespace epr
