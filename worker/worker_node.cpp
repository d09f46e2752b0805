// The worker node: registration and reconnection (run), the tracing threads (tracing_loop,
// process_tile) and the per-job state they share. The calls to the master are the session's
// (worker/master_session.h); see worker_node.h for the whole picture.
#include "worker/worker_node.h"

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <future>
#include <map>
#include <random>
#include <stdexcept>
#include <thread>
#include <tuple>
#include <vector>

#include "common/check.h"
#include "common/log.h"
#include "common/scene_loader.h"
#include "common/thread_name.h"
#include "wire/rpc/status.h"
#include "wire/rpc/token.h"
#include "worker/backoff.h"
#include "worker/courier.h"
#include "worker/job_cache.h"
#include "worker/master_session.h"
#include "worker/scene_fetch.h"
#include "worker/tile_lease.h"
#include "worker/time_accounting.h"

namespace epr {
namespace {

constexpr int kMinWaitMs = 5, kMaxWaitMs = 60000;  // bounds on the master's Wait.retry_after_ms
constexpr size_t kMaxFailingJobs = 256;            // job failure records kept

std::string default_name() {
  char host[256] = {};
  if (::gethostname(host, sizeof host - 1) != 0) std::snprintf(host, sizeof host, "worker");
  return fmt::format("{}-{}", host, ::getpid());
}

}  // namespace

struct WorkerNode::Impl {
  explicit Impl(WorkerNodeOptions o)
      : opts(std::move(o)),
        log(logger("worker")),
        threads(opts.threads > 0 ? opts.threads : int(std::max(1u, std::thread::hardware_concurrency()))),
        cache(opts.cache_dir),
        config{opts.master,
               {opts.tls, opts.ca_file, opts.cert_file, opts.key_file},
               rpc::configured_token(opts.token_file).value_or(""),
               opts.name.empty() ? default_name() : opts.name,
               threads,
               cache.path(),
               opts.min_backoff_ms,
               opts.max_backoff_ms},
        jobs(size_t(std::max(1, opts.max_cached_jobs)),
             [this](const v1::SceneRef& ref) { return load_scene_for(ref); }),
        rng(std::random_device{}()) {
    if (!cache.fallback_reason().empty())
      log->warn("scene cache: {}; using {} instead (removed when the worker ends)", cache.fallback_reason(),
                cache.path());
    trim_scene_cache(cache.path(), opts.cache_max_bytes);  // the bound may be lower than last time
  }

  WorkerNodeOptions opts;
  std::shared_ptr<spdlog::logger> log;
  int threads;
  CacheRoot cache;
  MasterSession::Config config;
  JobCache jobs;
  StopSignal signal;
  NodeCounters counters;
  TimeAccounting time;

  Mutex mu;
  std::condition_variable_any cv;  // run() ends
  bool running EPR_GUARDED_BY(mu) = false;
  std::shared_ptr<MasterSession> session EPR_GUARDED_BY(mu);  // from before Register until the session's threads end
  std::string worker_id EPR_GUARDED_BY(mu);
  std::map<std::string, int> job_failures EPR_GUARDED_BY(mu);  // job id -> consecutive failures to prepare it
  std::mt19937_64 rng EPR_GUARDED_BY(mu);

  void stop(const std::string& reason) EPR_EXCLUDES(mu) {
    signal.stop(reason);
    std::shared_ptr<MasterSession> s;
    {
      MutexLock lock(mu);
      s = session;
    }
    if (s) s->end(reason, /*lost=*/false);
  }

  // ---- scenes ------------------------------------------------------------------------------------

