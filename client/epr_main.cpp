// epr: the command-line client. `epr render` runs the whole system on this machine.
#include <fmt/format.h>
#include <pthread.h>
#include <signal.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <atomic>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <optional>
#include <thread>

#include "client/embedded_render.h"
#include "client/local_render.h"
#include "client/remote_commands.h"
#include "client/render_flags.h"
#include "client/trace_path.h"
#include "common/address.h"
#include "common/log.h"
#include "common/tile.h"
#include "master/memory_estimate.h"

namespace {

using namespace epr;

// SIGINT and SIGTERM during an embedded render: the first cancels the render, which then stops its
// workers and master and removes the master's private folder on the way out; a second one exits at
// once. The signals are blocked in every thread (the mask is set before any thread starts and is
// inherited) and taken by one thread that waits for them, never by a handler.
class InterruptWatch {
 public:
  explicit InterruptWatch(CallCanceller& canceller) {
    sigemptyset(&signals_);
    sigaddset(&signals_, SIGINT);
    sigaddset(&signals_, SIGTERM);
    pthread_sigmask(SIG_BLOCK, &signals_, nullptr);
    thread_ = std::thread([this, &canceller] {
      while (!done_) {
        const timespec poll{0, 100'000'000};
        const int sig = sigtimedwait(&signals_, nullptr, &poll);
        if (sig <= 0) continue;
        if (signal_) std::_Exit(128 + sig);
        signal_ = sig;
        std::fprintf(stderr, "\nepr render: %s: stopping (send it again to exit at once)\n",
                     sig == SIGINT ? "SIGINT" : "SIGTERM");
        canceller.cancel();
      }
    });
  }
  ~InterruptWatch() {
    done_ = true;
    thread_.join();
  }
  int signal() const { return signal_; }  // the first signal taken; 0: none

 private:
  sigset_t signals_;
  std::atomic<bool> done_{false};
  std::atomic<int> signal_{0};
  std::thread thread_;
};

// Makes the folder of the output prefix and checks that files can be written there, before a render
// whose outputs would otherwise be lost at its end. The reason when that is impossible.
std::optional<std::string> prepare_output_folder(const std::string& prefix) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::path(prefix).parent_path();
  std::error_code ec;
  if (!dir.empty() && !fs::is_directory(dir, ec)) {
    fs::create_directories(dir, ec);
    if (ec) return fmt::format("cannot create the output folder '{}': {}", dir.string(), ec.message());
  }
  const fs::path probe = (dir.empty() ? fs::path(".") : dir) / fmt::format(".epr-write-check-{}", ::getpid());
  errno = 0;
  bool ok = false;
  {
    std::ofstream f(probe);
    ok = bool(f);
  }
  const std::string why = errno ? std::strerror(errno) : "cannot create a file";
  fs::remove(probe, ec);
  if (!ok) return fmt::format("cannot write into the output folder '{}': {}", dir.empty() ? "." : dir.string(), why);
  return std::nullopt;
}

void print_progress(const RoundProgress& p, int spp, bool tty) {
  const int width = 30;
  const double frac = std::min(1.0, p.mean_spp / std::max(1, spp));
  const int filled = int(frac * width);
  const std::string bar = std::string(size_t(filled), '#') + std::string(size_t(width - filled), '.');
  const std::string eta = p.eta_seconds >= 0 ? fmt::format("{:.0f}s", p.eta_seconds) : "?";
  const std::string line =
      fmt::format("[{}] round {:3d}  spp {:6.1f}/{} (min {:.0f})  M' {:5.1f}  active {:3.0f}%  {:6.1f}s  ETA {}", bar,
                  p.round, p.mean_spp, spp, p.min_spp, p.mean_mprime, 100 * p.pixels_active, p.seconds, eta);
  std::fprintf(stderr, tty ? "\r%s" : "%s\n", line.c_str());
  std::fflush(stderr);
}

void print_status(const v1::JobStatus& s, bool tty) {
  const int width = 30;
  const double target = std::max(1u, s.target_spp());
  const double frac = std::min(1.0, s.spp_mean() / target);
  const int filled = int(frac * width);
  const std::string bar = std::string(size_t(filled), '#') + std::string(size_t(width - filled), '.');
  const std::string eta = s.eta_seconds() >= 0 ? fmt::format("{:.0f}s", s.eta_seconds()) : "?";
  const double pixels = double(s.effective().width()) * s.effective().height();
  const std::string line =
      fmt::format("[{}] round {:3d}  spp {:6.1f}/{} (min {})  M' {:5.1f}  skipped {:3.0f}%  {:6.1f}s  ETA {}", bar,
                  s.round(), s.spp_mean(), s.target_spp(), s.spp_min(), s.reprojected_per_pixel_mean(),
                  pixels > 0 ? 100.0 * s.pixels_skipped() / pixels : 0.0, s.seconds_elapsed(), eta);
  std::fprintf(stderr, tty ? "\r%s" : "%s\n", line.c_str());
  std::fflush(stderr);
}

