#include "master/server/job_service.h"

#include <fmt/format.h>

#include <algorithm>
#include <atomic>
#include <optional>
#include <random>
#include <string>

#include "common/check.h"
#include "common/log.h"
#include "master/reprojection_outcomes.h"
#include "master/server/reactors.h"
#include "master/server/window_run.h"
#include "wire/convert.h"
#include "wire/rpc/chunked.h"

namespace epr {
namespace {

grpc::Status no_job(const std::string& id) { return {grpc::StatusCode::NOT_FOUND, fmt::format("no job '{}'", id)}; }

// Sends a status whenever the job changes, at most one write in flight; the newest status wins.
class JobWatcher final : public grpc::ServerWriteReactor<v1::JobStatus> {
 public:
  JobWatcher(JobManager& jobs, const std::string& id, uint32_t min_interval_ms)
      : jobs_(jobs), min_interval_ms_(min_interval_ms) {
    auto first = jobs_.get(id);
    if (!first) {
      finished_ = true;  // an OnCancel that follows must not finish the call again
      Finish(no_job(id));
      return;
    }
    handle_ = jobs_.watch(id, [this](const JobSnapshot& s) { offer(s); });
    offer(*first);
  }
  void OnWriteDone(bool ok) override EPR_EXCLUDES(mu_) {
    MutexLock lock(mu_);
    writing_ = false;
    if (!ok) return finish_locked(grpc::Status(grpc::StatusCode::CANCELLED, "client went away"));
    if (last_written_final_) return finish_locked(grpc::Status::OK);
    if (pending_) write_locked();
  }
  void OnCancel() override EPR_EXCLUDES(mu_) {
    MutexLock lock(mu_);
    finish_locked(grpc::Status(grpc::StatusCode::CANCELLED, "watch cancelled"));
  }
  void OnDone() override {
    if (handle_) jobs_.unwatch(handle_);
    delete this;
  }

 private:
  void offer(const JobSnapshot& s) EPR_EXCLUDES(mu_) {
    MutexLock lock(mu_);
    if (finished_ || (have_written_ && s.version <= written_version_ && !is_terminal(s.state))) return;
    pending_ = s;
    if (!writing_) write_locked();
  }
  void write_locked() EPR_REQUIRES(mu_) {
    const JobSnapshot s = *pending_;
    pending_.reset();
    const auto now = std::chrono::steady_clock::now();
    if (min_interval_ms_ && have_written_ && !is_terminal(s.state) &&
        now - last_write_ < std::chrono::milliseconds(min_interval_ms_)) {
      pending_ = s;  // sent with the next change or the final status
      return;
    }
    to_proto(s, &out_);
    written_version_ = s.version;
    have_written_ = true;
    last_written_final_ = is_terminal(s.state);
    last_write_ = now;
    writing_ = true;
    StartWrite(&out_);
  }
  void finish_locked(grpc::Status st) EPR_REQUIRES(mu_) {
    if (finished_) return;
    finished_ = true;
    Finish(std::move(st));
  }

  JobManager& jobs_;
  uint32_t min_interval_ms_;
  uint64_t handle_ = 0;  // set by the constructor, read by OnDone
  Mutex mu_;
  v1::JobStatus out_ EPR_GUARDED_BY(mu_);  // the write in flight (gRPC reads it until OnWriteDone)
  std::optional<JobSnapshot> pending_ EPR_GUARDED_BY(mu_);
  uint64_t written_version_ EPR_GUARDED_BY(mu_) = 0;
  bool have_written_ EPR_GUARDED_BY(mu_) = false;
  bool writing_ EPR_GUARDED_BY(mu_) = false;
  bool finished_ EPR_GUARDED_BY(mu_) = false;
  bool last_written_final_ EPR_GUARDED_BY(mu_) = false;
  std::chrono::steady_clock::time_point last_write_ EPR_GUARDED_BY(mu_);
};

// Receives an uploaded scene: manifest, then each file's bytes in order.
class SceneUploader final : public grpc::ServerReadReactor<v1::SceneChunk> {
 public:
  SceneUploader(JobManager& jobs, v1::SceneRef* ref) : jobs_(jobs), ref_(ref) { StartRead(&chunk_); }
  void OnReadDone(bool ok) override {
    if (!ok) return end();
    if (chunk_.has_manifest()) {
      if (manifest_seen_) return Finish(invalid("the manifest must come once, first"));
      manifest_seen_ = true;
      const auto& m = chunk_.manifest();
      if (m.total_bytes() > jobs_.options().max_scene_bytes)
        return Finish(invalid(fmt::format("scene of {} bytes is over the limit of {}", m.total_bytes(),
                                          jobs_.options().max_scene_bytes)));
      expected_hash_ = m.content_hash();
      bundle_.entry_path = m.entry_path();
      uint64_t sum = 0;
      for (const auto& f : m.files()) {
        if (!is_safe_relative_path(f.path()))
          return Finish(invalid(fmt::format("scene file path '{}' is not safe", f.path())));
        sum += f.size_bytes();
        received_.emplace_back(f.size_bytes());
        bundle_.files.emplace_back(f.path(), std::string());
      }
      if (sum != m.total_bytes()) return Finish(invalid("the manifest's sizes do not add up to total_bytes"));
    } else if (chunk_.has_data()) {
      const auto& d = chunk_.data();
      if (!manifest_seen_) return Finish(invalid("data before the manifest"));
      if (d.file_index() >= bundle_.files.size()) return Finish(invalid("data for a file the manifest does not list"));
      auto& [path, file] = bundle_.files[d.file_index()];
      if (auto err = received_[d.file_index()].add(d.offset(), d.data().size()))
        return Finish(invalid(fmt::format("scene file '{}': {}", path, *err)));
      file += d.data();
    }
    StartRead(&chunk_);
  }
  void OnDone() override { delete this; }

