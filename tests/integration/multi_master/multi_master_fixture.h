// The fixture of the multi-master process tests (multi_master_test.cpp, farm_test.cpp): real
// epr-master processes on loopback, each with its state directory, epr-worker processes given every
// master's address, `epr` runs, and the single-process reference renders the jobs must equal.
#pragma once

#include <gtest/gtest.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <memory>
#include <regex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "../cluster/binaries.h"
#include "../cluster/image_difference.h"
#include "../cluster/process.h"
#include "common/image.h"

namespace epr::testing {
namespace fs = std::filesystem;
using namespace std::chrono_literals;

// A small job: 64x64 pixels in 4 tiles, `rounds` rounds of 4 paths, every pixel traced in each
// (min-paths = spp), so that a job runs for a known number of rounds.
inline Args job_flags(int seed, int rounds) {
  const int spp = 4 * rounds;
  return {"builtin:cornell",
          "--width",
          "64",
          "--height",
          "64",
          "--spp",
          std::to_string(spp),
          "--paths-per-round",
          "4",
          "--tile",
          "32",
          "--mode",
          "skip",
          "--reproject",
          "cpu",
          "--min-paths",
          std::to_string(spp),
          "--seed",
          std::to_string(seed),
          "--round-growth",
          "0"};
}

// A port nothing listens on right now (bound, read, closed).
inline int free_port() {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t len = sizeof a;
  if (fd < 0 || ::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 ||
      ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len) != 0)
    throw std::runtime_error("no free port");
  ::close(fd);
  return ntohs(a.sin_port);
}

struct MasterProc {
  std::string name;  // its state directory and log prefix
  int port = 0;
  std::unique_ptr<Process> proc;
  std::vector<std::string> old_logs;  // of the processes killed before this one
  std::string host = "127.0.0.1";     // how the workers and clients name it
  Args extra;                         // more epr-master flags (--name NAME)
  std::string address() const { return host + ":" + std::to_string(port); }
};

