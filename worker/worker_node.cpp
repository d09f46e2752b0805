#include "worker/worker_node.h"

#include <fmt/format.h>
#include <grpcpp/grpcpp.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <functional>
#include <map>
#include <mutex>
#include <random>
#include <stdexcept>
#include <future>
#include <thread>
#include <tuple>
#include <utility>
#include <vector>

#include "common/cpu_time.h"
#include "common/log.h"
#include "common/scene_loader.h"
#include "common/thread_name.h"
#include "epr/v1/worker_service.grpc.pb.h"
#include "wire/rpc/channel.h"
#include "wire/rpc/chunked.h"
#include "wire/rpc/status.h"
#include "wire/rpc/token.h"
#include "wire/tile_result_stream.h"
#include "worker/backoff.h"
#include "worker/job_cache.h"
#include "worker/scene_fetch.h"
#include "worker/tile_lease.h"

#ifndef EPR_VERSION
#define EPR_VERSION "0.0.0"
#endif

namespace epr {
namespace {

using namespace std::chrono_literals;
using Millis = std::chrono::milliseconds;

// Deadlines of the unary calls. FetchScene and SubmitTile scale with their size (kSlowLinkBytesPerSecond
// on top of a fixed allowance), so a large scene or tile on a slow link is not cut off.
constexpr Millis kRegisterDeadline = 10s;
constexpr Millis kLeaseDeadline = 10s;
// How long the master may hold a LeaseTile call when no tile is available yet (a round closing, its
// last tiles out, no job): the answer then comes the moment a tile is there (LeaseRequest.max_wait_ms).
constexpr uint32_t kLeaseMaxWaitMs = 1000;
constexpr Millis kReturnDeadline = 5s;
constexpr Millis kLostReturnDeadline = 1s;  // best effort after the session broke
constexpr Millis kUnregisterDeadline = 3s;
constexpr Millis kFetchDeadlineBase = 60s;
constexpr Millis kSubmitDeadlineBase = 30s;
constexpr double kSlowLinkBytesPerSecond = 1e6;
constexpr int kSubmitAttempts = 3;                  // SubmitTile tries on UNAVAILABLE / DEADLINE_EXCEEDED
constexpr int kMinWaitMs = 5, kMaxWaitMs = 60000;  // bounds on the master's Wait.retry_after_ms
constexpr size_t kMaxFailingJobs = 256;             // job failure records kept

Millis size_deadline(Millis base, double bytes) {
  return base + Millis(int64_t(bytes / kSlowLinkBytesPerSecond * 1000.0));
}

std::string default_name() {
  char host[256] = {};
  if (::gethostname(host, sizeof host - 1) != 0) std::snprintf(host, sizeof host, "worker");
  return fmt::format("{}-{}", host, ::getpid());
}

// One registration with the master: its worker id and limits, the channel, and what is in flight.
struct Session {
  struct Hold {
    uint64_t lease_id = 0;
    std::atomic<bool> abandoned{false};  // heartbeat said invalid: drop it without returning it
  };

  std::string worker_id;
  uint32_t heartbeat_ms = 1000;
  TileResultLimits limits;
  std::shared_ptr<grpc::Channel> channel;
  std::unique_ptr<v1::WorkerService::Stub> stub;

  std::atomic<bool> ending{false};   // threads wind down (stop, or the session broke)
  std::atomic<bool> lost{false};     // it broke: finished tiles are not submitted any more
  std::atomic<bool> healthy{false};  // some call after Register succeeded (resets the backoff)

  std::mutex mu;  // guards the members below
  std::string end_reason;
  std::map<uint64_t, std::shared_ptr<Hold>> held;
  std::map<grpc::ClientContext*, bool> calls;  // in flight -> cancel on stop()

  std::vector<uint64_t> held_ids(bool include_abandoned) {
    std::lock_guard lock(mu);
    std::vector<uint64_t> ids;
    for (const auto& [id, h] : held)
      if (include_abandoned || !h->abandoned) ids.push_back(id);
    return ids;
  }
};

// Where the tracing threads' wall time goes (WorkerNodeStats::time_*): each thread is in one activity
// at a time; at every change the elapsed time is credited to the activities of all threads, split by
// whether another thread was tracing meanwhile. A few changes per tile: one mutex is cheap enough.
enum class Activity { kOther, kTracing, kLeasing, kWaiting, kSubmitting };
constexpr int kActivities = 5;

class TimeAccounting {
 public:
  void enter(Activity a) { change(nullptr, &a); }
  void leave(Activity a) { change(&a, nullptr); }
  void move(Activity from, Activity to) { change(&from, &to); }
  void add_cpu(Activity a, double seconds) {
    std::lock_guard lock(mu_);
    cpu_[int(a)] += seconds;
  }
  WorkerTimeSplit cpu() {
    std::lock_guard lock(mu_);
    return to_split(cpu_);
  }

