// A master killed with SIGKILL mid-job (DESIGN.md section 4): restarted on the same port and state
// directory, it resumes the job from its last checkpoint; the workers register again by themselves
// and a client's `epr watch` follows the job across the restart. The result must equal the
// undisturbed render of the same job (`epr render --single-process`, which the cluster tests show
// equal to an undisturbed cluster run): M, M' and the path-traced estimate bit-identical, the
// combined image within float rounding. A second test kills workers and the master at random
// moments of one run.
//
// The moments are random but seeded: the seed is printed, and EPR_TEST_SEED=N repeats a run.
// Real processes on loopback (epr-master, epr-worker, epr); each test keeps its folder of logs and
// prints their tails when it fails.
#include <gtest/gtest.h>
#include <signal.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <memory>
#include <random>
#include <regex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "binaries.h"
#include "common/image.h"
#include "farm_steps.h"
#include "process.h"

namespace epr::testing {
namespace {
namespace fs = std::filesystem;
using namespace std::chrono_literals;

uint64_t test_seed() {
  if (const char* s = std::getenv("EPR_TEST_SEED")) return std::strtoull(s, nullptr, 10);
  return std::random_device{}();
}

// A second or two of tracing for two single-threaded workers (restart_job(): 32 rounds of 8 paths,
// no growing rounds). The kills are placed by round (an early random round, then a random pause of
// at most 100 ms), not by wall time, so that they land mid-job however loaded the machine is: a kill
// at round 1-4 leaves most of the rounds to run.
class MasterRestartTest : public SingleMasterTest {
 protected:
  void SetUp() override {
    start_story("epr-restart");
    seed_ = test_seed();
    rng_.seed(seed_);
    std::printf("EPR_TEST_SEED=%llu\n", static_cast<unsigned long long>(seed_));
    RecordProperty("seed", std::to_string(seed_));
  }

  void TearDown() override {
    if (watch_) watch_->stop();
    if (HasFailure()) {
      std::fprintf(stderr, "seed %llu\n", static_cast<unsigned long long>(seed_));
      if (watch_) print_log_tail("epr watch", watch_->err());
    }
    SingleMasterTest::TearDown();
  }

  // Starts epr-master on `port` (0: a free one) with the test's state directory.
  void start_master(int port) {
    SingleMasterTest::start_master(port, {"--state-dir", path("state"), "--lease-timeout-ms", "1500"});
  }

  std::string submit() { return SingleMasterTest::submit(restart_job()); }

  // The undisturbed render of the job, `epr render --single-process`, in the background while the
  // cluster starts (most of that is waiting for processes to come up).
  void start_reference() {
    reference_ = std::make_unique<Process>(reference_argv(restart_job(), path("ref")), dir_ / "reference");
  }

  // `epr watch` in the background, following the job before the master is killed: it has to
  // outlive the master it started with.
  void start_watch(const std::string& id) {
    watch_ = std::make_unique<Process>(Args{kEpr, "watch", id, "--master", address()}, dir_ / "watch");
    ASSERT_TRUE(wait_until([&] { return watch_->err().find("round") != std::string::npos || !watch_->running(); }, 30s))
        << "epr watch printed no progress";
    ASSERT_TRUE(watch_->running()) << watch_->err();
  }

  // Waits until some worker has leased a tile of round `round` or later.
  bool wait_for_round(int round, Millis timeout) {
    return wait_until([&] { return highest_round_leased(workers_) >= round; }, timeout);
  }

  // Waits until the job reaches a random round in [lo, hi].
  void wait_for_random_round(int lo, int hi) {
    const int round = std::uniform_int_distribution<int>(lo, hi)(rng_);
    ASSERT_TRUE(wait_for_round(round, 90s)) << "the job never reached round " << round;
    note("round %d leased", round);
  }

  // Sleeps a random time in [lo, hi] ms (the test's seeded generator).
  void random_pause(int lo, int hi) {
    const int ms = std::uniform_int_distribution<int>(lo, hi)(rng_);
    note("pause %d ms", ms);
    std::this_thread::sleep_for(Millis(ms));
  }

  // SIGKILLs the master mid-job (the test fails if the job had already ended) and starts a new
  // one on the same port and state directory; the new one must find the job again.
  void kill_and_restart_master(const std::string& id) {
    ASSERT_EQ(master_->err().find("job " + id + " done"), std::string::npos)
        << "the job ended before the master was killed: nothing would be tested";
    master_->signal(SIGKILL);
    ASSERT_EQ(master_->wait_for(5s), 128 + SIGKILL);
    old_master_logs_.push_back(master_->err());
    const int port = port_;
    ASSERT_NO_FATAL_FAILURE(start_master(port));
    ASSERT_EQ(port_, port);
    const std::regex loaded(
        "run ([0-9]+), 1 jobs loaded, ([01]) resume from their checkpoint, ([01]) start from round 0");
    std::smatch m;
    const std::string err = master_->err();
    ASSERT_TRUE(std::regex_search(err, m, loaded)) << err;
    EXPECT_EQ(std::stoi(m[2]) + std::stoi(m[3]), 1);
    note("master SIGKILLed and restarted (run %s): the job %s", m[1].str().c_str(),
         m[2] == "1" ? "resumes from its checkpoint" : "starts again from round 0");
  }

