#include "client/job_client.h"

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <thread>

#include "common/builtin_scenes.h"
#include "common/log.h"
#include "common/scene_loader.h"
#include "wire/convert.h"
#include "wire/rpc/channel.h"
#include "wire/rpc/chunked.h"
#include "wire/rpc/status.h"
#include "wire/rpc/token.h"
#include "wire/sha256.h"

namespace epr {
namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

namespace {

constexpr size_t kMaxNameBytes = 256;  // JobSpec.name

std::string random_hex(size_t bytes) {
  std::random_device rd;
  std::string s;
  for (size_t i = 0; i < bytes; ++i) s += fmt::format("{:02x}", rd() & 0xff);
  return s;
}

std::string seconds_text(std::chrono::milliseconds ms) { return fmt::format("{:g} s", ms.count() / 1000.0); }

// "EXR", "STATS_IMAGE" ... for messages.
std::string kind_name(v1::ResultKind kind) {
  std::string n = v1::ResultKind_Name(kind);
  const std::string prefix = "RESULT_KIND_";
  return n.rfind(prefix, 0) == 0 ? n.substr(prefix.size()) : n;
}

// The name a job gets when the user gives none: the built-in's name or the scene file's name.
std::string default_job_name(const std::string& scene) {
  std::string n = scene.rfind("builtin:", 0) == 0 ? scene.substr(8) : fs::path(scene).filename().string();
  if (n.size() > kMaxNameBytes) n.resize(kMaxNameBytes);
  return n;
}

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return s;
}

}  // namespace

// ---- errors and cancellation --------------------------------------------------------------------

bool RpcError::unreachable() const { return rpc::is_unreachable(code()); }

std::string state_name(v1::JobState state) {
  const std::optional<JobState> s = from_proto(state);
  if (!s) return "UNSPECIFIED";
  std::string name = to_string(*s);
  for (char& c : name) c = char(std::toupper(static_cast<unsigned char>(c)));
  return name;
}

bool is_terminal(v1::JobState state) {
  const std::optional<JobState> s = from_proto(state);
  return s && is_terminal(*s);
}

void CallCanceller::cancel() {
  MutexLock lock(mu_);
  cancelled_ = true;
  if (active_) active_->TryCancel();
}

bool CallCanceller::cancelled() const {
  MutexLock lock(mu_);
  return cancelled_;
}

bool CallCanceller::attach(grpc::ClientContext* ctx) {
  MutexLock lock(mu_);
  if (cancelled_) return false;
  active_ = ctx;
  return true;
}

void CallCanceller::detach() {
  MutexLock lock(mu_);
  active_ = nullptr;
}

// ---- construction, deadlines, errors ------------------------------------------------------------

JobClient::JobClient(const std::string& target, JobClientOptions options)
    : target_(target), options_(std::move(options)) {
  if (!options_.token.empty() && !rpc::is_valid_token(options_.token))
    throw std::runtime_error("the bearer token must be printable ASCII without spaces");
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(64 << 20);  // ListJobs pages of large statuses; results come chunked
  args.SetUserAgentPrefix("epr");
  const rpc::ClientTls tls{options_.tls || !options_.ca_file.empty(), options_.ca_file, "", ""};
  if (tls.enabled && !options_.tls_server_name.empty()) args.SetSslTargetNameOverride(options_.tls_server_name);
  channel_ = grpc::CreateCustomChannel(target_, rpc::channel_credentials(tls), args);
  stub_ = v1::JobService::NewStub(channel_);
}

JobClient::JobClient(std::shared_ptr<grpc::Channel> channel, const std::string& target, JobClientOptions options)
    : target_(target),
      options_(std::move(options)),
      channel_(std::move(channel)),
      stub_(v1::JobService::NewStub(channel_)) {}

void JobClient::prepare(grpc::ClientContext* ctx, std::chrono::milliseconds timeout) const {
  rpc::prepare_call(*ctx, bounded(timeout), options_.token);
}

std::chrono::milliseconds JobClient::bounded(std::chrono::milliseconds timeout) const {
  if (!options_.end_by) return timeout;
  const auto left =
      std::chrono::duration_cast<std::chrono::milliseconds>(*options_.end_by - std::chrono::system_clock::now());
  return std::max(std::chrono::milliseconds(1), std::min(timeout, left));
}