  Scene load_scene_for(const v1::SceneRef& ref) EPR_EXCLUDES(mu) {
    if (!ref.builtin().empty()) {
      SceneBundleData b;
      b.builtin = ref.builtin();
      if (content_hash(b) != ref.content_hash())
        throw std::runtime_error(
            fmt::format("built-in scene '{}' does not have content hash {}", ref.builtin(), ref.content_hash()));
      return load_scene(ref.builtin());
    }
    if (!is_content_hash(ref.content_hash()))
      throw std::runtime_error(
          fmt::format("scene reference '{}' is neither a built-in nor a content hash", ref.content_hash()));
    const std::string& root = cache.path();
    std::optional<std::string> entry = cached_scene_entry(root, ref.content_hash());
    if (entry) {
      touch_cached_scene(root, ref.content_hash());
    } else {
      std::shared_ptr<MasterSession> s;
      {
        MutexLock lock(mu);
        s = session;
      }
      if (!s || s->ending()) throw std::runtime_error("no master session to fetch the scene from");
      entry = s->fetch_scene(ref);
      for (const std::string& gone : trim_scene_cache(root, opts.cache_max_bytes, ref.content_hash()))
        log->info("scene cache over {} MiB: removed scene {} (least recently used)", opts.cache_max_bytes >> 20, gone);
    }
    return load_scene(*entry);
  }

  // Delay before leasing again after a job could not be prepared; grows with repeated failures.
  int job_failed(const std::string& job_id) EPR_EXCLUDES(mu) {
    MutexLock lock(mu);
    if (job_failures.size() > kMaxFailingJobs) job_failures.clear();
    const int n = job_failures[job_id]++;
    const double u = std::uniform_real_distribution<double>(0.0, 1.0)(rng);
    return backoff_delay_ms(n, 500, std::max(1000, opts.max_backoff_ms), u);
  }

  void job_ok(const std::string& job_id) EPR_EXCLUDES(mu) {
    MutexLock lock(mu);
    job_failures.erase(job_id);
  }

  // ---- tracing -----------------------------------------------------------------------------------

  // Traces a leased tile and hands the result to a background submission (`pending`: this thread's
  // submission in flight, at most one), so that the next tile is leased and traced while the master
  // receives this one.
  void process_tile(MasterSession& s, const v1::TileLease& lease, Courier& submitter, std::future<void>* pending,
                    ThreadActivity* activity) {
    ++counters.tiles_leased;
    const uint64_t id = lease.lease_id();
    auto h = s.hold(id);
    log->debug("lease {}: job {} round {} tile {}", id, lease.job_id(), lease.round(), lease.tile_index());
    // A lease this worker cannot trace goes back as failed, and the thread waits (with backoff) before
    // leasing again, so a broken job cannot make the worker spin.
    auto give_up = [&](const std::string& what, const std::string& reason, v1::LeaseFailure failure) {
      const int delay = job_failed(lease.job_id());
      log->error("{} (lease {} returned, leasing again in {} ms)", what, id, delay);
      s.return_leases({id}, reason, failure);
      s.wait(delay);
    };

    LeasedTile tile;
    if (auto err = unpack_tile_lease(lease, &tile)) {
      // A master bug: the tile would come straight back.
      return give_up(
          fmt::format("lease {} (job {} tile {}) is unusable: {}", id, lease.job_id(), lease.tile_index(), *err),
          "unusable lease: " + *err, v1::LEASE_FAILURE_TILE);
    }
    std::shared_ptr<const JobContext> job;
    try {
      job = jobs.get(lease);
    } catch (const std::exception& e) {
      if (s.ending()) return;  // interrupted (the lease stays held: returned on the way out)
      return give_up(fmt::format("job {}: cannot prepare its scene: {}", lease.job_id(), e.what()),
                     fmt::format("worker {} cannot prepare the job: {}", config.name, e.what()),
                     v1::LEASE_FAILURE_SCENE);
    }
    job_ok(lease.job_id());

    std::optional<TileResult> result;
    try {
      // Vertices are encoded as they are traced (the bytes SubmitTile sends), not in a pass afterwards.
      const TileRenderer renderer(*job->tracer, tile.filter, job->codec_bounds);
      ThreadActivity::Doing tracing(activity, Activity::kTracing);
      result = render_leased_tile(renderer, tile, [&] { return s.ending() || h->abandoned.load(); });
    } catch (const std::exception& e) {
      return give_up(fmt::format("job {} tile {}: tracing failed: {}", lease.job_id(), lease.tile_index(), e.what()),
                     fmt::format("worker {} failed tracing the tile: {}", config.name, e.what()),
                     v1::LEASE_FAILURE_TILE);
    }
    if (result) {
      counters.paths_traced += result->stats.paths.paths;
      counters.micros_tracing += uint64_t(result->stats.seconds * 1e6);
    }
    if (h->abandoned) {
      ++counters.tiles_abandoned;
      log->debug("lease {} abandoned (the master no longer needs it)", id);
      s.release(id);
      return;
    }
    if (!result || s.lost()) return;  // stopping or broken: the hold is returned on the way out
    {
      ThreadActivity::Doing submitting(activity, Activity::kSubmitting);
      if (pending->valid()) pending->get();  // the previous submission (rethrowing what it threw)
    }
    *pending = submitter.run([&s, lease, job, h, id, r = std::move(*result)] {
      if (s.submit(lease, job->codec_bounds, r, *h)) s.release(id);
    });
  }

