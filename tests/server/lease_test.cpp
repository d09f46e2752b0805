// Slow and failing workers against a real in-process master over loopback gRPC:
//  - a worker that stalls on its tile does not hold the round hostage: an idle WorkerNode gets a
//    speculative copy, the first complete result wins, the staller is told "not wanted" and its late
//    result is dropped and counted; the image is bit-identical to the undisturbed render; a dead
//    worker's tile (no heartbeat) is not copied but comes back when its lease expires;
//  - a worker that keeps failing tiles is blocked for the job after 3 failures while a good worker
//    finishes it; a job every registered worker is blocked for fails with the reason;
//  - a file scene no worker can load (a WorkerNode whose scene cache and temporary folder cannot be
//    written) fails its job with a clear error, and the same worker then renders the next job.
#include <atomic>
#include <cstdlib>
#include <optional>

#include "tests/server/farm_fixture.h"

namespace epr::test {
namespace {

const std::string kCornellObj = EPR_SOURCE_DIR "/scenes/cornell-box/CornellBox-Original.obj";

class LeaseTest : public FarmFixture {};

// TMPDIR set to `value` for the object's lifetime (set before the workers that read it start).
class ScopedTmpdir {
 public:
  explicit ScopedTmpdir(const std::string& value) {
    if (const char* old = std::getenv("TMPDIR")) old_ = old;
    ::setenv("TMPDIR", value.c_str(), 1);
  }
  ~ScopedTmpdir() {
    if (old_)
      ::setenv("TMPDIR", old_->c_str(), 1);
    else
      ::unsetenv("TMPDIR");
  }