  // {while another thread traced, while none did}, up to now.
  std::pair<WorkerTimeSplit, WorkerTimeSplit> split() {
    std::lock_guard lock(mu_);
    advance();
    double with[kActivities], without[kActivities];
    for (int a = 0; a < kActivities; ++a) {
      with[a] = seconds_[a][1];
      without[a] = seconds_[a][0];
    }
    return {to_split(with), to_split(without)};
  }

 private:
  static WorkerTimeSplit to_split(const double (&by)[kActivities]) {
    WorkerTimeSplit t;
    t.other = by[int(Activity::kOther)];
    t.tracing = by[int(Activity::kTracing)];
    t.leasing = by[int(Activity::kLeasing)];
    t.waiting = by[int(Activity::kWaiting)];
    t.submitting = by[int(Activity::kSubmitting)];
    return t;
  }

  using Clock = std::chrono::steady_clock;
  void change(const Activity* from, const Activity* to) {
    std::lock_guard lock(mu_);
    advance();
    if (from) --threads_in_[int(*from)];
    if (to) ++threads_in_[int(*to)];
  }
  void advance() {
    const auto now = Clock::now();
    const double dt = std::chrono::duration<double>(now - last_).count();
    last_ = now;
    const int tracing = threads_in_[int(Activity::kTracing)];
    for (int a = 0; a < kActivities; ++a) {
      // A tracing thread sees another one tracing if there are two; any other thread if there is one.
      const bool others = a == int(Activity::kTracing) ? tracing > 1 : tracing > 0;
      seconds_[a][others ? 1 : 0] += double(threads_in_[a]) * dt;
    }
  }
  std::mutex mu_;
  Clock::time_point last_ = Clock::now();
  int threads_in_[kActivities] = {};
  double seconds_[kActivities][2] = {};
  double cpu_[kActivities] = {};  // thread CPU seconds
};

// The activity of one tracing thread: `Doing` switches it for a scope and switches back after.
class ThreadActivity {
 public:
  explicit ThreadActivity(TimeAccounting& t) : t_(t), cpu_(thread_cpu_seconds()) { t_.enter(current_); }
  ~ThreadActivity() {
    t_.add_cpu(current_, thread_cpu_seconds() - cpu_);
    t_.leave(current_);
  }
  ThreadActivity(const ThreadActivity&) = delete;
  ThreadActivity& operator=(const ThreadActivity&) = delete;

  class Doing {
   public:
    Doing(ThreadActivity* a, Activity what) : a_(a) {
      if (!a_) return;
      before_ = a_->current_;
      a_->set(what);
    }
    ~Doing() {
      if (a_) a_->set(before_);
    }
    Doing(const Doing&) = delete;
    Doing& operator=(const Doing&) = delete;

   private:
    ThreadActivity* a_;
    Activity before_ = Activity::kOther;
  };

 private:
  void set(Activity a) {
    if (a == current_) return;
    const double cpu = thread_cpu_seconds();
    t_.add_cpu(current_, cpu - cpu_);
    cpu_ = cpu;
    t_.move(current_, a);
    current_ = a;
  }
  TimeAccounting& t_;
  Activity current_ = Activity::kOther;
  double cpu_;  // thread CPU seconds at the last change
};

// Runs the calls a tracing thread hands it (the submissions of its tiles, or the leases it asks for
// ahead) on a long-lived thread of its own, in order, while the tracing thread traces; a thread
// started per call (std::async) cost a thread creation twice per tile. The destructor runs what is
// queued and joins: every call ends before its tracing thread does.
class Courier {
 public:
  explicit Courier(std::string name) : name_(std::move(name)), thread_([this] { loop(); }) {}
  ~Courier() {
    {
      std::lock_guard lock(mu_);
      stopping_ = true;
    }
    cv_.notify_one();
    thread_.join();
  }
  Courier(const Courier&) = delete;
  Courier& operator=(const Courier&) = delete;

  template <typename F>
  auto run(F f) -> std::future<decltype(f())> {
    auto task = std::make_shared<std::packaged_task<decltype(f())()>>(std::move(f));
    auto result = task->get_future();
    {
      std::lock_guard lock(mu_);
      tasks_.emplace_back([task] { (*task)(); });
    }
    cv_.notify_one();
    return result;
  }