bool JobClient::past_end_by() const { return options_.end_by && std::chrono::system_clock::now() >= *options_.end_by; }

void print_upload_progress(const UploadProgress& p) {
  const double mib = 1024.0 * 1024.0;
  using Stage = UploadProgress::Stage;
  if (p.stage == Stage::kLoading)
    std::fprintf(stderr, "the master is loading the scene (%.1f MiB)\n", double(p.total) / mib);
  else if (p.stage == Stage::kLoaded)
    std::fprintf(stderr, "the master loaded the scene in %.1f s\n", p.seconds);
  else if (p.done)
    std::fprintf(stderr, "uploaded the scene (%.1f MiB) in %.1f s\n", double(p.total) / mib, p.seconds);
  else
    std::fprintf(stderr, "uploading the scene: %.1f of %.1f MiB (%.0f%%)\n", double(p.sent) / mib,
                 double(p.total) / mib, p.total ? 100.0 * double(p.sent) / double(p.total) : 100.0);
  std::fflush(stderr);
}

void JobClient::fail(const grpc::Status& s, const std::string& call) const {
  const std::string detail = rpc::describe(s);
  switch (s.error_code()) {
    case grpc::StatusCode::UNAVAILABLE:
      throw RpcError(s, fmt::format("cannot reach master at {} ({})", target_, detail));
    case grpc::StatusCode::DEADLINE_EXCEEDED:
      if (past_end_by())
        throw RpcError(s, fmt::format("the time limit ran out during {} (master at {})", call, target_));
      throw RpcError(s, fmt::format("master at {} did not answer {} in time ({})", target_, call, detail));
    case grpc::StatusCode::CANCELLED:
      throw RpcError(s, fmt::format("{} to master at {} was cancelled", call, target_));
    default:
      throw RpcError(s, fmt::format("master at {} refused {}: {}", target_, call, detail));
  }
}

void JobClient::check_reachable() {
  const auto deadline = std::chrono::system_clock::now() + bounded(options_.timeout);
  grpc_connectivity_state state = channel_->GetState(/*try_to_connect=*/true);
  while (state != GRPC_CHANNEL_READY) {
    if (state == GRPC_CHANNEL_TRANSIENT_FAILURE || state == GRPC_CHANNEL_SHUTDOWN)
      fail(grpc::Status(grpc::StatusCode::UNAVAILABLE, "connection failed"), "connect");
    if (!channel_->WaitForStateChange(state, deadline))
      throw RpcError(
          grpc::Status(grpc::StatusCode::DEADLINE_EXCEEDED, "no connection"),
          fmt::format("cannot reach master at {} (no connection within {})", target_, seconds_text(options_.timeout)));
    state = channel_->GetState(true);
  }
}

// ---- submitting ---------------------------------------------------------------------------------

v1::JobSpec JobClient::make_job_spec(const RenderOptions& opts, const SubmitOptions& submit) {
  return make_job_spec(opts, bundle_scene(opts.scene, opts.lighting, opts.env_folder, BundleLoad::kUpload), submit);
}