 private:
  void end() {
    if (!manifest_seen_) return Finish(invalid("no manifest"));
    for (size_t i = 0; i < received_.size(); ++i)
      if (!received_[i].complete())
        return Finish(invalid(fmt::format("file '{}' is incomplete", bundle_.files[i].first)));
    const std::string hash = content_hash(bundle_);
    if (!expected_hash_.empty() && expected_hash_ != hash)
      return Finish(invalid(fmt::format("content hash mismatch: announced {}, computed {}", expected_hash_, hash)));
    ref_->set_content_hash(hash);
    ref_->set_total_bytes(bundle_.total_bytes());
    jobs_.add_scene(std::move(bundle_));
    Finish(grpc::Status::OK);
  }
  JobManager& jobs_;
  v1::SceneRef* ref_;
  v1::SceneChunk chunk_;
  SceneBundleData bundle_;
  std::vector<rpc::ChunkTracker> received_;  // per file of the manifest
  std::string expected_hash_;
  bool manifest_seen_ = false;
};

}  // namespace

void to_proto(const JobSnapshot& s, v1::JobStatus* out) {
  out->Clear();
  out->set_id(s.id);
  out->set_name(s.name);
  out->set_state(to_proto(s.state));
  out->set_error_message(s.error);
  out->set_priority(s.priority);
  to_render_settings(s.options, s.camera, Bounds3{}, out->mutable_effective());
  out->mutable_effective()->clear_codec_bounds();
  out->set_target_spp(uint32_t(s.options.spp));
  out->set_paths_per_round(uint32_t(s.options.paths_per_round));
  out->set_seed(s.options.seed);
  out->mutable_scene()->set_content_hash(s.scene_hash);
  out->mutable_scene()->set_builtin(s.scene_builtin);
  out->mutable_scene()->set_total_bytes(s.scene_bytes);
  out->mutable_scene()->set_triangle_count(s.triangles);
  out->set_round(uint32_t(s.progress.round));
  out->set_rounds_planned(uint32_t(s.rounds_planned));
  out->set_spp_min(uint32_t(s.progress.min_spp));
  out->set_spp_mean(s.progress.mean_spp);
  out->set_paths_per_pixel_mean(s.progress.mean_paths);
  out->set_reprojected_per_pixel_mean(s.progress.mean_reprojected);
  out->set_pixels_skipped(uint32_t(s.progress.pixels_skipped));
  out->set_paths_traced(s.progress.paths_traced);
  out->set_paths_skipped(s.progress.paths_skipped);
  out->set_rays_traced(s.counters.rays);
  out->set_vertices_received(s.counters.vertices_received);
  const ReprojectionOutcomes outcomes = ReprojectionOutcomes::of(s.counts, s.counters.worker_culled);
  out->set_vertices_accepted(outcomes.accepted);
  out->set_vertices_occluded(outcomes.occluded);
  out->set_vertices_culled(outcomes.culled);
  out->set_vertices_not_diffuse(outcomes.not_diffuse);
  out->set_non_finite_dropped(s.counters.non_finite + s.counts.invalid);
  out->set_tiles_leased(s.counters.tiles_leased);
  out->set_tiles_committed(s.counters.tiles_committed);
  out->set_tiles_re_leased(s.counters.tiles_re_leased);
  out->set_tiles_dropped(s.counters.tiles_dropped);
  out->set_workers_active(s.workers_active);
  out->set_tiles_speculative(s.counters.tiles_speculative);
  out->set_worker_failures(s.counters.worker_failures);
  out->set_workers_blocked(s.workers_blocked);
  out->set_submitted_unix_ms(s.submitted_ms);
  out->set_started_unix_ms(s.started_ms);
  out->set_finished_unix_ms(s.finished_ms);
  out->set_seconds_elapsed(s.seconds_elapsed);
  out->set_eta_seconds(s.eta_seconds);
  out->set_seconds_tracing(s.counters.seconds_tracing);
  out->set_seconds_reprojecting(s.counters.seconds_reprojecting);
  out->set_budget_exhausted(s.budget_exhausted);
  out->set_batch_id(s.batch.id);
  out->set_batch_name(s.batch.name);
  if (s.batch.frame) out->set_frame(*s.batch.frame);
  out->set_batch_frames(s.batch.frames);
}

grpc::Status JobServiceImpl::checked_request(const v1::JobSpec& req, const std::vector<uint32_t>& frames,
                                             JobRequest* jr) {
  if (auto err = from_job_spec(req, &jr->options, &jr->camera)) return invalid(*err);
  const auto& scene = req.scene();
  switch (scene.source_case()) {
    case v1::SceneBundle::kBuiltin:
      jr->bundle.builtin = scene.builtin();
      break;
    case v1::SceneBundle::kFiles:
      jr->bundle = from_proto(scene.files());
      if (!scene.content_hash().empty() && scene.content_hash() != content_hash(jr->bundle))
        return invalid("the scene's content_hash does not match its files");
      break;
    case v1::SceneBundle::kUploadedHash: {
      auto b = jobs_.scene(scene.uploaded_hash());
      if (!b) return {grpc::StatusCode::NOT_FOUND, fmt::format("no uploaded scene '{}'", scene.uploaded_hash())};
      jr->bundle = *b;
      break;
    }
    default:
      return invalid("the job has no scene");
  }
  jr->name = req.name();
  jr->priority = req.priority();
  jr->request_id = req.request_id();
  if (req.has_time_budget_seconds()) jr->time_budget_seconds = req.time_budget_seconds();
  jr->batch = batch_from_spec(req);
  if (auto err = jobs_.admit(jr, req.has_camera(), frames)) return invalid(*err);
  return grpc::Status::OK;
}

grpc::ServerUnaryReactor* JobServiceImpl::SubmitJob(grpc::CallbackServerContext* ctx, const v1::JobSpec* req,
                                                    v1::JobId* resp) {
  JobRequest jr;
  const std::vector<uint32_t> frames = req->has_frame() ? std::vector<uint32_t>{req->frame()} : std::vector<uint32_t>{};
  if (grpc::Status st = checked_request(*req, frames, &jr); !st.ok()) return finish(ctx, st);
  const auto r = jobs_.submit(std::move(jr));
  if (r.unstored) {
    jobs_.discard_checked_scene(r.scene_hash);
    return finish(ctx, grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED, r.error));
  }
  if (!r.error.empty()) {
    jobs_.discard_checked_scene(r.scene_hash);
    return finish(ctx, invalid(r.error));
  }
  resp->set_id(r.id);
  return finish(ctx, grpc::Status::OK);
}

