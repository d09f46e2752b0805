// Frame windows without a run-wide round barrier (DESIGN.md "Frame windows", "Rounds"): a frame closes
// round r once its own tiles of r and its neighbours' of r - 1 are applied, so while one frame's tiles
// are held back the frames further away go on -- and what each frame counts stays a function of the
// rounds, not of when tiles came. Driven through a JobManager in the test process (JobsWorker).
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <future>
#include <string>
#include <thread>
#include <vector>

#include "master/server/job_manager.h"
#include "tests/server/in_process_worker.h"
#include "tests/server/job_images.h"
#include "tests/server/render_jobs.h"

namespace epr {
namespace window_pipeline_test {
namespace {
namespace fs = std::filesystem;
using namespace std::chrono_literals;

constexpr uint32_t kFrames = 5;

// Frame `frame` of batch "pipe" (frames 1..5 as one run, K = 1), the eye moving sideways: 32 x 32
// pixels in four tiles, 24 rounds of 2 paths, skipping once a pixel has 16 paths (round 8 on: no
// frame is done before the held tiles go in).
JobRequest frame_request(uint32_t frame) {
  JobRequest req;
  req.options.width = req.options.height = 32;
  req.options.spp = 48;
  req.options.paths_per_round = 2;
  req.options.round_growth = 0;
  req.options.min_paths = 16;
  req.options.mode = RenderMode::kSkip;
  req.options.reproject = ReprojectMethod::kCpu;
  req.options.tile_size = 16;
  req.options.seed = 200 + frame;
  req.camera.eye.x += 0.05f * float(frame);
  req.bundle.builtin = "builtin:cornell";
  req.name = "pipe-" + std::to_string(frame);
  req.request_id = req.name;
  req.batch.id = "pipe";
  req.batch.frame = frame;
  req.batch.frames = kFrames;
  req.batch.window = 1;
  req.batch.window_first = 1;
  req.batch.window_last = kFrames;
  return req;
}

MasterOptions options(const fs::path& dir) {
  MasterOptions o = test::all_frames_at_once(dir);
  o.lease_timeout_ms = 600000;  // the held tiles' leases stay theirs
  return o;
}

// Traces the jobs `ids` to their end and checks each frame's M, M' and path sums against `undisturbed`'s.
void finish_and_compare(JobManager& jobs, test::JobsWorker* w, const std::vector<std::string>& ids,
                        const std::vector<test::RenderedJob>& undisturbed) {
  test::trace_until(jobs, {w}, ids);
  for (size_t f = 0; f < ids.size(); ++f) {
    SCOPED_TRACE("frame " + std::to_string(f + 1));
    const test::JobImages r = test::results_of(jobs, ids[f]);
    EXPECT_EQ(r.counts.data, undisturbed[f].images.counts.data) << "M and M'";
    EXPECT_EQ(r.pathtrace.data, undisturbed[f].images.pathtrace.data) << "path sums";
  }
}

TEST(WindowPipeline, FramesCloseRoundsWhileANeighboursRoundIsHeldBackAndCountTheSame) {
  std::vector<JobRequest> run;
  for (uint32_t f = 1; f <= kFrames; ++f) run.push_back(frame_request(f));
  const fs::path dir = test::fresh_dir("epr-window-pipeline", "held");
  const std::vector<test::RenderedJob> undisturbed = test::render_jobs(options(dir / "undisturbed"), run, 1);
  ASSERT_EQ(undisturbed.size(), size_t(kFrames));
  {
    JobManager jobs(options(dir / "held"));
    std::vector<std::string> ids;
    for (const auto& r : run) ids.push_back(jobs.submit(r).id);
    // Frame 5's tiles are leased and held; every other tile is traced. Frame f closes round r only
    // with frame f + 1's round r - 1 applied, so frame 4 closes round 0 only, frame 3 rounds 0-2,
    // frame 2 rounds 0-4 and frame 1 rounds 0-6, all while frame 5 is still in round 0. With the
    // rounds of a run in step, no frame would close round 0.
    test::JobsWorker w(jobs);
    std::vector<TileLeaseInfo> held;
    const auto rounds = [&](size_t i) { return jobs.get(ids[i])->progress.round; };
    for (auto end = std::chrono::steady_clock::now() + 120s; rounds(0) < 7 && std::chrono::steady_clock::now() < end;) {
      auto l = w.lease();
      if (l && l->job_id == ids[kFrames - 1])
        held.push_back(*l);
      else if (l)
        w.submit(*l);
      else
        std::this_thread::sleep_for(1ms);
    }
    EXPECT_EQ(rounds(0), 7) << "frame 1 closed seven rounds while frame 5's round 0 was held";
    EXPECT_EQ(rounds(kFrames - 1), 0) << "frame 5 is still in round 0";
    EXPECT_FALSE(held.empty());
    // Each frame is where the rule stops it (frame 1 waits for frame 2's round 6, which waits for
    // frame 3's round 4, ...): a moment more changes nothing.
    std::this_thread::sleep_for(200ms);
    EXPECT_EQ(rounds(0), 7);
    EXPECT_EQ(rounds(1), 5);
    EXPECT_EQ(rounds(2), 3);
    EXPECT_EQ(rounds(3), 1) << "frame 4 closed round 0 only: its round 1 needs frame 5's round 0";
    // The held tiles go in, and the run ends: every frame's M, M' and path sums are those of the
    // undisturbed render's, whose frames went nearly in step.
    for (const auto& l : held) EXPECT_TRUE(w.submit(l));
    finish_and_compare(jobs, &w, ids, undisturbed);
  }
  fs::remove_all(dir);
}

TEST(WindowPipeline, ADrainStopsARunsFramesAfterOneRoundAndARestartResumesThemWithTheSameCounts) {
  // A drain (epr-master on SIGTERM) while the run's frames are rounds apart -- frame 5's tiles held
  // back until frame 1 has closed 7 rounds, then let go as the drain begins: each frame goes on to the
  // highest round any had open and is checkpointed there once its neighbours' round is in. The
  // restarted master resumes all five from that one round, and the counts are the undisturbed
  // render's. (Checkpoints at round 0 and the drain only: frames stopped at rounds of their own would
  // have no common round to resume from but 0.)
  std::vector<JobRequest> run;
  for (uint32_t f = 1; f <= kFrames; ++f) run.push_back(frame_request(f));
  const fs::path dir = test::fresh_dir("epr-window-pipeline", "drain");
  const std::vector<test::RenderedJob> undisturbed = test::render_jobs(options(dir / "undisturbed"), run, 1);
  ASSERT_EQ(undisturbed.size(), size_t(kFrames));
  MasterOptions o = options(dir / "state");
  o.checkpoints = true;
  o.checkpoint_interval_s = 3600;
  std::vector<std::string> ids;
  {
    JobManager jobs(o);
    for (const auto& r : run) ids.push_back(jobs.submit(r).id);
    std::atomic<bool> hold{true}, stop{false};
    std::thread tracer([&] {
      test::JobsWorker w(jobs, "drained");
      std::vector<TileLeaseInfo> held;
      while (!stop) {
        if (!hold && !held.empty()) {
          for (const auto& l : held) w.submit(l);
          held.clear();
        }
        auto l = w.lease();
        if (l && hold && l->job_id == ids[kFrames - 1])
          held.push_back(*l);
        else if (l)
          w.submit(*l);
        else
          std::this_thread::sleep_for(1ms);
      }
    });
    const bool apart = test::poll_until([&] { return jobs.get(ids[0])->progress.round >= 7; }, 120s);
    auto drain = std::async(std::launch::async, [&] { return jobs.drain_and_checkpoint(120s); });
    std::this_thread::sleep_for(100ms);  // the drain begins (if it begins later, the frames are nearer)
    hold = false;
    const bool drained = drain.get();
    stop = true;
    tracer.join();
    ASSERT_TRUE(apart) << "frame 1 did not get to round 7";
    ASSERT_TRUE(drained);
  }
  {
    JobManager jobs(o);
    ASSERT_TRUE(test::poll_until([&] {
      for (const auto& id : ids)
        if (jobs.get(id)->state != JobState::kRunning) return false;
      return true;
    }));
    const int round = jobs.get(ids[0])->progress.round;
    EXPECT_GE(round, 8) << "from the drain's checkpoints after frame 1's open round at least, not round 0";
    for (const auto& id : ids) EXPECT_EQ(jobs.get(id)->progress.round, round) << "every frame at one round";
    test::JobsWorker w(jobs);
    finish_and_compare(jobs, &w, ids, undisturbed);
  }
  fs::remove_all(dir);
}

}  // namespace
}  // namespace window_pipeline_test
}  // namespace epr
