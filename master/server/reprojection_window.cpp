// The reprojection thread's side of frame windows (window_run.h, DESIGN.md "Frame windows"): a
// run's frames start together, every committed tile's vertices go into the frames of its window as
// well as its own, and a round closes for every frame of the run at once, once all their tiles of it
// are applied -- so each frame's M' and skip mask after round r count the vertices of round r of all
// its neighbours, whatever the order tiles arrived in.
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
  if (rounds.size() > 1)
    log->warn("window run {}..{} of batch {}: its frames were checkpointed after different rounds; they start again",
              b.window_first, b.window_last, b.id);
  log->info("window run {}..{} of batch {} (K = {}) starting: frames {}", b.window_first, b.window_last, b.id, b.window,
            frame_list);
  for (const auto& j : frames) start_or_fail(j);
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
