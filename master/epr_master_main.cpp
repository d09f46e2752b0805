// epr-master: the reprojection master of an eprfarm cluster. SIGTERM or SIGINT drains it (the open
// rounds finish and are checkpointed, no new one opens; JobManager::drain_and_checkpoint, at most
// --drain-timeout) and then stops it with exit code 0; a second signal cuts the drain short.
#include <fmt/format.h>

#include <CLI/CLI.hpp>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <optional>
#include <string>
#include <thread>

#include "common/address.h"
#include "common/limits.h"
#include "common/log.h"
#include "master/memory_estimate.h"
#include "master/server/master_name.h"
#include "master/server/master_server.h"
#include "master/server/state_dir_lock.h"
#include "wire/rpc/token.h"

namespace {
volatile std::sig_atomic_t g_stop = 0;

// --checkpoint-interval: "auto" (-1, MasterOptions' automatic interval) or seconds in [0, 86400].
std::optional<double> checkpoint_interval_seconds(const std::string& v) {
  if (v == "auto") return -1;
  try {
    size_t used = 0;
    const double s = std::stod(v, &used);
    if (used == v.size() && s >= 0 && s <= 86400) return s;
  } catch (const std::exception&) {
  }
  return std::nullopt;
}

void on_signal(int) { g_stop = g_stop + 1; }  // the number of signals received
}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"epr-master: job queue, tile leases and reprojection (OSMesa) for an eprfarm cluster"};
  epr::MasterServerOptions o;
  std::string log_level = "info";
  app.add_option("--listen", o.listen, "gRPC listen address for clients and workers")->capture_default_str();
  o.http_listen = "0.0.0.0:8080";
  app.add_option("--http", o.http_listen,
                 "monitoring HTTP address HOST:PORT (dashboard, JSON, /metrics); \"\" disables it")
      ->capture_default_str();
  app.add_option("--state-dir", o.jobs.state_dir,
                 "folder for results, scenes and job checkpoints; a master restarted on the same folder resumes its "
                 "jobs; one master per folder (it is locked while the master runs) (default: a temp folder, no "
                 "checkpoints, removed when the master exits)");
  std::string name;
  app.add_option("--name", name,
                 "this master's name, the prefix of its job ids (NAME.j000123-abcd) by which clients given several "
                 "masters find a job: 1 to 40 of A-Z a-z 0-9 _ - (default: the name saved in --state-dir, else "
                 "HOSTNAME-PORT, saved there for the next start)")
      ->check([](const std::string& v) -> std::string {
        return epr::is_valid_master_name(v) ? "" : "1 to 40 of A-Z a-z 0-9 _ - (no dots), got '" + v + "'";
      });
  app.add_flag("!--no-checkpoints", o.jobs.checkpoints,
               "do not checkpoint jobs (a restarted master then starts unfinished jobs again)");
  std::string checkpoint_interval = "auto";
  app.add_option("--checkpoint-interval", checkpoint_interval,
                 "seconds at least between a job's round checkpoints; 0: after every round; auto: 20x what the "
                 "job's last checkpoint cost, so that checkpoints take at most ~5% of the master's time")
      ->check([](const std::string& v) -> std::string {
        return checkpoint_interval_seconds(v) ? "" : "expected auto or seconds in [0, 86400], got '" + v + "'";
      })
      ->capture_default_str();
  double drain_timeout_s = 60;
  app.add_option("--drain-timeout", drain_timeout_s,
                 "seconds at most that SIGTERM waits for the running jobs' open rounds to finish and be "
                 "checkpointed before the master exits (0: exit at once; jobs resume from their last checkpoint)")
      ->check(CLI::Range(0.0, 3600.0))
      ->capture_default_str();
  app.add_option("--lease-timeout-ms", o.jobs.lease_timeout_ms, "a tile lease not extended for this long is re-queued")
      ->capture_default_str();
  app.add_option("--heartbeat-ms", o.jobs.heartbeat_interval_ms, "heartbeat interval asked of workers")
      ->capture_default_str();
  app.add_option("--reproject", o.jobs.reproject_backend_override,
                 "force the reprojector: cpu (default: what each job asks)")
      ->check(CLI::IsMember({"", "cpu"}));
  app.add_option("--max-queued-vertices", o.jobs.max_queued_vertices, "back-pressure bound of the commit queue")
      ->capture_default_str();
  app.add_option("--reproject-batch-records", o.jobs.reproject_batch_records,
                 "records (vertices) of queued tiles of one round applied in one reprojector call; 0: one call per "
                 "tile")
      ->capture_default_str();
  std::string memory_budget;
  app.add_option("--memory-budget", memory_budget,
                 "jobs run side by side while their estimated master memory fits this; a job that exceeds it "
                 "alone is refused at submission: bytes, or with a suffix K, M, G, T (8G); 0: no limit, one job "
                 "at a time (default: 80% of this machine's physical memory)")
      ->check([](const std::string& v) -> std::string {
        return v == "0" || epr::parse_byte_size(v) ? "" : "expected bytes like 8G, 512M or 0, got '" + v + "'";
      });
  app.add_option("--max-image-side", o.jobs.max_image_side, "jobs with a wider or taller image are refused")
      ->check(CLI::Range(1, 16384))
      ->capture_default_str();
  app.add_option("--max-spp", o.jobs.max_spp, "jobs asking for more samples per pixel are refused")
      ->check(CLI::Range(1, 1000000))
      ->capture_default_str();
  app.add_option("--max-scene-bytes", o.jobs.max_scene_bytes,
                 "scene bundles (inline or uploaded) over this size are refused")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--max-running-jobs", o.jobs.max_running_jobs,
                 "jobs running at once at most (the memory budget decides below that)")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--max-jobs", o.jobs.max_jobs, "jobs kept; finished ones beyond this are forgotten oldest first")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--speculative-factor", o.jobs.speculative_factor,
                 "copy a tile to an idle worker once its lease runs this many times the round's median tile time "
                 "(0: never)")
      ->check(CLI::Range(0.0, 1000.0))
      ->capture_default_str();
  app.add_option("--speculative-floor-ms", o.jobs.speculative_floor_ms, "... and at least this long")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  app.add_option("--max-worker-failures", o.jobs.max_worker_failures,
                 "failed tiles after which a worker gets no more tiles of that job (0: never block)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  app.add_option("--max-tile-losses", o.jobs.max_tile_losses,
                 "a job fails once one of its tiles has lost its worker this many times (a lease expired: the "
                 "worker crashed or vanished), rather than crash worker after worker (0: never)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  // Frame windows (DESIGN.md "Frame windows"), ranges in common/limits.h.
  auto in_range = [](const epr::Range<double>& r) {
    return [r](const std::string& v) -> std::string {
      try {
        size_t used = 0;
        const double x = std::stod(v, &used);
        if (used == v.size()) return r.check(x).value_or("");
      } catch (const std::exception&) {
      }
      return fmt::format("{}: expected a number, got '{}'", r.what, v);
    };
  };
  double window_run_wait_s = o.jobs.window_run_wait_ms / 1000.0;
  app.add_option("--window-run-wait", window_run_wait_s,
                 "seconds a window run waits for all its frames to be queued before it starts with those there")
      ->check(in_range(epr::limits::kWindowRunWaitSeconds))
      ->capture_default_str();
  app.add_option("--window-cut-share", o.jobs.window_cut_share,
                 "a window never spans a cut: neighbouring frames of a run whose views share less than this "
                 "fraction exchange no vertices, nor do frames on either side of them (0: no cuts)")
      ->check(in_range(epr::limits::kWindowCutShare))
      ->capture_default_str();
  std::string token_file;
  app.add_option("--token-file", token_file,
                 "file holding the bearer token clients and workers must send (else $EPR_TOKEN; none: no check)");
  app.add_option("--tls-cert", o.tls_cert_file, "PEM certificate chain: serve gRPC over TLS");
  app.add_option("--tls-key", o.tls_key_file, "PEM private key of --tls-cert");
  app.add_option("--tls-client-ca", o.tls_client_ca_file, "PEM CA: require client certificates that chain to it");
  app.add_option("--log-level", log_level, "trace, debug, info, warn, error or off")
      ->check(CLI::IsMember({"trace", "debug", "info", "warn", "error", "off"}))
      ->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  epr::set_log_level(log_level);
  o.jobs.checkpoint_interval_s = *checkpoint_interval_seconds(checkpoint_interval);
  o.jobs.window_run_wait_ms = int(std::lround(window_run_wait_s * 1000));
  o.jobs.memory_budget_bytes = memory_budget.empty()  ? epr::default_memory_budget()
                               : memory_budget == "0" ? 0
                                                      : *epr::parse_byte_size(memory_budget);

  // Addresses by the rules every program follows (common/address.h): a port outside 0-65535 is an
  // error, never taken modulo 65536 by gRPC. A unix: socket is gRPC's own.
  try {
    if (o.listen.rfind("unix:", 0) != 0) epr::require_address("--listen", o.listen, {.port_zero = true});
    if (!o.http_listen.empty()) epr::require_address("--http", o.http_listen, {.port_zero = true, .empty_host = true});
  } catch (const std::invalid_argument& e) {
    std::fprintf(stderr, "epr-master: %s\n", e.what());
    return 2;
  }
  if ((o.tls_cert_file.empty()) != (o.tls_key_file.empty())) {
    std::fprintf(stderr, "epr-master: --tls-cert and --tls-key go together\n");
    return 2;
  }
  try {
    if (auto token = epr::rpc::configured_token(token_file)) o.token = *token;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "epr-master: %s\n", e.what());
    return 2;
  }
  std::signal(SIGTERM, on_signal);
  std::signal(SIGINT, on_signal);
  try {
    // One master per state directory: a second one would write into the first one's jobs.
    std::optional<epr::StateDirLock> lock;
    if (!o.jobs.state_dir.empty()) lock.emplace(o.jobs.state_dir);
    o.jobs.name = epr::choose_master_name(name, o.jobs.state_dir, epr::listen_port(o.listen));
    epr::MasterServer server(o);
    std::fprintf(stderr, "epr-master listening on port %d\n", server.port());
    std::fprintf(stderr, "master name: %s (job ids %s.j...)\n", o.jobs.name.c_str(), o.jobs.name.c_str());
    std::fprintf(stderr, "window runs: wait %g s for their frames; a cut where neighbouring views share under %g\n",
                 o.jobs.window_run_wait_ms / 1000.0, o.jobs.window_cut_share);
    if (server.http_port()) std::fprintf(stderr, "dashboard: %s\n", server.dashboard_url().c_str());
    while (!g_stop) std::this_thread::sleep_for(std::chrono::milliseconds(100));
    if (drain_timeout_s > 0)
      server.jobs().drain_and_checkpoint(std::chrono::milliseconds(int64_t(drain_timeout_s * 1000)),
                                         [] { return g_stop > 1; });
    server.shutdown();
  } catch (const std::exception& e) {
    std::fprintf(stderr, "epr-master: %s\n", e.what());
    return 1;
  }
  return 0;
}
