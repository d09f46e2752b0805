// Worker utilisation with one job against several jobs queued at once (the master runs as many as
// its memory budget admits and leases across them, job_manager.h).
//
// Two measures over one window, from the first SubmitJob to the last job done (so every round barrier,
// frame build and result write of the jobs counts against them):
//   util:        the master's view, the workers' tracing seconds of the committed tiles
//                (JobStatus.seconds_tracing summed over the jobs) / (tracing threads x the window);
//   thread util: the worker's own view (WorkerNodeStats::time_*), the share of its tracing threads'
//                wall time spent inside a tile's tracing rather than waiting for a lease, for the
//                master (a round barrier, back-pressure), for a submission, or on the worker's own
//                overhead between tiles. The split by activity is printed under each run; embedded,
//                also the tiles traced and committed and the sum of the tiles' own timers (node and
//                master), and with --cpu-split the threads' CPU seconds by activity.
// On a machine with few cores the master's threads take CPU from the tracing threads: util counts
// that against the worker, thread util counts it where the thread was preempted. --pin runs the
// cluster's epr-master on CPU 0 and a one-thread epr-worker on CPU 1, so that they do not share one.
// Set-ups (every rep runs each set-up in turn, so that drifting load hits them alike):
//   embedded: a MasterServer and one WorkerNode in this process over the server's in-process gRPC
//             channel, as `epr render` runs them (the split read from the node);
//   embedded-socket: the same with the node connected to the server's loopback port;
//   cluster:  real epr-master and epr-worker processes on loopback (the split read from the worker's
//             SIGUSR1 line, epr_worker_main.cpp, at the window's start and end).
// Each (set-up, jobs) pair runs --reps times; the medians are printed side by side with the ratio of
// the several-jobs figure to the one-job figure. Wall figures are distorted when other processes
// share the machine; the load average is printed with each run.
//
//   utilisation_bench [--setups embedded,embedded-socket,cluster] [--jobs 1,3] [--reps 3] [--size 192] [--spp 64]
//                     [--ppr 1] [--mode skip] [--scene builtin:cornell] [--reproject cpu] [--threads 0]
//                     [--pin] [--cpu-split]
#include <sched.h>
#include <signal.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <regex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "client/job_client.h"
#include "common/log.h"
#include "epr/v1/job_service.grpc.pb.h"
#include "master/memory_estimate.h"
#include "master/server/master_server.h"
#include "tests/integration/cluster/process.h"
#include "tests/wait_until.h"
#include "wire/convert.h"
#include "wire/scene_bundle.h"
#include "worker/worker_node.h"

namespace fs = std::filesystem;
using namespace std::chrono_literals;

