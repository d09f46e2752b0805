// What the process tests of a master with workers share (the tests of this folder and the
// multi-master fixture): job flags, the test's folder of logs and story, the fixture holding the
// farm's processes and running `epr` against it, epr-master's and epr-worker's argv, the
// single-process reference render, the rounds the workers have leased, and the comparison of a
// job's images with the reference's.
#pragma once

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <regex>
#include <string>
#include <utility>
#include <vector>

#include "binaries.h"
#include "common/image.h"
#include "image_difference.h"
#include "process.h"

namespace epr::testing {

/// A job of the Cornell box in skip mode with CPU reprojection: SIZExSIZE pixels in 32x32 tiles,
/// `spp` paths a pixel in rounds of `paths_per_round` (no growing rounds), every pixel traced for
/// its first `min_paths`.
inline Args skip_job(int size, int spp, int paths_per_round, int min_paths, int seed) {
  return {"builtin:cornell",
          "--width",
          std::to_string(size),
          "--height",
          std::to_string(size),
          "--spp",
          std::to_string(spp),
          "--paths-per-round",
          std::to_string(paths_per_round),
          "--tile",
          "32",
          "--mode",
          "skip",
          "--reproject",
          "cpu",
          "--min-paths",
          std::to_string(min_paths),
          "--seed",
          std::to_string(seed),
          "--round-growth",
          "0"};
}

/// The master-restart job: 128x128 pixels in 16 tiles, 32 rounds of 8 paths; every pixel traces for
/// the first 12 rounds (min-paths), skipping thins out the rest.
inline Args restart_job() { return skip_job(128, 256, 8, 96, 11); }

/// A process test with a folder of logs, TMP/PREFIX-PID-TEST-N (made empty by start_story; N counts
/// the tests run, as --gtest_repeat runs a test again in the same process), and a story: lines
/// printed with the seconds since it began.
class StoryTest : public ::testing::Test {
 protected:
  /// Starts the story's clock and makes the test's folder.
  void start_story(const std::string& prefix) {
    start_ = std::chrono::steady_clock::now();
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    static int n = 0;
    dir_ = std::filesystem::temp_directory_path() /
           (prefix + "-" + std::to_string(::getpid()) + "-" + info->name() + "-" + std::to_string(++n));
    std::filesystem::remove_all(dir_);
    std::filesystem::create_directories(dir_);
  }

  /// A file in the test's folder.
  std::string path(const std::string& name) const { return (dir_ / name).string(); }

  /// Prints a line of the test's story with the seconds since it began.
  template <class... A>
  void note(const char* format, A... args) {
    print_note(start_, format, args...);
  }

