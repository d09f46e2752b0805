// A frame-window batch on a real epr-master killed with SIGKILL mid-run (DESIGN.md "Frame windows",
// "Checkpoints"): `epr submit --frames 1-6 --frame-window 2 --window-run 6` of the Cornell fly-through
// on a master with a state directory (a checkpoint after every round) and two epr-workers; the
// master is killed once every frame has checkpointed some rounds, a new one starts on the same port
// and state directory, and the batch ends. Every frame's M, M' and path sums equal, bit for bit, those
// of the same batch rendered undisturbed by one worker (so across worker counts too); the combined
// image within float rounding. And the same batch by three workers, undisturbed, against the one worker's.
//
// Where the kill falls is chosen, not left to timing: the master is stopped (SIGSTOP), its state
// directory read as a restarted master reads it (CheckpointStore::load_progress), and killed only
// when the case under test holds; otherwise it continues and is stopped again a moment later.
//  - At one round: every frame's newest checkpoint is of one round r >= 6 (of 24, skipping pixels
//    since round 4); the run resumes from r.
//  - Between two frames' checkpoints of one round: the frames at one round as above, then one
//    frame's newest checkpoint replaced by its previous one (an earlier round p), the files a kill
//    between the two frames' commits leaves. Where every other frame's previous checkpoint is of
//    round p too (the frames checkpoint after the same rounds, unless the checkpointer skipped one),
//    the run resumes from p, else it starts again from round 0; the counts still equal.
#include <gtest/gtest.h>
#include <signal.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <iterator>
#include <map>
#include <memory>
#include <regex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "binaries.h"
#include "farm_steps.h"
#include "master/server/checkpoint.h"
#include "process.h"

namespace epr::testing {
namespace window_restart {
namespace {
namespace fs = std::filesystem;
using namespace std::chrono_literals;

constexpr int kFrames = 6;
// The kill comes after this round's checkpoints at the earliest: the frames skip pixels by then.
constexpr int kKillRound = 6;

// The batch: frames 1-6 of the Cornell fly-through, one window run with K = 2, skip_job's settings
// at 64 x 64 pixels (four tiles): 24 rounds of 2 paths, skipping after the first 4.
Args batch_flags() {
  Args flags = skip_job(64, 48, 2, 8, 5);
  flags.front() = std::string(EPR_SOURCE_DIR) + "/scenes/cornell-flythrough.json";
  flags.insert(flags.end(), {"--frames", "1-" + std::to_string(kFrames), "--frame-window", "2", "--window-run",
                             std::to_string(kFrames)});
  return flags;
}

// OUT.NNNN, the files `epr get BATCH --out OUT` writes for frame `frame`.
std::string frame_prefix(const std::string& out, int frame) {
  char digits[16];
  std::snprintf(digits, sizeof digits, ".%04d", frame);
  return out + digits;
}

class WindowRestartTest : public SingleMasterTest {
 protected:
  void SetUp() override { start_story("epr-window-restart"); }

  static void TearDownTestSuite() {
    if (!reference_dir().empty()) fs::remove_all(reference_dir());
  }

  // The undisturbed batch, rendered once for the suite by a master without a state directory and one
  // worker; its frames' files are reference_dir()/f.NNNN.*.
  static fs::path& reference_dir() {
    static fs::path dir;
    return dir;
  }

  void render_reference() {
    if (!reference_dir().empty()) return;
    ASSERT_NO_FATAL_FAILURE(start_master(0, {}));
    start_worker("ref-w1");
    ASSERT_TRUE(wait_until([&] { return registered() >= 1; }, 30s)) << "the reference worker did not register";
    const std::string batch = submit(batch_flags());
    ASSERT_FALSE(batch.empty());
    const RunResult got = epr({"get", batch, "--out", path("ref/f")}, 600s);
    ASSERT_EQ(got.code, 0) << got.err;
    note("reference batch %s rendered by one worker", batch.c_str());
    for (auto& w : workers_) w->stop();
    workers_.clear();
    master_->stop();
    master_.reset();
    const fs::path dir = fs::temp_directory_path() / ("epr-window-restart-ref-" + std::to_string(::getpid()));
    fs::remove_all(dir);
    fs::rename(dir_ / "ref", dir);
    reference_dir() = dir;
  }

  // The master of the run under test: a state directory, a checkpoint after every round.
  void start_master_with_state(int port) {
    ASSERT_NO_FATAL_FAILURE(
        start_master(port, {"--state-dir", path("state"), "--checkpoint-interval", "0", "--lease-timeout-ms", "1500"}));
  }

