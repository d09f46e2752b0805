#include "worker/master_session.h"

#include <fmt/format.h>

#include <algorithm>

#include "common/thread_name.h"
#include "wire/rpc/channel.h"
#include "wire/rpc/chunked.h"
#include "wire/rpc/status.h"
#include "worker/backoff.h"
#include "worker/scene_fetch.h"
#include "worker/tile_renderer.h"

namespace epr {
namespace {

using namespace std::chrono_literals;
using Millis = std::chrono::milliseconds;

// Deadlines of the unary calls. FetchScene and SubmitTile scale with their size (kSlowLinkBytesPerSecond
// on top of a fixed allowance), so a large scene or tile on a slow link is not cut off.
constexpr Millis kRegisterDeadline = 10s;
constexpr Millis kLeaseDeadline = 10s;
constexpr Millis kReturnDeadline = 5s;
constexpr Millis kLostReturnDeadline = 1s;  // best effort after the session broke
constexpr Millis kUnregisterDeadline = 3s;
constexpr Millis kFetchDeadlineBase = 60s;
constexpr Millis kSubmitDeadlineBase = 30s;
constexpr double kSlowLinkBytesPerSecond = 1e6;
constexpr int kSubmitAttempts = 3;  // SubmitTile tries on UNAVAILABLE / DEADLINE_EXCEEDED

Millis size_deadline(Millis base, double bytes) {
  return rpc::scaled_deadline(base, uint64_t(std::max(0.0, bytes)), kSlowLinkBytesPerSecond);
}

}  // namespace

// ---- StopSignal -----------------------------------------------------------------------------------

void StopSignal::stop(const std::string& reason) {
  {
    MutexLock lock(mu_);
    if (!stopping_) reason_ = reason;
    stopping_ = true;
  }
  cv_.notify_all();
}

std::string StopSignal::reason() const {
  MutexLock lock(mu_);
  return reason_;
}

bool StopSignal::wait_for(int ms, const std::function<bool()>& until) {
  MutexLock lock(mu_);
  return cv_.wait_for(lock, Millis(ms), [&] { return stopping_.load() || (until && until()); });
}

void StopSignal::wait(const std::function<bool()>& until) {
  MutexLock lock(mu_);
  cv_.wait(lock, [&] { return stopping_.load() || until(); });
}

void StopSignal::notify(const std::function<void()>& change) {
  {
    MutexLock lock(mu_);
    change();
  }
  cv_.notify_all();
}

// ---- the session's state --------------------------------------------------------------------------

// Registers a call so that the end of the session can cancel it: always when the session is lost,
// and when the worker stops if cancel_on_stop (the calls that wait on the master).
class MasterSession::CallScope {
 public:
  CallScope(MasterSession& s, grpc::ClientContext& ctx, bool cancel_on_stop) : s_(s), ctx_(ctx) {
    s.track(ctx, cancel_on_stop);
  }
  ~CallScope() { s_.untrack(ctx_); }
  CallScope(const CallScope&) = delete;
  CallScope& operator=(const CallScope&) = delete;

