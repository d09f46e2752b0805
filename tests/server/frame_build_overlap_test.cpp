// A fresh job's round 0 is leased while its frame (deep framebuffer, accumulation) is being built:
// tiles traced and committed before the frame exists wait in the commit queue and are applied after
// it, with the same image as the single-process render. The build is held (or failed) through
// MasterOptions::before_frame_build; everything else is real gRPC on loopback. Also: a job cancelled,
// a master shut down, a worker lost or a build failing while the frame is built; and a job resumed
// from its checkpoint, which still restores its frame before any lease.
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <condition_variable>
#include <mutex>
#include <nlohmann/json.hpp>
#include <stdexcept>

#include "tests/server/farm_fixture.h"

namespace epr::test {
namespace {

// Holds the reprojection thread before a frame build until released; or makes the build fail.
class BuildGate {
 public:
  void enter(const std::string& job) {
    std::unique_lock lock(mu_);
    entered_.push_back(job);
    cv_.notify_all();
    cv_.wait(lock, [&] { return open_; });
    if (!fail_with_.empty()) throw std::runtime_error(fail_with_);
  }
  bool entered(size_t n = 1) const {
    std::lock_guard lock(mu_);
    return entered_.size() >= n;
  }
  void release(std::string fail_with = "") {
    std::lock_guard lock(mu_);
    open_ = true;
    fail_with_ = std::move(fail_with);
    cv_.notify_all();
  }
  std::function<void(const std::string&)> hook() {
    return [this](const std::string& job) { enter(job); };
  }

 private:
  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::vector<std::string> entered_;
  bool open_ = false;
  std::string fail_with_;
};

class FrameBuildOverlap : public FarmFixture {
 protected:
  void TearDown() override {
    gate_.release();  // a test that failed half-way must not leave the master's thread held
    FarmFixture::TearDown();
  }

  MasterOptions gated() {
    MasterOptions mo;
    mo.before_frame_build = gate_.hook();
    return mo;
  }

  // Every tile of the open round, leased by `w`, traced and committed; their leases.
  std::vector<v1::TileLease> commit_round(WireWorker& w, uint32_t round, size_t tiles) {
    std::vector<v1::TileLease> leased;
    for (size_t i = 0; i < tiles; ++i) {
      auto t = w.lease_wait(10s);
      if (!t) {
        ADD_FAILURE() << "tile " << i << " of " << tiles << " was not leased";
        break;
      }
      EXPECT_EQ(t->round(), round);
      v1::SubmitAck ack;
      const grpc::Status st = w.submit(w.render(*t), &ack);
      EXPECT_TRUE(st.ok()) << st.error_message();
      EXPECT_EQ(ack.outcome(), v1::SUBMIT_OUTCOME_COMMITTED) << ack.reason();
      leased.push_back(*t);
    }
    return leased;
  }

  nlohmann::json statistics(const std::string& id) {
    return nlohmann::json::parse(fetch_result_bytes(*jobs_, id, v1::RESULT_KIND_JSON, 10s));
  }