grpc::ServerUnaryReactor* JobServiceImpl::CheckFrames(grpc::CallbackServerContext* ctx,
                                                      const v1::CheckFramesRequest* req, v1::CheckFramesReply*) {
  if (req->frames_size() == 0) return finish(ctx, invalid("no frames to check"));
  if (req->spec().has_frame()) return finish(ctx, invalid("the frames to check are in 'frames', not in the spec"));
  JobRequest jr;
  return finish(ctx, checked_request(req->spec(), {req->frames().begin(), req->frames().end()}, &jr));
}

grpc::ServerReadReactor<v1::SceneChunk>* JobServiceImpl::UploadScene(grpc::CallbackServerContext* ctx,
                                                                     v1::SceneRef* resp) {
  return new SceneUploader(jobs_, resp);
}

grpc::ServerUnaryReactor* JobServiceImpl::GetJob(grpc::CallbackServerContext* ctx, const v1::JobId* req,
                                                 v1::JobStatus* resp) {
  auto s = jobs_.get(req->id());
  if (!s) return finish(ctx, no_job(req->id()));
  to_proto(*s, resp);
  return finish(ctx, grpc::Status::OK);
}

grpc::ServerWriteReactor<v1::JobStatus>* JobServiceImpl::WatchJob(grpc::CallbackServerContext* ctx,
                                                                  const v1::WatchJobRequest* req) {
  return new JobWatcher(jobs_, req->job_id(), req->min_interval_ms());
}

