// Graceful stops of the real programs on loopback (what Kubernetes and compose do when they remove
// a pod or container: SIGTERM, then SIGKILL after a grace period).
//  - A worker on SIGTERM gives its leases back: the master leases those tiles again at once, so the
//    job finishes long before the lease timeout (60 s here) would have freed them.
//  - A master on SIGTERM drains: the open round is finished and checkpointed (whatever
//    --checkpoint-interval says; 3600 s here, so that only round 0 would be on disk otherwise), and
//    it exits 0. Restarted on the same state folder, it resumes the job from the drained round, not
//    from round 0, and the result equals the undisturbed render: M, M' and the path-traced estimate
//    bit-identical, the combined image within float rounding. With no worker left to finish the
//    round, the drain gives up at once and the job resumes from its last checkpoint.
#include <gtest/gtest.h>
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <memory>
#include <regex>
#include <string>
#include <vector>

#include "binaries.h"
#include "farm_steps.h"
#include "process.h"

namespace epr::testing {
namespace {
namespace fs = std::filesystem;
using namespace std::chrono_literals;

// Tiles that take a while to trace on one thread (64x64 pixels, 64 paths each), so that a worker
// stopped mid-tile holds the lease.
Args slow_tile_job() {
  return {"builtin:cornell",
          "--width",
          "128",
          "--height",
          "128",
          "--spp",
          "128",
          "--paths-per-round",
          "64",
          "--tile",
          "64",
          "--mode",
          "pt",
          "--seed",
          "5",
          "--round-growth",
          "0"};
}

class DrainTest : public SingleMasterTest {
 protected:
  void SetUp() override { start_story("epr-drain"); }

  // epr-master's flags for the drains of open rounds: the test's state folder and a checkpoint an
  // hour after the first round's, so that without the drain only round 0 would be on disk.
  Args draining_master_flags() const {
    return {"--state-dir",     path("state"), "--checkpoint-interval", "3600",
            "--drain-timeout", "60",          "--lease-timeout-ms",    "1500"};
  }

  // The highest round some worker has leased a tile of.
  int highest_round_leased() const { return testing::highest_round_leased(workers_); }