namespace {

std::vector<std::string> split(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream in(s);
  for (std::string item; std::getline(in, item, ',');)
    if (!item.empty()) out.push_back(item);
  return out;
}

double load_average() {
  double l = -1;
  if (FILE* f = std::fopen("/proc/loadavg", "r")) {
    if (std::fscanf(f, "%lf", &l) != 1) l = -1;
    std::fclose(f);
  }
  return l;
}

double median(std::vector<double> v) {
  if (v.empty()) return -1;
  std::sort(v.begin(), v.end());
  return v.size() % 2 ? v[v.size() / 2] : (v[v.size() / 2 - 1] + v[v.size() / 2]) / 2;
}

/// CPU seconds (user + system) of process `pid`: all its threads, living or ended, and those of its
/// living threads named `name` (the worker's tracing threads are "epr-trace").
struct ProcessCpu {
  double total = 0, named = 0;
};

double stat_cpu_seconds(const fs::path& stat) {
  std::ifstream in(stat);
  std::string line;
  if (!std::getline(in, line)) return 0;
  const size_t close = line.rfind(')');  // the command name may hold spaces and parentheses
  if (close == std::string::npos) return 0;
  std::istringstream fields(line.substr(close + 2));
  std::string f;
  unsigned long long utime = 0, stime = 0;
  for (int i = 3; fields >> f; ++i) {  // field 3 is the state; 14 and 15 are utime and stime
    if (i == 14) utime = std::stoull(f);
    if (i == 15) {
      stime = std::stoull(f);
      break;
    }
  }
  return double(utime + stime) / double(::sysconf(_SC_CLK_TCK));
}

ProcessCpu process_cpu(pid_t pid, const std::string& name) {
  ProcessCpu c;
  const fs::path proc = fs::path("/proc") / std::to_string(pid);
  c.total = stat_cpu_seconds(proc / "stat");
  std::error_code ec;
  for (const auto& task : fs::directory_iterator(proc / "task", ec)) {
    std::ifstream comm(task.path() / "comm");
    std::string n;
    if (std::getline(comm, n) && n == name) c.named += stat_cpu_seconds(task.path() / "stat");
  }
  return c;
}

struct Settings {
  int size = 192, spp = 64, ppr = 1, threads = 0;
  bool pin = false;        // cluster: epr-master on CPU 0, epr-worker on CPU 1 (--threads 1 unless told)
  bool cpu_split = false;  // embedded: the node's WorkerNodeOptions::cpu_split (reads the CPU clocks)
  std::string mode = "skip", reproject = "cpu", scene = "builtin:cornell";
};

epr::RenderOptions job_options(const Settings& s, int j) {
  epr::RenderOptions o;
  o.width = o.height = s.size;
  o.spp = s.spp;
  o.paths_per_round = s.ppr;
  o.mode = s.mode == "pt"   ? epr::RenderMode::kPathTrace
           : s.mode == "rp" ? epr::RenderMode::kReproject
                            : epr::RenderMode::kSkip;
  o.reproject = s.reproject == "gl" ? epr::ReprojectMethod::kGl : epr::ReprojectMethod::kCpu;
  o.seed = uint64_t(j + 1);
  return o;
}

struct Run {
  double utilisation = -1;       // master's view: tracing seconds / (threads x window)
  double node_utilisation = -1;  // the worker's own split: tracing / its threads' wall time
  double seconds = 0;
  epr::WorkerTimeSplit split;  // the tracing threads' time over the window, by activity
  epr::WorkerTimeSplit cpu;    // their CPU seconds over the window, by activity
  // Embedded: the node's tiles over the window, and its own sum of the tiles' tracing seconds (all
  // tiles traced, committed or not), against the master's sum (committed tiles).
  uint64_t leased = 0, committed = 0, uncommitted = 0;
  double node_tracing = -1, master_tracing = 0;
  // CPU seconds over the window: the tracing threads; the worker's other threads (cluster) or every other
  // thread of this process (embedded: master, worker's other threads, the bench's client); the master
  // process (cluster).
  double cpu_tracing = -1, cpu_worker_other = 0, cpu_master = 0;
};

/// Submits `n` jobs to `target`, waits for all; the window and the jobs' tracing seconds.
/// `at_start`, if given, runs once just before the first SubmitJob, `at_end` once the last job is done.
bool submit_and_wait(const std::string& target, const Settings& s, int n, double* window, double* tracing,
                     const std::function<void()>& at_start = {}, const std::function<void()>& at_end = {}) {
  auto stub = epr::v1::JobService::NewStub(grpc::CreateChannel(target, grpc::InsecureChannelCredentials()));
  if (at_start) at_start();
  const auto start = std::chrono::steady_clock::now();
  std::vector<std::string> ids;
  for (int j = 0; j < n; ++j) {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + 60s);
    epr::v1::JobId id;
    const grpc::Status st =
        stub->SubmitJob(&ctx, epr::to_job_spec(job_options(s, j), epr::bundle_scene(s.scene), epr::CameraSpec{}), &id);
    if (!st.ok()) {
      std::fprintf(stderr, "SubmitJob: %s\n", st.error_message().c_str());
      return false;
    }
    ids.push_back(id.id());
  }
  *tracing = 0;
  for (const std::string& id : ids) {
    for (;;) {
      grpc::ClientContext ctx;
      ctx.set_deadline(std::chrono::system_clock::now() + 30s);
      epr::v1::JobId req;
      req.set_id(id);
      epr::v1::JobStatus st;
      if (const grpc::Status g = stub->GetJob(&ctx, req, &st); !g.ok()) {
        std::fprintf(stderr, "GetJob %s: %s\n", id.c_str(), g.error_message().c_str());
        return false;
      }
      if (st.state() == epr::v1::JOB_STATE_DONE) {
        *tracing += st.seconds_tracing();
        break;
      }
      if (st.state() == epr::v1::JOB_STATE_FAILED || st.state() == epr::v1::JOB_STATE_CANCELLED) {
        std::fprintf(stderr, "job %s ended: %s\n", id.c_str(), st.error_message().c_str());
        return false;
      }
      std::this_thread::sleep_for(5ms);
    }
  }
  *window = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (at_end) at_end();
  return true;
}

