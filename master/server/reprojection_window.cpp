// The reprojection thread's side of frame windows (window_run.h, DESIGN.md "Frame windows"): a
// run's frames start together, every committed tile's vertices go into the frames of its window as
// well as its own, and each frame closes its rounds by itself: round r once its own tiles of r and
// its neighbours' of r - 1 are applied (of r at its last round), a neighbour's round r counted from
// the frame's close of r on (held until then) -- so each frame's M' and skip mask after round r count
// its own rounds 0..r and its neighbours' 0..r-1, whatever the order tiles arrived in.
#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <set>
#include <tuple>

#include "common/log.h"
#include "master/server/checkpoint.h"
#include "master/server/reprojection_worker.h"
#include "master/view_overlap.h"
#include "wire/scene_bundle.h"
#include "wire/scene_shelf.h"

namespace epr {
namespace {

// The count units of a sample traced for frame `from` in frame job `g`'s M'.
uint32_t window_sample_units(const Job& g, uint32_t from) {
  const uint32_t to = g.request.batch.frame.value_or(0);
  return window_count_unit(g.request.batch) == 1
             ? 1
             : window_sample_weight(to > from ? to - from : from - to, g.request.batch.window_halving);
}

}  // namespace

void ReprojectionWorker::start_run(const std::vector<std::shared_ptr<Job>>& frames) {
  auto log = logger("master");
  const BatchMembership& b = frames.front()->request.batch;
  auto run = std::make_shared<WindowRun>();
  run->frames = frames;
  run->window = b.window;
  std::string frame_list;
  for (const auto& j : frames)
    frame_list += fmt::format("{}{}", frame_list.empty() ? "" : ",", *j->request.batch.frame);
  // Held until the frames have started: they take the same scene from the shelf.
  const std::shared_ptr<const Scene> scene = measure_cuts(frames.front(), run.get());
  // A frame's checkpoint after round r holds its neighbours' rounds up to r: frames checkpointed
  // after different rounds (a master stopped between their checkpoints) would miss each other's
  // rounds in between. They resume from the earliest of these rounds where every frame has a
  // checkpoint of it (the newest or the previous one: the run's frames checkpoint after the same
  // rounds), else they start again; the counts come out the same either way.
  std::set<int> rounds;
  std::vector<std::pair<std::shared_ptr<Job>, int>> newest;
  {
    JobLock lock(m_.mu_);
    for (const auto& j : frames) {
      rounds.insert(j->resume ? j->resume->progress.round : -1);
      newest.emplace_back(j, j->resume ? j->resume->progress.round : -1);
    }
  }
  std::vector<std::shared_ptr<const JobProgressRecord>> earlier;
  if (rounds.size() > 1 && *rounds.begin() >= 0 && m_.store_)
    for (const auto& [j, r] : newest) {
      if (r == *rounds.begin()) {
        earlier.push_back(nullptr);
        continue;
      }
      auto record = m_.store_->load_progress_after(j->id, *rounds.begin());
      if (!record) break;
      earlier.push_back(std::make_shared<const JobProgressRecord>(std::move(*record)));
    }
  const bool fell_back = rounds.size() > 1 && earlier.size() == frames.size();
  {
    JobLock lock(m_.mu_);
    if (fell_back)
      for (size_t i = 0; i < frames.size(); ++i) {
        if (!earlier[i]) continue;
        frames[i]->resume = earlier[i];
        frames[i]->counters = earlier[i]->counters;
        frames[i]->progress = earlier[i]->progress;
        frames[i]->counts = earlier[i]->counts;
        frames[i]->round = uint32_t(std::max(0, earlier[i]->progress.round));
      }
    else if (rounds.size() > 1)
      for (const auto& j : frames) {
        j->resume.reset();
        j->counters = {};
        j->progress = {};
        j->counts = {};
        j->round = 0;
      }
    for (const auto& j : frames) {
      j->run = run;
      const uint32_t f = j->request.batch.frame.value_or(0);
      std::tie(j->fed_by_first, j->fed_by_last) = run->fed_by(f);
      std::tie(j->view_share_previous, j->view_share_next) = run->shares_of(f);
    }
  }
  if (frames.size() < run_length(b))
    log->warn(
        "window run {}..{} of batch {} starts with {} of its {} frames ({}): the others ended or did not "
        "come within {} s",
        b.window_first, b.window_last, b.id, frames.size(), run_length(b), frame_list,
        m_.options_.window_run_wait_ms / 1000.0);
  if (fell_back)
    log->warn(
        "window run {}..{} of batch {}: its frames were checkpointed after different rounds; they resume after round "
        "{}, some from their previous checkpoint",
        b.window_first, b.window_last, b.id, *rounds.begin());
  else if (rounds.size() > 1)
    log->warn("window run {}..{} of batch {}: its frames were checkpointed after different rounds; they start again",
              b.window_first, b.window_last, b.id);
  log->info("window run {}..{} of batch {} (K = {}) starting: frames {}", b.window_first, b.window_last, b.id, b.window,
            frame_list);
  // Resumed frames are restored before their rounds open. Fresh ones open their rounds 0 all at once,
  // so that workers trace every frame's first round while the frames are built one by one; a frame
  // is built when its commits come up to be applied (build_unbuilt), in the order workers returned
  // its tiles, or when the thread has nothing else to do.
  for (const auto& j : frames) {
    bool fresh;
    {
      JobLock lock(m_.mu_);
      fresh = j->resume == nullptr;
    }
    if (!fresh) {
      start_or_fail(j);
      continue;
    }
    try {
      prepare_job(j);
      if (begin_running(j, nullptr)) unbuilt_.push_back(j);
    } catch (const std::exception& e) {
      fail_start(j, e.what());
    }
  }
}

bool ReprojectionWorker::build_unbuilt(const std::shared_ptr<Job>& job) {
  for (auto it = unbuilt_.begin(); it != unbuilt_.end();) {
    const std::shared_ptr<Job> g = *it;
    if (job && g != job) {
      ++it;
      continue;
    }
    it = unbuilt_.erase(it);
    bool running;
    {
      JobLock lock(m_.mu_);
      running = g->state == JobState::kRunning;
    }
    if (!running || !renders_.count(g->id)) continue;  // it ended meanwhile
    try {
      build_frame(g);
    } catch (const std::exception& e) {
      fail_start(g, e.what());
    }
    return true;
  }
  return false;
}

std::shared_ptr<const Scene> ReprojectionWorker::measure_cuts(const std::shared_ptr<Job>& first, WindowRun* run) {
  const BatchMembership& b = first->request.batch;
  const double below = m_.options_.window_cut_share;
  if (below <= 0) return nullptr;
  // Every frame of the run this master has, ended ones too: a run started again after a restart
  // measures the same pairs as before, whichever of its frames finished meanwhile.
  std::vector<std::pair<uint32_t, CameraSpec>> cameras;
  {
    JobLock lock(m_.mu_);
    for (const auto& [id, j] : m_.jobs_.all())
      if (same_run(j->request.batch, b)) cameras.emplace_back(j->request.batch.frame.value_or(0), j->request.camera);
  }
  std::sort(cameras.begin(), cameras.end(), [](const auto& x, const auto& y) { return x.first < y.first; });
  if (cameras.size() < 2) return nullptr;
  std::shared_ptr<const Scene> scene;
  try {
    scene = share_bundle_scene(*first->bundle, first->scene_hash, m_.cache_dir(), first->request.options.lighting);
  } catch (const std::exception&) {
    return nullptr;  // the frames fail to start with the reason
  }
  const RenderOptions& o = first->request.options;
  const auto start = std::chrono::steady_clock::now();
  // The rays are traced with the scene's BVH on the shelf, which the frames' edge pixels use next.
  const std::shared_ptr<const SceneBvh> bvh = shelved_bvh(scene);
  std::vector<ViewProbe> probes;
  for (const auto& c : cameras) probes.push_back(view_probe(*bvh, c.second, o.width, o.height));
  std::string shares;
  for (size_t i = 0; i + 1 < probes.size(); ++i) {
    run->measured.push_back(cameras[i].first);
    run->share.push_back(mutual_view_share(probes[i], probes[i + 1], *bvh));
    run->cut.push_back(run->share.back() < below);
    shares +=
        fmt::format("{}{}-{} {:.0f} %", i ? ", " : "", cameras[i].first, cameras[i + 1].first, 100 * run->share.back());
  }
  run->measured.push_back(cameras.back().first);
  auto log = logger("master");
  log->info("window run {}..{} of batch {}: neighbouring frames' views share {} (measured in {:.2f} s)", b.window_first,
            b.window_last, b.id, shares,
            std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
  for (size_t i = 0; i < run->cut.size(); ++i)
    if (run->cut[i])
      log->info("window run {}..{} of batch {}: a cut between frames {} and {} (views share {:.0f} %, below {:.0f} %)",
                b.window_first, b.window_last, b.id, run->measured[i], run->measured[i + 1], 100 * run->share[i],
                100 * below);
  return scene;
}

void ReprojectionWorker::reproject_into_neighbours(const Job& job, uint32_t round,
                                                   const std::shared_ptr<const Batch>& batch) {
  std::vector<std::shared_ptr<Job>> into;
  const uint32_t frame = job.request.batch.frame.value_or(0);
  {
    JobLock lock(m_.mu_);
    if (!job.run) return;
    for (auto& g : job.run->neighbours(frame))
      if (g->state == JobState::kRunning) into.push_back(std::move(g));
  }
  std::vector<const AssembledTile*> tiles;
  for (const auto& g : into) {
    auto it = renders_.find(g->id);
    if (it == renders_.end()) continue;
    RoundDriver* d = it->second.driver.get();
    const uint32_t units = window_sample_units(*g, frame);
    // g counts a neighbour's round r from its own close of r + 1 on: until g has closed round r, the
    // tiles wait (flush_deferred at g's close); a frame not built yet has closed none.
    if (!d || round >= uint32_t(d->frame().round())) {
      it->second.deferred.push_back({round, frame, units, batch});
      continue;
    }
    if (tiles.empty())
      for (const auto& t : *batch) tiles.push_back(&t->tile);
    d->reproject(tiles, units);
    const double s = d->frame().seconds_reprojecting();
    JobLock lock(m_.mu_);
    g->counters.seconds_reprojecting = s;
  }
}

void ReprojectionWorker::flush_deferred(Render& render, int64_t through) {
  auto& d = render.deferred;
  // One order whatever the order the tiles came in: by round, then by the frame they were traced for.
  std::stable_sort(d.begin(), d.end(), [](const Deferred& a, const Deferred& b) {
    return std::tie(a.round, a.from_frame) < std::tie(b.round, b.from_frame);
  });
  size_t n = 0;
  std::vector<const AssembledTile*> tiles;
  for (; n < d.size() && int64_t(d[n].round) <= through; ++n) {
    tiles.clear();
    for (const auto& t : *d[n].batch) tiles.push_back(&t->tile);
    render.driver->reproject(tiles, d[n].units);
  }
  d.erase(d.begin(), d.begin() + std::ptrdiff_t(n));
}

bool ReprojectionWorker::drain_stops(const Job& job, uint32_t round) {
  if (!m_.draining_ || !job.run) return m_.draining_;
  RunRounds& rr = runs_[job.run.get()];
  if (!rr.drain) {
    uint32_t top = round;
    for (const auto& g : job.run->frames)
      if (g->state == JobState::kRunning) top = std::max(top, g->round);
    rr.drain = top;
  }
  return round >= *rr.drain;
}

bool ReprojectionWorker::neighbours_through(const WindowRun& run, const Job& g, int64_t round) const {
  for (const auto& n : run.neighbours(g.request.batch.frame.value_or(0)))
    // A frame that ended left the run.
    if (n->state == JobState::kRunning && (n->remaining == 0 ? int64_t(n->round) : int64_t(n->round) - 1) < round)
      return false;
  return true;
}

bool ReprojectionWorker::advance_frame(const std::shared_ptr<const WindowRun>& run, const std::shared_ptr<Job>& g) {
  auto it = renders_.find(g->id);
  if (it == renders_.end() || !it->second.driver) return false;
  Render& render = it->second;
  if (render.checkpoint) {
    // The checkpoint after round r: once the neighbours' rounds r are in, the frame holds its own
    // rounds 0..r and theirs, the state a restart resumes from (with the skip mask of its close of r).
    {
      JobLock lock(m_.mu_);
      if (g->state != JobState::kRunning || !neighbours_through(*run, *g, render.checkpoint_round)) return false;
    }
    flush_deferred(render, render.checkpoint_round);
    JobProgressRecord record = std::move(*render.checkpoint);
    render.checkpoint.reset();
    save_round_checkpoint(g, std::move(record), /*due=*/true);
    std::vector<const AssembledTile*> tiles;
    for (const auto& batch : render.own) {
      tiles.clear();
      for (const auto& t : *batch) tiles.push_back(&t->tile);
      render.driver->apply(tiles);
    }
    render.own.clear();
    return true;
  }
  const bool held = render.held.has_value();
  uint32_t round;
  int64_t need;  // the neighbours' rounds that must be in the frame first: up to this one
  {
    JobLock lock(m_.mu_);
    if (g->state != JobState::kRunning) return false;
    if (!held && (!g->round_open || g->remaining > 0)) return false;  // its own tiles are still to come
    round = g->round;
    // Round r closes with the neighbours' rounds up to r - 1; the last round with theirs up to r, and
    // a drain's stop after r waits for them too.
    const bool last = int64_t(round) + 1 >= rounds_planned(g->request.options);
    need = held || last ? int64_t(round) : int64_t(round) - 1;
    if (!neighbours_through(*run, *g, need)) return false;
  }
  flush_deferred(render, need);
  if (held) {
    ClosedRound closed = std::move(*render.held);
    render.held.reset();
    open_next_round(g, std::move(closed), /*checkpoint=*/true);
    return true;
  }
  if (m_.options_.before_round_close) m_.options_.before_round_close(g->id, round);
  std::optional<ClosedRound> closed = end_round(g);
  if (!closed) return true;       // it finished
  flush_deferred(render, round);  // the neighbours' round r counts from now on
  bool checkpoint, drain;
  {
    JobLock lock(m_.mu_);
    // One checkpoint decision per round of the run, by the first frame to close it, so that the
    // frames' checkpoints are of one round.
    RunRounds& rr = runs_[run.get()];
    if (int64_t(round) > rr.closed) {
      rr.closed = round;
      if (m_.checkpointer_ && checkpoint_due(*g)) rr.checkpoint.insert(round);
    }
    checkpoint = rr.checkpoint.count(round) > 0;
    drain = drain_stops(*g, round);
  }
  if (drain) {
    render.held = std::move(*closed);  // no next round: the drain's checkpoint once the neighbours' round is in
    return true;
  }
  if (checkpoint) {
    render.checkpoint = closed->checkpoint;
    render.checkpoint_round = round;
  }
  open_next_round(g, std::move(*closed), /*checkpoint=*/false, /*may_drain=*/false);
  return true;
}

void ReprojectionWorker::advance_run(const std::shared_ptr<const WindowRun>& run) {
  for (bool moved = true; moved;) {
    moved = false;
    for (const auto& g : run->frames) moved = advance_frame(run, g) || moved;
  }
  JobLock lock(m_.mu_);
  for (const auto& g : run->frames)
    if (g->state == JobState::kRunning) return;
  runs_.erase(run.get());
}

}  // namespace epr