  // A lease the worker's log shows granted and not (yet) submitted: "round R tile T", or "".
  static std::string open_lease(const std::string& log) {
    const std::regex granted("lease ([0-9]+): job \\S+ (round [0-9]+ tile [0-9]+)");
    std::string found;
    for (auto it = std::sregex_iterator(log.begin(), log.end(), granted); it != std::sregex_iterator(); ++it)
      if (log.find("lease " + (*it)[1].str() + ": submitted") == std::string::npos) found = (*it)[2];
    return found;
  }
};

TEST_F(DrainTest, WorkerSigtermReturnsItsLeasesAndTheirTilesAreLeasedAgainAtOnce) {
  // No worker lease may expire in this test: 60 s, longer than the whole job may take.
  ASSERT_NO_FATAL_FAILURE(start_master(0, {"--lease-timeout-ms", "60000", "--speculative-factor", "0"}));
  Process& w1 = start_worker("w1");
  ASSERT_TRUE(wait_until([&] { return registered() >= 1; }, 30s));
  const std::string id = submit(slow_tile_job());
  ASSERT_FALSE(id.empty());
  note("job %s submitted", id.c_str());
  // Freeze w1 in short slices until its log shows a lease it has not submitted: it is tracing that
  // tile (64x64 pixels x 64 paths on one thread) and cannot finish it before the signal arrives.
  std::string held;
  ASSERT_TRUE(wait_until(
      [&] {
        w1.signal(SIGSTOP);
        held = open_lease(w1.err());
        if (held.empty()) w1.signal(SIGCONT);
        return !held.empty();
      },
      60s))
      << "w1 never held a lease";
  w1.signal(SIGTERM);
  w1.signal(SIGCONT);
  const auto terminated = std::chrono::steady_clock::now();
  note("SIGTERM to w1 holding %s", held.c_str());
  const std::optional<int> code = w1.wait_for(15s);
  ASSERT_TRUE(code.has_value()) << "w1 did not exit within 15 s of SIGTERM";
  EXPECT_EQ(*code, 0);
  std::smatch m;
  const std::string w1_log = w1.err();
  ASSERT_TRUE(std::regex_search(w1_log, m, std::regex("\\(([0-9]+) leases returned\\)"))) << "w1 did not leave";
  EXPECT_GE(std::stoi(m[1]), 1) << "w1 returned no lease";
  const std::regex returned("worker w1-\\S+ returned [1-9][0-9]* lease\\(s\\)");
  EXPECT_TRUE(wait_until([&] { return std::regex_search(master_->err(), returned); }, 5s))
      << "the master logged no returned lease";
  note("w1 exited 0 after returning %s lease(s)", m[1].str().c_str());

  // Another worker finishes the job; the returned tile is leased again at once.
  Process& w2 = start_worker("w2");
  const RunResult watched = epr({"watch", id}, 45s);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - terminated).count();
  ASSERT_EQ(watched.code, 0) << watched.err;
  note("job done %.1f s after the SIGTERM", seconds);
  EXPECT_LT(seconds, 45.0) << "the returned tile waited for its lease to expire";
  EXPECT_NE(w2.err().find("job " + id + " " + held), std::string::npos) << "w2 never leased " << held;
  EXPECT_EQ(master_->err().find("expired"), std::string::npos) << "a lease expired instead of being returned";
}

TEST_F(DrainTest, MasterSigtermCheckpointsTheOpenRoundAndResumesFromIt) {
  const Args job = restart_job();
  reference_ = std::make_unique<Process>(reference_argv(job, path("ref")), dir_ / "reference");
  const Args master_flags = draining_master_flags();
  ASSERT_NO_FATAL_FAILURE(start_master(0, master_flags));
  start_worker("w1");
  start_worker("w2");
  ASSERT_TRUE(wait_until([&] { return registered() >= 2; }, 30s));
  const std::string id = submit(job);
  ASSERT_FALSE(id.empty());
  note("job %s submitted", id.c_str());
  ASSERT_TRUE(wait_until([&] { return highest_round_leased() >= 4; }, 90s)) << "the job never reached round 4";
  ASSERT_EQ(master_->err().find("job " + id + " done"), std::string::npos) << "the job ended: nothing to drain";
  const int leased_at_signal = highest_round_leased();
  master_->signal(SIGTERM);
  note("SIGTERM to the master while round %d is leased", leased_at_signal);
  const std::optional<int> code = master_->wait_for(60s);
  ASSERT_TRUE(code.has_value()) << "the master did not exit within 60 s of SIGTERM";
  EXPECT_EQ(*code, 0);
  const std::string old_log = master_->err();
  old_master_logs_.push_back(old_log);
  std::smatch m;
  ASSERT_TRUE(std::regex_search(old_log, m, std::regex("job \\S+: draining: round ([0-9]+) closed and checkpointed")))
      << "the master did not checkpoint the open round";
  const int drained_round = std::stoi(m[1]);
  EXPECT_GE(drained_round, leased_at_signal) << "the drain checkpointed a round before the one open at SIGTERM";
  EXPECT_NE(old_log.find("drained in"), std::string::npos);
  EXPECT_EQ(old_log.find("running from round"), std::string::npos);
  note("drained: round %d checkpointed, exit code %d", drained_round, *code);

  const int port = port_;
  ASSERT_NO_FATAL_FAILURE(start_master(port, master_flags));
  ASSERT_TRUE(wait_until([&] { return master_->err().find("running from round") != std::string::npos; }, 60s))
      << "the job did not resume";
  const std::string log = master_->err();
  ASSERT_TRUE(std::regex_search(log, m, std::regex("job \\S+ running from round ([0-9]+)")));
  const int resumed = std::stoi(m[1]);
  note("restarted: the job runs from round %d", resumed);
  EXPECT_EQ(resumed, drained_round + 1) << "the job did not resume after the drained round";
  EXPECT_NE(log.find("1 jobs loaded, 1 resume from their checkpoint, 0 start from round 0"), std::string::npos);

  const RunResult watched = epr({"watch", id}, 120s);
  ASSERT_EQ(watched.code, 0) << watched.err;
  const RunResult got = epr({"get", id, "--out", path("cluster")}, 30s);
  ASSERT_EQ(got.code, 0) << got.err;
  ASSERT_NO_FATAL_FAILURE(expect_reference_done(*reference_));
  expect_images_equal(path("cluster"), path("ref"));
}

TEST_F(DrainTest, MasterSigtermWithNoWorkerLeftStopsAtOnceAndResumesFromItsLastCheckpoint) {
  const Args master_flags{"--state-dir", path("state"), "--drain-timeout", "60", "--lease-timeout-ms", "1500"};
  ASSERT_NO_FATAL_FAILURE(start_master(0, master_flags));
  Process& w1 = start_worker("w1");
  ASSERT_TRUE(wait_until([&] { return registered() >= 1; }, 30s));
  const std::string id = submit(restart_job());
  ASSERT_FALSE(id.empty());
  ASSERT_TRUE(wait_until([&] { return highest_round_leased() >= 2; }, 90s)) << "the job never reached round 2";
  // The only worker leaves (it returns its leases and unregisters): nothing can finish the open round.
  w1.signal(SIGTERM);
  ASSERT_TRUE(w1.wait_for(15s).has_value()) << "w1 did not exit";
  ASSERT_EQ(master_->err().find("job " + id + " done"), std::string::npos) << "the job ended: nothing to drain";
  const auto terminated = std::chrono::steady_clock::now();
  master_->signal(SIGTERM);
  const std::optional<int> code = master_->wait_for(20s);
  ASSERT_TRUE(code.has_value()) << "the master waited for a round no worker can finish";
  EXPECT_EQ(*code, 0);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - terminated).count();
  EXPECT_LT(seconds, 10.0) << "the drain should give up at once without workers, not wait --drain-timeout";
  const std::string old_log = master_->err();
  old_master_logs_.push_back(old_log);
  EXPECT_NE(old_log.find("(no worker is left to trace): " + id), std::string::npos) << "the log does not say why";
  note("no worker: the master exited %.1f s after SIGTERM", seconds);

