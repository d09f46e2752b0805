// A tile that kills every worker taking it (as a scene that makes Embree abort does) fails its job,
// not the farm. The real epr-master and epr-workers on loopback: the workers have the test hook
// EPR_TEST_ABORT_ON_TILE (worker/worker_node.cpp) set to a pixel of tile 5 and abort when they start
// it; the test restarts each one that dies, as a container runtime would. Each dead worker's lease
// expires (--lease-timeout-ms); at the third (--max-tile-losses 3) the master fails the job naming
// the tile and the count, stays up and renders the next job, and a restart keeps the job failed.
#include <gtest/gtest.h>
#include <signal.h>

#include <chrono>
#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "binaries.h"
#include "farm_steps.h"
#include "process.h"

namespace epr::testing {
namespace {
namespace fs = std::filesystem;
using namespace std::chrono_literals;

// 128x128 pixels in 32x32 tiles, row-major: pixel (40, 40) is in tile 5 (x 32-63, y 32-63).
const char* const kAbortPixel = "40,40";
const char* const kLostTileReason = "tile 5 (pixels x 32-63, y 32-63) lost its worker 3 times";

class TileLossTest : public SingleMasterTest {
 protected:
  void SetUp() override { start_story("epr-tile-loss"); }

  void start_master() {
    SingleMasterTest::start_master(0, {"--state-dir", path("state"), "--lease-timeout-ms", "2000", "--max-tile-losses",
                                       "3", "--speculative-factor", "0"});
  }

  // A worker; with `crashing`, one that aborts on the tile holding kAbortPixel.
  Process& start_worker(bool crashing) {
    const std::string name = "w" + std::to_string(++started_);
    ProcessOptions po;
    if (crashing) po.env = {std::string("EPR_TEST_ABORT_ON_TILE=") + kAbortPixel};
    workers_.push_back(std::make_unique<Process>(worker_argv(address(), name, path("cache-" + name)), dir_ / name, po));
    return *workers_.back();
  }

  nlohmann::json status(const std::string& id) {
    const RunResult r = epr({"get", id, "--json"}, 30s);
    EXPECT_EQ(r.code, 0) << r.err;
    return nlohmann::json::parse(r.out, nullptr, false);
  }

  int started_ = 0;
};

TEST_F(TileLossTest, ATileThatKillsItsWorkersFailsItsJobAndTheFarmGoesOn) {
  ASSERT_NO_FATAL_FAILURE(start_master());
  const Args job = skip_job(128, 16, 8, 16, 7);
  const std::string id = submit(job);
  ASSERT_FALSE(id.empty());
  note("job %s submitted", id.c_str());
  // Two crashing workers, each replaced when it dies, until the master gives the job up.
  start_worker(true);
  start_worker(true);
  int crashes = 0;
  const std::string failed_line = "job " + id + " failed: ";
  const bool failed = wait_until(
      [&] {
        if (master_->err().find(failed_line) != std::string::npos) return true;
        for (size_t i = 0; i < workers_.size(); ++i) {
          Process& w = *workers_[i];
          if (w.exit_code() || w.running()) continue;
          ++crashes;
          EXPECT_EQ(w.exit_code(), 128 + SIGABRT) << w.name() << ":\n" << w.err();
          EXPECT_NE(w.err().find("EPR_TEST_ABORT_ON_TILE: aborting on job " + id + " tile 5"), std::string::npos)
              << w.err();
          note("%s aborted on tile 5 (%d so far)", w.name().c_str(), crashes);
          start_worker(true);
        }
        return false;
      },
      180s);
  ASSERT_TRUE(failed) << "the job did not fail; " << crashes << " workers crashed";
  note("the master failed the job after %d crashes", crashes);
  EXPECT_GE(crashes, 3);
  ASSERT_TRUE(master_->running()) << master_->err();
  const nlohmann::json s = status(id);
  EXPECT_EQ(s.value("state", ""), "JOB_STATE_FAILED") << s.dump();
  EXPECT_NE(s.value("error_message", "").find(kLostTileReason), std::string::npos) << s.dump();

  // The farm goes on: without the crashing workers, the next job renders.
  for (auto& w : workers_) w->stop();
  start_worker(false);
  const std::string next = submit(skip_job(64, 8, 8, 8, 3));
  ASSERT_FALSE(next.empty());
  const RunResult watched = epr({"watch", next}, 120s);
  EXPECT_EQ(watched.code, 0) << watched.out << watched.err;
  EXPECT_EQ(status(next).value("state", ""), "JOB_STATE_DONE");
  note("job %s done", next.c_str());

  // A restart on the same state folder keeps the job failed, with its reason.
  EXPECT_EQ(master_->stop(30s), 0) << master_->err();
  ASSERT_NO_FATAL_FAILURE(start_master());
  const nlohmann::json again = status(id);
  EXPECT_EQ(again.value("state", ""), "JOB_STATE_FAILED") << again.dump();
  EXPECT_NE(again.value("error_message", "").find(kLostTileReason), std::string::npos) << again.dump();
  EXPECT_EQ(status(next).value("state", ""), "JOB_STATE_DONE");
}

}  // namespace
}  // namespace epr::testing