 private:
  void loop() {
    set_thread_name(name_);
    std::unique_lock lock(mu_);
    for (;;) {
      cv_.wait(lock, [&] { return stopping_ || !tasks_.empty(); });
      if (tasks_.empty()) return;
      auto task = std::move(tasks_.front());
      tasks_.pop_front();
      lock.unlock();
      task();
      lock.lock();
    }
  }
  std::mutex mu_;
  std::condition_variable cv_;
  std::deque<std::function<void()>> tasks_;
  bool stopping_ = false;
  const std::string name_;
  std::thread thread_;  // last: started once the members above exist
};

}  // namespace

struct WorkerNode::Impl {
  explicit Impl(WorkerNodeOptions o)
      : opts(std::move(o)),
        log(logger("worker")),
        token(rpc::configured_token(opts.token_file).value_or("")),
        name(opts.name.empty() ? default_name() : opts.name),
        threads(opts.threads > 0 ? opts.threads : int(std::max(1u, std::thread::hardware_concurrency()))),
        jobs(size_t(std::max(1, opts.max_cached_jobs)),
             [this](const v1::SceneRef& ref) { return load_scene_for(ref); }),
        rng(std::random_device{}()) {}

  WorkerNodeOptions opts;
  std::shared_ptr<spdlog::logger> log;
  std::string token;
  std::string name;
  int threads;
  JobCache jobs;

  std::mutex mu;  // guards the members below and orders session ends with waits
  std::condition_variable cv;
  std::atomic<bool> stopping{false};
  std::string stop_reason;
  bool running = false;
  std::shared_ptr<Session> session;
  grpc::ClientContext* register_call = nullptr;
  std::map<std::string, int> job_failures;  // job id -> consecutive failures to prepare it
  std::mt19937_64 rng;
  std::string worker_id;

  struct Counters {
    std::atomic<uint64_t> registrations{0}, reconnects{0}, tiles_leased{0}, tiles_committed{0}, tiles_duplicate{0},
        tiles_stale{0}, tiles_refused{0}, tiles_abandoned{0}, tiles_returned{0}, paths_traced{0}, vertices_sent{0},
        exact_samples_sent{0}, scenes_fetched{0}, scene_bytes_fetched{0};
    std::atomic<uint64_t> micros_tracing{0};
  } counters;
  TimeAccounting time;

  // ---- plumbing --------------------------------------------------------------------------------

  void prepare(grpc::ClientContext& ctx, Millis deadline) const { rpc::prepare_call(ctx, deadline, token); }

  // Registers a call of `s` so that stop() / the end of the session can cancel it.
  class CallScope {
   public:
    CallScope(Impl& impl, Session& s, grpc::ClientContext& ctx, bool cancel_on_stop) : s_(s), ctx_(ctx) {
      std::lock_guard lock(s.mu);
      s.calls[&ctx] = cancel_on_stop;
      if (s.lost || (cancel_on_stop && (s.ending || impl.stopping))) ctx.TryCancel();
    }
    ~CallScope() {
      std::lock_guard lock(s_.mu);
      s_.calls.erase(&ctx_);
    }

   private:
    Session& s_;
    grpc::ClientContext& ctx_;
  };

  // Waits up to `ms`; returns early (true) on stop or when `s` (if given) ends.
  bool wait_for(const Session* s, int ms) {
    std::unique_lock lock(mu);
    return cv.wait_for(lock, Millis(ms), [&] { return stopping.load() || (s && s->ending.load()); });
  }

  // Ends session `s`. lost: it broke (cancel everything in flight); else: stopping (in-flight submits
  // may finish).
  void end_session(Session& s, const std::string& reason, bool lost) {
    {
      std::lock_guard lock(mu);
      if (s.ending && !(lost && !s.lost)) return;
      std::lock_guard slock(s.mu);
      if (s.end_reason.empty()) s.end_reason = reason;
      if (lost) s.lost = true;
      s.ending = true;
      for (auto& [ctx, cancel_on_stop] : s.calls)
        if (lost || cancel_on_stop) ctx->TryCancel();
    }
    cv.notify_all();
  }

  void stop(const std::string& reason) {
    std::shared_ptr<Session> s;
    {
      std::lock_guard lock(mu);
      if (!stopping) stop_reason = reason;
      stopping = true;
      s = session;
      if (register_call) register_call->TryCancel();
    }
    cv.notify_all();
    if (s) end_session(*s, reason, /*lost=*/false);
  }

