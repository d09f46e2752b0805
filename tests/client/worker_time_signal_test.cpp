// epr-worker's SIGUSR1 line (epr_worker_main.cpp; bench/utilisation_bench reads it): the real
// epr-master and a one-thread epr-worker on loopback. Before any job the worker's thread has traced
// nothing; after an `epr submit --wait` job it has, the activities add up to no more than the
// thread's life, and a later line never shows less of any activity than an earlier one.
#include <gtest/gtest.h>
#include <signal.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <regex>
#include <string>
#include <vector>

#include "tests/integration/cluster/process.h"

namespace epr {
namespace {
namespace fs = std::filesystem;
using namespace std::chrono_literals;
using testing::binary;
using testing::Process;
using testing::run_process;

struct TimeLine {
  int threads = 0;
  double tracing = 0, leasing = 0, waiting = 0, submitting = 0, other = 0;
  double total() const { return tracing + leasing + waiting + submitting + other; }
};

std::vector<TimeLine> time_lines(const std::string& err) {
  static const std::regex line(
      "epr-worker time: threads ([0-9]+) tracing ([0-9.]+) leasing ([0-9.]+) waiting ([0-9.]+) submitting "
      "([0-9.]+) other ([0-9.]+)");
  std::vector<TimeLine> out;
  for (auto it = std::sregex_iterator(err.begin(), err.end(), line); it != std::sregex_iterator(); ++it) {
    const std::smatch& m = *it;
    out.push_back(
        {std::stoi(m[1]), std::stod(m[2]), std::stod(m[3]), std::stod(m[4]), std::stod(m[5]), std::stod(m[6])});
  }
  return out;
}

// Sends SIGUSR1 and waits for the worker's line number `n` (from 0).
TimeLine ask(Process& worker, size_t n) {
  worker.signal(SIGUSR1);
  std::vector<TimeLine> lines;
  testing::wait_until([&] { return (lines = time_lines(worker.err())).size() > n; }, 30s);
  if (lines.size() <= n) {
    ADD_FAILURE() << "no time line " << n << " in the worker's log:\n" << worker.err();
    return {};
  }
  return lines[n];
}

TEST(WorkerTimeSignal, SplitsTheTracingThreadsTimeByActivity) {
  const fs::path dir = fs::temp_directory_path() / ("epr-worker-time-" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  Process master({binary("master", "epr-master"), "--listen", "127.0.0.1:0", "--http", "", "--state-dir",
                  (dir / "state").string()},
                 dir / "master");
  const int port = testing::listening_port(master, 60s);
  ASSERT_NE(port, 0) << master.err();
  const std::string target = "127.0.0.1:" + std::to_string(port);
  const auto worker_start = std::chrono::steady_clock::now();
  Process worker(
      {binary("worker", "epr-worker"), "--master", target, "--threads", "1", "--cache-dir", (dir / "cache").string()},
      dir / "worker");
  ASSERT_TRUE(testing::wait_until([&] { return master.err().find("registered") != std::string::npos; }, 60s))
      << master.err();

  const TimeLine idle = ask(worker, 0);
  EXPECT_EQ(idle.threads, 1);
  EXPECT_EQ(idle.tracing, 0);
  EXPECT_GT(idle.leasing + idle.waiting, 0);  // asking the master, which has no job

  const auto submit = run_process(
      {binary("client", "epr"), "submit", "builtin:cornell", "--master", target, "--width", "64", "--height", "64",
       "--spp", "8", "--tile", "16", "--reproject", "cpu", "--wait", "--out", (dir / "cornell").string()},
      dir / "submit", 120s);
  ASSERT_EQ(submit.code, 0) << submit.err;

  const TimeLine done = ask(worker, 1);
  const double lived = std::chrono::duration<double>(std::chrono::steady_clock::now() - worker_start).count();
  EXPECT_EQ(done.threads, 1);
  EXPECT_GT(done.tracing, 0);
  // One thread: its activities cover at most its life (the worker started after worker_start).
  EXPECT_LE(done.total(), lived);
  EXPECT_GE(done.tracing, idle.tracing);
  EXPECT_GE(done.leasing, idle.leasing);
  EXPECT_GE(done.waiting, idle.waiting);
  EXPECT_GE(done.submitting, idle.submitting);
  EXPECT_GE(done.other, idle.other);
  EXPECT_GT(done.total(), idle.total());

  EXPECT_EQ(worker.stop(), 0) << worker.err();
  if (!HasFailure()) fs::remove_all(dir);
}

}  // namespace
}  // namespace epr