// `epr render --single-process --trace-path X,Y,N`: one path traced and printed, nothing written.
int run_trace_path(const RenderOptions& o, bool single_process, const std::string& ref_text) {
  std::string why;
  const std::optional<PathRef> ref = parse_path_ref(ref_text, &why);
  if (!ref) {
    std::fprintf(stderr, "epr render: --trace-path: %s\n", why.c_str());
    return 2;
  }
  if (!single_process) {
    std::fprintf(stderr,
                 "epr render: --trace-path replays a path of the single-process render: add --single-process\n");
    return 2;
  }
  try {
    trace_path(o, *ref, stdout);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "epr render: %s\n", e.what());
    return 1;
  }
  return 0;
}

int run_render(RenderOptions& o, const std::map<std::string, std::string>& extra, bool single_process, int workers,
               const std::string& http, double timeout_seconds, const std::string& memory_budget,
               const std::string& trace_path_ref) {
  finish_options(o, extra);
  if (auto err = output_prefix_error(o.out)) {
    std::fprintf(stderr, "epr render: --out: %s\n", err->c_str());
    return 2;
  }
  if (o.tile_size == 0) {  // --tile not given
    EmbeddedOptions eo;    // the tracing threads this render starts (one "worker" when single-process)
    eo.workers = single_process ? 1 : workers;
    o.tile_size = auto_tile_size(o.width, o.height, eo.workers * embedded_threads_per_worker(o, eo));
    o.taper_tiles = true;
  }
  if (auto err = o.validate()) {
    std::fprintf(stderr, "epr render: %s\n", err->c_str());
    return 2;
  }
  if (!trace_path_ref.empty()) return run_trace_path(o, single_process, trace_path_ref);
  // A frame this machine cannot hold is refused before anything starts, with what it would need.
  const uint64_t budget = memory_budget.empty()  ? default_memory_budget()
                          : memory_budget == "0" ? 0
                                                 : *parse_byte_size(memory_budget);
  if (auto err = memory_budget_error(o, /*checkpoints=*/false, budget)) {
    std::fprintf(stderr, "epr render: %s (--memory-budget)\n", err->c_str());
    return 2;
  }
  if (auto err = prepare_output_folder(o.out)) {
    std::fprintf(stderr, "epr render: %s (--out %s)\n", err->c_str(), o.out.c_str());
    return 2;
  }
  const bool tty = isatty(STDERR_FILENO);
  try {
    if (single_process) {
      const RenderOutputs out = render_local(o, [&](const RoundProgress& p) { print_progress(p, o.spp, tty); });
      if (tty) std::fprintf(stderr, "\n");
      write_outputs(o.out, out);
      std::fprintf(stderr, "wrote %s.exr, %s.png, %s.json (%.2f s, %.0f paths/s)\n", o.out.c_str(), o.out.c_str(),
                   o.out.c_str(), out.stats.value("seconds", 0.0), out.stats.value("paths_per_second", 0.0));
      if (auto w = nonfinite_warning(out.stats.value("nonfinite_dropped", uint64_t(0)),
                                     out.stats.value("paths", uint64_t(0))))
        std::fprintf(stderr, "epr render: warning: %s\n", w->c_str());
      return 0;
    }
    remove_stale_state_dirs();  // what killed renders left behind
    CallCanceller canceller;
    InterruptWatch interrupts(canceller);
    EmbeddedOptions eo;
    eo.workers = workers;
    eo.http_listen = http;
    eo.timeout_seconds = timeout_seconds;
    eo.memory_budget_bytes = budget;
    eo.canceller = &canceller;
    std::optional<EmbeddedResult> result;
    try {
      result = render_embedded(
          o, eo, [&](const v1::JobStatus& s) { print_status(s, tty); },
          [&](const std::string& target, const std::string& dashboard) {
            std::fprintf(stderr, "master on %s with %d local worker(s)\n", target.c_str(), workers);
            if (!dashboard.empty()) std::fprintf(stderr, "dashboard: %s\n", dashboard.c_str());
          });
    } catch (const std::exception&) {
      if (interrupts.signal()) {
        std::fprintf(stderr, "epr render: stopped by %s; nothing written\n",
                     interrupts.signal() == SIGINT ? "SIGINT" : "SIGTERM");
        return 128 + interrupts.signal();
      }
      throw;
    }
    const EmbeddedResult& r = *result;
    if (tty) std::fprintf(stderr, "\n");
    if (r.status.state() != v1::JOB_STATE_DONE) {
      std::fprintf(stderr, "epr render: the job ended %s: %s\n", v1::JobState_Name(r.status.state()).c_str(),
                   r.status.error_message().c_str());
      return 1;
    }
    std::string names;
    for (const auto& f : r.files) names += (names.empty() ? "" : ", ") + f.path;
    std::fprintf(stderr, "wrote %s (%.2f s, %llu paths, %llu skipped)\n", names.c_str(), r.status.seconds_elapsed(),
                 static_cast<unsigned long long>(r.status.paths_traced()),
                 static_cast<unsigned long long>(r.status.paths_skipped()));
    if (auto w = nonfinite_warning(r.status.non_finite_dropped(), r.status.paths_traced()))
      std::fprintf(stderr, "epr render: warning: %s\n", w->c_str());
  } catch (const OutputError& e) {  // refused before anything was rendered or written
    std::fprintf(stderr, "epr render: %s\n", e.what());
    return 2;
  } catch (const std::exception& e) {
    if (tty) std::fprintf(stderr, "\n");
    std::fprintf(stderr, "epr render: %s\n", e.what());
    return 1;
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"eprfarm: path tracing accelerated by eye path reprojection"};
  app.require_subcommand(1);
  std::string log_level = "warn";
  app.add_option("--log-level", log_level, "trace, debug, info, warn, error or off")
      ->check(CLI::IsMember({"trace", "debug", "info", "warn", "error", "off"}));

  RenderOptions render_opts;
  std::map<std::string, std::string> render_extra;
  CLI::App* render = app.add_subcommand("render", "render a scene on this machine (embedded master and workers)");
  add_render_flags(render, render_opts, render_extra);
  bool single_process = false;
  int local_workers = 1;
  render->add_flag("--single-process", single_process,
                   "trace and reproject in this process without gRPC (the reference the cluster must equal)");
  render->add_option("--workers", local_workers, "local worker nodes (each uses all cores / workers)")
      ->check(CLI::Range(1, 64))
      ->capture_default_str();
  double render_timeout = 0;
  render
      ->add_option("--timeout", render_timeout,
                   "seconds the whole render may take (scene upload, rounds, results); 0: no limit")
      ->check(CLI::Range(0.0, 1e9))
      ->capture_default_str();
  std::string render_http = "127.0.0.1:0";
  render
      ->add_option("--http", render_http,
                   "the embedded master's dashboard address HOST:PORT (port 0: a free one; \"\" disables it)")
      ->check([](const std::string& v) -> std::string {
        std::string why;
        return v.empty() || parse_address(v, {.port_zero = true, .empty_host = true}, &why) ? ""
                                                                                            : "'" + v + "': " + why;
      })
      ->capture_default_str();
  std::string render_memory_budget;
  render
      ->add_option("--memory-budget", render_memory_budget,
                   "refuse a frame whose estimated master memory exceeds this: bytes, or with a suffix K, M, G, T "
                   "(8G); 0: no limit (default: 80% of this machine's physical memory)")
      ->check([](const std::string& v) -> std::string {
        return v == "0" || parse_byte_size(v) ? "" : "expected bytes like 8G, 512M or 0, got '" + v + "'";
      });
  std::string trace_path_ref;
  render->add_option("--trace-path", trace_path_ref,
                     "with --single-process: trace only path SAMPLE of pixel X,Y (X,Y,SAMPLE, as a worker's log of a "
                     "dropped non-finite sample gives it, with its --seed) and print its vertices; writes no file");
  RemoteCommands remote(app);  // submit, watch, get, list, cancel

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  set_log_level(log_level);
  if (auto code = remote.run()) return *code;
  try {
    if (render->parsed())
      return run_render(render_opts, render_extra, single_process, local_workers, render_http, render_timeout,
                        render_memory_budget, trace_path_ref);
  } catch (const CLI::ValidationError& e) {
    std::fprintf(stderr, "epr: %s\n", e.what());
    return 2;
  }
  return 0;
}
