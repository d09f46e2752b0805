// Several jobs running at once on one JobManager: admission by the memory budget, leases across the
// running jobs (priority, then fair share), a worker tracing another job while one job's round
// closes, images identical to each job rendered alone, and two running jobs resumed after a restart.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <filesystem>
#include <map>
#include <mutex>
#include <set>
#include <thread>

#include "common/image.h"
#include "master/gl_context.h"
#include "master/memory_estimate.h"
#include "master/server/job_manager.h"
#include "tests/server/in_process_worker.h"
#include "tests/server/job_images.h"

namespace epr {
namespace {
namespace fs = std::filesystem;
using namespace std::chrono_literals;
using test::expect_same_images;
using test::JobImages;
using test::JobsWorker;
using test::results_of;

fs::path fresh_dir(const std::string& name) { return test::fresh_dir("epr-multi-job-test", name); }

constexpr uint64_t kLargeBudget = uint64_t(1) << 40;

JobRequest request(const std::string& key, RenderMode mode, int width, int height, uint64_t seed = 5,
                   ReprojectMethod method = ReprojectMethod::kCpu) {
  JobRequest req;
  req.options.width = width;
  req.options.height = height;
  req.options.spp = 32;
  req.options.paths_per_round = 4;
  req.options.min_paths = 8;
  req.options.mode = mode;
  req.options.reproject = method;
  req.options.tile_size = 16;
  req.options.seed = seed;
  req.bundle.builtin = "builtin:cornell";
  req.name = key;
  req.request_id = key;
  return req;
}

JobState state(const JobManager& jobs, const std::string& id) { return jobs.get(id).value().state; }

/// Traces until every one of `ids` is done or has closed `until_round` rounds (test::trace_until).
void work(JobManager& jobs, JobsWorker& w, const std::vector<std::string>& ids, int until_round = 1 << 30) {
  test::trace_until(jobs, {&w}, ids, until_round, 180s);
}

/// M, M' and the path-traced sums bit for bit; the combined image within float rounding.
void expect_same_render(const JobImages& a, const JobImages& b, const std::string& what) {
  SCOPED_TRACE(what);
  ASSERT_FALSE(a.counts.data.empty());
  expect_same_images(a, b);
}

/// The job rendered alone on a master of its own.
JobImages render_alone(const JobRequest& req) {
  const fs::path dir = fresh_dir("alone");
  MasterOptions o;
  o.state_dir = dir.string();
  o.checkpoints = false;
  JobImages r;
  {
    JobManager jobs(o);
    const auto s = jobs.submit(req);
    EXPECT_EQ(s.error, "");
    JobsWorker w(jobs);
    work(jobs, w, {s.id});
    r = results_of(jobs, s.id);
  }
  fs::remove_all(dir);
  return r;
}

// A gate the reprojection thread waits at (MasterOptions hooks) until the test opens it. Declared after
// the JobManager it holds, so that it opens before the manager joins its thread.
struct Gate {
  std::mutex mu;
  std::condition_variable cv;
  bool open = false;
  std::atomic<bool> waiting{false};
  void wait() {
    waiting = true;
    std::unique_lock<std::mutex> lock(mu);
    cv.wait(lock, [&] { return open; });
    waiting = false;
  }
  void release() {
    {
      std::lock_guard<std::mutex> lock(mu);
      open = true;
    }
    cv.notify_all();
  }
};
struct GateOpener {
  Gate& gate;
  ~GateOpener() { gate.release(); }
};

TEST(MultiJob, TheMemoryBudgetAdmitsTwoJobsAndTheThirdStartsWhenOneEnds) {
  const fs::path dir = fresh_dir("admission");
  MasterOptions o;
  o.state_dir = dir.string();
  const JobRequest a = request("a", RenderMode::kSkip, 64, 64), b = request("b", RenderMode::kSkip, 64, 64),
                   c = request("c", RenderMode::kSkip, 64, 64);
  const MemoryEstimate e = estimate_job_memory(a.options, /*checkpoints=*/true);
  const uint64_t own = e.total() - e.queue_bytes;
  o.memory_budget_bytes = kCommitQueueBytes + 2 * own + own / 2;  // two jobs fit, three do not
  {
    JobManager jobs(o);
    const std::string ia = jobs.submit(a).id, ib = jobs.submit(b).id, ic = jobs.submit(c).id;
    ASSERT_TRUE(test::poll_until(
        [&] { return state(jobs, ia) == JobState::kRunning && state(jobs, ib) == JobState::kRunning; }));
    // The third stays queued while both run (no worker: they never end).
    EXPECT_FALSE(test::poll_until([&] { return state(jobs, ic) != JobState::kQueued; }, 300ms));
    // epr_tiles_waiting: round 0 of both running jobs, none committed, and the queued job's first round.
    const uint64_t tiles = 16;
    EXPECT_EQ(jobs.tiles_waiting(), 3 * tiles);
    ASSERT_TRUE(jobs.cancel(ia));
    EXPECT_TRUE(test::poll_until([&] { return state(jobs, ic) == JobState::kRunning; })) << "the third job starts";
    EXPECT_EQ(state(jobs, ib), JobState::kRunning);
    EXPECT_EQ(jobs.tiles_waiting(), 2 * tiles);
    // And it completes beside the other.
    JobsWorker w(jobs);
    ASSERT_NO_FATAL_FAILURE(work(jobs, w, {ib, ic}));
    EXPECT_EQ(jobs.tiles_waiting(), 0u);
  }
  fs::remove_all(dir);
}

TEST(MultiJob, NoBudgetRunsOneJobAtATime) {
  const fs::path dir = fresh_dir("no-budget");
  MasterOptions o;
  o.state_dir = dir.string();
  o.checkpoints = false;
  JobManager jobs(o);
  const std::string ia = jobs.submit(request("a", RenderMode::kSkip, 32, 32)).id;
  const std::string ib = jobs.submit(request("b", RenderMode::kSkip, 32, 32)).id;
  ASSERT_TRUE(test::poll_until([&] { return state(jobs, ia) == JobState::kRunning; }));
  EXPECT_FALSE(test::poll_until([&] { return state(jobs, ib) != JobState::kQueued; }, 300ms));
  jobs.shutdown();
  fs::remove_all(dir);
}

TEST(MultiJob, EqualPriorityJobsShareTheWorkers) {
  const fs::path dir = fresh_dir("fair");
  MasterOptions o;
  o.state_dir = dir.string();
  o.checkpoints = false;
  o.memory_budget_bytes = kLargeBudget;
  JobManager jobs(o);
  const std::string ia = jobs.submit(request("a", RenderMode::kSkip, 64, 64)).id;
  const std::string ib = jobs.submit(request("b", RenderMode::kSkip, 64, 64)).id;
  ASSERT_TRUE(
      test::poll_until([&] { return state(jobs, ia) == JobState::kRunning && state(jobs, ib) == JobState::kRunning; }));
  JobsWorker w(jobs);
  std::map<std::string, int> leased;
  for (int i = 0; i < 10; ++i) {
    const auto l = w.lease();
    ASSERT_TRUE(l);
    ++leased[l->job_id];
  }
  // Fewest leases out first: the two jobs alternate.
  EXPECT_EQ(leased[ia], 5);
  EXPECT_EQ(leased[ib], 5);
  EXPECT_EQ(jobs.get(ia)->workers_active, 1u);
  jobs.shutdown();
  fs::remove_all(dir);
}

TEST(MultiJob, HigherPriorityIsLeasedFirst) {
  const fs::path dir = fresh_dir("priority");
  MasterOptions o;
  o.state_dir = dir.string();
  o.checkpoints = false;
  o.memory_budget_bytes = kLargeBudget;
  JobManager jobs(o);
  const std::string low = jobs.submit(request("low", RenderMode::kSkip, 64, 64)).id;
  JobRequest h = request("high", RenderMode::kSkip, 64, 64);
  h.priority = 5;
  const std::string high = jobs.submit(h).id;
  ASSERT_TRUE(test::poll_until(
      [&] { return state(jobs, low) == JobState::kRunning && state(jobs, high) == JobState::kRunning; }));
  JobsWorker w(jobs);
  for (int i = 0; i < 16; ++i) {  // every tile of the high job's round 0
    const auto l = w.lease();
    ASSERT_TRUE(l);
    EXPECT_EQ(l->job_id, high) << "lease " << i;
  }
  const auto l = w.lease();
  ASSERT_TRUE(l);
  EXPECT_EQ(l->job_id, low) << "the lower priority once the higher has no tile to hand out";
  jobs.shutdown();
  fs::remove_all(dir);
}

TEST(MultiJob, AWorkerTracesAnotherJobWhileOneJobsRoundCloses) {
  const fs::path dir = fresh_dir("round-close");
  Gate gate;
  std::string held_job;
  std::mutex held_mu;
  MasterOptions o;
  o.state_dir = dir.string();
  o.checkpoints = false;
  o.memory_budget_bytes = kLargeBudget;
  o.before_round_close = [&](const std::string& job, uint32_t round) {
    std::string hold;
    {
      std::lock_guard<std::mutex> lock(held_mu);
      hold = held_job;
    }
    if (job == hold && round == 0) gate.wait();
  };
  JobManager jobs(o);
  GateOpener opener{gate};
  JobRequest small = request("small", RenderMode::kSkip, 16, 16);  // one tile
  small.priority = 1;
  const std::string is = jobs.submit(small).id;
  {
    std::lock_guard<std::mutex> lock(held_mu);
    held_job = is;
  }
  const std::string ib = jobs.submit(request("big", RenderMode::kSkip, 64, 64)).id;
  ASSERT_TRUE(
      test::poll_until([&] { return state(jobs, is) == JobState::kRunning && state(jobs, ib) == JobState::kRunning; }));
  JobsWorker w(jobs);
  const auto first = w.lease();
  ASSERT_TRUE(first);
  ASSERT_EQ(first->job_id, is);
  ASSERT_EQ(w.submit(*first), CommitOutcome::kCommitted);
  // The small job's round 0 is applied and its close held: it has no tile to hand out.
  ASSERT_TRUE(test::poll_until([&] { return gate.waiting.load(); }));
  EXPECT_EQ(jobs.get(is)->progress.round, 0);
  const auto next = w.lease();
  ASSERT_TRUE(next) << "the worker is told to wait although another job has tiles";
  EXPECT_EQ(next->job_id, ib);
  EXPECT_EQ(w.submit(*next), CommitOutcome::kCommitted);
  gate.release();
  ASSERT_NO_FATAL_FAILURE(work(jobs, w, {is, ib}));
  jobs.shutdown();
  fs::remove_all(dir);
}

// Three jobs of different modes (and a GL one where OSMesa is there: two GL reprojectors live in one
// context) rendered together, each against itself rendered alone.
TEST(MultiJob, JobsRenderedTogetherEqualEachRenderedAlone) {
  std::vector<JobRequest> reqs = {request("skip", RenderMode::kSkip, 48, 40, 5),
                                  request("rp", RenderMode::kReproject, 40, 32, 7),
                                  request("pt", RenderMode::kPathTrace, 32, 32, 9)};
  if (gl_available()) {
    reqs.push_back(request("skip-gl", RenderMode::kSkip, 48, 40, 11, ReprojectMethod::kGl));
    reqs.push_back(request("rp-gl", RenderMode::kReproject, 40, 32, 13, ReprojectMethod::kGl));
  }
  const fs::path dir = fresh_dir("together");
  MasterOptions o;
  o.state_dir = dir.string();
  o.checkpoints = false;
  o.memory_budget_bytes = kLargeBudget;
  std::vector<JobImages> together;
  {
    JobManager jobs(o);
    std::vector<std::string> ids;
    for (const auto& r : reqs) ids.push_back(jobs.submit(r).id);
    ASSERT_TRUE(test::poll_until([&] {
      return std::all_of(ids.begin(), ids.end(), [&](const auto& id) { return state(jobs, id) != JobState::kQueued; });
    })) << "every job runs at once";
    // Two workers taking turns, so that the jobs' tiles interleave.
    JobsWorker w1(jobs, "w1"), w2(jobs, "w2");
    std::set<std::string> seen;
    for (auto end = std::chrono::steady_clock::now() + 180s; std::chrono::steady_clock::now() < end;) {
      bool done = true;
      for (const auto& id : ids) done &= state(jobs, id) == JobState::kDone;
      if (done) break;
      for (JobsWorker* w : {&w1, &w2})
        if (auto l = w->lease()) {
          seen.insert(l->job_id);
          w->submit(*l);
        }
    }
    EXPECT_EQ(seen.size(), ids.size());
    for (const auto& id : ids) {
      ASSERT_EQ(state(jobs, id), JobState::kDone) << jobs.get(id)->error;
      together.push_back(results_of(jobs, id));
    }
  }
  fs::remove_all(dir);
  for (size_t i = 0; i < reqs.size(); ++i) expect_same_render(together[i], render_alone(reqs[i]), reqs[i].name);
}

TEST(MultiJob, TwoRunningJobsResumeFromTheirCheckpointsAfterARestart) {
  JobRequest a = request("a", RenderMode::kSkip, 48, 40, 5), b = request("b", RenderMode::kSkip, 40, 48, 6);
  for (JobRequest* r : {&a, &b}) {  // rounds of 2 paths: both jobs are mid-way at round 2
    r->options.paths_per_round = 2;
    r->options.round_growth = 0;
  }
  const fs::path dir = fresh_dir("resume");
  MasterOptions o;
  o.state_dir = dir.string();
  o.checkpoint_interval_s = 0;  // after every round
  o.memory_budget_bytes = kLargeBudget;
  std::string ia, ib;
  {
    JobManager jobs(o);
    ia = jobs.submit(a).id;
    ib = jobs.submit(b).id;
    JobsWorker w(jobs);
    ASSERT_NO_FATAL_FAILURE(work(jobs, w, {ia, ib}, 2));
    EXPECT_EQ(state(jobs, ia), JobState::kRunning);
    EXPECT_EQ(state(jobs, ib), JobState::kRunning);
  }  // destroyed with both jobs mid-way
  {
    JobManager jobs(o);
    ASSERT_TRUE(test::poll_until([&] {
      return state(jobs, ia) == JobState::kRunning && state(jobs, ib) == JobState::kRunning;
    })) << "both resume at once";
    EXPECT_GE(jobs.get(ia)->progress.round, 1) << "from its checkpoint, not round 0";
    EXPECT_GE(jobs.get(ib)->progress.round, 1) << "from its checkpoint, not round 0";
    JobsWorker w(jobs);
    ASSERT_NO_FATAL_FAILURE(work(jobs, w, {ia, ib}));
    const JobImages ra = results_of(jobs, ia), rb = results_of(jobs, ib);
    expect_same_render(ra, render_alone(a), "a");
    expect_same_render(rb, render_alone(b), "b");
  }
  fs::remove_all(dir);
}

}  // namespace
}  // namespace epr