  // The hold of a lease, made when the lease arrives (a stop returns it even before it is traced).
  std::shared_ptr<Session::Hold> hold(Session& s, uint64_t lease_id) {
    std::lock_guard lock(s.mu);
    auto& h = s.held[lease_id];
    if (!h) {
      h = std::make_shared<Session::Hold>();
      h->lease_id = lease_id;
    }
    return h;
  }

  void release(Session& s, uint64_t lease_id) {
    std::lock_guard lock(s.mu);
    s.held.erase(lease_id);
  }

  // Handles a failed call of the lease/heartbeat loops: the session is over unless it already is.
  void call_failed(Session& s, const char* what, const grpc::Status& status) {
    if (s.ending) return;  // our own cancellation
    end_session(s, fmt::format("{}: {}", what, rpc::describe(status)), /*lost=*/true);
  }

  // ---- registration ------------------------------------------------------------------------------

  std::shared_ptr<Session> connect(std::string* why) {
    auto s = std::make_shared<Session>();
    grpc::ChannelArguments args;
    // The channel's own reconnection follows our backoff rather than gRPC's (up to 120 s) default.
    args.SetInt(GRPC_ARG_INITIAL_RECONNECT_BACKOFF_MS, std::max(1, opts.min_backoff_ms));
    args.SetInt(GRPC_ARG_MIN_RECONNECT_BACKOFF_MS, std::max(1, opts.min_backoff_ms));
    args.SetInt(GRPC_ARG_MAX_RECONNECT_BACKOFF_MS, std::max(opts.min_backoff_ms, opts.max_backoff_ms));
    s->channel = grpc::CreateCustomChannel(
        opts.master, rpc::channel_credentials({opts.tls, opts.ca_file, opts.cert_file, opts.key_file}), args);
    s->stub = v1::WorkerService::NewStub(s->channel);

    v1::WorkerInfo info;
    info.set_protocol_version(v1::PROTOCOL_VERSION_V1);
    info.set_name(name);
    info.set_threads(uint32_t(threads));
    info.set_version(EPR_VERSION);
    for (const auto& h : cached_scene_hashes(opts.cache_dir)) info.add_cached_scenes(h);

    grpc::ClientContext ctx;
    prepare(ctx, kRegisterDeadline);
    {
      std::lock_guard lock(mu);
      if (stopping) return nullptr;
      register_call = &ctx;
    }
    v1::RegisterResponse resp;
    const grpc::Status status = s->stub->Register(&ctx, info, &resp);
    {
      std::lock_guard lock(mu);
      register_call = nullptr;
    }
    if (!status.ok()) {
      *why = rpc::describe(status);
      if (status.error_code() == grpc::StatusCode::FAILED_PRECONDITION)
        log->error("master {} does not speak protocol epr.v1: {}", opts.master, status.error_message());
      return nullptr;
    }
    const std::string& id = resp.worker_id().id();
    if (id.empty() || id.size() > 64) {
      *why = "Register answered without a usable worker id";
      return nullptr;
    }
    s->worker_id = id;
    s->heartbeat_ms =
        std::clamp<uint32_t>(resp.heartbeat_interval_ms() ? resp.heartbeat_interval_ms() : 1000, 50, 60000);
    if (resp.max_vertices_per_chunk()) s->limits.max_vertices_per_chunk = resp.max_vertices_per_chunk();
    if (resp.max_chunk_bytes()) s->limits.max_chunk_bytes = resp.max_chunk_bytes();
    return s;
  }

  // ---- scenes ------------------------------------------------------------------------------------

  Scene load_scene_for(const v1::SceneRef& ref) {
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
    std::optional<std::string> entry = cached_scene_entry(opts.cache_dir, ref.content_hash());
    if (!entry) entry = fetch_scene(ref);
    return load_scene(*entry);
  }

  std::string fetch_scene(const v1::SceneRef& ref) {
    std::shared_ptr<Session> s;
    {
      std::lock_guard lock(mu);
      s = session;
    }
    if (!s || s->ending) throw std::runtime_error("no master session to fetch the scene from");
    log->info("fetching scene {} ({} bytes) from the master", ref.content_hash(), ref.total_bytes());
    v1::FetchSceneRequest req;
    req.mutable_worker_id()->set_id(s->worker_id);
    req.set_content_hash(ref.content_hash());
    grpc::ClientContext ctx;
    prepare(ctx, size_deadline(kFetchDeadlineBase, double(ref.total_bytes())));
    CallScope scope(*this, *s, ctx, /*cancel_on_stop=*/true);
    SceneReceiver rx(opts.cache_dir, ref.content_hash());
    auto reader = s->stub->FetchScene(&ctx, req);
    const rpc::StreamEnd end =
        rpc::read_stream<v1::SceneChunk>(ctx, *reader, [&](const v1::SceneChunk& chunk) { return rx.add(chunk); });
    if (end.error) throw std::runtime_error(fmt::format("FetchScene {}: {}", ref.content_hash(), *end.error));
    if (!end.status.ok())
      throw std::runtime_error(fmt::format("FetchScene {}: {}", ref.content_hash(), rpc::describe(end.status)));
    std::string entry;
    if (auto e = rx.finish(&entry)) throw std::runtime_error(fmt::format("FetchScene {}: {}", ref.content_hash(), *e));
    ++counters.scenes_fetched;
    counters.scene_bytes_fetched += rx.bytes_received();
    return entry;
  }