  // Every job's newest checkpoint round, as a restarted master would load it (-1: none yet).
  std::map<std::string, int> checkpoint_rounds() const {
    std::map<std::string, int> rounds;
    CheckpointStore store(dir_ / "state");
    std::error_code ec;
    for (const auto& entry : fs::directory_iterator(dir_ / "state" / "jobs", ec)) {
      if (!entry.is_directory()) continue;
      const std::string id = entry.path().filename().string();
      const auto progress = store.load_progress(id, nullptr);
      rounds[id] = progress && progress->frame ? progress->progress.round : -1;
    }
    return rounds;
  }

  // Stops the master when all kFrames frames' newest checkpoints are of one round >= kKillRound and
  // kills it there (a stopped master writes no other); returns the round. A stop that finds the
  // frames apart (their checkpoints being written) lets the master go on and stops it again later.
  int kill_at_one_round() {
    int round = -1;
    for (int tries = 0; tries < 400 && round < 0; ++tries) {
      const bool some = wait_until(
          [&] {
            const auto rounds = checkpoint_rounds();
            if (int(rounds.size()) != kFrames) return false;
            for (const auto& [id, r] : rounds)
              if (r < kKillRound) return false;
            return true;
          },
          120s);
      if (!some) {
        ADD_FAILURE() << "the frames never all checkpointed round " << kKillRound;
        return -1;
      }
      master_->signal(SIGSTOP);
      std::set<int> distinct;
      for (const auto& [id, r] : checkpoint_rounds()) distinct.insert(r);
      if (distinct.size() == 1) {
        round = *distinct.begin();
        break;
      }
      master_->signal(SIGCONT);
      std::this_thread::sleep_for(Millis(5 + tries % 20));  // a moment further into the round
    }
    if (round < 0) {
      ADD_FAILURE() << "the frames' checkpoints were never found at one round";
      return -1;
    }
    EXPECT_EQ(master_->err().find(" done:"), std::string::npos)
        << "a frame ended before the master was killed: the kill would not be mid-run";
    master_->signal(SIGKILL);
    EXPECT_EQ(master_->wait_for(10s), 128 + SIGKILL);
    old_master_logs_.push_back(master_->err());
    note("master stopped and SIGKILLed with every frame's newest checkpoint of round %d", round);
    return round;
  }

  // Restarts the master on the same port and state directory; it must load the six frames, each
  // with its checkpoint.
  void restart_master() {
    const int port = port_;
    ASSERT_NO_FATAL_FAILURE(start_master_with_state(port));
    ASSERT_EQ(port_, port);
    const std::string loaded = std::to_string(kFrames) + " jobs loaded, " + std::to_string(kFrames) +
                               " resume from their checkpoint, 0 start from round 0";
    ASSERT_NE(master_->err().find(loaded), std::string::npos) << master_->err();
  }

  // The batch's frames fetched (`epr get` waits for them) against the reference: M, M' and the
  // path sums bit for bit, the combined image within float rounding; and the window did reproject.
  void fetch_and_compare(const std::string& batch) {
    const RunResult got = epr({"get", batch, "--out", path("out/f")}, 600s);
    ASSERT_EQ(got.code, 0) << got.err;
    note("fetched the batch");
    double mprime = 0;
    for (int f = 1; f <= kFrames; ++f) {
      const std::string mine = frame_prefix(path("out/f"), f);
      expect_images_equal(mine, frame_prefix((reference_dir() / "f").string(), f), "frame " + std::to_string(f) + ": ");
      const Image counts = read_image(mine + ".counts.exr");
      for (size_t i = 1; i < counts.data.size(); i += 2) mprime += counts.data[i];
    }
    EXPECT_GT(mprime, 0.0) << "nothing was reprojected: M' would not be compared";
  }

  // Starts the farm under test (the state directory's master and two workers) and submits the batch;
  // its id.
  std::string start_run() {
    render_reference();
    if (HasFatalFailure()) return "";
    start_master_with_state(0);
    if (HasFatalFailure()) return "";
    start_worker("w1");
    start_worker("w2");
    if (!wait_until([&] { return registered() >= 2; }, 30s)) {
      ADD_FAILURE() << "the workers did not register";
      return "";
    }
    const std::string batch = submit(batch_flags());
    note("batch %s submitted", batch.c_str());
    return batch;
  }