// Newest first. The page token is the submission number of the last job sent: the next page holds
// the older jobs, so jobs submitted between two pages neither repeat nor shift one.
grpc::ServerUnaryReactor* JobServiceImpl::ListJobs(grpc::CallbackServerContext* ctx, const v1::ListJobsRequest* req,
                                                   v1::ListJobsResponse* resp) {
  const size_t page = req->page_size() ? std::min<size_t>(req->page_size(), 1000) : 100;
  std::optional<uint64_t> before;
  if (!req->page_token().empty()) {
    try {
      size_t used = 0;
      before = std::stoull(req->page_token(), &used);
      if (used != req->page_token().size()) throw std::invalid_argument("trailing characters");
    } catch (const std::exception&) {
      return finish(ctx, invalid("malformed page_token"));
    }
  }
  std::vector<JobSnapshot> selected;
  for (auto& s : jobs_.list())
    if ((!before || s.seq < *before) && (req->batch_id().empty() || s.batch.id == req->batch_id()) &&
        (req->states().empty() ||
         std::find(req->states().begin(), req->states().end(), to_proto(s.state)) != req->states().end()))
      selected.push_back(std::move(s));
  std::sort(selected.begin(), selected.end(), [](const JobSnapshot& a, const JobSnapshot& b) { return a.seq > b.seq; });
  for (size_t i = 0; i < selected.size() && i < page; ++i) to_proto(selected[i], resp->add_jobs());
  if (selected.size() > page) resp->set_next_page_token(std::to_string(selected[page - 1].seq));
  return finish(ctx, grpc::Status::OK);
}

namespace {
std::string random_instance() {
  std::random_device rd;
  return fmt::format("{:08x}{:08x}{:08x}{:08x}", rd(), rd(), rd(), rd());
}
}  // namespace

JobServiceImpl::JobServiceImpl(JobManager& jobs) : jobs_(jobs), instance_(random_instance()) {}

grpc::ServerUnaryReactor* JobServiceImpl::GetMasterInfo(grpc::CallbackServerContext* ctx, const v1::MasterInfoRequest*,
                                                        v1::MasterInfo* resp) {
  resp->set_name(jobs_.options().name);
  resp->set_instance(instance_);
  uint32_t queued = 0, running = 0;
  double samples_left = 0;
  for (const auto& s : jobs_.list()) {
    if (s.state != JobState::kQueued && s.state != JobState::kRunning) continue;
    ++(s.state == JobState::kQueued ? queued : running);
    const double pixels = double(s.options.width) * s.options.height;
    samples_left += pixels * std::max(0.0, double(s.options.spp) - s.progress.mean_spp);
  }
  resp->set_jobs_queued(queued);
  resp->set_jobs_running(running);
  resp->set_samples_left(uint64_t(samples_left));
  return finish(ctx, grpc::Status::OK);
}

grpc::ServerUnaryReactor* JobServiceImpl::CancelJob(grpc::CallbackServerContext* ctx, const v1::JobId* req,
                                                    v1::JobStatus* resp) {
  if (!jobs_.cancel(req->id())) return finish(ctx, no_job(req->id()));
  to_proto(*jobs_.get(req->id()), resp);
  return finish(ctx, grpc::Status::OK);
}

grpc::ServerWriteReactor<v1::ResultChunk>* JobServiceImpl::FetchResult(grpc::CallbackServerContext* ctx,
                                                                       const v1::ResultRequest* req) {
  using Writer = ListWriter<v1::ResultChunk>;
  const std::optional<ResultKind> kind = from_proto(req->kind());
  if (!kind) return new Writer({}, invalid("unknown result kind"));
  const ResultKindInfo& k = result_kind(*kind);
  const JobManager::ResultFile file = jobs_.result_file(req->job_id(), *kind, req->allow_partial());
  using Error = JobManager::ResultFile::Error;
  switch (file.error) {
    case Error::kNone:
      break;
    case Error::kNoJob:
      return new Writer({}, no_job(req->job_id()));
    case Error::kNotReady:
      return new Writer({}, {grpc::StatusCode::FAILED_PRECONDITION, file.why});
    case Error::kNotProduced:
      return new Writer({}, {grpc::StatusCode::NOT_FOUND, file.why});
    case Error::kFailed:
      return new Writer({}, {grpc::StatusCode::INTERNAL, file.why});
  }
  const std::string& bytes = file.bytes;
  std::vector<v1::ResultChunk> chunks(1);
  auto* h = chunks[0].mutable_header();
  h->set_kind(req->kind());
  h->set_media_type(std::string(k.media_type));
  h->set_suggested_filename(fmt::format("{}{}", req->job_id(), k.suffix));
  h->set_total_bytes(bytes.size());
  h->set_sha256(sha256_hex(bytes));
  h->set_round(uint32_t(file.round));
  h->set_partial(file.partial);
  rpc::for_each_chunk(bytes, [&](uint64_t offset, std::string_view piece) {
    auto* d = chunks.emplace_back().mutable_data();
    d->set_offset(offset);
    d->set_data(piece.data(), piece.size());
    return true;
  });
  return new Writer(std::move(chunks));
}

}  // namespace epr