  void tracing_loop(MasterSession& s) {
    set_thread_name("epr-trace");
    ThreadActivity activity(time);  // destroyed last: the drain below is accounted for
    // This thread's calls in the background (destroyed after the futures): submissions apart from the
    // lease asked for ahead, which the master may hold until the next round opens.
    Courier submitter("epr-submit"), leaser("epr-lease");
    std::future<void> pending;  // this thread's tile result being submitted
    struct Drain {              // on every way out: the last submission ends before the thread does
      std::future<void>* f;
      ThreadActivity* activity;
      ~Drain() {
        ThreadActivity::Doing submitting(activity, Activity::kSubmitting);
        if (f->valid()) f->wait();
      }
    } drain{&pending, &activity};
    // The next lease, asked for while this thread traces its tile: the master's answer arrives during
    // the tracing instead of after it.
    std::future<MasterSession::LeaseCall> next;
    while (!s.ending()) {
      MasterSession::LeaseCall call;
      {
        ThreadActivity::Doing leasing(&activity, Activity::kLeasing);
        call = next.valid() ? next.get() : s.lease_tile();
      }
      const v1::Lease& lease = call.lease;
      if (!call.status.ok()) {
        s.call_failed("LeaseTile", call.status);
        break;
      }
      switch (lease.kind_case()) {
        case v1::Lease::kTile:
          next = leaser.run([&s] { return s.lease_tile(); });
          process_tile(s, lease.tile(), submitter, &pending, &activity);
          break;
        case v1::Lease::kWait: {
          ThreadActivity::Doing waiting(&activity, Activity::kWaiting);
          s.wait(std::clamp<int>(int(lease.wait().retry_after_ms()), kMinWaitMs, kMaxWaitMs));
          break;
        }
        case v1::Lease::kShutdown:
          log->info("the master asks the worker to shut down: {}", lease.shutdown().reason());
          stop("master shutdown: " + lease.shutdown().reason());
          return;
        default:
          log->warn("LeaseTile answered with neither a tile, a wait nor a shutdown");
          s.wait(1000);
          break;
      }
    }
  }

  // ---- sessions ----------------------------------------------------------------------------------

  // A registered session, or nullptr with the master's answer in *status.
  std::shared_ptr<MasterSession> connect(grpc::Status* status) EPR_EXCLUDES(mu) {
    auto s = std::make_shared<MasterSession>(config, signal, counters, log);
    {
      // Published before Register, so that a stop cancels the call.
      MutexLock lock(mu);
      if (signal.stopping()) return nullptr;
      session = s;
    }
    *status = s->register_worker();
    if (!status->ok()) {
      MutexLock lock(mu);
      session.reset();
      return nullptr;
    }
    return s;
  }

  // Runs one session until it ends; returns with every thread joined.
  void run_session(const std::shared_ptr<MasterSession>& s) EPR_EXCLUDES(mu) {
    {
      MutexLock lock(mu);
      worker_id = s->worker_id();
    }
    ++counters.registrations;
    log->info("registered with {} as {} ({} tracing threads, heartbeat every {} ms)", opts.master, s->worker_id(),
              threads, s->heartbeat_ms());
    if (signal.stopping()) s->end(signal.reason(), /*lost=*/false);
    std::thread heartbeat([&] { s->heartbeat_loop(); });
    std::vector<std::thread> tracers;
    for (int i = 0; i < threads; ++i) tracers.emplace_back([&] { tracing_loop(*s); });
    signal.wait([&] { return s->ending(); });
    if (signal.stopping()) s->end("stopping", /*lost=*/false);
    for (auto& t : tracers) t.join();
    heartbeat.join();
    {
      MutexLock lock(mu);
      session.reset();
    }
  }

