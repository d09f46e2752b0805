// epr-worker: a render farm worker. Connects to one or several epr-masters, leases tiles, traces them,
// streams the results back, until SIGTERM / SIGINT (every master's leases are given back) or the only
// master's Shutdown. A second signal while stopping exits at once. Exits 1 with the reasons when every
// master refuses the worker for good (a name or thread count over its limits, a wrong token).
// SIGUSR1 prints one line to stderr: the tracing threads' wall time so far by activity
// (WorkerNodeStats::time_*, thread-seconds), "epr-worker time: threads T tracing S leasing S waiting S
// submitting S other S".
#include <pthread.h>
#include <signal.h>

#include <CLI/CLI.hpp>
#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <stdexcept>
#include <thread>

#include "common/log.h"
#include "wire/rpc/master_list.h"
#include "worker/worker_node.h"

int main(int argc, char** argv) {
  epr::WorkerNodeOptions opts;
  std::string log_level = "info";
  CLI::App app{"epr-worker: traces tiles for an epr-master (eye path reprojection render farm)"};
  app.add_option("--master", opts.master,
                 "epr-master's gRPC address, HOST:PORT; or several, comma-separated (HOST:PORT, dns:///NAME:PORT): "
                 "a name that resolves to several addresses (a headless Service) is one master per address")
      ->capture_default_str();
  app.add_option("--resolve-interval-ms", opts.resolve_interval_ms,
                 "how often master names are resolved again (also soon after a master fails)")
      ->check(CLI::Range(100, 3600000))
      ->capture_default_str();
  app.add_option("--threads", opts.threads, "tracing threads, 0 = all cores")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  app.add_option("--name", opts.name, "name shown on the master's dashboard (default HOSTNAME-PID)");
  app.add_option("--cache-dir", opts.cache_dir,
                 "scene cache folder (a private temporary one, removed at exit, when it cannot be written)")
      ->capture_default_str();
  uint64_t cache_max_mb = opts.cache_max_bytes >> 20;
  app.add_option("--cache-max-mb", cache_max_mb, "scene cache size bound, MiB: least recently used scenes go first")
      ->check(CLI::Range(uint64_t(1), uint64_t(1) << 30))
      ->capture_default_str();
  app.add_flag("--tls", opts.tls, "connect to the master over TLS");
  app.add_option("--ca-file", opts.ca_file, "PEM roots that sign the master's certificate (default: the system's)");
  app.add_option("--tls-cert", opts.cert_file, "PEM client certificate, for masters that require one");
  app.add_option("--tls-key", opts.key_file, "PEM key of --tls-cert");
  app.add_option("--token-file", opts.token_file,
                 "file holding the bearer token for the master (default: the EPR_TOKEN environment variable)")
      ->check(CLI::ExistingFile);
  app.add_option("--max-backoff-ms", opts.max_backoff_ms, "longest wait between reconnection attempts, ms")
      ->check(CLI::Range(10, 600000))
      ->capture_default_str();
  app.add_option("--log-level", log_level, "trace, debug, info, warn, error or off")
      ->check(CLI::IsMember({"trace", "debug", "info", "warn", "error", "off"}))
      ->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  try {  // the addresses, by the rules every program follows (common/address.h)
    epr::parse_master_list(opts.master);
  } catch (const std::invalid_argument& e) {
    std::fprintf(stderr, "epr-worker: %s\n", e.what());
    return 2;
  }
  opts.cache_max_bytes = cache_max_mb << 20;
  epr::set_log_level(log_level);
  auto log = epr::logger("worker");

  // Signals go to one thread that waits for them (sigwait), never to a handler: stop() takes locks.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGUSR1);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);  // inherited by every thread started below

  try {
    epr::WorkerNode node(opts);
    std::atomic<bool> done{false};
    std::thread signal_thread([&] {
      bool stopping = false;
      while (!done) {
        const timespec timeout{0, 200'000'000};
        const int sig = sigtimedwait(&signals, nullptr, &timeout);
        if (sig <= 0) continue;
        if (sig == SIGUSR1) {
          const epr::WorkerNodeStats st = node.stats();
          epr::WorkerTimeSplit t = st.time_others_tracing;
          t += st.time_none_tracing;
          std::fprintf(
              stderr, "epr-worker time: threads %d tracing %.6f leasing %.6f waiting %.6f submitting %.6f other %.6f\n",
              node.threads(), t.tracing, t.leasing, t.waiting, t.submitting, t.other);
          std::fflush(stderr);
          continue;
        }
        if (stopping) {
          log->warn("second signal: exiting without returning leases");
          std::_Exit(128 + sig);
        }
        log->info("{}: returning leases and stopping (send it again to exit at once)",
                  sig == SIGINT ? "SIGINT" : "SIGTERM");
        stopping = true;
        node.stop();
      }
    });
    const std::optional<std::string> refused = node.run();
    done = true;
    signal_thread.join();
    if (refused) {
      std::fprintf(stderr, "epr-worker: %s\n", refused->c_str());
      return 1;
    }
  } catch (const std::exception& e) {
    log->error("{}", e.what());
    return 1;
  }
  return 0;
}