 private:
  MasterSession& s_;
  grpc::ClientContext& ctx_;
};

void MasterSession::track(grpc::ClientContext& ctx, bool cancel_on_stop) {
  MutexLock lock(mu_);
  calls_[&ctx] = cancel_on_stop;
  if (lost_ || (cancel_on_stop && ending_)) ctx.TryCancel();
}

void MasterSession::untrack(grpc::ClientContext& ctx) {
  MutexLock lock(mu_);
  calls_.erase(&ctx);
}

MasterSession::MasterSession(Config config, StopSignal& signal, NodeCounters& counters,
                             std::shared_ptr<spdlog::logger> log)
    : config_(std::move(config)), signal_(signal), counters_(counters), log_(std::move(log)) {
  grpc::ChannelArguments args;
  // The channel's own reconnection follows the node's backoff rather than gRPC's (up to 120 s) default.
  args.SetInt(GRPC_ARG_INITIAL_RECONNECT_BACKOFF_MS, std::max(1, config_.min_backoff_ms));
  args.SetInt(GRPC_ARG_MIN_RECONNECT_BACKOFF_MS, std::max(1, config_.min_backoff_ms));
  args.SetInt(GRPC_ARG_MAX_RECONNECT_BACKOFF_MS, std::max(config_.min_backoff_ms, config_.max_backoff_ms));
  if (config_.tls.enabled && !config_.tls_server_name.empty())
    args.SetSslTargetNameOverride(config_.tls_server_name);  // connected by address: check the name's certificate
  channel_ = config_.in_process
                 ? config_.in_process(args)
                 : grpc::CreateCustomChannel(config_.master, rpc::channel_credentials(config_.tls), args);
  stub_ = v1::WorkerService::NewStub(channel_);
}

MasterSession::~MasterSession() = default;

void MasterSession::prepare(grpc::ClientContext& ctx, Millis deadline) const {
  rpc::prepare_call(ctx, deadline, config_.token);
}

std::string MasterSession::end_reason() const {
  MutexLock lock(mu_);
  return end_reason_;
}

void MasterSession::end(const std::string& reason, bool lost) {
  signal_.notify([&] {
    if (ending_ && !(lost && !lost_)) return;
    MutexLock lock(mu_);
    if (end_reason_.empty()) end_reason_ = reason;
    if (lost) lost_ = true;
    ending_ = true;
    for (auto& [ctx, cancel_on_stop] : calls_)
      if (lost || cancel_on_stop) ctx->TryCancel();
  });
}

bool MasterSession::wait(int ms) {
  return signal_.wait_for(ms, [&] { return ending_.load(); });
}

void MasterSession::call_failed(const char* what, const grpc::Status& status) {
  if (ending_) return;  // our own cancellation
  end(fmt::format("{}: {}", what, rpc::describe(status)), /*lost=*/true);
}

std::shared_ptr<MasterSession::Hold> MasterSession::hold(uint64_t lease_id) {
  MutexLock lock(mu_);
  auto& h = held_[lease_id];
  if (!h) {
    h = std::make_shared<Hold>();
    h->lease_id = lease_id;
  }
  return h;
}

void MasterSession::release(uint64_t lease_id) {
  MutexLock lock(mu_);
  held_.erase(lease_id);
}

std::vector<uint64_t> MasterSession::held_ids(bool include_abandoned) const {
  MutexLock lock(mu_);
  std::vector<uint64_t> ids;
  for (const auto& [id, h] : held_)
    if (include_abandoned || !h->abandoned) ids.push_back(id);
  return ids;
}

// ---- calls ----------------------------------------------------------------------------------------

grpc::Status MasterSession::register_worker() {
  v1::WorkerInfo info;
  info.set_protocol_version(v1::PROTOCOL_VERSION_V1);
  info.set_name(config_.name);
  info.set_threads(uint32_t(config_.threads));
  for (const auto& h : cached_scene_hashes(config_.cache_dir)) info.add_cached_scenes(h);

  grpc::ClientContext ctx;
  prepare(ctx, kRegisterDeadline);
  v1::RegisterResponse resp;
  grpc::Status status;
  {
    CallScope scope(*this, ctx, /*cancel_on_stop=*/true);
    status = stub_->Register(&ctx, info, &resp);
  }
  if (!status.ok()) return status;
  const std::string& id = resp.worker_id().id();
  if (id.empty() || id.size() > 64) return {grpc::StatusCode::UNKNOWN, "Register answered without a usable worker id"};
  worker_id_ = id;
  heartbeat_ms_ = std::clamp<uint32_t>(resp.heartbeat_interval_ms() ? resp.heartbeat_interval_ms() : 1000, 50, 60000);
  if (resp.max_vertices_per_chunk()) limits_.max_vertices_per_chunk = resp.max_vertices_per_chunk();
  if (resp.max_chunk_bytes()) limits_.max_chunk_bytes = resp.max_chunk_bytes();
  registered_ = true;
  // Which master this is, whatever the address (a master under two addresses is served once).
  grpc::ClientContext info_ctx;
  prepare(info_ctx, kRegisterDeadline);
  v1::MasterInfo master;
  {
    CallScope scope(*this, info_ctx, /*cancel_on_stop=*/true);
    if (v1::JobService::NewStub(channel_)->GetMasterInfo(&info_ctx, v1::MasterInfoRequest{}, &master).ok())
      master_instance_ = master.instance();
  }
  return grpc::Status::OK;
}

void MasterSession::heartbeat_loop() {
  set_thread_name("epr-heartbeat");
  while (!ending_) {
    if (wait(int(heartbeat_ms_))) break;
    v1::HeartbeatRequest req;
    req.mutable_worker_id()->set_id(worker_id_);
    for (uint64_t id : held_ids(/*include_abandoned=*/false)) req.add_lease_ids(id);
    grpc::ClientContext ctx;
    prepare(ctx, Millis(std::clamp<int64_t>(2 * int64_t(heartbeat_ms_), 2000, 10000)));
    CallScope scope(*this, ctx, /*cancel_on_stop=*/true);
    v1::HeartbeatResponse resp;
    const grpc::Status status = stub_->Heartbeat(&ctx, req, &resp);
    if (!status.ok()) {
      call_failed("Heartbeat", status);
      break;
    }
    healthy_ = true;
    MutexLock lock(mu_);
    for (const auto& state : resp.leases()) {
      if (state.valid()) continue;
      if (auto it = held_.find(state.lease_id()); it != held_.end()) it->second->abandoned = true;
    }
  }
}

MasterSession::LeaseCall MasterSession::lease_tile(uint32_t max_wait_ms) {
  v1::LeaseRequest req;
  req.mutable_worker_id()->set_id(worker_id_);
  req.set_max_wait_ms(max_wait_ms);
  grpc::ClientContext ctx;
  prepare(ctx, kLeaseDeadline);
  LeaseCall call;
  {
    // Cancelled by a stop (the master may be holding it): a tile the master granted before it saw the
    // cancellation is given back by the master itself.
    CallScope scope(*this, ctx, /*cancel_on_stop=*/true);
    call.status = stub_->LeaseTile(&ctx, req, &call.lease);
  }
  if (call.status.ok()) {
    healthy_ = true;
    if (call.lease.has_tile()) hold(call.lease.tile().lease_id());
  }
  return call;
}

bool MasterSession::submit(const v1::TileLease& lease, const Bounds3& codec_bounds, const TileResult& result,
                           const Hold& h) {
  const TileResultIdentity identity{lease.lease_id(), lease.job_id(), lease.round(), lease.tile_index(), worker_id_};
  Backoff retry(200, 2000, lease.lease_id());
  for (int attempt = 1;; ++attempt) {
    TileResultWriter writer(result, identity, codec_bounds, limits_);
    const auto& head = writer.header();
    const double bytes =
        17.0 * head.pixel_count() + 16.0 * double(head.vertex_count()) + 17.0 * double(head.exact_sample_count());
    grpc::ClientContext ctx;
    prepare(ctx, size_deadline(kSubmitDeadlineBase, bytes));
    CallScope scope(*this, ctx, /*cancel_on_stop=*/false);
    v1::SubmitAck ack;
    auto stream = stub_->SubmitTile(&ctx, &ack);
    write_tile_result(writer, *stream);  // the trailer goes with the half-close
    const grpc::Status status = stream->Finish();
    if (status.ok()) {
      switch (ack.outcome()) {
        case v1::SUBMIT_OUTCOME_COMMITTED:
          ++counters_.tiles_committed;
          counters_.vertices_sent += head.vertex_count();
          counters_.exact_samples_sent += head.exact_sample_count();
          break;
        case v1::SUBMIT_OUTCOME_DUPLICATE:
          ++counters_.tiles_duplicate;
          break;
        case v1::SUBMIT_OUTCOME_STALE:
          ++counters_.tiles_stale;
          break;
        default:
          break;
      }
      log_->debug("lease {}: submitted, accepted={} {}", lease.lease_id(), ack.accepted(), ack.reason());
      return true;
    }
    const auto code = status.error_code();
    if (rpc::is_unreachable(code) && attempt < kSubmitAttempts && !lost_ && !h.abandoned) {
      const int delay = retry.next_ms();
      log_->warn("lease {}: SubmitTile failed ({}), retrying in {} ms", lease.lease_id(), rpc::describe(status), delay);
      if (signal_.wait_for(delay) && signal_.stopping()) return false;
      continue;
    }
    if (code == grpc::StatusCode::INVALID_ARGUMENT || code == grpc::StatusCode::FAILED_PRECONDITION ||
        code == grpc::StatusCode::RESOURCE_EXHAUSTED) {
      // The master refused this result; the session is fine. A bug on one side: say so loudly.
      ++counters_.tiles_refused;
      log_->error("lease {} (job {} tile {}): the master refused the result: {}", lease.lease_id(), lease.job_id(),
                  lease.tile_index(), rpc::describe(status));
      return true;
    }
    call_failed("SubmitTile", status);
    return false;
  }
}

grpc::Status MasterSession::send_return(const std::vector<uint64_t>& ids, const std::string& reason,
                                        v1::LeaseFailure failure, Millis deadline, bool tracked) {
  v1::ReturnLeaseRequest req;
  req.mutable_worker_id()->set_id(worker_id_);
  for (uint64_t id : ids) req.add_lease_ids(id);
  req.set_reason(reason);
  req.set_failure(failure);
  grpc::ClientContext ctx;
  prepare(ctx, deadline);
  v1::ReturnLeaseResponse resp;
  grpc::Status status;
  if (tracked) {
    CallScope scope(*this, ctx, /*cancel_on_stop=*/false);
    status = stub_->ReturnLease(&ctx, req, &resp);
  } else {
    status = stub_->ReturnLease(&ctx, req, &resp);
  }
  if (status.ok()) counters_.tiles_returned += ids.size();
  return status;
}

bool MasterSession::return_leases(const std::vector<uint64_t>& ids, const std::string& reason,
                                  v1::LeaseFailure failure) {
  if (ids.empty()) return true;
  const grpc::Status status = send_return(ids, reason, failure, kReturnDeadline, /*tracked=*/true);
  if (!status.ok()) {
    call_failed("ReturnLease", status);
    return false;
  }
  for (uint64_t id : ids) release(id);
  return true;
}

void MasterSession::farewell(const std::string& reason) {
  const auto ids = held_ids(/*include_abandoned=*/false);
  if (!ids.empty()) {
    const grpc::Status status =
        send_return(ids, reason, v1::LEASE_FAILURE_UNSPECIFIED, kReturnDeadline, /*tracked=*/false);
    if (!status.ok()) log_->warn("could not return {} leases: {}", ids.size(), rpc::describe(status));
  }
  v1::WorkerId wid;
  wid.set_id(worker_id_);
  grpc::ClientContext ctx;
  prepare(ctx, kUnregisterDeadline);
  v1::UnregisterResponse resp;
  const grpc::Status status = stub_->Unregister(&ctx, wid, &resp);
  if (!status.ok()) log_->debug("Unregister: {}", rpc::describe(status));
  log_->info("left {} ({} leases returned)", config_.master, ids.size());
}

void MasterSession::salvage() {
  const auto ids = held_ids(/*include_abandoned=*/false);
  if (!ids.empty())
    send_return(ids, "worker lost its session", v1::LEASE_FAILURE_UNSPECIFIED, kLostReturnDeadline, /*tracked=*/false);
}

std::string MasterSession::fetch_scene(const v1::SceneRef& ref, const std::string& cache_root) {
  log_->info("fetching scene {} ({} bytes) from the master", ref.content_hash(), ref.total_bytes());
  v1::FetchSceneRequest req;
  req.mutable_worker_id()->set_id(worker_id_);
  req.set_content_hash(ref.content_hash());
  grpc::ClientContext ctx;
  prepare(ctx, size_deadline(kFetchDeadlineBase, double(ref.total_bytes())));
  CallScope scope(*this, ctx, /*cancel_on_stop=*/true);
  SceneReceiver rx(cache_root.empty() ? config_.cache_dir : cache_root, ref.content_hash());
  auto reader = stub_->FetchScene(&ctx, req);
  const rpc::StreamEnd end =
      rpc::read_stream<v1::SceneChunk>(ctx, *reader, [&](const v1::SceneChunk& chunk) { return rx.add(chunk); });
  if (end.error && rx.disk_failure())
    throw CacheWriteError(fmt::format("FetchScene {}: {}", ref.content_hash(), *end.error));
  if (end.error) throw std::runtime_error(fmt::format("FetchScene {}: {}", ref.content_hash(), *end.error));
  if (!end.status.ok())
    throw std::runtime_error(fmt::format("FetchScene {}: {}", ref.content_hash(), rpc::describe(end.status)));
  std::string entry;
  if (auto e = rx.finish(&entry)) {
    const std::string what = fmt::format("FetchScene {}: {}", ref.content_hash(), *e);
    if (rx.disk_failure()) throw CacheWriteError(what);
    throw std::runtime_error(what);
  }
  ++counters_.scenes_fetched;
  counters_.scene_bytes_fetched += rx.bytes_received();
  return entry;
}

}  // namespace epr