  BuildGate gate_;
};

class FrameBuildOverlapReprojectors : public FrameBuildOverlap,
                                      public ::testing::WithParamInterface<ReprojectMethod> {};

TEST_P(FrameBuildOverlapReprojectors, RoundZeroCommittedBeforeTheFrameExistsGivesTheSameImage) {
  start(gated());
  RenderOptions o = cornell(RenderMode::kSkip, 64, 6, 2);  // 16 tiles, 3 rounds
  o.reproject = GetParam();
  const std::string id = submit(o, bundle_scene(o.scene));
  ASSERT_TRUE(eventually([&] { return gate_.entered(); })) << "the frame build never began";
  // Round 0 is open while the build is held: the job runs and leases its tiles.
  v1::JobStatus s = status(id);
  EXPECT_EQ(s.state(), v1::JOB_STATE_RUNNING);
  EXPECT_GT(s.started_unix_ms(), 0);
  WireWorker w(channel_, "early");
  const size_t tiles = make_tiles(o).size();
  ASSERT_EQ(commit_round(w, 0, tiles).size(), tiles);
  // All of round 0 is committed, none of it applied: the round cannot close without the frame.
  s = status(id);
  EXPECT_EQ(s.tiles_committed(), tiles);
  EXPECT_EQ(s.round(), 0u);
  EXPECT_EQ(s.state(), v1::JOB_STATE_RUNNING);
  EXPECT_FALSE(w.lease()) << "round 1 opened before round 0 was applied";

  gate_.release();
  // Round 0 is applied once the frame exists and round 1 opens with its skip masks.
  ASSERT_TRUE(eventually([&] { return status(id).round() >= 1; }));
  {
    RunningNode node(node_options("rest"));
    s = wait_done(id);
  }
  ASSERT_EQ(s.state(), v1::JOB_STATE_DONE) << s.error_message();
  EXPECT_EQ(s.tiles_dropped(), 0u);
  expect_same_as_local(id, o);
  // The combined image within float rounding (reprojected sums are added in another order).
  const Image combined = fetch_image(id, v1::RESULT_KIND_EXR);
  const RenderOutputs local = render_local(o);
  ASSERT_EQ(combined.data.size(), local.combined.data.size());
  size_t differ = 0;
  for (size_t i = 0; i < combined.data.size(); ++i) {
    const float x = combined.data[i], y = local.combined.data[i];
    differ += !(std::fabs(x - y) <= 1e-5f + 1e-4f * std::max(std::fabs(x), std::fabs(y)));
  }
  EXPECT_EQ(differ, 0u);
  // The job's seconds run from round 0's opening: the frame's build is inside them.
  const nlohmann::json stats = statistics(id);
  EXPECT_GE(stats.at("seconds_frame_build").get<double>(), 0.0);
  EXPECT_GE(stats.at("seconds").get<double>(), stats.at("seconds_frame_build").get<double>());
}

INSTANTIATE_TEST_SUITE_P(Reprojectors, FrameBuildOverlapReprojectors,
                         ::testing::Values(ReprojectMethod::kCpu, ReprojectMethod::kGl),
                         [](const auto& info) { return std::string(to_string(info.param)); });

TEST_F(FrameBuildOverlap, CancelledWhileTheFrameIsBuiltEndsCancelledAndTheNextJobRuns) {
  start(gated());
  const RenderOptions o = cornell(RenderMode::kSkip, 64, 4, 2);
  const std::string first = submit(o, bundle_scene(o.scene));
  ASSERT_TRUE(eventually([&] { return gate_.entered(); }));
  WireWorker w(channel_, "w");
  ASSERT_EQ(commit_round(w, 0, 1).size(), 1u);
  const auto held = w.lease_wait(10s);
  ASSERT_TRUE(held);
  {
    grpc::ClientContext ctx;
    set_deadline(&ctx);
    v1::JobId req;
    req.set_id(first);
    v1::JobStatus resp;
    ASSERT_TRUE(jobs_->CancelJob(&ctx, req, &resp).ok());
  }
  EXPECT_EQ(status(first).state(), v1::JOB_STATE_CANCELLED);
  // The cancelled job's lease is not wanted any more, and its result is dropped.
  EXPECT_EQ(w.heartbeat({held->lease_id()}), std::vector<bool>{false});
  v1::SubmitAck ack;
  ASSERT_TRUE(w.submit(w.render(*held), &ack).ok());
  EXPECT_EQ(ack.outcome(), v1::SUBMIT_OUTCOME_STALE);
  EXPECT_FALSE(w.lease()) << "a cancelled job's tile was leased";

  gate_.release();  // the build ends; the job stays cancelled and the master goes on
  const std::string second = submit(o, bundle_scene(o.scene));
  v1::JobStatus s;
  {
    RunningNode node(node_options("next"));
    s = wait_done(second);
  }
  ASSERT_EQ(s.state(), v1::JOB_STATE_DONE) << s.error_message();
  expect_same_as_local(second, o);
  EXPECT_EQ(status(first).state(), v1::JOB_STATE_CANCELLED);
}

TEST_F(FrameBuildOverlap, FailedBuildFailsTheJobWithItsReasonAndDropsItsLeases) {
  start(gated());
  const RenderOptions o = cornell(RenderMode::kSkip, 64, 4, 2);
  const std::string first = submit(o, bundle_scene(o.scene));
  ASSERT_TRUE(eventually([&] { return gate_.entered(); }));
  WireWorker w(channel_, "w");
  ASSERT_EQ(commit_round(w, 0, 2).size(), 2u);  // committed, queued, never applied
  const auto held = w.lease_wait(10s);
  ASSERT_TRUE(held);
  gate_.release("out of memory for the deep framebuffer (test)");
  const v1::JobStatus s = wait_done(first);
  EXPECT_EQ(s.state(), v1::JOB_STATE_FAILED);
  EXPECT_NE(s.error_message().find("out of memory for the deep framebuffer (test)"), std::string::npos)
      << s.error_message();
  EXPECT_EQ(w.heartbeat({held->lease_id()}), std::vector<bool>{false});
  v1::SubmitAck ack;
  ASSERT_TRUE(w.submit(w.render(*held), &ack).ok());
  EXPECT_EQ(ack.outcome(), v1::SUBMIT_OUTCOME_STALE);

  // The master's thread goes on to the next job.
  const std::string second = submit(o, bundle_scene(o.scene));
  // The released gate fails every build: a master of its own for the next job.
  EXPECT_EQ(wait_done(second).state(), v1::JOB_STATE_FAILED);
  server_->shutdown();
  server_.reset();
  start();
  const std::string third = submit(o, bundle_scene(o.scene));
  v1::JobStatus t;
  {
    RunningNode node(node_options("next"));
    t = wait_done(third);
  }
  ASSERT_EQ(t.state(), v1::JOB_STATE_DONE) << t.error_message();
  expect_same_as_local(third, o);
}

TEST_F(FrameBuildOverlap, WorkerLostWhileTheFrameIsBuiltHasItsTileTracedAgain) {
  MasterOptions mo = gated();
  mo.lease_timeout_ms = 1500;  // long enough for `w` to trace a tile without heartbeats
  start(mo);
  const RenderOptions o = cornell(RenderMode::kSkip, 64, 4, 2);
  const std::string id = submit(o, bundle_scene(o.scene));
  ASSERT_TRUE(eventually([&] { return gate_.entered(); }));
  WireWorker lost(channel_, "lost");
  const auto gone = lost.lease_wait(10s);  // never traced, never heartbeaten
  ASSERT_TRUE(gone);
  // Its lease expires while the frame is still being built, and its tile is leased again.
  ASSERT_TRUE(eventually([&] { return status(id).tiles_re_leased() + status(id).worker_failures() > 0; }))
      << "the lost worker's lease did not expire";
  WireWorker w(channel_, "w");
  const size_t tiles = make_tiles(o).size();
  const auto leased = commit_round(w, 0, tiles);
  bool again = false;
  for (const auto& t : leased) again |= t.tile_index() == gone->tile_index();
  EXPECT_TRUE(again) << "the lost worker's tile was not leased again";
  gate_.release();
  v1::JobStatus s;
  {
    RunningNode node(node_options("rest"));
    s = wait_done(id);
  }
  ASSERT_EQ(s.state(), v1::JOB_STATE_DONE) << s.error_message();
  expect_same_as_local(id, o);
}

TEST_F(FrameBuildOverlap, ShutdownWhileTheFrameIsBuiltLosesNoWork) {
  const RenderOptions o = cornell(RenderMode::kSkip, 64, 4, 2);
  std::string id;
  {
    start(gated());
    id = submit(o, bundle_scene(o.scene));
    ASSERT_TRUE(eventually([&] { return gate_.entered(); }));
    WireWorker w(channel_, "w");
    ASSERT_EQ(commit_round(w, 0, 3).size(), 3u);
    // The master stops while its thread is in the build: shutdown waits for the build to end.
    std::thread stopper([&] { server_->shutdown(); });
    std::this_thread::sleep_for(100ms);
    gate_.release();
    stopper.join();
    server_.reset();
  }
  // A master on the same state directory has the job and renders it from round 0 to the same image.
  start();
  v1::JobStatus s;
  {
    RunningNode node(node_options("after"));
    s = wait_done(id);
  }
  ASSERT_EQ(s.state(), v1::JOB_STATE_DONE) << s.error_message();
  expect_same_as_local(id, o);
}

TEST_F(FrameBuildOverlap, ResumedJobRestoresItsFrameBeforeItsRoundOpens) {
  const RenderOptions o = cornell(RenderMode::kSkip, 64, 8, 2);  // 4 rounds
  std::string id;
  {
    MasterOptions mo;
    mo.checkpoint_interval_s = 0;  // after every round
    start(mo);
    id = submit(o, bundle_scene(o.scene));
    WireWorker w(channel_, "first");
    ASSERT_EQ(commit_round(w, 0, make_tiles(o).size()).size(), make_tiles(o).size());
    ASSERT_TRUE(eventually([&] { return status(id).round() >= 1; }));
    server_->shutdown();
    server_.reset();
  }
  start(gated());
  ASSERT_TRUE(eventually([&] { return gate_.entered(); })) << "the resumed job's frame build never began";
  // Held before its frame is built: the resumed job is not running and no tile is leased.
  EXPECT_EQ(status(id).state(), v1::JOB_STATE_QUEUED);
  WireWorker w(channel_, "second");
  EXPECT_FALSE(w.lease(300)) << "a resumed job leased a tile before its frame was restored";
  gate_.release();
  const auto t = w.lease_wait(10s);
  ASSERT_TRUE(t);
  EXPECT_EQ(t->round(), 1u) << "the resumed job goes on from its checkpoint's round";
  v1::SubmitAck ack;
  ASSERT_TRUE(w.submit(w.render(*t), &ack).ok());
  EXPECT_EQ(ack.outcome(), v1::SUBMIT_OUTCOME_COMMITTED) << ack.reason();
  v1::JobStatus s;
  {
    RunningNode node(node_options("rest"));
    s = wait_done(id);
  }
  ASSERT_EQ(s.state(), v1::JOB_STATE_DONE) << s.error_message();
  expect_same_as_local(id, o);
}

}  // namespace
}  // namespace epr::test