v1::JobSpec JobClient::make_job_spec(const RenderOptions& opts, SceneBundleData bundle, const SubmitOptions& submit) {
  if (!bundle.builtin.empty())
    parse_builtin_spec(bundle.builtin.substr(8));  // unknown names fail here, not on the master
  // The job names its camera explicitly (the master requires one): the overrides, completed from the
  // scene's own camera unless they give all of it. OBJ files carry no camera (scene_loader.h: they
  // get CameraSpec's default), so only built-ins and scene JSON files are loaded for it.
  const bool full_camera = opts.eye && opts.look && opts.up && opts.fov;
  const std::string ext = lower(fs::path(opts.scene).extension().string());
  CameraSpec scene_camera;
  if (!full_camera && (ext != ".obj" || !bundle.builtin.empty()))
    scene_camera = bundle.camera ? *bundle.camera : load_scene(opts.scene).camera;
  if (auto err = opts.camera_for(scene_camera).validate()) throw std::invalid_argument("camera: " + *err);

  const bool upload =
      bundle.builtin.empty() && (options_.store_scene || bundle.total_bytes() > options_.inline_scene_limit);
  v1::JobSpec spec;
  if (upload) {
    const std::string hash = options_.store_scene ? options_.store_scene(std::move(bundle)) : upload_scene(bundle);
    spec = to_job_spec(opts, SceneBundleData{}, scene_camera);
    spec.mutable_scene()->Clear();
    spec.mutable_scene()->set_uploaded_hash(hash);
  } else {
    spec = to_job_spec(opts, bundle, scene_camera);
  }

  const std::string name = submit.name.empty() ? default_job_name(opts.scene) : submit.name;
  if (name.size() > kMaxNameBytes)
    throw std::invalid_argument(fmt::format("job name is {} bytes long, at most {}", name.size(), kMaxNameBytes));
  spec.set_name(name);
  spec.set_priority(submit.priority);
  if (submit.time_budget_seconds) spec.set_time_budget_seconds(*submit.time_budget_seconds);
  spec.set_request_id(submit.request_id.empty() ? random_hex(16) : submit.request_id);
  return spec;
}

std::string JobClient::submit(const RenderOptions& opts, const SubmitOptions& submit_opts) {
  return submit(make_job_spec(opts, submit_opts));
}

std::string JobClient::submit(const v1::JobSpec& spec) {
  // With a request id the master deduplicates, so a call that timed out (and may have queued the job)
  // is safe to repeat once.
  const int attempts = spec.request_id().empty() ? 1 : 2;
  // The master loads a file scene before it answers: the deadline grows with the scene's size.
  uint64_t scene_bytes = 0;
  for (const auto& f : spec.scene().files().files()) scene_bytes += f.data().size();
  if (spec.scene().has_uploaded_hash()) {
    MutexLock lock(mu_);
    if (auto it = uploaded_bytes_.find(spec.scene().uploaded_hash()); it != uploaded_bytes_.end())
      scene_bytes = it->second;
  }
  const auto timeout = rpc::scaled_deadline(options_.timeout, scene_bytes, options_.min_scene_load_bytes_per_second);
  const bool report = options_.upload_progress && scene_bytes >= UploadProgress::kLoadReportBytes;
  const auto t0 = std::chrono::steady_clock::now();
  if (report) options_.upload_progress({scene_bytes, scene_bytes, 0, true, UploadProgress::Stage::kLoading});
  for (int attempt = 1;; ++attempt) {
    grpc::ClientContext ctx;
    prepare(&ctx, timeout);
    v1::JobId id;
    const grpc::Status s = stub_->SubmitJob(&ctx, spec, &id);
    if (s.ok()) {
      if (id.id().empty())
        throw RpcError(grpc::Status(grpc::StatusCode::INTERNAL, "empty job id"),
                       fmt::format("master at {} answered SubmitJob without a job id", target_));
      if (report)
        options_.upload_progress({scene_bytes, scene_bytes,
                                  std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(), true,
                                  UploadProgress::Stage::kLoaded});
      return id.id();
    }
    if (s.error_code() == grpc::StatusCode::DEADLINE_EXCEEDED && attempt < attempts && !past_end_by()) {
      logger("client")->warn("SubmitJob to {} timed out; retrying with the same request id", target_);
      continue;
    }
    fail(s, "SubmitJob");
  }
}