int threads_of(const Settings& s) {
  if (s.threads > 0) return s.threads;
  return s.pin ? 1 : int(std::max(1u, std::thread::hardware_concurrency()));
}

/// Restricts this process (and the children it starts from now on) to `cpu`, or to every CPU (-1).
void pin_to(int cpu) {
  cpu_set_t set;
  CPU_ZERO(&set);
  const int n = int(std::max(1u, std::thread::hardware_concurrency()));
  for (int c = 0; c < n; ++c)
    if (cpu < 0 || c == cpu % n) CPU_SET(c, &set);
  if (sched_setaffinity(0, sizeof set, &set) != 0) std::perror("sched_setaffinity");
}

/// The epr-worker's tracing threads' time so far (thread-seconds by activity): SIGUSR1 makes it print
/// a line to stderr (epr_worker_main.cpp); waits for the line after the `seen` ones already read.
bool worker_split(epr::testing::Process& worker, int* seen, epr::WorkerTimeSplit* out) {
  worker.signal(SIGUSR1);
  const std::regex line(
      "epr-worker time: threads [0-9]+ tracing ([0-9.]+) leasing ([0-9.]+) waiting ([0-9.]+) submitting ([0-9.]+) "
      "other ([0-9.]+)");
  std::vector<std::smatch> found;
  std::string err;
  const bool ok = epr::test::wait_until(
      [&] {
        err = worker.err();
        found.clear();
        for (auto it = std::sregex_iterator(err.begin(), err.end(), line); it != std::sregex_iterator(); ++it)
          found.push_back(*it);
        return int(found.size()) > *seen;
      },
      10s, 2ms);
  if (!ok) return false;
  const std::smatch& m = found[size_t(*seen)];
  *seen += 1;
  out->tracing = std::stod(m[1]);
  out->leasing = std::stod(m[2]);
  out->waiting = std::stod(m[3]);
  out->submitting = std::stod(m[4]);
  out->other = std::stod(m[5]);
  return true;
}

