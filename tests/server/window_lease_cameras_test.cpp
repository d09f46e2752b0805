// The cameras a window job's lease carries for the worker's culling (TileLease.window_cameras,
// DESIGN.md "Frame windows"): every frame of the run within K, whatever that frame's state when the
// lease goes out (a lease naming only the frames already running made the worker cull by timing, and
// M' of the batch's frames changed from run to run: seen in bench/frame_window_cost.py's conference
// fly-through, K = 2, when a run's frames started one after another). A run opens every frame's
// round 0 before any frame is built; the first lease goes out while frame 1's build is held.
#include <gtest/gtest.h>

#include <condition_variable>
#include <memory>
#include <mutex>

#include "master/server/job_manager.h"
#include "tests/server/in_process_worker.h"
#include "tests/server/render_jobs.h"

namespace epr {
namespace window_lease_cameras {
namespace {

// Frame `frame` of batch "cams" (frames 1..3, one run, K = 2), its eye moved `frame` tenths sideways.
JobRequest run_frame(uint32_t frame) { return test::small_run_frame("cams", frame, 2, 50); }

TEST(WindowLeaseCameras, AFramesFirstLeaseCarriesTheCamerasOfNeighboursNotYetBuilt) {
  const auto dir = test::fresh_dir("epr-window-cameras", "first-lease");
  std::mutex mu;
  std::condition_variable cv;
  bool held = false, open = false;
  MasterOptions o;
  o.state_dir = dir.string();
  o.checkpoints = false;
  o.memory_budget_bytes = uint64_t(1) << 40;
  // The reprojection thread stops before frame 1's frame build: every frame runs, none is built.
  o.before_frame_build = [&](const std::string&) {
    std::unique_lock lock(mu);
    held = true;
    cv.notify_all();
    cv.wait(lock, [&] { return open; });
  };
  auto release = [&] {
    std::lock_guard lock(mu);
    open = true;
    cv.notify_all();
  };
  {
    JobManager jobs(o);
    // Destroyed before the manager: a test that fails half-way does not leave its thread held.
    const std::shared_ptr<void> unhold(nullptr, [&](void*) { release(); });
    std::vector<std::string> ids;
    for (uint32_t f = 1; f <= 3; ++f) {
      const auto s = jobs.submit(run_frame(f));
      ASSERT_EQ(s.error, "");
      ids.push_back(s.id);
    }
    {
      std::unique_lock lock(mu);
      ASSERT_TRUE(cv.wait_for(lock, std::chrono::seconds(60), [&] { return held; })) << "frame 1 never started";
    }
    EXPECT_EQ(jobs.get(ids[0])->state, JobState::kRunning);
    EXPECT_EQ(jobs.get(ids[2])->state, JobState::kRunning) << "frame 3's round 0 is open before any build";
    test::JobsWorker w(jobs);
    std::optional<TileLeaseInfo> lease;
    EXPECT_TRUE(test::poll_until([&] { return (lease = w.lease()).has_value(); })) << "no tile of frame 1 leased";
    release();
    ASSERT_TRUE(lease);
    EXPECT_EQ(lease->job_id, ids[0]);
    ASSERT_EQ(lease->window_cameras.size(), 2u) << "frames 2 and 3, built or not";
    EXPECT_EQ(lease->window_cameras[0].eye.x, run_frame(2).camera.eye.x);
    EXPECT_EQ(lease->window_cameras[1].eye.x, run_frame(3).camera.eye.x);
    jobs.shutdown();
  }
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace window_lease_cameras
}  // namespace epr