std::string JobClient::upload_scene(const SceneBundleData& bundle) {
  if (!bundle.builtin.empty()) throw std::invalid_argument("built-in scenes are not uploaded");
  const std::string hash = content_hash(bundle);
  const uint64_t total = bundle.total_bytes();
  check_reachable();
  grpc::ClientContext ctx;
  prepare(&ctx, rpc::scaled_deadline(options_.timeout, total, options_.min_transfer_bytes_per_second));
  v1::SceneRef ref;
  auto writer = stub_->UploadScene(&ctx, &ref);

  // A false Write means the master has already answered (e.g. it knows the hash): stop sending and
  // read its answer. Progress goes out at most once a second.
  const auto t0 = Clock::now();
  auto reported = t0;
  UploadProgress progress{0, total, 0, false};
  auto send = [&](const v1::SceneChunk& chunk) {
    if (!writer->Write(chunk)) return false;
    progress.sent += chunk.data().data().size();
    if (options_.upload_progress && Clock::now() - reported >= std::chrono::seconds(1)) {
      reported = Clock::now();
      progress.seconds = std::chrono::duration<double>(reported - t0).count();
      options_.upload_progress(progress);
    }
    return true;
  };
  if (rpc::send_scene(bundle, send)) writer->WritesDone();
  const grpc::Status s = writer->Finish();
  if (!s.ok()) fail(s, "UploadScene");
  if (ref.content_hash() != hash)
    throw RpcError(
        grpc::Status(grpc::StatusCode::DATA_LOSS, "hash mismatch"),
        fmt::format("master at {} stored the uploaded scene as {}, expected {}", target_, ref.content_hash(), hash));
  {
    MutexLock lock(mu_);
    uploaded_bytes_[hash] = total;
  }
  if (options_.upload_progress) {
    progress.sent = total;  // also when the master already had the scene
    progress.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
    progress.done = true;
    progress.stage = UploadProgress::Stage::kUploaded;
    options_.upload_progress(progress);
  }
  logger("client")->info("uploaded scene {} ({} bytes) to {}", hash, total, target_);
  return hash;
}

// ---- unary queries ------------------------------------------------------------------------------

// GetJob and CancelJob: a JobId in, the job's status out.
template <class Call>
v1::JobStatus JobClient::job_id_call(const std::string& job_id, const char* what, Call&& call) const {
  v1::JobId req;
  req.set_id(job_id);
  v1::JobStatus status;
  const grpc::Status s = call(req, &status);
  if (!s.ok()) fail(s, what);
  return status;
}

v1::JobStatus JobClient::get(const std::string& job_id) {
  grpc::ClientContext ctx;
  prepare(&ctx, options_.timeout);
  return job_id_call(job_id, "GetJob",
                     [&](const v1::JobId& req, v1::JobStatus* out) { return stub_->GetJob(&ctx, req, out); });
}

std::vector<v1::JobStatus> JobClient::list(const std::vector<v1::JobState>& states, size_t limit,
                                           const std::string& batch_id) {
  std::vector<v1::JobStatus> jobs;
  v1::ListJobsRequest req;
  for (v1::JobState st : states) req.add_states(st);
  req.set_batch_id(batch_id);
  for (;;) {
    req.set_page_size(limit ? uint32_t(std::min<size_t>(100, limit - jobs.size())) : 100);
    grpc::ClientContext ctx;
    prepare(&ctx, options_.timeout);
    v1::ListJobsResponse resp;
    const grpc::Status s = stub_->ListJobs(&ctx, req, &resp);
    if (!s.ok()) fail(s, "ListJobs");
    for (auto& j : *resp.mutable_jobs()) jobs.push_back(std::move(j));
    if (limit && jobs.size() >= limit) {
      jobs.resize(limit);
      break;
    }
    // An empty or repeated token ends the listing (a repeated one would loop forever).
    if (resp.next_page_token().empty() || resp.next_page_token() == req.page_token()) break;
    req.set_page_token(resp.next_page_token());
  }
  return jobs;
}

v1::JobStatus JobClient::cancel(const std::string& job_id) {
  grpc::ClientContext ctx;
  prepare(&ctx, options_.timeout);
  return job_id_call(job_id, "CancelJob",
                     [&](const v1::JobId& req, v1::JobStatus* out) { return stub_->CancelJob(&ctx, req, out); });
}

v1::MasterInfo JobClient::master_info() {
  grpc::ClientContext ctx;
  prepare(&ctx, options_.timeout);
  v1::MasterInfo info;
  const grpc::Status s = stub_->GetMasterInfo(&ctx, v1::MasterInfoRequest{}, &info);
  if (s.error_code() == grpc::StatusCode::UNIMPLEMENTED) return {};
  if (!s.ok()) fail(s, "GetMasterInfo");
  return info;
}

// ---- watching -----------------------------------------------------------------------------------