  // ---- leases --------------------------------------------------------------------------------------

  // Gives leases back, reporting `failure` (the master counts it against this worker for the job and
  // stops leasing it the job's tiles after a few). A failure that means the session is gone ends it.
  bool return_leases(Session& s, const std::vector<uint64_t>& ids, const std::string& reason,
                     v1::LeaseFailure failure = v1::LEASE_FAILURE_UNSPECIFIED) {
    if (ids.empty()) return true;
    v1::ReturnLeaseRequest req;
    req.mutable_worker_id()->set_id(s.worker_id);
    for (uint64_t id : ids) req.add_lease_ids(id);
    req.set_reason(reason);
    req.set_failure(failure);
    grpc::ClientContext ctx;
    prepare(ctx, kReturnDeadline);
    CallScope scope(*this, s, ctx, /*cancel_on_stop=*/false);
    v1::ReturnLeaseResponse resp;
    const grpc::Status status = s.stub->ReturnLease(&ctx, req, &resp);
    if (!status.ok()) {
      call_failed(s, "ReturnLease", status);
      return false;
    }
    counters.tiles_returned += ids.size();
    return true;
  }

  // Delay before leasing again after a job could not be prepared; grows with repeated failures.
  int job_failed(const std::string& job_id) {
    std::lock_guard lock(mu);
    if (job_failures.size() > kMaxFailingJobs) job_failures.clear();
    const int n = job_failures[job_id]++;
    const double u = std::uniform_real_distribution<double>(0.0, 1.0)(rng);
    return backoff_delay_ms(n, 500, std::max(1000, opts.max_backoff_ms), u);
  }

  void job_ok(const std::string& job_id) {
    std::lock_guard lock(mu);
    job_failures.erase(job_id);
  }

  // Leases, traces and hands the result to a background submission (`pending`: this thread's
  // submission in flight, at most one), so that the next tile is leased and traced while the master
  // receives this one.
  void process_tile(Session& s, const v1::TileLease& lease, Courier& submitter, std::future<void>* pending,
                    ThreadActivity* activity) {
    ++counters.tiles_leased;
    const uint64_t id = lease.lease_id();
    auto h = hold(s, id);
    log->debug("lease {}: job {} round {} tile {}", id, lease.job_id(), lease.round(), lease.tile_index());

    LeasedTile tile;
    if (auto err = unpack_tile_lease(lease, &tile)) {
      // A master bug: the tile would come straight back, so wait before leasing again.
      const int delay = job_failed(lease.job_id());
      log->error("lease {} (job {} tile {}) is unusable: {} (returned, leasing again in {} ms)", id, lease.job_id(),
                 lease.tile_index(), *err, delay);
      if (return_leases(s, {id}, "unusable lease: " + *err, v1::LEASE_FAILURE_TILE)) release(s, id);
      wait_for(&s, delay);
      return;
    }
    std::shared_ptr<const JobContext> job;
    try {
      job = jobs.get(lease);
    } catch (const std::exception& e) {
      if (s.ending) return;  // interrupted (the lease stays held: returned on the way out)
      const int delay = job_failed(lease.job_id());
      log->error("job {}: cannot prepare its scene: {} (lease {} returned, leasing again in {} ms)", lease.job_id(),
                 e.what(), id, delay);
      if (return_leases(s, {id}, fmt::format("worker {} cannot prepare the job: {}", name, e.what()),
                        v1::LEASE_FAILURE_SCENE))
        release(s, id);
      wait_for(&s, delay);
      return;
    }
    job_ok(lease.job_id());

    std::optional<TileResult> result;
    try {
      // Vertices are encoded as they are traced (the bytes SubmitTile sends), not in a pass afterwards.
      const TileRenderer renderer(*job->tracer, tile.filter, job->codec_bounds);
      ThreadActivity::Doing tracing(activity, Activity::kTracing);
      result = render_leased_tile(renderer, tile, [&] { return s.ending.load() || h->abandoned.load(); });
    } catch (const std::exception& e) {
      const int delay = job_failed(lease.job_id());
      log->error("job {} tile {}: tracing failed: {} (lease {} returned, leasing again in {} ms)", lease.job_id(),
                 lease.tile_index(), e.what(), id, delay);
      if (return_leases(s, {id}, fmt::format("worker {} failed tracing the tile: {}", name, e.what()),
                        v1::LEASE_FAILURE_TILE))
        release(s, id);
      wait_for(&s, delay);
      return;
    }
    if (result) {
      counters.paths_traced += result->stats.paths.paths;
      counters.micros_tracing += uint64_t(result->stats.seconds * 1e6);
    }
    if (h->abandoned) {
      ++counters.tiles_abandoned;
      log->debug("lease {} abandoned (the master no longer needs it)", id);
      release(s, id);
      return;
    }
    if (!result || s.lost) return;  // stopping or broken: the hold is returned on the way out
    {
      ThreadActivity::Doing submitting(activity, Activity::kSubmitting);
      finish_submission(pending);
    }
    *pending = submitter.run([this, &s, lease, job, h, id, r = std::move(*result)] {
      if (submit(s, lease, *job, r, *h)) release(s, id);
    });
  }

