// A render whose samples come out NaN or infinite beyond a trace says so at its end, however it ran:
// `epr submit --wait`, `epr watch`, the master's log, `epr render` (embedded master) and
// `epr render --single-process`. No valid scene makes such samples, so the tracing programs run with
// the path tracer's test hook EPR_TEST_NONFINITE_EVERY=4 (worker/path_tracer.cpp): samples 3 and 7 of
// every pixel's 8 come out NaN, are dropped and counted by the real code, and their counts travel the
// real way (tile statistics over gRPC, the master's job counters, JobStatus). The same renders
// without the hook give no warning. A tile with dropped samples is logged with its first one's seed,
// pixel and sample (worker/nonfinite_log.h), and `epr render --single-process --trace-path` replays it.
#include <gtest/gtest.h>

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

// The end-of-render warning's text (common/tile.cpp, nonfinite_warning) with its two counts.
const std::regex kDropped(
    "([0-9]+) samples came out NaN or infinite and were dropped \\([^)]* per million of the ([0-9]+) paths traced\\)");
constexpr const char* kNaNOrInfinite = "came out NaN or infinite";

// 32x32 pixels of 8 path-traced samples: 8192 paths.
constexpr uint64_t kPaths = 32 * 32 * 8;
Args job_flags() {
  return {
      "builtin:cornell", "--width", "32",     "--height", "32", "--spp", "8", "--paths-per-round", "4", "--tile", "16",
      "--round-growth",  "0",       "--mode", "pt"};
}

// `text` as a regular expression that matches it literally (job ids hold dots).
std::string literal(const std::string& text) {
  return std::regex_replace(text, std::regex(R"([.^$|()\[\]{}*+?\\])"), R"(\$&)");
}

// `argv` with every 4th sample of a pixel NaN.
Args poisoned(Args argv) {
  argv.insert(argv.begin(), {"/usr/bin/env", "EPR_TEST_NONFINITE_EVERY=4"});
  return argv;
}

// The warning in `text` reports a quarter of the job's paths dropped (`prefix`, a regular expression,
// starts its line).
void expect_quarter_dropped(const std::string& text, const std::string& prefix, const std::string& what) {
  std::smatch m;
  const std::regex line(prefix + "[^\\n]*");
  ASSERT_TRUE(std::regex_search(text, m, line)) << what << " has no line starting '" << prefix << "':\n" << text;
  const std::string warning = m.str();
  ASSERT_TRUE(std::regex_search(warning, m, kDropped)) << what << ": no non-finite warning in: " << warning;
  EXPECT_EQ(std::stoull(m[2].str()), kPaths) << what << ": " << warning;
  EXPECT_EQ(std::stoull(m[1].str()), kPaths / 4) << what << ": " << warning;
}

class NonFiniteWarningTest : public SingleMasterTest {
 protected:
  void SetUp() override { start_story("epr-nonfinite"); }

  // `epr submit --wait --out JOB-N` of the job: its id (first line of stdout) and the run.
  RunResult submit_and_wait(std::string* id) {
    Args args{"submit"};
    const Args f = job_flags();
    args.insert(args.end(), f.begin(), f.end());
    args.insert(args.end(), {"--wait", "--out", path("job-" + std::to_string(runs_ + 1))});
    RunResult r = epr(args, 120s);
    EXPECT_FALSE(r.timed_out) << "epr submit --wait did not return within 120 s:\n" << r.err;
    EXPECT_EQ(r.code, 0) << r.err;
    *id = r.out.substr(0, r.out.find('\n'));
    EXPECT_FALSE(id->empty()) << "no job id printed:\n" << r.out << r.err;
    return r;
  }

  // One epr-worker, only tracing while the job runs (the previous one is stopped first).
  void start_worker(const std::string& name, bool nonfinite) {
    for (auto& w : workers_) w->stop();
    const Args argv = worker_argv(address(), name, path("cache-" + name));
    workers_.push_back(std::make_unique<Process>(nonfinite ? poisoned(argv) : argv, dir_ / name));
  }
};

