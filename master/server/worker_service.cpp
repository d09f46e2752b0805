#include "master/server/worker_service.h"

#include <fmt/format.h>

#include "common/limits.h"
#include "common/log.h"
#include "master/server/reactors.h"
#include "wire/convert.h"
#include "wire/rpc/chunked.h"

namespace epr {
namespace {

TileResultIdentity identity_of(const v1::TileResultHeader& h) {
  return {h.lease_id(), h.job_id(), h.round(), h.tile_index(), h.worker_id().id()};
}

grpc::Status unknown_worker(const std::string& id) {
  return {grpc::StatusCode::NOT_FOUND, fmt::format("unknown worker id '{}': register again", id)};
}

// Reads one tile result chunk by chunk into a TileResultAssembler, then commits it.
class SubmitTileReader final : public grpc::ServerReadReactor<v1::TileResultChunk> {
 public:
  SubmitTileReader(JobManager& jobs, v1::SubmitAck* ack) : jobs_(jobs), ack_(ack) { StartRead(&chunk_); }

  void OnReadDone(bool ok) override {
    if (!ok) return end_of_stream();
    if (draining_) return StartRead(&chunk_);  // a stale result: read it to the end, then say so
    if (!assembler_) {
      if (chunk_.part_case() != v1::TileResultChunk::kHeader)
        return Finish(invalid("the first chunk must be the header"));
      TileCheck check = jobs_.expect(identity_of(chunk_.header()));
      if (check.verdict != TileVerdict::kExpected) {
        if (!check.stale()) return refuse(chunk_.header(), check.why);
        draining_ = true;
        drained_ = check.verdict;
        reason_ = std::move(check.why);
        stale_job_ = chunk_.header().job_id();
        return StartRead(&chunk_);
      }
      header_ = chunk_.header();
      assembler_ = std::make_unique<TileResultAssembler>(std::move(check.expectation));
    }
    if (auto err = assembler_->add(&chunk_)) return refuse(header_, *err);
    StartRead(&chunk_);
  }
  void OnDone() override { delete this; }
  void OnCancel() override {}

 private:
  // An invalid result counts as a failure of the worker holding the lease (if the header names the
  // lease's holder) and gives the lease back, so the tile goes to another worker at once.
  void refuse(const v1::TileResultHeader& h, const std::string& why) {
    jobs_.fail_leases(h.worker_id().id(), {h.lease_id()}, LeaseFailure::kInvalidResult,
                      fmt::format("tile result refused: {}", why));
    Finish(invalid(why));
  }

  void end_of_stream() {
    if (draining_) {
      // e.g. the losing copy of a speculatively re-leased tile; an unknown job has nothing to count
      if (drained_ != TileVerdict::kUnknownJob)
        jobs_.count_dropped(
            stale_job_, drained_ == TileVerdict::kEarlierEpoch ? DropReason::kEarlierEpoch : DropReason::kStaleRound);
      ack_->set_accepted(false);
      ack_->set_outcome(v1::SUBMIT_OUTCOME_STALE);
      ack_->set_reason(reason_);
      return Finish(grpc::Status::OK);
    }
    if (!assembler_ || !assembler_->complete())
      return Finish(invalid("the stream ended before its trailer: nothing was committed"));
    const CommitOutcome out = jobs_.commit(header_.job_id(), header_.round(), header_.tile_index(), assembler_->take());
    ack_->set_accepted(out == CommitOutcome::kCommitted);
    ack_->set_outcome(out == CommitOutcome::kCommitted   ? v1::SUBMIT_OUTCOME_COMMITTED
                      : out == CommitOutcome::kDuplicate ? v1::SUBMIT_OUTCOME_DUPLICATE
                                                         : v1::SUBMIT_OUTCOME_STALE);
    if (out == CommitOutcome::kDuplicate) ack_->set_reason("the tile was already committed from another lease");
    if (out == CommitOutcome::kStale) ack_->set_reason("the job or round moved on");
    Finish(grpc::Status::OK);
  }