  // Waits for a background submission to end (rethrowing what it threw).
  static void finish_submission(std::future<void>* pending) {
    if (pending->valid()) pending->get();
  }

  // True once the master has answered for the tile (committed, dropped or refused); false if the
  // result did not get through (the lease stays held and is returned on the way out).
  bool submit(Session& s, const v1::TileLease& lease, const JobContext& job, const TileResult& result,
              const Session::Hold& h) {
    const TileResultIdentity identity{lease.lease_id(), lease.job_id(), lease.round(), lease.tile_index(), s.worker_id};
    Backoff retry(200, 2000, lease.lease_id());
    for (int attempt = 1;; ++attempt) {
      TileResultWriter writer(result, identity, job.codec_bounds, s.limits);
      const auto& head = writer.header();
      const double bytes =
          17.0 * head.pixel_count() + 16.0 * double(head.vertex_count()) + 17.0 * double(head.exact_sample_count());
      grpc::ClientContext ctx;
      prepare(ctx, size_deadline(kSubmitDeadlineBase, bytes));
      CallScope scope(*this, s, ctx, /*cancel_on_stop=*/false);
      v1::SubmitAck ack;
      auto stream = s.stub->SubmitTile(&ctx, &ack);
      write_tile_result(writer, *stream);  // the trailer goes with the half-close
      const grpc::Status status = stream->Finish();
      if (status.ok()) {
        switch (ack.outcome()) {
          case v1::SUBMIT_OUTCOME_COMMITTED:
            ++counters.tiles_committed;
            counters.vertices_sent += head.vertex_count();
            counters.exact_samples_sent += head.exact_sample_count();
            break;
          case v1::SUBMIT_OUTCOME_DUPLICATE:
            ++counters.tiles_duplicate;
            break;
          case v1::SUBMIT_OUTCOME_STALE:
            ++counters.tiles_stale;
            break;
          default:
            break;
        }
        log->debug("lease {}: submitted, accepted={} {}", lease.lease_id(), ack.accepted(), ack.reason());
        return true;
      }
      const auto code = status.error_code();
      const bool transient = code == grpc::StatusCode::UNAVAILABLE || code == grpc::StatusCode::DEADLINE_EXCEEDED;
      if (transient && attempt < kSubmitAttempts && !s.lost && !h.abandoned) {
        const int delay = retry.next_ms();
        log->warn("lease {}: SubmitTile failed ({}), retrying in {} ms", lease.lease_id(), rpc::describe(status), delay);
        if (wait_for(nullptr, delay) && stopping) return false;
        continue;
      }
      if (code == grpc::StatusCode::INVALID_ARGUMENT || code == grpc::StatusCode::FAILED_PRECONDITION ||
          code == grpc::StatusCode::RESOURCE_EXHAUSTED) {
        // The master refused this result; the session is fine. A bug on one side: say so loudly.
        ++counters.tiles_refused;
        log->error("lease {} (job {} tile {}): the master refused the result: {}", lease.lease_id(), lease.job_id(),
                   lease.tile_index(), rpc::describe(status));
        return true;
      }
      call_failed(s, "SubmitTile", status);
      return false;
    }
  }

  // ---- the loops -----------------------------------------------------------------------------------