v1::JobStatus JobClient::watch(const std::string& job_id, const WatchCallback& on_status, uint32_t min_interval_ms,
                               CallCanceller* canceller) {
  v1::WatchJobRequest req;
  req.set_job_id(job_id);
  req.set_min_interval_ms(min_interval_ms);
  check_reachable();  // the first call must not wait out watch_call_timeout on a silent address

  std::optional<v1::JobStatus> last;
  bool lost = false;             // the master went away mid-watch...
  Clock::time_point lost_since;  // ...at this time
  for (;;) {
    grpc::ClientContext ctx;
    auto timeout = options_.watch_call_timeout;
    if (lost) {
      // Wait for the master to come back, but only for what is left of the reconnect window.
      ctx.set_wait_for_ready(true);
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
          lost_since + options_.watch_reconnect_timeout - Clock::now());
      timeout = std::max(std::chrono::milliseconds(1), std::min(timeout, left));
    }
    prepare(&ctx, timeout);
    if (canceller && !canceller->attach(&ctx)) fail(grpc::Status(grpc::StatusCode::CANCELLED, "cancelled"), "WatchJob");

    auto reader = stub_->WatchJob(&ctx, req);
    v1::JobStatus st;
    bool stopped = false;
    try {
      while (!stopped && reader->Read(&st)) {
        last = st;
        lost = false;
        stopped = !on_status(st);
      }
    } catch (...) {
      ctx.TryCancel();
      reader->Finish();
      if (canceller) canceller->detach();
      throw;
    }
    if (stopped) ctx.TryCancel();
    const grpc::Status s = reader->Finish();
    if (canceller) canceller->detach();
    if (stopped || (last && is_terminal(last->state()))) return *last;
    if (canceller && canceller->cancelled()) fail(grpc::Status(grpc::StatusCode::CANCELLED, "cancelled"), "WatchJob");
    if (past_end_by()) fail(grpc::Status(grpc::StatusCode::DEADLINE_EXCEEDED, "the time limit ran out"), "WatchJob");

    const auto code = s.error_code();
    if (code == grpc::StatusCode::DEADLINE_EXCEEDED && last && !lost) continue;  // refresh the call
    // The stream ended without the job's end, or with a failure a later call may not meet again
    // (rpc::is_transient: the master away, busy or restarting); any other error is final.
    const bool went_away = s.ok() || rpc::is_transient(code);
    if (!last || !went_away)
      fail(s.ok() ? grpc::Status(grpc::StatusCode::UNAVAILABLE, "stream ended early") : s, "WatchJob");
    // The master went away after we saw the job (a restart: jobs resume from their checkpoint).
    if (!lost) {
      lost = true;
      lost_since = Clock::now();
      logger("client")->warn("lost the watch of job {} at {} ({}); reconnecting for up to {}", job_id, target_,
                             rpc::status_code_name(code), seconds_text(options_.watch_reconnect_timeout));
    } else if (Clock::now() - lost_since >= options_.watch_reconnect_timeout) {
      throw RpcError(
          s.ok() ? grpc::Status(grpc::StatusCode::UNAVAILABLE, "stream ended early") : s,
          fmt::format("lost master at {} while watching job {} and could not reconnect within {} ({})", target_, job_id,
                      seconds_text(options_.watch_reconnect_timeout), rpc::status_code_name(code)));
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(200));  // no hot loop on a master that ends streams at once
  }
}

// ---- results ------------------------------------------------------------------------------------

