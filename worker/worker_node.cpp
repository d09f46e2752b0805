// The worker node: registration and reconnection (run), the tracing threads (tracing_loop,
// process_tile) and the per-job state they share. The calls to the master are the session's
// (worker/master_session.h); see worker_node.h for the whole picture.
#include "worker/worker_node.h"

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <future>
#include <map>
#include <optional>
#include <random>
#include <stdexcept>
#include <thread>
#include <tuple>
#include <utility>
#include <vector>

#include "common/check.h"
#include "common/log.h"
#include "common/scene_loader.h"
#include "common/thread_name.h"
#include "wire/rpc/status.h"
#include "wire/rpc/token.h"
#include "wire/scene_shelf.h"
#include "worker/backoff.h"
#include "worker/courier.h"
#include "worker/job_cache.h"
#include "worker/master_pool.h"
#include "worker/master_session.h"
#include "worker/master_targets.h"
#include "worker/scene_fetch.h"
#include "worker/tile_lease.h"
#include "worker/time_accounting.h"

namespace epr {
namespace {

constexpr int kMinWaitMs = 5, kMaxWaitMs = 60000;  // bounds on the master's Wait.retry_after_ms

// Test hook (tests/integration/cluster/tile_loss_test.cpp): EPR_TEST_ABORT_ON_TILE=X,Y makes the
// worker call std::abort(), as a crash in Embree would, when it starts a tile holding pixel (X, Y).
std::optional<std::pair<int, int>> abort_on_tile_pixel() {
  static const std::optional<std::pair<int, int>> pixel = []() -> std::optional<std::pair<int, int>> {
    const char* v = std::getenv("EPR_TEST_ABORT_ON_TILE");
    int x = 0, y = 0;
    char extra = 0;
    if (!v || std::sscanf(v, "%d,%d%c", &x, &y, &extra) != 2) return std::nullopt;
    return std::pair{x, y};
  }();
  return pixel;
}
constexpr size_t kMaxFailingJobs = 256;  // job failure records kept
// How long a master may hold a LeaseTile call when no tile is available yet (a round closing, its
// last tiles out, no job): the answer then comes the moment a tile is there (LeaseRequest.max_wait_ms).
constexpr uint32_t kLeaseMaxWaitMs = 1000;
constexpr uint32_t kMinParkMs = 200;  // with several masters: the shortest such hold

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
        name(opts.name.empty() ? default_name() : opts.name),
        jobs(size_t(std::max(1, opts.max_cached_jobs)),
             [this](const v1::SceneRef& ref, const std::string& master) { return load_scene_for(ref, master); }),
        time(opts.cpu_split),
        pool(pool_options(), signal, counters, log),
        rng(std::random_device{}()) {
    if (!cache.fallback_reason().empty())
      log->warn("scene cache: {}; using {} instead (removed when the worker ends)", cache.fallback_reason(),
                cache.path());
    trim_scene_cache(cache.path(), opts.cache_max_bytes);  // the bound may be lower than last time
  }

  MasterPool::Options pool_options() const {
    MasterPool::Options p;
    p.targets = parse_master_list(opts.master);
    p.resolver = opts.resolver;
    p.resolve_interval_ms = std::max(10, opts.resolve_interval_ms);
    p.session = {"",
                 "",
                 {opts.tls, opts.ca_file, opts.cert_file, opts.key_file},
                 rpc::configured_token(opts.token_file).value_or(""),
                 name,
                 threads,
                 cache.path(),
                 opts.min_backoff_ms,
                 opts.max_backoff_ms,
                 opts.in_process};
    p.threads = threads;
    return p;
  }

  WorkerNodeOptions opts;
  std::shared_ptr<spdlog::logger> log;
  int threads;
  CacheRoot cache;
  std::string name;
  JobCache jobs;
  StopSignal signal;
  NodeCounters counters;
  TimeAccounting time;
  MasterPool pool;

  Mutex mu;
  std::condition_variable_any cv;  // run() ends
  bool running EPR_GUARDED_BY(mu) = false;
  std::map<std::string, int> job_failures EPR_GUARDED_BY(mu);  // master + job id -> consecutive failures to prepare it
  std::mt19937_64 rng EPR_GUARDED_BY(mu);

  void stop(const std::string& reason) {
    signal.stop(reason);
    pool.end_sessions(reason);
  }

  // ---- scenes ------------------------------------------------------------------------------------