  void heartbeat_loop(Session& s) {
    set_thread_name("epr-heartbeat");
    while (!s.ending) {
      if (wait_for(&s, int(s.heartbeat_ms))) break;
      v1::HeartbeatRequest req;
      req.mutable_worker_id()->set_id(s.worker_id);
      for (uint64_t id : s.held_ids(/*include_abandoned=*/false)) req.add_lease_ids(id);
      grpc::ClientContext ctx;
      prepare(ctx, Millis(std::clamp<int64_t>(2 * int64_t(s.heartbeat_ms), 2000, 10000)));
      CallScope scope(*this, s, ctx, /*cancel_on_stop=*/true);
      v1::HeartbeatResponse resp;
      const grpc::Status status = s.stub->Heartbeat(&ctx, req, &resp);
      if (!status.ok()) {
        call_failed(s, "Heartbeat", status);
        break;
      }
      s.healthy = true;
      std::lock_guard lock(s.mu);
      for (const auto& state : resp.leases()) {
        if (state.valid()) continue;
        if (auto it = s.held.find(state.lease_id()); it != s.held.end()) it->second->abandoned = true;
      }
    }
  }

  struct LeaseCall {
    grpc::Status status;
    v1::Lease lease;
  };
  // One LeaseTile call; a tile it grants is held at once (heartbeats report it, a stop returns it).
  LeaseCall lease_tile(Session& s) {
    v1::LeaseRequest req;
    req.mutable_worker_id()->set_id(s.worker_id);
    req.set_max_wait_ms(kLeaseMaxWaitMs);
    grpc::ClientContext ctx;
    prepare(ctx, kLeaseDeadline);
    LeaseCall call;
    {
      // Cancelled by stop() (the master may be holding it): a tile the master granted before it saw
      // the cancellation is given back by the master itself.
      CallScope scope(*this, s, ctx, /*cancel_on_stop=*/true);
      call.status = s.stub->LeaseTile(&ctx, req, &call.lease);
    }
    if (call.status.ok() && call.lease.has_tile()) hold(s, call.lease.tile().lease_id());
    return call;
  }

  void tracing_loop(Session& s) {
    set_thread_name("epr-trace");
    ThreadActivity activity(time);  // destroyed last: the drain below is accounted for
    // This thread's calls in the background (destroyed after the futures): submissions apart from the
    // lease asked for ahead, which the master may hold until the next round opens.
    Courier submitter("epr-submit"), leaser("epr-lease");
    std::future<void> pending;      // this thread's tile result being submitted
    struct Drain {                  // on every way out: the last submission ends before the thread does
      std::future<void>* f;
      ThreadActivity* activity;
      ~Drain() {
        ThreadActivity::Doing submitting(activity, Activity::kSubmitting);
        if (f->valid()) f->wait();
      }
    } drain{&pending, &activity};
    // The next lease, asked for while this thread traces its tile: the master's answer arrives during
    // the tracing instead of after it.
    std::future<LeaseCall> next;
    while (!s.ending) {
      LeaseCall call;
      {
        ThreadActivity::Doing leasing(&activity, Activity::kLeasing);
        call = next.valid() ? next.get() : lease_tile(s);
      }
      const v1::Lease& lease = call.lease;
      if (!call.status.ok()) {
        call_failed(s, "LeaseTile", call.status);
        break;
      }
      s.healthy = true;
      switch (lease.kind_case()) {
        case v1::Lease::kTile:
          next = leaser.run([this, &s] { return lease_tile(s); });
          process_tile(s, lease.tile(), submitter, &pending, &activity);
          break;
        case v1::Lease::kWait: {
          ThreadActivity::Doing waiting(&activity, Activity::kWaiting);
          wait_for(&s, std::clamp<int>(int(lease.wait().retry_after_ms()), kMinWaitMs, kMaxWaitMs));
          break;
        }
        case v1::Lease::kShutdown:
          log->info("the master asks the worker to shut down: {}", lease.shutdown().reason());
          stop("master shutdown: " + lease.shutdown().reason());
          return;
        default:
          log->warn("LeaseTile answered with neither a tile, a wait nor a shutdown");
          wait_for(&s, 1000);
          break;
      }
    }
  }

  // Runs one session until it ends; returns with every thread joined.
  void run_session(const std::shared_ptr<Session>& s) {
    {
      std::lock_guard lock(mu);
      session = s;
      worker_id = s->worker_id;
    }
    ++counters.registrations;
    log->info("registered with {} as {} ({} tracing threads, heartbeat every {} ms)", opts.master, s->worker_id,
              threads, s->heartbeat_ms);
    if (stopping) end_session(*s, stop_reason, /*lost=*/false);
    std::thread heartbeat([&] { heartbeat_loop(*s); });
    std::vector<std::thread> tracers;
    for (int i = 0; i < threads; ++i) tracers.emplace_back([&] { tracing_loop(*s); });
    {
      std::unique_lock lock(mu);
      cv.wait(lock, [&] { return s->ending || stopping; });
    }
    if (stopping) end_session(*s, "stopping", /*lost=*/false);
    for (auto& t : tracers) t.join();
    heartbeat.join();
    {
      std::lock_guard lock(mu);
      session.reset();
    }
  }