 private:
  std::optional<std::string> old_;
};

TEST_F(LeaseTest, StalledTileIsCopiedToAnIdleWorkerAndTheFirstResultWins) {
  MasterOptions mo;
  mo.lease_timeout_ms = 120000;  // the staller's lease never expires: only a speculative copy can help
  mo.worker_timeout_ms = 120000;
  mo.speculative_factor = 2.0;
  mo.speculative_floor_ms = 300;
  start(mo);
  const RenderOptions o = cornell(RenderMode::kSkip, 64, 6, 2);  // 16 tiles, 3 rounds
  const std::string id = submit(o, bundle_scene(o.scene));

  // The staller takes a tile of each round it can get, traces it at once, then sits on the result
  // (heartbeating, so its lease stays valid) until the master says the tile is no longer wanted.
  WireWorker staller(channel_, "staller");
  std::atomic<bool> done{false};
  std::atomic<int> stalled{0};
  int not_wanted = 0, late_duplicate = 0, late_stale = 0, late_committed = 0;
  std::thread staller_thread([&] {
    while (!done) {
      auto t = staller.lease(200);  // the master holds the call until a tile is there (or 200 ms pass)
      if (!t) continue;
      ++stalled;
      const auto chunks = staller.render(*t);
      bool released = false;
      for (;;) {
        // Read before the heartbeat: once the job is done, one more heartbeat must still say that the
        // tile is not wanted (the job may end between two heartbeats of the last round).
        const bool job_done = done;
        const std::vector<bool> wanted = staller.heartbeat({t->lease_id()});
        released = wanted.size() != 1 || !wanted[0];
        if (released || job_done) break;
        // The staller's heartbeat interval: it is a slow worker on purpose, and a heartbeat is how a
        // worker learns that its tile is no longer wanted.
        std::this_thread::sleep_for(50ms);
      }
      if (!released) break;  // still wanted after the job ended: counted as missing below
      ++not_wanted;
      v1::SubmitAck ack;
      const grpc::Status st = staller.submit(chunks, &ack);
      EXPECT_TRUE(st.ok()) << st.error_message();
      late_duplicate += ack.outcome() == v1::SUBMIT_OUTCOME_DUPLICATE;
      late_stale += ack.outcome() == v1::SUBMIT_OUTCOME_STALE;
      late_committed += ack.outcome() == v1::SUBMIT_OUTCOME_COMMITTED;
    }
  });
  // Let the staller hold a tile of round 0 before the fast worker joins.
  EXPECT_TRUE(eventually([&] { return stalled > 0; })) << "the staller got no tile";

  RunningNode fast(node_options("fast", 1));
  const v1::JobStatus st = wait_done(id, 180s);
  done = true;
  staller_thread.join();
  fast.stop();

  ASSERT_EQ(st.state(), v1::JOB_STATE_DONE) << st.error_message();
  const v1::JobStatus after = status(id);  // the staller's last late result may have come after `st`
  EXPECT_GE(stalled, 1);
  EXPECT_GE(st.tiles_speculative(), 1u);
  EXPECT_GE(not_wanted, 1) << "the staller's heartbeat must say its tile is no longer wanted";
  EXPECT_EQ(late_committed, 0);
  EXPECT_EQ(late_duplicate + late_stale, not_wanted);
  EXPECT_GE(after.tiles_dropped(), uint64_t(not_wanted)) << "late results are dropped and counted";
  EXPECT_EQ(st.tiles_re_leased(), 0u) << "no lease expired: the copies did the work";
  EXPECT_EQ(st.worker_failures(), 0u) << "slow is not failing";
  expect_same_as_local(id, o);
}

// That no copy goes out before the threshold, or at all with speculative_factor 0, is lease policy:
// tests/server/lease_table_test.cpp checks it on a clock of its own, without waiting.

TEST_F(LeaseTest, DeadHoldersTileComesBackByExpiryNotByACopy) {
  MasterOptions mo;
  mo.lease_timeout_ms = 1500;
  mo.heartbeat_interval_ms = 200;  // a holder silent for 300 ms is not alive for speculation
  mo.worker_timeout_ms = 60000;
  mo.speculative_floor_ms = 300;
  start(mo);
  const RenderOptions o = cornell(RenderMode::kPathTrace, 32, 2, 1);  // 4 tiles per round
  const std::string id = submit(o, bundle_scene(o.scene));
  WireWorker dead(channel_, "dead"), live(channel_, "live");
  auto held = dead.lease_wait();  // never heartbeated, never submitted
  ASSERT_TRUE(held);
  std::optional<v1::TileLease> t;
  int tiles = 0;
  while ((t = live.lease_wait())) {
    v1::SubmitAck ack;
    ASSERT_TRUE(live.submit(live.render(*t), &ack).ok());
    ASSERT_EQ(ack.outcome(), v1::SUBMIT_OUTCOME_COMMITTED);
    if (++tiles == 4) break;  // the 4th is the dead worker's tile, after its lease expired
  }
  ASSERT_EQ(tiles, 4);
  EXPECT_EQ(t->tile_index(), held->tile_index());
  const v1::JobStatus st = status(id);
  EXPECT_EQ(st.tiles_speculative(), 0u) << "a dead holder's tile must not be copied";
  EXPECT_EQ(st.tiles_re_leased(), 1u);
  EXPECT_EQ(st.worker_failures(), 1u) << "the expired lease counts against the dead worker";
}

TEST_F(LeaseTest, FailingWorkerIsBlockedAfterThreeFailuresAndAGoodWorkerFinishes) {
  MasterOptions mo;  // max_worker_failures = 3
  // The bad worker never heartbeats and must still be registered when the next job is submitted,
  // however long the first job takes (a minute under ThreadSanitizer on a loaded machine).
  mo.worker_timeout_ms = 600000;
  start(mo);
  const RenderOptions o = cornell(RenderMode::kSkip, 64, 4, 2);
  const std::string id = submit(o, bundle_scene(o.scene));
  WireWorker bad(channel_, "bad");
  WireWorker bystander(channel_, "bystander");  // registered and not blocked: the job must not fail
  for (int i = 0; i < 3; ++i) {
    auto t = bad.lease_wait();
    ASSERT_TRUE(t) << "failure " << i;
    ASSERT_TRUE(bad.give_back(t->lease_id(), v1::LEASE_FAILURE_TILE, "tracing failed: out of memory").ok());
  }
  v1::JobStatus st = status(id);
  EXPECT_EQ(st.state(), v1::JOB_STATE_RUNNING);
  EXPECT_EQ(st.worker_failures(), 3u);
  EXPECT_EQ(st.workers_blocked(), 1u);
  // Tiles are waiting, but none for the blocked worker.
  for (int i = 0; i < 5; ++i) EXPECT_FALSE(bad.lease()) << "a blocked worker got a tile";
  // The tiles it returned go to others: a good worker finishes the job, exactly.
  RunningNode good(node_options("good", 1));
  st = wait_done(id);
  good.stop();
  ASSERT_EQ(st.state(), v1::JOB_STATE_DONE) << st.error_message();
  EXPECT_EQ(st.workers_blocked(), 1u);
  EXPECT_EQ(st.worker_failures(), 3u);
  EXPECT_EQ(st.tiles_re_leased(), 3u);
  expect_same_as_local(id, o);

  // Blocking is per job: the next job leases to the same worker again.
  const std::string next = submit(o, bundle_scene(o.scene));
  auto t = bad.lease_wait();
  ASSERT_TRUE(t);
  EXPECT_EQ(t->job_id(), next);
}

TEST_F(LeaseTest, RefusedResultsAndExpiredLeasesCountAsFailures) {
  MasterOptions mo;
  mo.lease_timeout_ms = 400;
  mo.worker_timeout_ms = 60000;
  mo.max_worker_failures = 2;
  start(mo);
  const RenderOptions o = cornell(RenderMode::kPathTrace, 32, 2, 1);
  const std::string id = submit(o, bundle_scene(o.scene));
  WireWorker bad(channel_, "bad"), other(channel_, "other");
  // 1: a result that does not match its lease (wrong pixel count) is refused and counted.
  auto t = bad.lease_wait();
  ASSERT_TRUE(t);
  auto chunks = bad.render(*t);
  chunks.front().mutable_header()->set_pixel_count(chunks.front().header().pixel_count() + 1);
  v1::SubmitAck ack;
  EXPECT_EQ(bad.submit(chunks, &ack).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(status(id).worker_failures(), 1u);
  // 2: a lease left to expire (no heartbeat) is counted.
  ASSERT_TRUE(bad.lease_wait());
  ASSERT_TRUE(eventually([&] { return status(id).worker_failures() == 2; }));
  const v1::JobStatus st = status(id);
  EXPECT_EQ(st.workers_blocked(), 1u);
  EXPECT_EQ(st.state(), v1::JOB_STATE_RUNNING) << "'other' is registered and not blocked";
  EXPECT_FALSE(bad.lease());
  // A plain return (stopping) is not a failure.
  auto ot = other.lease_wait();
  ASSERT_TRUE(ot);
  ASSERT_TRUE(other.give_back(ot->lease_id(), v1::LEASE_FAILURE_UNSPECIFIED, "stopping").ok());
  EXPECT_EQ(status(id).worker_failures(), 2u);
}

TEST_F(LeaseTest, JobFailsWithTheReasonWhenEveryRegisteredWorkerIsBlocked) {
  start();
  const RenderOptions o = cornell(RenderMode::kPathTrace, 32, 2, 1);
  const std::string id = submit(o, bundle_scene(o.scene));
  WireWorker bad(channel_, "bad"), leaving(channel_, "leaving");
  for (int i = 0; i < 3; ++i) {
    auto t = bad.lease_wait();
    ASSERT_TRUE(t);
    ASSERT_TRUE(bad.give_back(t->lease_id(), v1::LEASE_FAILURE_TILE, "GPU fell off the bus").ok());
  }
  EXPECT_EQ(status(id).state(), v1::JOB_STATE_RUNNING) << "'leaving' could still do the job";
  leaving.unregister();  // now every registered worker is blocked
  const v1::JobStatus st = wait_done(id, 30s);
  ASSERT_EQ(st.state(), v1::JOB_STATE_FAILED);
  EXPECT_NE(st.error_message().find("blocked"), std::string::npos) << st.error_message();
  EXPECT_NE(st.error_message().find("GPU fell off the bus"), std::string::npos) << st.error_message();

  // The master serves the next job.
  const std::string next = submit(o, bundle_scene(o.scene));
  WireWorker fresh(channel_, "fresh");
  const auto until = std::chrono::steady_clock::now() + 60s;  // a guard against hanging
  while (!terminal(status(next)) && std::chrono::steady_clock::now() < until) {
    auto t = fresh.lease(200);  // held by the master until a tile is there (or 200 ms pass)
    if (!t) continue;
    v1::SubmitAck ack;
    ASSERT_TRUE(fresh.submit(fresh.render(*t), &ack).ok());
  }
  EXPECT_EQ(wait_done(next).state(), v1::JOB_STATE_DONE);
}

TEST_F(LeaseTest, SceneNoWorkerCanLoadFailsTheJobAndTheMasterServesTheNext) {
  start();
  // A worker whose cache holds a regular file where the scene's folder goes (the fetched file scene
  // cannot be moved into place), and whose temporary folder, where it would fetch the scene instead,
  // is a regular file too.
  const SceneBundleData bundle = bundle_scene(kCornellObj);
  std::ofstream(dir_ / "not-a-folder") << "x";
  const ScopedTmpdir no_fallback((dir_ / "not-a-folder").string());
  WorkerNodeOptions no = node_options("broken-cache", 1);
  no.cache_dir = (dir_ / "cache").string();
  fs::create_directories(dir_ / "cache" / "scenes");
  std::ofstream(dir_ / "cache" / "scenes" / content_hash(bundle)) << "x";
  no.max_backoff_ms = 1000;
  RenderOptions o = cornell(RenderMode::kPathTrace, 24, 2, 1);
  o.scene = kCornellObj;
  const std::string bad_job = submit(o, bundle);
  const RenderOptions b = cornell(RenderMode::kPathTrace, 24, 2, 1);
  const std::string good_job = submit(b, bundle_scene(b.scene));  // queued behind it

  RunningNode node(no);
  const v1::JobStatus st = wait_done(bad_job, 60s);
  ASSERT_EQ(st.state(), v1::JOB_STATE_FAILED);
  EXPECT_NE(st.error_message().find("no worker could load the job's scene"), std::string::npos) << st.error_message();
  EXPECT_NE(st.error_message().find("broken-cache"), std::string::npos) << "names the worker: " << st.error_message();
  EXPECT_EQ(st.workers_blocked(), 1u);
  EXPECT_GE(st.worker_failures(), 3u);

  // The built-in scene of the next job needs no cache: the same worker renders it.
  const v1::JobStatus next = wait_done(good_job, 60s);
  node.stop();
  ASSERT_EQ(next.state(), v1::JOB_STATE_DONE) << next.error_message();
  expect_same_as_local(good_job, b);
}

}  // namespace
}  // namespace epr::test