  // A lease's scene: built-ins are generated; file scenes come from the disk cache (shared by every
  // master: entries are named by their content hash) or are fetched from `master`, which granted it.
  // With opts.shared_scenes, a scene another user in this process holds (the embedded render's client
  // and master) is taken from the shelf (wire/scene_shelf.h), built-ins too: neither fetched nor
  // loaded again, and traced with the BVH the shelf keeps for it.
  std::shared_ptr<const Scene> load_scene_for(const v1::SceneRef& ref, const std::string& master) {
    if (!ref.builtin().empty()) {
      SceneBundleData b;
      b.builtin = ref.builtin();
      if (content_hash(b) != ref.content_hash())
        throw std::runtime_error(
            fmt::format("built-in scene '{}' does not have content hash {}", ref.builtin(), ref.content_hash()));
      if (!opts.shared_scenes) return std::make_shared<const Scene>(load_scene(ref.builtin()));
      if (auto shelved = shelved_scene(ref.content_hash())) return shelved;
      return shelve_scene(ref.content_hash(), std::make_shared<const Scene>(load_scene(ref.builtin())));
    }
    if (!is_content_hash(ref.content_hash()))
      throw std::runtime_error(
          fmt::format("scene reference '{}' is neither a built-in nor a content hash", ref.content_hash()));
    if (opts.shared_scenes)
      if (auto shelved = shelved_scene(ref.content_hash())) return shelved;
    std::string root = cache.path();
    std::optional<std::string> entry = cached_scene_entry(root, ref.content_hash());
    if (!entry && !cache.fallback_if_made().empty()) {  // fetched into the fallback folder before
      root = cache.fallback_if_made();
      entry = cached_scene_entry(root, ref.content_hash());
    }
    if (entry) {
      touch_cached_scene(root, ref.content_hash());
    } else {
      const std::shared_ptr<MasterSession> s = pool.session(master);
      if (!s || s->ending()) throw std::runtime_error("no master session to fetch the scene from");
      try {
        entry = s->fetch_scene(ref, root);
      } catch (const CacheWriteError& e) {
        // This worker's disk (full, read-only...), not the scene: the private temporary folder.
        const std::string fallback = cache.fallback();
        if (fallback == root) throw;
        log->warn("{}; fetching the scene into {} instead (removed when the worker ends)", e.what(), fallback);
        root = fallback;
        entry = s->fetch_scene(ref, root);
      }
      for (const std::string& gone : trim_scene_cache(root, opts.cache_max_bytes, ref.content_hash()))
        log->info("scene cache over {} MiB: removed scene {} (least recently used)", opts.cache_max_bytes >> 20, gone);
    }
    auto loaded = std::make_shared<const Scene>(load_scene(*entry));
    return opts.shared_scenes ? shelve_scene(ref.content_hash(), std::move(loaded)) : loaded;
  }

  // Delay before leasing again after a job could not be prepared; grows with repeated failures.
  int job_failed(const std::string& key) EPR_EXCLUDES(mu) {
    MutexLock lock(mu);
    if (job_failures.size() > kMaxFailingJobs) job_failures.clear();
    const int n = job_failures[key]++;
    const double u = std::uniform_real_distribution<double>(0.0, 1.0)(rng);
    return backoff_delay_ms(n, 500, std::max(1000, opts.max_backoff_ms), u);
  }

  void job_ok(const std::string& key) EPR_EXCLUDES(mu) {
    MutexLock lock(mu);
    job_failures.erase(key);
  }

  // ---- tracing -----------------------------------------------------------------------------------