bool run_embedded(const Settings& s, int n, const fs::path& dir, bool in_process, Run* out) {
  epr::MasterServerOptions mo;
  mo.listen = "127.0.0.1:0";
  mo.jobs.state_dir = (dir / "state").string();
  mo.jobs.checkpoints = false;
  mo.jobs.memory_budget_bytes = epr::default_memory_budget();
  if (s.reproject == "cpu") mo.jobs.reproject_backend_override = "cpu";
  epr::MasterServer server(mo);
  epr::WorkerNodeOptions wo;
  wo.master = server.local_target();
  if (in_process)
    wo.in_process = [&server](const grpc::ChannelArguments& args) { return server.in_process_channel(args); };
  wo.threads = threads_of(s);
  wo.name = "bench";
  wo.cpu_split = s.cpu_split;
  wo.cache_dir = (dir / "cache").string();
  epr::WorkerNode node(wo);
  std::thread node_thread([&] { node.run(); });
  epr::test::wait_until([&] { return !server.jobs().workers().empty(); }, 30s, 5ms);
  const epr::WorkerNodeStats before = node.stats();
  double window = 0, tracing = 0;
  ProcessCpu cpu0, cpu1;
  const bool ok = submit_and_wait(
      server.local_target(), s, n, &window, &tracing, [&] { cpu0 = process_cpu(::getpid(), "epr-trace"); },
      [&] { cpu1 = process_cpu(::getpid(), "epr-trace"); });
  const epr::WorkerNodeStats after = node.stats();
  node.stop();
  node_thread.join();
  server.shutdown();
  if (!ok) return false;
  out->seconds = window;
  out->utilisation = tracing / (double(wo.threads) * window);
  epr::WorkerTimeSplit others = after.time_others_tracing, none = after.time_none_tracing;
  others -= before.time_others_tracing;
  none -= before.time_none_tracing;
  const double total = others.total() + none.total();
  out->node_utilisation = total > 0 ? (others.tracing + none.tracing) / total : -1;
  out->split = others;
  out->split.tracing += none.tracing;
  out->split.leasing += none.leasing;
  out->split.waiting += none.waiting;
  out->split.submitting += none.submitting;
  out->split.other += none.other;
  out->cpu = after.cpu;
  out->cpu -= before.cpu;
  out->leased = after.tiles_leased - before.tiles_leased;
  out->committed = after.tiles_committed - before.tiles_committed;
  out->uncommitted = (after.tiles_duplicate + after.tiles_stale + after.tiles_abandoned + after.tiles_returned) -
                     (before.tiles_duplicate + before.tiles_stale + before.tiles_abandoned + before.tiles_returned);
  out->node_tracing = after.seconds_tracing - before.seconds_tracing;
  out->master_tracing = tracing;
  out->cpu_tracing = cpu1.named - cpu0.named;
  out->cpu_worker_other = (cpu1.total - cpu1.named) - (cpu0.total - cpu0.named);
  return true;
}