  // After a stop: give the leases back and leave.
  void farewell(Session& s) {
    const auto ids = s.held_ids(/*include_abandoned=*/false);
    if (!ids.empty()) {
      v1::ReturnLeaseRequest req;
      req.mutable_worker_id()->set_id(s.worker_id);
      for (uint64_t id : ids) req.add_lease_ids(id);
      req.set_reason(stop_reason.empty() ? "worker stopping" : stop_reason);
      grpc::ClientContext ctx;
      prepare(ctx, kReturnDeadline);
      v1::ReturnLeaseResponse resp;
      const grpc::Status status = s.stub->ReturnLease(&ctx, req, &resp);
      if (status.ok())
        counters.tiles_returned += ids.size();
      else
        log->warn("could not return {} leases: {}", ids.size(), rpc::describe(status));
    }
    v1::WorkerId wid;
    wid.set_id(s.worker_id);
    grpc::ClientContext ctx;
    prepare(ctx, kUnregisterDeadline);
    v1::UnregisterResponse resp;
    const grpc::Status status = s.stub->Unregister(&ctx, wid, &resp);
    if (!status.ok()) log->debug("Unregister: {}", rpc::describe(status));
    log->info("left {} ({} leases returned)", opts.master, ids.size());
  }

  // After the session broke: try to give the leases back (the master may still be there).
  void salvage(Session& s) {
    const auto ids = s.held_ids(/*include_abandoned=*/false);
    if (ids.empty()) return;
    v1::ReturnLeaseRequest req;
    req.mutable_worker_id()->set_id(s.worker_id);
    for (uint64_t id : ids) req.add_lease_ids(id);
    req.set_reason("worker lost its session");
    grpc::ClientContext ctx;
    prepare(ctx, kLostReturnDeadline);
    v1::ReturnLeaseResponse resp;
    if (s.stub->ReturnLease(&ctx, req, &resp).ok()) counters.tiles_returned += ids.size();
  }

  void run() {
    {
      std::lock_guard lock(mu);
      if (running) throw std::logic_error("WorkerNode::run() is already running");
      running = true;
    }
    Backoff backoff(opts.min_backoff_ms, opts.max_backoff_ms, std::random_device{}());
    while (!stopping) {
      std::string why;
      const std::shared_ptr<Session> s = connect(&why);
      if (!s) {
        if (stopping) break;
        const int delay = backoff.next_ms();
        // Warn on attempts 1, 2, 4, 8, ...: a master that stays away does not flood the log.
        const int attempt = backoff.attempts();
        log->log((attempt & (attempt - 1)) == 0 ? spdlog::level::warn : spdlog::level::debug,
                 "cannot register with {}: {}; retrying in {} ms", opts.master, why, delay);
        wait_for(nullptr, delay);
        continue;
      }
      run_session(s);
      if (s->healthy) backoff.reset();
      if (stopping && !s->lost) {
        farewell(*s);
        break;
      }
      salvage(*s);
      if (stopping) break;
      ++counters.reconnects;
      const int delay = backoff.next_ms();
      log->warn("lost the session with {} ({}); registering again in {} ms", opts.master, s->end_reason, delay);
      wait_for(nullptr, delay);
    }
    {
      std::lock_guard lock(mu);
      running = false;
      worker_id.clear();
    }
    cv.notify_all();
  }
};

WorkerNode::WorkerNode(WorkerNodeOptions options) : impl_(std::make_unique<Impl>(std::move(options))) {}

WorkerNode::~WorkerNode() {
  impl_->stop("worker destroyed");
  std::unique_lock lock(impl_->mu);
  impl_->cv.wait(lock, [&] { return !impl_->running; });
}

void WorkerNode::run() { impl_->run(); }

void WorkerNode::stop() { impl_->stop("stop requested"); }

WorkerNodeStats WorkerNode::stats() const {
  const auto& c = impl_->counters;
  WorkerNodeStats s;
  {
    std::lock_guard lock(impl_->mu);
    s.worker_id = impl_->worker_id;
    s.registered = impl_->session != nullptr && !impl_->session->ending;
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