TEST_F(NonFiniteWarningTest, SubmitWaitWatchAndTheMasterLogWarnOfDroppedSamples) {
  master_ = std::make_unique<Process>(master_argv(0, {"--state-dir", path("state")}), dir_ / "master");
  port_ = listening_port(*master_, 30s);
  ASSERT_GT(port_, 0) << "epr-master did not start:\n" << master_->err();

  start_worker("poisoned", true);
  std::string id;
  const RunResult waited = submit_and_wait(&id);
  ASSERT_FALSE(id.empty());
  note("job %s done", id.c_str());
  expect_quarter_dropped(waited.err, literal("job " + id + ": warning: "), "epr submit --wait");

  const RunResult watched = epr({"watch", id}, 120s);
  ASSERT_EQ(watched.code, 0) << watched.err;
  expect_quarter_dropped(watched.err, literal("job " + id + ": warning: "), "epr watch");

  // The master logs it when the job is done (a moment after the clients may see DONE).
  const std::string master_line = "job " + id + ": ";
  EXPECT_TRUE(wait_until(
      [&] { return master_->err().find(master_line + std::to_string(kPaths / 4)) != std::string::npos; }, 30s))
      << "the master did not log the warning";
  expect_quarter_dropped(master_->err(), literal(master_line) + "[0-9]+ samples", "the master's log");

  // A clean worker's job: no warning anywhere.
  start_worker("clean", false);
  std::string clean;
  const RunResult clean_wait = submit_and_wait(&clean);
  ASSERT_FALSE(clean.empty());
  EXPECT_EQ(clean_wait.err.find(kNaNOrInfinite), std::string::npos) << clean_wait.err;
  const RunResult clean_watch = epr({"watch", clean}, 120s);
  ASSERT_EQ(clean_watch.code, 0) << clean_watch.err;
  EXPECT_EQ(clean_watch.err.find(kNaNOrInfinite), std::string::npos) << clean_watch.err;
  // Stopped, the master has logged all it will about both jobs: one warning, the first job's.
  master_->stop(30s);
  EXPECT_EQ(count_of(master_->err(), kNaNOrInfinite), 1u) << master_->err();
}

TEST_F(NonFiniteWarningTest, EprRenderWarnsOfDroppedSamples) {
  for (const bool single : {false, true}) {
    for (const bool nonfinite : {true, false}) {
      const std::string name = std::string(single ? "single" : "embedded") + (nonfinite ? "-nan" : "-clean");
      Args argv{kEpr, "render"};
      const Args f = job_flags();
      argv.insert(argv.end(), f.begin(), f.end());
      argv.insert(argv.end(), {"--http", "", "--out", path(name)});
      if (single) argv.push_back("--single-process");
      const RunResult r = run_process(nonfinite ? poisoned(argv) : argv, dir_ / name, 120s);
      ASSERT_EQ(r.code, 0) << name << ":\n" << r.err;
      note("%s rendered", name.c_str());
      if (nonfinite)
        expect_quarter_dropped(r.err, "epr render: warning: ", name);
      else
        EXPECT_EQ(r.err.find(kNaNOrInfinite), std::string::npos) << name << ":\n" << r.err;
    }
  }
}

// The replay a tile's log line names: its seed, pixel and sample (worker/nonfinite_log.cpp).
const std::regex kReplay("--seed ([0-9]+) --trace-path ([0-9]+),([0-9]+),([0-9]+)");
constexpr const char* kDroppedInTile = "non-finite path samples dropped in tile";

// `epr render <job flags> --single-process --seed S --trace-path X,Y,N`, poisoned or not: its stdout.
std::string replay(const std::string& seed, const std::string& ref, bool nonfinite, const fs::path& log) {
  Args argv{kEpr, "render"};
  const Args f = job_flags();
  argv.insert(argv.end(), f.begin(), f.end());
  argv.insert(argv.end(), {"--single-process", "--seed", seed, "--trace-path", ref});
  const RunResult r = run_process(nonfinite ? poisoned(argv) : argv, log, 120s);
  EXPECT_EQ(r.code, 0) << "replay of " << ref << ":\n" << r.err;
  return r.out;
}