  // Traces a tile leased from `use`'s master and hands the result to a background submission to the
  // same master (`pending`: this thread's submission in flight, at most one), so that the next tile
  // is leased and traced while the master receives this one.
  void process_tile(const std::shared_ptr<MasterPool::Use>& use, const v1::TileLease& lease, Courier& submitter,
                    std::future<void>* pending, ThreadActivity* activity) {
    MasterSession& s = use->session();
    ++counters.tiles_leased;
    const uint64_t id = lease.lease_id();
    auto h = s.hold(id);
    // With several masters, the line names the one that granted the lease.
    log->debug("lease {}: job {} round {} tile {}{}", id, lease.job_id(), lease.round(), lease.tile_index(),
               pool.single() ? "" : " from " + use->name());
    const std::string job_key = use->target() + " " + lease.job_id();
    // A lease this worker cannot trace goes back as failed, and the thread waits (with backoff) before
    // leasing again, so a broken job cannot make the worker spin.
    auto give_up = [&](const std::string& what, const std::string& reason, v1::LeaseFailure failure) {
      const int delay = job_failed(job_key);
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
      job = jobs.get(lease, use->target());
    } catch (const std::exception& e) {
      if (s.ending()) return;  // interrupted (the lease stays held: returned on the way out)
      return give_up(fmt::format("job {}: cannot prepare its scene: {}", lease.job_id(), e.what()),
                     fmt::format("worker {} cannot prepare the job: {}", name, e.what()), v1::LEASE_FAILURE_SCENE);
    }
    job_ok(job_key);

    if (const auto p = abort_on_tile_pixel(); p && tile.rect.x0 <= p->first && p->first < tile.rect.x1 &&
                                              tile.rect.y0 <= p->second && p->second < tile.rect.y1) {
      log->critical("EPR_TEST_ABORT_ON_TILE: aborting on job {} tile {}", lease.job_id(), lease.tile_index());
      std::abort();
    }
    std::optional<TileResult> result;
    try {
      // Vertices are encoded as they are traced (the bytes SubmitTile sends), not in a pass afterwards.
      const TileRenderer renderer(*job->tracer, tile.filter, job->codec_bounds);
      ThreadActivity::Doing tracing(activity, Activity::kTracing);
      result = render_leased_tile(renderer, tile, [&] { return s.ending() || h->abandoned.load(); });
    } catch (const std::exception& e) {
      return give_up(fmt::format("job {} tile {}: tracing failed: {}", lease.job_id(), lease.tile_index(), e.what()),
                     fmt::format("worker {} failed tracing the tile: {}", name, e.what()), v1::LEASE_FAILURE_TILE);
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
    // The Use goes with the submission (the master's link says no farewell before it ends) and is
    // dropped when the call ends: the task itself may outlive it (in the future's shared state).
    *pending = submitter.run([slot = hand_over(use), lease, job, h, id, r = std::move(*result)] {
      const std::shared_ptr<MasterPool::Use> u = std::exchange(*slot, nullptr);
      if (u->session().submit(lease, job->codec_bounds, r, *h)) u->session().release(id);
    });
  }

  // A Use for a task run on a Courier: the task takes it out when it runs, so it goes when the call
  // ends however long copies of the task live.
  static std::shared_ptr<std::shared_ptr<MasterPool::Use>> hand_over(std::shared_ptr<MasterPool::Use> use) {
    return std::make_shared<std::shared_ptr<MasterPool::Use>>(std::move(use));
  }

  // How long a master may hold this thread's lease call when it has no tile yet. One master: long
  // (the answer comes the moment its next round opens). Several: at once, so that a master without
  // work does not keep the thread from the others, except for the last one asked in a pass that found
  // no tile (`park`), which holds the call a while (no busy polling).
  static uint32_t max_wait_ms(size_t masters, bool park) {
    if (masters <= 1) return kLeaseMaxWaitMs;
    return park ? std::max<uint32_t>(kMinParkMs, kLeaseMaxWaitMs / uint32_t(masters)) : 0;
  }

  // The master to ask after `last`, in the order of `up`, passing over `skip` (unless it is the only
  // one); a thread that asked none yet starts at its own index, so the threads spread over the masters.
  static std::string next_master(const std::vector<std::string>& up, const std::string& last, int index,
                                 const std::string& skip = {}) {
    auto it = std::find(up.begin(), up.end(), last);
    std::string next = it == up.end()              ? up[size_t(index) % up.size()]
                       : std::next(it) == up.end() ? up.front()
                                                   : *std::next(it);
    if (next == skip && up.size() > 1) return next_master(up, next, index);
    return next;
  }

  // Leases from every connected master in turn (round robin, one lease per master in turn; a master
  // with no tile is skipped at once), traces, and submits to the master that leased the tile.
  void tracing_loop(int index) {
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
    // The next lease, asked for (of the next master in turn) while this thread traces its tile: the
    // master's answer arrives during the tracing instead of after it.
    struct Ahead {
      std::future<MasterSession::LeaseCall> call;
      std::string target;
      const MasterSession* session = nullptr;
    } ahead;
    std::string last;           // the master asked last
    std::string favourite;      // the master that gave this thread its last tile
    int misses = 0;             // masters in a row that had no tile
    int retry_ms = kMaxWaitMs;  // the shortest Wait.retry_after_ms among them
    while (!signal.stopping()) {
      std::shared_ptr<MasterPool::Use> use;
      MasterSession::LeaseCall call;
      const uint64_t generation = pool.generation();
      if (ahead.call.valid()) {
        {
          ThreadActivity::Doing leasing(&activity, Activity::kLeasing);
          call = ahead.call.get();
        }
        use = pool.use(ahead.target);
        // A session that ended meanwhile: its link gives back what it granted.
        if (!use || &use->session() != ahead.session) use.reset();
        ahead = {};
        if (!use) continue;
      } else {
        const std::vector<std::string> up = pool.connected();
        if (up.empty()) {
          ThreadActivity::Doing waiting(&activity, Activity::kWaiting);
          signal.wait_for(1000, [&] { return pool.generation() != generation; });
          continue;
        }
        // A pass asks every other master at once, then holds its last call at the master that gave this
        // thread its last tile (the one likely to have more as soon as its next round opens).
        const bool park = misses + 1 >= int(up.size());
        const bool favoured = std::find(up.begin(), up.end(), favourite) != up.end();
        last = park && favoured ? favourite : next_master(up, last, index, favoured ? favourite : "");
        use = pool.use(last);
        if (!use) continue;
        ThreadActivity::Doing leasing(&activity, Activity::kLeasing);
        call = use->session().lease_tile(max_wait_ms(up.size(), park));
      }
      MasterSession& s = use->session();
      const v1::Lease& lease = call.lease;
      if (!call.status.ok()) {
        s.call_failed("LeaseTile", call.status);
        continue;
      }
      switch (lease.kind_case()) {
        case v1::Lease::kTile: {
          misses = 0;
          retry_ms = kMaxWaitMs;
          favourite = use->target();
          const std::vector<std::string> up = pool.connected();
          if (!up.empty()) {
            last = next_master(up, use->target(), index);
            if (auto next = pool.use(last)) {
              ahead.target = last;
              ahead.session = &next->session();
              ahead.call = leaser.run([slot = hand_over(next), wait = max_wait_ms(up.size(), false)] {
                const std::shared_ptr<MasterPool::Use> u = std::exchange(*slot, nullptr);
                return u->session().lease_tile(wait);
              });
            }
          }
          process_tile(use, lease.tile(), submitter, &pending, &activity);
          break;
        }
        case v1::Lease::kWait: {
          retry_ms = std::min(retry_ms, std::clamp<int>(int(lease.wait().retry_after_ms()), kMinWaitMs, kMaxWaitMs));
          if (++misses < int(pool.connected().size())) break;  // the next master in turn
          use.reset();  // a master that ends meanwhile need not wait for this thread
          ThreadActivity::Doing waiting(&activity, Activity::kWaiting);
          signal.wait_for(retry_ms, [&] { return pool.generation() != generation; });
          misses = 0;
          retry_ms = kMaxWaitMs;
          break;
        }
        case v1::Lease::kShutdown:
          if (pool.single()) {
            log->info("the master asks the worker to shut down: {}", lease.shutdown().reason());
            stop("master shutdown: " + lease.shutdown().reason());
            return;
          }
          log->info("master {} asks the worker to leave: {}; serving the others", use->name(),
                    lease.shutdown().reason());
          use->master_shutdown(lease.shutdown().reason());
          break;
        default:
          log->warn("LeaseTile answered with neither a tile, a wait nor a shutdown");
          s.wait(1000);
          break;
      }
    }
  }

  // ---- running -----------------------------------------------------------------------------------

  std::optional<std::string> run() {
    {
      MutexLock lock(mu);
      if (running) throw std::logic_error("WorkerNode::run() is already running");
      running = true;
    }
    std::vector<std::thread> tracers;
    for (int i = 0; i < threads; ++i) tracers.emplace_back([this, i] { tracing_loop(i); });
    const std::optional<std::string> refused = pool.run();
    if (refused) signal.stop(*refused);
    for (auto& t : tracers) t.join();
    {
      MutexLock lock(mu);
      running = false;
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

int WorkerNode::threads() const { return impl_->threads; }

WorkerNodeStats WorkerNode::stats() const {
  const auto& c = impl_->counters;
  WorkerNodeStats s;
  s.masters = impl_->pool.status();
  for (const MasterStatus& m : s.masters) {
    if (m.state != MasterState::kConnected) continue;
    if (!s.registered) s.worker_id = m.worker_id;
    s.registered = true;
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