  JobManager& jobs_;
  v1::SubmitAck* ack_;
  v1::TileResultChunk chunk_;
  v1::TileResultHeader header_;
  std::unique_ptr<TileResultAssembler> assembler_;
  bool draining_ = false;
  TileVerdict drained_ = TileVerdict::kStaleRound;  // with draining_: the stale verdict
  std::string reason_, stale_job_;
};

}  // namespace

grpc::ServerUnaryReactor* WorkerServiceImpl::Register(grpc::CallbackServerContext* ctx, const v1::WorkerInfo* req,
                                                      v1::RegisterResponse* resp) {
  if (req->protocol_version() != v1::PROTOCOL_VERSION_V1)
    return finish(ctx,
                  {grpc::StatusCode::FAILED_PRECONDITION,
                   fmt::format("this master speaks protocol version 1, the worker {}", int(req->protocol_version()))});
  if (req->threads() < 1 || req->threads() > 4096) return finish(ctx, invalid("threads must be between 1 and 4096"));
  if (req->name().size() > limits::kMaxNameBytes)
    return finish(ctx, invalid(fmt::format("worker names are limited to {} bytes", limits::kMaxNameBytes)));
  if (req->cached_scenes_size() > 4096) return finish(ctx, invalid("cached_scenes is limited to 4096 hashes"));
  resp->mutable_worker_id()->set_id(
      jobs_.register_worker(req->name(), req->threads(), {req->cached_scenes().begin(), req->cached_scenes().end()}));
  resp->set_heartbeat_interval_ms(uint32_t(jobs_.options().heartbeat_interval_ms));
  resp->set_max_vertices_per_chunk(kMaxVerticesPerChunk);
  resp->set_max_chunk_bytes(kMaxChunkBytes);
  return finish(ctx, grpc::Status::OK);
}

grpc::ServerUnaryReactor* WorkerServiceImpl::Heartbeat(grpc::CallbackServerContext* ctx,
                                                       const v1::HeartbeatRequest* req, v1::HeartbeatResponse* resp) {
  const std::vector<uint64_t> leases(req->lease_ids().begin(), req->lease_ids().end());
  auto states = jobs_.heartbeat(req->worker_id().id(), leases);
  if (!states) return finish(ctx, unknown_worker(req->worker_id().id()));
  for (size_t i = 0; i < leases.size(); ++i) {
    auto* s = resp->add_leases();
    s->set_lease_id(leases[i]);
    s->set_valid((*states)[i].first);
    s->set_deadline_unix_ms((*states)[i].second);
  }
  return finish(ctx, grpc::Status::OK);
}

grpc::ServerWriteReactor<v1::SceneChunk>* WorkerServiceImpl::FetchScene(grpc::CallbackServerContext* ctx,
                                                                        const v1::FetchSceneRequest* req) {
  auto bundle = jobs_.scene(req->content_hash());
  if (!bundle || !bundle->builtin.empty()) {
    return new ListWriter<v1::SceneChunk>(
        {}, {grpc::StatusCode::NOT_FOUND, fmt::format("no file scene with hash '{}'", req->content_hash())});
  }
  return new ListWriter<v1::SceneChunk>(rpc::scene_chunks(*bundle));
}

namespace {

// Fills `resp` from a decision; the call's status.
grpc::Status lease_answer(const std::string& worker, const LeaseDecision& d, v1::Lease* resp) {
  if (std::holds_alternative<UnknownWorker>(d)) return unknown_worker(worker);
  if (auto* w = std::get_if<LeaseWait>(&d)) {
    resp->mutable_wait()->set_retry_after_ms(w->retry_after_ms);
    return grpc::Status::OK;
  }
  const TileLeaseInfo& t = std::get<TileLeaseInfo>(d);
  auto* l = resp->mutable_tile();
  l->set_lease_id(t.lease_id);
  l->set_job_id(t.job_id);
  l->set_round(t.round);
  l->set_tile_index(t.tile_index);
  l->mutable_rect()->set_x0(uint32_t(t.rect.x0));
  l->mutable_rect()->set_y0(uint32_t(t.rect.y0));
  l->mutable_rect()->set_x1(uint32_t(t.rect.x1));
  l->mutable_rect()->set_y1(uint32_t(t.rect.y1));
  const bool any_skip = std::any_of(t.skip.begin(), t.skip.end(), [](uint8_t s) { return s != 0; });
  if (any_skip) {
    std::string bits((t.skip.size() + 7) / 8, '\0');
    for (size_t i = 0; i < t.skip.size(); ++i)
      if (t.skip[i]) bits[i / 8] = char(uint8_t(bits[i / 8]) | uint8_t(1u << (i % 8)));
    l->set_skip_bits(bits);
  }
  const bool uniform = std::all_of(t.first_sample.begin(), t.first_sample.end(),
                                   [&](uint32_t f) { return f == t.first_sample.front(); });
  if (uniform) {
    l->set_uniform_first_sample_index(t.first_sample.empty() ? 0 : t.first_sample.front());
  } else {
    *l->mutable_first_sample_index() = {t.first_sample.begin(), t.first_sample.end()};
  }
  l->set_paths_per_pixel(t.paths_per_pixel);
  *l->mutable_pixel_paths() = {t.paths.begin(), t.paths.end()};
  l->set_seed(t.seed);
  to_render_settings(t.options, t.camera, t.codec_bounds, l->mutable_settings());
  for (const CameraSpec& c : t.window_cameras) to_proto(c, l->add_window_cameras());
  l->mutable_scene()->set_content_hash(t.scene_hash);
  l->mutable_scene()->set_builtin(t.scene_builtin);
  l->mutable_scene()->set_total_bytes(t.scene_bytes);
  l->mutable_scene()->set_triangle_count(t.triangles);
  l->set_deadline_unix_ms(t.deadline_ms);
  return grpc::Status::OK;
}

// A LeaseTile call that may be kept waiting (LeaseRequest.max_wait_ms, JobManager::lease_tile_or_park).
// Whoever comes first answers it: the manager's decision, or the client's cancellation. A tile granted
// to a call that the client cancelled before the answer reached it is given back at once.
class LeaseTileReactor final : public grpc::ServerUnaryReactor {
 public:
  LeaseTileReactor(JobManager& jobs, grpc::CallbackServerContext* ctx, const v1::LeaseRequest& req, v1::Lease* resp)
      : jobs_(jobs), ctx_(ctx), worker_(req.worker_id().id()), resp_(resp) {
    const int max_wait = int(std::min<uint32_t>(req.max_wait_ms(), uint32_t(JobManager::kMaxParkMs)));
    auto now = jobs_.lease_tile_or_park(
        worker_, max_wait, [this](LeaseDecision d) { answer(d); }, &handle_);
    if (now) answer(*now);
  }
  void OnCancel() override {
    if (jobs_.cancel_parked(handle_)) Finish(grpc::Status(grpc::StatusCode::CANCELLED, "the worker went away"));
  }
  void OnDone() override {
    if (granted_ && ctx_->IsCancelled()) jobs_.return_leases(worker_, {granted_});
    delete this;
  }

