// A window run's start (DESIGN.md "Frame windows", reprojection_window.cpp): every fresh frame's
// round 0 opens before any frame is built, and a frame is built when its commits come up to be
// applied, so the thread builds frames in the order workers return their tiles. The builds are
// watched (and the first held) through MasterOptions::before_frame_build; tracing is real
// (JobsWorker) and the images are compared with a run whose commits come in frame order.
#include <gtest/gtest.h>

#include <chrono>
#include <condition_variable>
#include <map>
#include <mutex>
#include <set>
#include <tuple>

#include "master/server/job_manager.h"
#include "tests/server/in_process_worker.h"
#include "tests/server/job_images.h"
#include "tests/server/render_jobs.h"

namespace epr {
namespace window_setup_test {
namespace {
using namespace std::chrono_literals;

// Records the frame builds in order and holds the first until released.
class Builds {
 public:
  std::function<void(const std::string&)> hook() {
    return [this](const std::string& job) {
      std::unique_lock lock(mu_);
      order_.push_back(job);
      cv_.notify_all();
      if (order_.size() == 1) cv_.wait_for(lock, 120s, [&] { return open_; });
    };
  }
  bool wait_first() {
    std::unique_lock lock(mu_);
    return cv_.wait_for(lock, 60s, [&] { return !order_.empty(); });
  }
  void release() {
    std::lock_guard lock(mu_);
    open_ = true;
    cv_.notify_all();
  }
  std::vector<std::string> order() const {
    std::lock_guard lock(mu_);
    return order_;
  }

 private:
  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::vector<std::string> order_;
  bool open_ = false;
};

TEST(WindowSetup, EveryRoundZeroOpensBeforeAnyBuildAndFramesAreBuiltAsTheirCommitsComeUp) {
  std::vector<JobRequest> reqs;
  for (uint32_t f = 1; f <= 3; ++f) reqs.push_back(test::small_run_frame("setup", f, 1, 70));
  // The same run with its commits in frame order: the images to compare with.
  const auto dir0 = test::fresh_dir("epr-window-setup", "frame-order");
  const std::vector<test::RenderedJob> in_order = test::render_jobs(test::all_frames_at_once(dir0), reqs, 1);
  std::filesystem::remove_all(dir0);

  const auto dir = test::fresh_dir("epr-window-setup", "last-first");
  Builds builds;
  MasterOptions o = test::all_frames_at_once(dir);
  o.before_frame_build = builds.hook();
  {
    JobManager jobs(o);
    // Destroyed before the manager: a test that fails half-way does not leave its thread held.
    const std::shared_ptr<void> unhold(nullptr, [&](void*) { builds.release(); });
    std::vector<std::string> ids;
    for (const auto& r : reqs) {
      const auto s = jobs.submit(r);
      ASSERT_EQ(s.error, "");
      ids.push_back(s.id);
    }
    ASSERT_TRUE(builds.wait_first()) << "no frame build began";
    EXPECT_EQ(builds.order(), std::vector<std::string>{ids[0]}) << "frame 1 is built first (frame order)";
    // Frame 1's build is held: every frame of the run is running with its round 0 open.
    for (size_t f = 0; f < ids.size(); ++f) EXPECT_EQ(jobs.get(ids[f])->state, JobState::kRunning) << "frame " << f + 1;
    // Every round-0 tile of every frame is leased while frame 1 is being built ...
    test::JobsWorker w(jobs);
    std::map<std::string, std::vector<TileLeaseInfo>> leases;
    std::set<std::tuple<std::string, uint32_t, uint32_t>> seen;
    while (auto l = w.lease()) {
      if (!seen.emplace(l->job_id, l->round, l->tile_index).second) break;  // a speculative copy: all are out
      EXPECT_EQ(l->round, 0u);
      leases[l->job_id].push_back(*l);
    }
    for (const auto& id : ids) EXPECT_EQ(leases[id].size(), 4u) << "round-0 tiles of job " << id << " leased";
    // ... and committed, frame 3's first, then frame 2's, then frame 1's.
    for (int f = 2; f >= 0; --f)
      for (const auto& l : leases[ids[size_t(f)]]) EXPECT_TRUE(w.submit(l).has_value()) << "frame " << f + 1;
    builds.release();
    test::trace_until(jobs, {&w}, ids);
    // Frame 3's commits came up first: it was built before frame 2.
    EXPECT_EQ(builds.order(), (std::vector<std::string>{ids[0], ids[2], ids[1]}));
    for (size_t f = 0; f < ids.size(); ++f) {
      SCOPED_TRACE("frame " + std::to_string(f + 1));
      test::expect_same_images(test::results_of(jobs, ids[f]), in_order[f].images);
    }
    jobs.shutdown();
  }
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace window_setup_test
}  // namespace epr