  // Restarted, the job resumes from its last round checkpoint and a new worker finishes it.
  const int port = port_;
  ASSERT_NO_FATAL_FAILURE(start_master(port, master_flags));
  EXPECT_NE(master_->err().find("1 jobs loaded, 1 resume from their checkpoint"), std::string::npos);
  start_worker("w2");
  const RunResult watched = epr({"watch", id}, 120s);
  EXPECT_EQ(watched.code, 0) << watched.err;
}

TEST_F(DrainTest, MasterSigtermCheckpointsEveryRunningJob) {
  // Two jobs run at once (the master's memory budget admits both): the drain finishes and
  // checkpoints the open round of each, and a restarted master resumes both from there.
  const Args master_flags = draining_master_flags();
  ASSERT_NO_FATAL_FAILURE(start_master(0, master_flags));
  start_worker("w1");
  start_worker("w2");
  ASSERT_TRUE(wait_until([&] { return registered() >= 2; }, 30s));
  Args second = restart_job();
  *(std::find(second.begin(), second.end(), "--seed") + 1) = "12";  // another image
  const std::string a = submit(restart_job()), b = submit(second);
  ASSERT_FALSE(a.empty());
  ASSERT_FALSE(b.empty());
  ASSERT_TRUE(wait_until(
      [&] {
        const std::string log = master_->err();
        return log.find("job " + a + " running") != std::string::npos &&
               log.find("job " + b + " running") != std::string::npos;
      },
      60s))
      << "the two jobs did not run at once";
  ASSERT_TRUE(wait_until([&] { return highest_round_leased() >= 3; }, 90s));
  const std::string before = master_->err();
  ASSERT_EQ(before.find(" done:"), std::string::npos) << "a job ended: nothing to drain";
  master_->signal(SIGTERM);
  const std::optional<int> code = master_->wait_for(60s);
  ASSERT_TRUE(code.has_value()) << "the master did not exit within 60 s of SIGTERM";
  EXPECT_EQ(*code, 0);
  const std::string old_log = master_->err();
  old_master_logs_.push_back(old_log);
  for (const std::string& id : {a, b})
    EXPECT_NE(old_log.find("job " + id + ": draining: round "), std::string::npos) << id << " was not checkpointed";
  EXPECT_NE(old_log.find("drained in"), std::string::npos);

  const int port = port_;
  ASSERT_NO_FATAL_FAILURE(start_master(port, master_flags));
  EXPECT_NE(master_->err().find("2 jobs loaded, 2 resume from their checkpoint, 0 start from round 0"),
            std::string::npos);
  for (const std::string& id : {a, b}) {
    const RunResult watched = epr({"watch", id}, 120s);
    EXPECT_EQ(watched.code, 0) << id << ": " << watched.err;
  }
}

}  // namespace
}  // namespace epr::testing