FetchedFile JobClient::fetch_to(const std::string& job_id, v1::ResultKind kind,
                                const std::function<std::string(const v1::ResultHeader&)>& path_for,
                                bool allow_partial) {
  static std::atomic<unsigned> counter{0};
  const std::string call = fmt::format("FetchResult({})", kind_name(kind));
  check_reachable();
  grpc::ClientContext ctx;
  prepare(&ctx, options_.transfer_timeout);
  v1::ResultRequest req;
  req.set_job_id(job_id);
  req.set_kind(kind);
  req.set_allow_partial(allow_partial);
  auto reader = stub_->FetchResult(&ctx, req);

  // The header, then the bytes into a temporary file beside the output, renamed at the end.
  std::optional<v1::ResultHeader> header;
  std::optional<rpc::ChunkTracker> received;
  FetchedFile file;
  std::string tmp;
  std::ofstream out;
  Sha256 sha;
  // "cannot write TMP: REASON", the system's reason of the failed call (errno, cleared before it).
  auto cannot_write = [&](std::error_code ec = {}) {
    const std::string why = ec ? ec.message() : errno ? std::strerror(errno) : "write failed";
    return std::runtime_error(fmt::format("cannot write {}: {}", tmp, why));
  };
  auto take = [&](const v1::ResultChunk& chunk) -> std::optional<std::string> {
    if (!header) {
      if (!chunk.has_header()) return "the first message is not the header";
      header = chunk.header();
      received.emplace(header->total_bytes());
      file = {kind, path_for(*header), header->total_bytes(), header->round(), header->partial()};
      tmp = fmt::format("{}.part-{}-{}", file.path, ::getpid(), counter++);
      if (const auto dir = fs::path(file.path).parent_path(); !dir.empty()) {
        std::error_code ec;
        fs::create_directories(dir, ec);
        if (ec) throw cannot_write(ec);
      }
      errno = 0;
      out.open(tmp, std::ios::binary | std::ios::trunc);
      if (!out) throw cannot_write();
      return std::nullopt;
    }
    if (!chunk.has_data()) return "a second header";
    const auto& d = chunk.data();
    if (auto err = received->add(d.offset(), d.data().size())) return err;
    errno = 0;
    out.write(d.data().data(), std::streamsize(d.data().size()));
    if (!out) throw cannot_write();
    sha.update(d.data());
    return std::nullopt;
  };
  // A reply that breaks the stream's rules (proto/epr/v1/job_service.proto, FetchResult).
  auto bad_stream = [&](const std::string& why) {
    return RpcError(grpc::Status(grpc::StatusCode::DATA_LOSS, why),
                    fmt::format("master at {} sent a bad {} stream for job {}: {}", target_, call, job_id, why));
  };
  try {
    const rpc::StreamEnd end = rpc::read_stream<v1::ResultChunk>(ctx, *reader, take);
    if (end.error) throw bad_stream(*end.error);
    if (!end.status.ok()) fail(end.status, call);
    if (!header) throw bad_stream("no header");
    errno = 0;
    out.close();
    if (!out) throw cannot_write();
    if (!received->complete())
      throw bad_stream(fmt::format("{} bytes received, {} announced", received->received(), header->total_bytes()));
    if (const std::string got = sha.hex(); got != lower(header->sha256()))
      throw bad_stream(fmt::format("SHA-256 {} does not match the announced {}", got, header->sha256()));
    fs::rename(tmp, file.path);
  } catch (...) {
    if (!tmp.empty()) {
      out.close();
      std::error_code ec;
      fs::remove(tmp, ec);
    }
    throw;
  }
  return file;
}

FetchedFile JobClient::fetch(const std::string& job_id, v1::ResultKind kind, const std::string& path,
                             bool allow_partial) {
  return fetch_to(
      job_id, kind, [&](const v1::ResultHeader&) { return path; }, allow_partial);
}

std::vector<FetchedFile> JobClient::fetch_all(const std::string& job_id, const std::string& prefix,
                                              bool allow_partial) {
  std::vector<FetchedFile> files;
  for (const ResultKindInfo& k : result_kinds()) {
    const v1::ResultKind kind = to_proto(k.kind);
    try {
      files.push_back(fetch_to(
          job_id, kind, [&](const v1::ResultHeader&) { return prefix + std::string(k.suffix); }, allow_partial));
    } catch (const RpcError& e) {
      // Kinds the job did not produce (reprojection kinds of a path-traced job), or that a master of
      // an older version does not know.
      const bool absent = e.code() == grpc::StatusCode::NOT_FOUND ||
                          e.code() == grpc::StatusCode::FAILED_PRECONDITION ||
                          e.code() == grpc::StatusCode::INVALID_ARGUMENT;
      if (k.kind == ResultKind::kExr || !absent) throw;
      logger("client")->debug("job {} has no {} result: {}", job_id, k.name, e.what());
    }
  }
  return files;
}

}  // namespace epr