  std::chrono::steady_clock::time_point start_;
  std::filesystem::path dir_;
};

/// epr-master on 127.0.0.1:PORT (0: a free one) with its HTTP endpoint on a free port, CPU
/// reprojection, 300 ms heartbeats and info logs; `extra` flags follow.
inline Args master_argv(int port, const Args& extra) {
  Args argv{kMaster,
            "--listen",
            "127.0.0.1:" + std::to_string(port),
            "--http",
            "127.0.0.1:0",
            "--reproject",
            "cpu",
            "--heartbeat-ms",
            "300",
            "--log-level",
            "info"};
  argv.insert(argv.end(), extra.begin(), extra.end());
  return argv;
}

/// epr-worker NAME of `masters` (a comma-separated list) on one thread, with its cache in
/// `cache_dir`, reconnecting within 500 ms, with debug logs (the leases the tests read).
inline Args worker_argv(const std::string& masters, const std::string& name, const std::string& cache_dir) {
  return {kWorker,   "--master",         masters, "--threads",   "1",    "--name", name, "--cache-dir",
          cache_dir, "--max-backoff-ms", "500",   "--log-level", "debug"};
}

/// `epr render --single-process --threads 1` of job `flags` into OUT.* (the undisturbed render).
inline Args reference_argv(const Args& flags, const std::string& out) {
  Args args{kEpr, "render"};
  args.insert(args.end(), flags.begin(), flags.end());
  args.insert(args.end(), {"--single-process", "--threads", "1", "--out", out});
  return args;
}

/// The highest round the workers' logs show a tile lease of (-1: none yet).
inline int highest_round_leased(const std::vector<std::unique_ptr<Process>>& workers) {
  const std::regex leased("lease [0-9]+: job \\S+ round ([0-9]+) tile");
  int highest = -1;
  for (auto& w : workers) {
    const std::string log = w->err();
    for (auto it = std::sregex_iterator(log.begin(), log.end(), leased); it != std::sregex_iterator(); ++it)
      highest = std::max(highest, std::stoi((*it)[1]));
  }
  return highest;
}

/// Waits for the reference render to end; it must end within 120 s, with exit code 0.
inline void expect_reference_done(Process& reference) {
  ASSERT_TRUE(reference.wait_for(std::chrono::seconds(120)).has_value()) << "the reference render did not end";
  ASSERT_EQ(reference.exit_code(), 0) << reference.err();
}

/// A job's images PREFIX.* against the reference's REF.*: M, M' and the path-traced estimate
/// bit-identical, the combined image within float rounding. `what` begins each message.
inline void expect_images_equal(const std::string& prefix, const std::string& ref, const std::string& what = "") {
  EXPECT_EQ(exact_difference(read_image(prefix + ".counts.exr"), read_image(ref + ".counts.exr")), "")
      << what << "M and M' per pixel";
  EXPECT_EQ(exact_difference(read_image(prefix + ".pathtrace.exr"), read_image(ref + ".pathtrace.exr")), "")
      << what << "path-traced estimate";
  EXPECT_EQ(close_difference(read_image(prefix + ".exr"), read_image(ref + ".exr")), "") << what << "combined image";
}

/// A story test of a farm: epr-master (master_, on 127.0.0.1:port_), its workers, and `epr` runs with
/// their output in the test's folder. TearDown stops them all; the folder is removed, or kept and the
/// logs' tails printed when the test failed.
class SingleMasterTest : public StoryTest {
 protected:
  void TearDown() override {
    if (reference_) reference_->stop();
    // Workers first: they return their leases to a master that is still there.
    for (auto& w : workers_) w->stop();
    if (master_) master_->stop();
    if (HasFailure()) {
      std::fprintf(stderr, "logs kept in %s\n", dir_.c_str());
      for (const auto& m : old_master_logs_) print_log_tail("earlier epr-master", m);
      if (master_) print_log_tail("epr-master", master_->err());
      for (auto& w : workers_) print_log_tail(w->name() + " " + std::to_string(w->pid()), w->err());
    } else {
      workers_.clear();
      master_.reset();
      reference_.reset();
      std::filesystem::remove_all(dir_);
    }
  }

  std::string address() const { return "127.0.0.1:" + std::to_string(port_); }

  /// Starts epr-master (master_argv) on `port` (0: a free one) with `extra` flags, its output in
  /// master-N; fails the test when it does not listen.
  void start_master(int port, const Args& extra) {
    const int bound = start_listening(master_, master_argv(port, extra),
                                      [&] { return dir_ / ("master-" + std::to_string(++masters_)); });
    if (bound == 0) FAIL() << "epr-master did not start on port " << port << ":\n" << master_->err();
    port_ = bound;
  }

  /// Starts epr-worker NAME (worker_argv) of the master, its output in NAME.
  Process& start_worker(const std::string& name) {
    workers_.push_back(std::make_unique<Process>(worker_argv(address(), name, path("cache-" + name)), dir_ / name));
    return *workers_.back();
  }

  /// Registrations of workers the current master has logged.
  size_t registered() const { return count_of(master_->err(), ") registered"); }

  /// Runs `epr ARGS...` to the end (killed after `timeout`), its output in epr-N.
  RunResult run_epr(Args args, Millis timeout) {
    args.insert(args.begin(), kEpr);
    return run_process(args, dir_ / ("epr-" + std::to_string(++runs_)), timeout);
  }

  /// Runs `epr ARGS... --master ADDRESS` against the farm's master.
  RunResult epr(Args args, Millis timeout = std::chrono::seconds(60)) {
    args.insert(args.end(), {"--master", address()});
    return run_epr(std::move(args), timeout);
  }

  /// `epr submit JOB...`: the job id (the first line it prints); exit code 0 is expected.
  std::string submit(const Args& job) {
    Args args{"submit"};
    args.insert(args.end(), job.begin(), job.end());
    const RunResult r = epr(args, std::chrono::seconds(30));
    EXPECT_EQ(r.code, 0) << r.err;
    return r.out.substr(0, r.out.find('\n'));
  }

  std::unique_ptr<Process> master_, reference_;
  std::vector<std::unique_ptr<Process>> workers_;
  std::vector<std::string> old_master_logs_;  // the stopped or killed masters' logs
  int port_ = 0, masters_ = 0, runs_ = 0;
};

}  // namespace epr::testing