 private:
  void answer(const LeaseDecision& d) {
    if (auto* t = std::get_if<TileLeaseInfo>(&d)) granted_ = t->lease_id;
    Finish(lease_answer(worker_, d, resp_));
  }
  JobManager& jobs_;
  grpc::CallbackServerContext* ctx_;
  std::string worker_;
  v1::Lease* resp_;
  uint64_t handle_ = 0;   // 0: not parked
  uint64_t granted_ = 0;  // the lease id handed out, if any
};

}  // namespace

grpc::ServerUnaryReactor* WorkerServiceImpl::LeaseTile(grpc::CallbackServerContext* ctx, const v1::LeaseRequest* req,
                                                       v1::Lease* resp) {
  return new LeaseTileReactor(jobs_, ctx, *req, resp);
}

grpc::ServerUnaryReactor* WorkerServiceImpl::ReturnLease(grpc::CallbackServerContext* ctx,
                                                         const v1::ReturnLeaseRequest* req, v1::ReturnLeaseResponse*) {
  // Failures of kinds this master does not know (a newer worker) count as tile failures; the reason
  // ends up in logs and maybe a job's error, so it is kept short.
  const LeaseFailure failure = req->failure() == v1::LEASE_FAILURE_UNSPECIFIED ? LeaseFailure::kNone
                               : req->failure() == v1::LEASE_FAILURE_SCENE     ? LeaseFailure::kScene
                                                                               : LeaseFailure::kTile;
  const std::string reason = req->reason().substr(0, 1024);
  jobs_.fail_leases(req->worker_id().id(), {req->lease_ids().begin(), req->lease_ids().end()}, failure, reason);
  logger("master")->info("worker {} returned {} lease(s){}: {}", req->worker_id().id(), req->lease_ids_size(),
                         failure == LeaseFailure::kNone ? "" : " as failed", reason);
  return finish(ctx, grpc::Status::OK);
}

grpc::ServerReadReactor<v1::TileResultChunk>* WorkerServiceImpl::SubmitTile(grpc::CallbackServerContext* ctx,
                                                                            v1::SubmitAck* ack) {
  return new SubmitTileReader(jobs_, ack);
}

grpc::ServerUnaryReactor* WorkerServiceImpl::Unregister(grpc::CallbackServerContext* ctx, const v1::WorkerId* req,
                                                        v1::UnregisterResponse*) {
  jobs_.unregister_worker(req->id());
  return finish(ctx, grpc::Status::OK);
}

}  // namespace epr