  std::optional<std::string> run() EPR_EXCLUDES(mu) {
    {
      MutexLock lock(mu);
      if (running) throw std::logic_error("WorkerNode::run() is already running");
      running = true;
    }
    std::optional<std::string> refused;
    Backoff backoff(opts.min_backoff_ms, opts.max_backoff_ms, std::random_device{}());
    while (!signal.stopping()) {
      grpc::Status status;
      const std::shared_ptr<MasterSession> s = connect(&status);
      if (!s) {
        if (signal.stopping()) break;
        const std::string why = rpc::describe(status);
        if (!rpc::is_transient(status.error_code())) {
          // Registering again would be refused the same way.
          refused = fmt::format("the master at {} refused worker '{}': {}", opts.master, config.name, why);
          log->error("{}; not retrying", *refused);
          break;
        }
        const int delay = backoff.next_ms();
        // Warn on attempts 1, 2, 4, 8, ...: a master that stays away does not flood the log.
        const int attempt = backoff.attempts();
        log->log((attempt & (attempt - 1)) == 0 ? spdlog::level::warn : spdlog::level::debug,
                 "cannot register with {}: {}; retrying in {} ms", opts.master, why, delay);
        signal.wait_for(delay);
        continue;
      }
      run_session(s);
      if (s->healthy()) backoff.reset();
      if (signal.stopping() && !s->lost()) {
        const std::string reason = signal.reason();
        s->farewell(reason.empty() ? "worker stopping" : reason);
        break;
      }
      s->salvage();
      if (signal.stopping()) break;
      ++counters.reconnects;
      const int delay = backoff.next_ms();
      log->warn("lost the session with {} ({}); registering again in {} ms", opts.master, s->end_reason(), delay);
      signal.wait_for(delay);
    }
    {
      MutexLock lock(mu);
      running = false;
      worker_id.clear();
    }
    cv.notify_all();
    return refused;
  }
};

WorkerNode::WorkerNode(WorkerNodeOptions options) : impl_(std::make_unique<Impl>(std::move(options))) {}

WorkerNode::~WorkerNode() {
  impl_->stop("worker destroyed");
  MutexLock lock(impl_->mu);
  impl_->cv.wait(lock, [&]() EPR_NO_THREAD_SAFETY_ANALYSIS { return !impl_->running; });  // with mu held
}

std::optional<std::string> WorkerNode::run() { return impl_->run(); }

void WorkerNode::stop() { impl_->stop("stop requested"); }

WorkerNodeStats WorkerNode::stats() const {
  const auto& c = impl_->counters;
  WorkerNodeStats s;
  {
    MutexLock lock(impl_->mu);
    s.worker_id = impl_->worker_id;
    s.registered = impl_->session != nullptr && impl_->session->registered() && !impl_->session->ending();
  }
  s.registrations = c.registrations;
  s.reconnects = c.reconnects;
  s.tiles_leased = c.tiles_leased;
  s.tiles_committed = c.tiles_committed;
  s.tiles_duplicate = c.tiles_duplicate;
  s.tiles_stale = c.tiles_stale;
  s.tiles_refused = c.tiles_refused;
  s.tiles_abandoned = c.tiles_abandoned;
  s.tiles_returned = c.tiles_returned;
  s.paths_traced = c.paths_traced;
  s.vertices_sent = c.vertices_sent;
  s.exact_samples_sent = c.exact_samples_sent;
  s.scenes_fetched = c.scenes_fetched;
  s.scene_bytes_fetched = c.scene_bytes_fetched;
  s.seconds_tracing = double(c.micros_tracing) * 1e-6;
  std::tie(s.time_others_tracing, s.time_none_tracing) = impl_->time.split();
  s.cpu = impl_->time.cpu();
  return s;
}

}  // namespace epr