  void fetch_and_compare(const std::string& id) {
    ASSERT_TRUE(watch_->wait_for(120s).has_value()) << "epr watch did not end";
    note("epr watch ended");
    EXPECT_EQ(watch_->exit_code(), 0) << "epr watch across the restart:\n" << watch_->err();
    EXPECT_NE(watch_->err().find("DONE"), std::string::npos) << watch_->err();
    const RunResult g = epr({"get", id, "--out", path("cluster")}, 30s);
    ASSERT_EQ(g.code, 0) << g.err;
    note("fetched the result");
    ASSERT_NO_FATAL_FAILURE(expect_reference_done(*reference_));
    const Image counts = read_image(path("cluster.counts.exr"));
    ASSERT_EQ(counts.channels, 2);
    expect_images_equal(path("cluster"), path("ref"));
    double mprime = 0;
    for (int y = 0; y < counts.height; ++y)
      for (int x = 0; x < counts.width; ++x) mprime += counts.at(x, y)[1];
    EXPECT_GT(mprime, 0.0) << "nothing was reprojected: M' would not be compared";
  }

  uint64_t seed_ = 0;
  std::mt19937_64 rng_;
  std::unique_ptr<Process> watch_;
};

TEST_F(MasterRestartTest, MasterKilledMidJobResumesFromItsCheckpoint) {
  start_reference();
  ASSERT_NO_FATAL_FAILURE(start_master(0));
  start_worker("w1");
  start_worker("w2");
  ASSERT_TRUE(wait_until([&] { return registered() >= 2; }, 30s));
  const std::string id = submit();
  ASSERT_FALSE(id.empty());
  note("job %s submitted", id.c_str());
  ASSERT_NO_FATAL_FAILURE(start_watch(id));
  ASSERT_NO_FATAL_FAILURE(wait_for_random_round(1, 4));
  random_pause(0, 100);
  ASSERT_NO_FATAL_FAILURE(kill_and_restart_master(id));
  // The workers find the new master by themselves.
  EXPECT_TRUE(wait_until([&] { return registered() >= 2; }, 30s)) << "the workers did not register again";
  note("both workers registered again");
  ASSERT_NO_FATAL_FAILURE(fetch_and_compare(id));
  // The killed master's leases were not honoured by the new one.
  for (auto& w : workers_) EXPECT_GE(count_of(w->err(), "registered with"), 2u) << w->name();
}

TEST_F(MasterRestartTest, WorkersAndMasterKilledAtRandomMomentsOfOneRun) {
  start_reference();
  ASSERT_NO_FATAL_FAILURE(start_master(0));
  for (const char* n : {"w1", "w2", "w3"}) start_worker(n);
  ASSERT_TRUE(wait_until([&] { return registered() >= 3; }, 30s));
  const std::string id = submit();
  ASSERT_FALSE(id.empty());
  note("job %s submitted", id.c_str());
  ASSERT_NO_FATAL_FAILURE(start_watch(id));
  // A worker dies, then the master, then another worker under the new master; replacements join.
  std::vector<size_t> order{0, 1, 2};
  std::shuffle(order.begin(), order.end(), rng_);
  ASSERT_NO_FATAL_FAILURE(wait_for_random_round(1, 2));
  random_pause(0, 100);
  note("SIGKILL %s", workers_[order[0]]->name().c_str());
  workers_[order[0]]->signal(SIGKILL);
  ASSERT_NO_FATAL_FAILURE(wait_for_random_round(3, 4));
  random_pause(0, 100);
  ASSERT_NO_FATAL_FAILURE(kill_and_restart_master(id));
  start_worker("w4");
  random_pause(100, 500);
  note("SIGKILL %s", workers_[order[1]]->name().c_str());
  workers_[order[1]]->signal(SIGKILL);
  start_worker("w5");
  ASSERT_NO_FATAL_FAILURE(fetch_and_compare(id));
  EXPECT_FALSE(workers_[order[2]]->err().empty());
  EXPECT_GE(count_of(workers_[order[2]]->err(), "registered with"), 2u) << "the surviving worker registered again";
}

}  // namespace
}  // namespace epr::testing
