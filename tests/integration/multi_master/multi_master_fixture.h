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
#include "../cluster/farm_steps.h"
#include "../cluster/process.h"
#include "common/image.h"

namespace epr::testing {
namespace fs = std::filesystem;
using namespace std::chrono_literals;

// A small job: 64x64 pixels in 4 tiles, `rounds` rounds of 4 paths, every pixel traced in each
// (min-paths = spp), so that a job runs for a known number of rounds.
inline Args job_flags(int seed, int rounds) { return skip_job(64, 4 * rounds, 4, 4 * rounds, seed); }

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

class MultiMasterTest : public StoryTest {
 protected:
  void SetUp() override { start_story("epr-multi-master"); }

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

  // Starts (or restarts) master `m` on its port (0: a free one) and state directory.
  void start_master(MasterProc& m) {
    Args extra{"--state-dir", path(m.name), "--lease-timeout-ms", "1500"};
    extra.insert(extra.end(), m.extra.begin(), m.extra.end());
    const int port = start_listening(m.proc, master_argv(m.port, extra),
                                     [&] { return dir_ / (m.name + "-" + std::to_string(++starts_)); });
    if (port == 0) FAIL() << m.name << " did not start on port " << m.port << ":\n" << m.proc->err();
    m.port = port;
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
    workers_.push_back(
        std::make_unique<Process>(worker_argv(all_addresses(), name, path("cache-" + name)), dir_ / name));
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
    references_.push_back(std::make_unique<Process>(reference_argv(flags, path(prefix)), dir_ / prefix));
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
        ASSERT_NO_FATAL_FAILURE(expect_reference_done(*r));
      }
    ASSERT_EQ(read_image(path(prefix + ".counts.exr")).channels, 2);
    expect_images_equal(path(prefix), path(ref), m.name + ": ");
  }

  std::vector<MasterProc> masters_;
  std::vector<std::unique_ptr<Process>> workers_, references_;
  int runs_ = 0, starts_ = 0;
};

}  // namespace epr::testing