bool run_cluster(const Settings& s, int n, const fs::path& dir, Run* out) {
  std::vector<std::string> args = {EPR_MASTER_BIN,           "--listen",    "127.0.0.1:0", "--http", "", "--state-dir",
                                   (dir / "state").string(), "--log-level", "info"};
  if (s.reproject == "cpu") args.insert(args.end(), {"--reproject", "cpu"});
  if (s.pin) pin_to(0);  // inherited by the child
  epr::testing::Process master(args, dir / "master");
  if (s.pin) pin_to(1);
  const std::regex listening("epr-master listening on port ([0-9]+)");
  std::smatch m;
  std::string err;
  if (!epr::test::wait_until([&] { return std::regex_search(err = master.err(), m, listening) || !master.running(); },
                             120s) ||
      !master.running()) {
    std::fprintf(stderr, "epr-master did not start:\n%s\n", err.c_str());
    return false;
  }
  const std::string target = "127.0.0.1:" + m[1].str();
  const int threads = threads_of(s);
  epr::testing::Process worker({EPR_WORKER_BIN, "--master", target, "--threads", std::to_string(threads), "--cache-dir",
                                (dir / "cache").string(), "--name", "bench"},
                               dir / "worker");
  if (s.pin) pin_to(-1);
  // Registered: the master logs it.
  if (!epr::test::wait_until([&] { return master.err().find("registered") != std::string::npos; }, 60s, 5ms))
    std::fprintf(stderr, "(the worker's registration was not seen in the master's log; going on)\n");
  double window = 0, tracing = 0;
  int seen = 0;
  epr::WorkerTimeSplit before, after;
  bool split_ok = true;
  ProcessCpu w0, w1, m0, m1;
  const bool ok = submit_and_wait(
      target, s, n, &window, &tracing,
      [&] {
        split_ok &= worker_split(worker, &seen, &before);
        w0 = process_cpu(worker.pid(), "epr-trace");
        m0 = process_cpu(master.pid(), "");
      },
      [&] {
        w1 = process_cpu(worker.pid(), "epr-trace");
        m1 = process_cpu(master.pid(), "");
        split_ok &= worker_split(worker, &seen, &after);
      });
  worker.stop();
  master.stop();
  if (!ok) return false;
  out->seconds = window;
  out->utilisation = tracing / (double(threads) * window);
  out->cpu_tracing = w1.named - w0.named;
  out->cpu_worker_other = (w1.total - w1.named) - (w0.total - w0.named);
  out->cpu_master = m1.total - m0.total;
  if (split_ok) {
    after -= before;
    out->split = after;
    out->node_utilisation = after.total() > 0 ? after.tracing / after.total() : -1;
  } else {
    std::fprintf(stderr, "(the worker's time split was not seen in its log)\n");
  }
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Worker utilisation: one job against several queued (embedded and loopback cluster)"};
  Settings s;
  std::string setups = "embedded,cluster", jobs = "1,3";
  int reps = 3;
  app.add_option("--setups", setups, "embedded, embedded-socket, cluster (comma-separated)")->capture_default_str();
  app.add_option("--jobs", jobs, "jobs submitted at once, per series (the first is the baseline)")
      ->capture_default_str();
  app.add_option("--reps", reps, "runs per series (medians printed)")->capture_default_str();
  app.add_option("--size", s.size, "image side, pixels")->capture_default_str();
  app.add_option("--spp", s.spp, "samples per pixel")->capture_default_str();
  app.add_option("--ppr", s.ppr, "paths per pixel per round")->capture_default_str();
  app.add_option("--mode", s.mode, "pt, rp or skip")->capture_default_str();
  app.add_option("--scene", s.scene, "built-in scene of every job")->capture_default_str();
  app.add_option("--reproject", s.reproject, "cpu or gl")->capture_default_str();
  app.add_option("--threads", s.threads, "tracing threads of the worker (0: all cores; 1 with --pin)")
      ->capture_default_str();
  app.add_flag("--pin", s.pin,
               "cluster: epr-master on CPU 0 and epr-worker on CPU 1 (sched_setaffinity), so that the master's "
               "threads do not take the tracing threads' core");
  app.add_flag("--cpu-split", s.cpu_split,
               "embedded: also split the tracing threads' CPU seconds by activity (reading their CPU clocks at "
               "every change moves preemptions to the tiles' hand-offs: a diagnostic that changes the figures)");
  CLI11_PARSE(app, argc, argv);
  for (const std::string& setup : split(setups))
    if (setup != "embedded" && setup != "embedded-socket" && setup != "cluster") {
      std::fprintf(stderr, "utilisation_bench: unknown set-up '%s' (embedded, embedded-socket, cluster)\n",
                   setup.c_str());
      return 2;
    }
  epr::set_log_level("warn");
  const std::vector<std::string> series = split(jobs);
  std::printf("# util = workers' tracing s / (threads x window), window = first submit .. last job done\n");
  std::printf("# thread util = the worker's tracing threads' time tracing / their wall time over the window\n");
  std::printf("# %s, %dx%d, spp %d, k %d, %s, %s reprojector, %d tracing threads, %d reps%s\n", s.scene.c_str(), s.size,
              s.size, s.spp, s.ppr, s.mode.c_str(), s.reproject.c_str(), threads_of(s), reps,
              s.pin ? ", cluster pinned: master CPU 0, worker CPU 1" : "");
  std::printf("%-15s %5s %4s %9s %10s %12s %6s\n", "setup", "jobs", "rep", "seconds", "util", "thread util", "load");
  std::map<std::string, std::map<std::string, std::vector<double>>> util, node_util;
  const fs::path dir = fs::temp_directory_path() / ("epr-utilisation-bench-" + std::to_string(::getpid()));
  for (int rep = 0; rep < reps; ++rep) {
    for (const std::string& setup : split(setups)) {
      for (const std::string& n : series) {  // alternated, so that drifting load hits every series alike
        fs::remove_all(dir);
        fs::create_directories(dir);
        Run r;
        const bool ok = setup == "cluster" ? run_cluster(s, std::stoi(n), dir, &r)
                                           : run_embedded(s, std::stoi(n), dir, setup == "embedded", &r);
        if (!ok) {
          fs::remove_all(dir);
          return 1;
        }
        util[setup][n].push_back(r.utilisation);
        if (r.node_utilisation >= 0) node_util[setup][n].push_back(r.node_utilisation);
        std::printf("%-15s %5s %4d %9.2f %9.1f%% %11.1f%% %6.2f\n", setup.c_str(), n.c_str(), rep, r.seconds,
                    100 * r.utilisation, r.node_utilisation >= 0 ? 100 * r.node_utilisation : -1.0, load_average());
        if (r.split.total() > 0) {
          const double t = r.split.total() / 100;
          std::printf("          split: tracing %.1f%% leasing %.1f%% waiting %.1f%% submitting %.1f%% other %.1f%%\n",
                      r.split.tracing / t, r.split.leasing / t, r.split.waiting / t, r.split.submitting / t,
                      r.split.other / t);
          if (r.cpu.total() > 0)  // embedded: the threads' own CPU seconds, against their wall seconds
            std::printf("          cpu s: tracing %.2f (wall %.2f) other %.2f (wall %.2f)\n", r.cpu.tracing,
                        r.split.tracing, r.cpu.other, r.split.other);
        }
        if (r.cpu_tracing >= 0) {  // who had the CPUs, as shares of the tracing threads' wall time
          const double tw = double(threads_of(s)) * r.seconds / 100;
          if (setup == "cluster")
            std::printf(
                "          cpu / (threads x window): tracing threads %.1f%%, worker's other threads %.1f%%, "
                "master %.1f%%%s\n",
                r.cpu_tracing / tw, r.cpu_worker_other / tw, r.cpu_master / tw, s.pin ? " (on its own CPU)" : "");
          else
            std::printf(
                "          cpu / (threads x window): tracing threads %.1f%%, the process's other threads "
                "(master, worker's others, client) %.1f%%\n",
                r.cpu_tracing / tw, r.cpu_worker_other / tw);
        }
        if (r.node_tracing >= 0)  // the tiles' own timers against the threads' time inside tiles
          std::printf(
              "          tiles: leased %llu committed %llu not committed %llu; tile timers: node %.2f s, "
              "master %.2f s\n",
              (unsigned long long)r.leased, (unsigned long long)r.committed, (unsigned long long)r.uncommitted,
              r.node_tracing, r.master_tracing);
        std::fflush(stdout);
      }
    }
  }
  fs::remove_all(dir);
  std::printf("\n# medians\n%-15s", "setup");
  for (const auto& n : series) std::printf(" %9s", (n + " job" + (n == "1" ? "" : "s")).c_str());
  for (size_t i = 1; i < series.size(); ++i) std::printf(" %9s", (series[i] + "/" + series[0]).c_str());
  std::printf("   (thread util)\n");
  for (const auto& [setup, by_n] : util) {
    std::printf("%-15s", setup.c_str());
    for (const auto& n : series) std::printf(" %8.1f%%", 100 * median(by_n.at(n)));
    for (size_t i = 1; i < series.size(); ++i)
      std::printf(" %9.3f", median(by_n.at(series[i])) / median(by_n.at(series[0])));
    if (node_util.count(setup)) {
      std::printf("  ");
      for (const auto& n : series) std::printf(" %5.1f%%", 100 * median(node_util[setup][n]));
    }
    std::printf("\n");
  }
  return 0;
}