class MultiMasterTest : public ::testing::Test {
 protected:
  void SetUp() override {
    start_ = std::chrono::steady_clock::now();
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = fs::temp_directory_path() / ("epr-multi-master-" + std::to_string(::getpid()) + "-" + info->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }

  void TearDown() override {
    for (auto& r : references_) r->stop();
    for (auto& w : workers_) w->stop();
    for (auto& m : masters_)
      if (m.proc) m.proc->stop();
    if (HasFailure()) {
      std::fprintf(stderr, "logs kept in %s\n", dir_.c_str());
      for (auto& m : masters_) {
        for (const auto& old : m.old_logs) print_log_tail("killed " + m.name, old);
        if (m.proc) print_log_tail(m.name, m.proc->err());
      }
      for (auto& w : workers_) print_log_tail(w->name(), w->err());
    } else {
      fs::remove_all(dir_);
    }
  }

  std::string path(const std::string& name) const { return (dir_ / name).string(); }

  template <class... A>
  void note(const char* format, A... args) {
    print_note(start_, format, args...);
  }

  // Starts (or restarts) master `m` on its port (0: a free one) and state directory.
  void start_master(MasterProc& m) {
    Args argv{kMaster,
              "--listen",
              "127.0.0.1:" + std::to_string(m.port),
              "--state-dir",
              path(m.name),
              "--http",
              "127.0.0.1:0",
              "--reproject",
              "cpu",
              "--lease-timeout-ms",
              "1500",
              "--heartbeat-ms",
              "300",
              "--log-level",
              "info"};
    argv.insert(argv.end(), m.extra.begin(), m.extra.end());
    const std::regex listening("epr-master listening on port ([0-9]+)");
    // A port just freed by a killed master may take a moment to be bindable again.
    for (int attempt = 0; attempt < 20; ++attempt) {
      m.proc = std::make_unique<Process>(argv, dir_ / (m.name + "-" + std::to_string(++starts_)));
      std::smatch match;
      std::string err;
      wait_until(
          [&] {
            err = m.proc->err();
            return std::regex_search(err, match, listening) || !m.proc->running();
          },
          10s);
      if (match.size() == 2 && m.proc->running()) {
        m.port = std::stoi(match[1]);
        return;
      }
      std::this_thread::sleep_for(250ms);
    }
    FAIL() << m.name << " did not start on port " << m.port << ":\n" << m.proc->err();
  }

  MasterProc& add_master(const std::string& name, bool start = true, Args extra = {}) {
    masters_.push_back({name, 0, nullptr, {}, "127.0.0.1", std::move(extra)});
    MasterProc& m = masters_.back();
    if (start) {
      start_master(m);
    } else {
      m.port = free_port();
    }
    return m;
  }

  std::string all_addresses() const {
    std::string list;
    for (const auto& m : masters_) {
      if (!list.empty()) list += ',';
      list += m.address();
    }
    return list;
  }

  void start_worker(const std::string& name) {
    workers_.push_back(std::make_unique<Process>(
        Args{kWorker, "--master", all_addresses(), "--threads", "1", "--name", name, "--cache-dir",
             path("cache-" + name), "--max-backoff-ms", "500", "--log-level", "debug"},
        dir_ / name));
  }

  RunResult epr(Args args, Millis timeout = 60s) {
    args.insert(args.begin(), kEpr);
    return run_process(args, dir_ / ("epr-" + std::to_string(++runs_)), timeout);
  }

  std::string submit(const MasterProc& m, const Args& flags) {
    Args args{"submit"};
    args.insert(args.end(), flags.begin(), flags.end());
    args.insert(args.end(), {"--master", m.address()});
    const RunResult r = epr(args, 30s);
    EXPECT_EQ(r.code, 0) << r.err;
    return r.out.substr(0, r.out.find('\n'));
  }

  // `epr render --single-process --threads 1` of a job into PREFIX.*, in the background.
  void start_reference(const Args& flags, const std::string& prefix) {
    Args args{kEpr, "render"};
    args.insert(args.end(), flags.begin(), flags.end());
    args.insert(args.end(), {"--single-process", "--threads", "1", "--out", path(prefix)});
    references_.push_back(std::make_unique<Process>(args, dir_ / prefix));
  }

  // Registrations master `m`'s current process has logged.
  static size_t registered(const MasterProc& m) { return count_of(m.proc->err(), ") registered"); }

  // Tiles of master `m` the workers leased, by their logs.
  size_t leased_from(const MasterProc& m, int min_round = 0) const {
    const std::regex leased("lease [0-9]+: job \\S+ round ([0-9]+) tile [0-9]+ from " +
                            std::regex_replace(m.address(), std::regex("\\."), "\\.") + "\\b");
    size_t n = 0;
    for (const auto& w : workers_) {
      const std::string log = w->err();
      for (auto it = std::sregex_iterator(log.begin(), log.end(), leased); it != std::sregex_iterator(); ++it)
        n += std::stoi((*it)[1]) >= min_round;
    }
    return n;
  }

  // `epr watch` until the job ends, `epr get` into PREFIX.*, and the comparison with REF.*.
  void expect_job_equals_reference(const MasterProc& m, const std::string& id, const std::string& prefix,
                                   const std::string& ref) {
    const RunResult w = epr({"watch", id, "--master", m.address()}, 120s);
    ASSERT_FALSE(w.timed_out) << m.name << "'s job did not end:\n" << w.err;
    ASSERT_EQ(w.code, 0) << w.err;
    EXPECT_NE(w.err.find("DONE"), std::string::npos) << w.err;
    const RunResult g = epr({"get", id, "--out", path(prefix), "--master", m.address()}, 30s);
    ASSERT_EQ(g.code, 0) << g.err;
    for (auto& r : references_)
      if (r->name().find(ref) != std::string::npos) {
        ASSERT_TRUE(r->wait_for(120s).has_value()) << "the reference render did not end";
        ASSERT_EQ(r->exit_code(), 0) << r->err();
      }
    const Image counts = read_image(path(prefix + ".counts.exr")), ref_counts = read_image(path(ref + ".counts.exr"));
    ASSERT_EQ(counts.channels, 2);
    EXPECT_EQ(exact_difference(counts, ref_counts), "") << m.name << ": M and M' per pixel";
    EXPECT_EQ(exact_difference(read_image(path(prefix + ".pathtrace.exr")), read_image(path(ref + ".pathtrace.exr"))),
              "")
        << m.name << ": path-traced estimate";
    EXPECT_EQ(close_difference(read_image(path(prefix + ".exr")), read_image(path(ref + ".exr"))), "")
        << m.name << ": combined image";
  }

  std::chrono::steady_clock::time_point start_;
  fs::path dir_;
  std::vector<MasterProc> masters_;
  std::vector<std::unique_ptr<Process>> workers_, references_;
  int runs_ = 0, starts_ = 0;
};

}  // namespace epr::testing