// The logged sample replays to a non-finite radiance with the hook, and without it to a finite one
// along the same vertices: the path is the one that was dropped, only its end poisoned.
void expect_replays_nonfinite(const std::string& log, const std::string& what, const fs::path& prefix) {
  std::smatch m;
  ASSERT_TRUE(std::regex_search(log, m, kReplay)) << what << " logged no replay:\n" << log;
  const std::string seed = m[1].str(), ref = m[2].str() + "," + m[3].str() + "," + m[4].str();
  EXPECT_EQ((std::stoul(m[4].str()) + 1) % 4, 0u)
      << what << ": sample " << m[4].str() << " is not one the hook poisons";
  const std::string poisoned_path = replay(seed, ref, true, fs::path(prefix.string() + "-replay-nan"));
  const std::string clean_path = replay(seed, ref, false, fs::path(prefix.string() + "-replay-clean"));
  EXPECT_NE(poisoned_path.find("radiance nan nan nan, non-finite"), std::string::npos) << poisoned_path;
  EXPECT_EQ(clean_path.find("non-finite"), std::string::npos) << clean_path;
  EXPECT_EQ(clean_path.find("nan"), std::string::npos) << clean_path;
  // Everything after the first line (counts of vertices and rays, each vertex) is the same path.
  const auto rest = [](const std::string& t) { return t.substr(t.find('\n') + 1); };
  EXPECT_NE(rest(clean_path).find("vertices "), std::string::npos) << clean_path;
  EXPECT_EQ(rest(poisoned_path), rest(clean_path));
  // A sample the hook does not poison replays finite with the hook on.
  const std::string next = m[2].str() + "," + m[3].str() + "," + std::to_string(std::stoul(m[4].str()) + 1);
  EXPECT_EQ(replay(seed, next, true, fs::path(prefix.string() + "-replay-next")).find("non-finite"), std::string::npos);
}

TEST_F(NonFiniteWarningTest, ADroppedSampleIsLoggedPerTileAndReplaysToTheSameNonFinitePath) {
  // One process renders 4 tiles x 2 rounds, each with dropped samples: tiles 1, 2, 4 and 8 are logged.
  Args argv{kEpr, "render"};
  const Args f = job_flags();
  argv.insert(argv.end(), f.begin(), f.end());
  argv.insert(argv.end(), {"--seed", "7", "--out", path("single"), "--single-process"});
  const RunResult r = run_process(poisoned(argv), dir_ / "single", 120s);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(count_of(r.err, kDroppedInTile), 4u) << r.err;
  EXPECT_NE(r.err.find("(tile 8 with such samples in this process)"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("--seed 7 --trace-path"), std::string::npos) << r.err;
  expect_replays_nonfinite(r.err, "epr render --single-process", dir_ / "single");

  // An epr-worker of a farm logs the same, with the seed its lease gave.
  master_ = std::make_unique<Process>(master_argv(0, {"--state-dir", path("state")}), dir_ / "master");
  port_ = listening_port(*master_, 30s);
  ASSERT_GT(port_, 0) << "epr-master did not start:\n" << master_->err();
  start_worker("poisoned", true);
  std::string id;
  submit_and_wait(&id);
  ASSERT_FALSE(id.empty());
  EXPECT_TRUE(wait_until([&] { return workers_.back()->err().find(kDroppedInTile) != std::string::npos; }, 30s))
      << workers_.back()->err();
  expect_replays_nonfinite(workers_.back()->err(), "epr-worker", dir_ / "worker");
}

// --trace-path without --single-process, or not X,Y,N, or outside the image, is refused.
TEST_F(NonFiniteWarningTest, TracePathRefusesWhatItCannotReplay) {
  for (const auto& [flags, expected] : std::vector<std::pair<Args, std::string>>{
           {{"--trace-path", "1,2,3"}, "add --single-process"},
           {{"--single-process", "--trace-path", "1,2"}, "expected X,Y,SAMPLE"},
           {{"--single-process", "--trace-path", "1,-2,3"}, "expected X,Y,SAMPLE"},
           {{"--single-process", "--trace-path", "32,0,0"}, "pixel 32,0 is outside the 32x32 image"}}) {
    Args argv{kEpr, "render"};
    const Args f = job_flags();
    argv.insert(argv.end(), f.begin(), f.end());
    argv.insert(argv.end(), flags.begin(), flags.end());
    const RunResult r = run_process(argv, dir_ / "refused", 60s);
    EXPECT_NE(r.code, 0) << flags.back();
    EXPECT_NE(r.err.find(expected), std::string::npos) << flags.back() << ":\n" << r.err;
  }
}

}  // namespace
}  // namespace epr::testing