  // Lines of the current master's log that match `pattern`.
  size_t log_matches(const std::string& pattern) const {
    const std::string log = master_->err();
    const std::regex re(pattern);
    return size_t(std::distance(std::sregex_iterator(log.begin(), log.end(), re), std::sregex_iterator()));
  }
};

TEST_F(WindowRestartTest, ThreeWorkersRenderTheFramesOfOne) {
  // The frames' rounds close by the neighbours' rounds, not in step: with three workers over gRPC the
  // frames drift apart otherwise than with one, and their counts must not.
  render_reference();
  ASSERT_FALSE(HasFatalFailure());
  ASSERT_NO_FATAL_FAILURE(start_master(0, {}));
  for (const char* name : {"w1", "w2", "w3"}) start_worker(name);
  ASSERT_TRUE(wait_until([&] { return registered() >= 3; }, 30s)) << "the workers did not register";
  const std::string batch = submit(batch_flags());
  ASSERT_FALSE(batch.empty());
  ASSERT_NO_FATAL_FAILURE(fetch_and_compare(batch));
}

TEST_F(WindowRestartTest, MasterKilledWithTheRunAtOneRoundResumesItAndTheFramesAreUnchanged) {
  const std::string batch = start_run();
  ASSERT_FALSE(batch.empty());
  const int round = kill_at_one_round();
  ASSERT_GE(round, kKillRound);
  ASSERT_NO_FATAL_FAILURE(restart_master());
  // The run resumed as a run: all six frames from the round of their checkpoints.
  EXPECT_TRUE(wait_until([&] { return log_matches("job \\S+ running from round") >= size_t(kFrames); }, 60s))
      << master_->err();
  EXPECT_EQ(log_matches("job \\S+ running from round " + std::to_string(round) + ":"), size_t(kFrames))
      << master_->err();
  EXPECT_EQ(master_->err().find("checkpointed after different rounds"), std::string::npos);
  ASSERT_NO_FATAL_FAILURE(fetch_and_compare(batch));
}

TEST_F(WindowRestartTest,
       MasterKilledBetweenTwoFramesCheckpointsResumesFromARoundAllHaveOrStartsAgainAndTheFramesAreUnchanged) {
  const std::string batch = start_run();
  ASSERT_FALSE(batch.empty());
  const int round = kill_at_one_round();
  ASSERT_GE(round, kKillRound);
  // One frame's newest checkpoint falls back to its previous one: that frame's round was not yet
  // committed when the master died.
  const auto rounds = checkpoint_rounds();
  const std::string behind = std::next(rounds.begin(), kFrames / 2)->first;
  const fs::path job = dir_ / "state" / "jobs" / behind;
  fs::copy_file(job / "progress.prev.ckpt", job / "progress.ckpt", fs::copy_options::overwrite_existing);
  // (The round before, or earlier: a checkpoint queued behind a newer one is not committed.)
  const int behind_round = checkpoint_rounds().at(behind);
  ASSERT_GE(behind_round, 1);
  ASSERT_LT(behind_round, round) << "the previous checkpoint is of an earlier round";
  note("job %s's newest checkpoint is now of round %d", behind.c_str(), behind_round);
  // Whether every frame has a checkpoint of that round, the newest or the previous one.
  bool common = true;
  {
    CheckpointStore store(dir_ / "state");
    for (const auto& [id, r] : checkpoint_rounds()) common = common && store.load_progress_after(id, behind_round);
  }
  note("every frame has a checkpoint of round %d: %s", behind_round, common ? "yes" : "no");
  ASSERT_NO_FATAL_FAILURE(restart_master());
  if (common) {
    // The run resumes from the round of the frame behind: the others from their previous checkpoint.
    EXPECT_TRUE(wait_until([&] { return log_matches("job \\S+ running from round") >= size_t(kFrames); }, 60s))
        << master_->err();
    EXPECT_EQ(log_matches("job \\S+ running from round " + std::to_string(behind_round) + ":"), size_t(kFrames))
        << master_->err();
    EXPECT_NE(master_->err().find("checkpointed after different rounds; they resume after round " +
                                  std::to_string(behind_round)),
              std::string::npos)
        << master_->err();
  } else {
    // The frames start together from round 0 (their round 0 traced while their frames are built).
    EXPECT_TRUE(
        wait_until([&] { return log_matches("job \\S+ running: .* round 0 is traced") >= size_t(kFrames); }, 60s))
        << master_->err();
    EXPECT_NE(master_->err().find("its frames were checkpointed after different rounds; they start again"),
              std::string::npos)
        << master_->err();
    EXPECT_EQ(log_matches("job \\S+ running from round"), 0u) << "no frame resumes from its checkpoint";
  }
  ASSERT_NO_FATAL_FAILURE(fetch_and_compare(batch));
}

}  // namespace
}  // namespace window_restart
}  // namespace epr::testing
