// JobClient: the client side of epr.v1.JobService (proto/epr/v1/job_service.proto), shared by the
// `epr` cluster commands (submit, watch, get, list, cancel) and the embedded default `epr render`,
// which submits to an in-process master over loopback.
//
// Every call has a deadline, so nothing hangs on a master that is down or silent, and deadlines
// follow the work a call carries (rpc::scaled_deadline):
//   * unary calls (GetJob, ListJobs, CancelJob): JobClientOptions::timeout;
//   * SubmitJob: `timeout` plus the time the master may take to load the job's file scene (its size
//     at min_scene_load_bytes_per_second): the master parses the scene before it answers;
//   * UploadScene: `timeout` plus the scene's size at min_transfer_bytes_per_second, after a
//     reachability check bounded by `timeout`; upload_progress reports the bytes sent;
//   * FetchResult (its size is known only once it starts): transfer_timeout, after the same check;
//   * WatchJob has no natural end: each call runs for at most watch_call_timeout and is then
//     re-issued (the master sends the current status first, so nothing is lost). If the master goes
//     away mid-watch (restart: jobs resume from their checkpoint), the watch reconnects for up to
//     watch_reconnect_timeout before it gives up. A CallCanceller stops it from another thread.
// JobClientOptions::end_by bounds all of them at once: a whole job's time limit (`epr render --timeout`).
//
// Errors are thrown as RpcError, carrying the grpc::Status and a message that names the master,
// e.g. "cannot reach master at localhost:50051 (UNAVAILABLE: failed to connect to all addresses)".
// Local problems (a scene file that cannot be read, an output that cannot be written) are
// SceneError and std::runtime_error.
#pragma once

#include <grpcpp/grpcpp.h>

#include <chrono>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "common/check.h"
#include "common/render_options.h"
#include "epr/v1/job_service.grpc.pb.h"
#include "wire/scene_bundle.h"

namespace epr {

/// An error status from the master (or no answer from it), with a message for humans.
class RpcError : public std::runtime_error {
 public:
  RpcError(grpc::Status status, const std::string& message) : std::runtime_error(message), status_(std::move(status)) {}
  const grpc::Status& status() const { return status_; }
  grpc::StatusCode code() const { return status_.error_code(); }
  /// True when the master could not be reached or did not answer in time (UNAVAILABLE,
  /// DEADLINE_EXCEEDED), as opposed to an answer that refused the request.
  bool unreachable() const;

 private:
  grpc::Status status_;
};

/// How far an upload has come: reported at most about once a second, and once when it is done. A
/// scene of at least kLoadReportBytes is reported twice more: as the master starts loading it (on
/// SubmitJob, which answers once the scene is loaded and checked) and when it has.
struct UploadProgress {
  enum class Stage { kUploading, kUploaded, kLoading, kLoaded };
  static constexpr uint64_t kLoadReportBytes = 1 << 20;
  uint64_t sent = 0, total = 0;  // bytes of scene files
  double seconds = 0;            // since the stage began (kLoaded: the master's load and check)
  bool done = false;             // the upload is complete (every stage but kUploading)
  Stage stage = Stage::kUploading;
};
using UploadProgressCallback = std::function<void(const UploadProgress&)>;

/// The default UploadProgressCallback: a line on stderr ("uploading the scene: 12.0 of 200.0 MiB (6%)").
void print_upload_progress(const UploadProgress& p);

struct JobClientOptions {
  bool tls = false;
  std::string ca_file;  // PEM roots for TLS; empty: the system's roots
  // TLS to a master reached by address (wire/rpc/master_list.h): the name its certificate holds.
  std::string tls_server_name;
  // Sent as "authorization: Bearer <token>" metadata on every call when not empty (wire/rpc/token.h).
  std::string token;
  std::chrono::milliseconds timeout{10'000};                  // unary calls and connection checks
  std::chrono::milliseconds transfer_timeout{600'000};        // a whole upload or result download
  std::chrono::milliseconds watch_call_timeout{300'000};      // one WatchJob call before re-issuing it
  std::chrono::milliseconds watch_reconnect_timeout{60'000};  // master unreachable mid-watch: give up after
  double min_transfer_bytes_per_second = 256 * 1024;          // slowest upload accepted
  double min_scene_load_bytes_per_second = 1e6;               // slowest scene parse on the master accepted
  // Every call ends by then (DEADLINE_EXCEEDED); unset: no limit beyond each call's own deadline.
  std::optional<std::chrono::system_clock::time_point> end_by;
  UploadProgressCallback upload_progress = print_upload_progress;  // empty: no report
  // File scenes up to this size travel inline in the JobSpec (the master's message limit is 4 MiB for
  // the whole spec); larger ones are streamed with UploadScene first.
  size_t inline_scene_limit = 3u << 20;
  // Set: file scenes go to this instead, whatever their size (a master in this process taking the
  // bundle as it is, the embedded render); returns the content hash the job names.
  std::function<std::string(SceneBundleData)> store_scene;
};

/// What a job is besides its RenderOptions.
struct SubmitOptions {
  std::string name;  // empty: derived from the scene ("cornell", "room.obj")
  int32_t priority = 0;
  std::optional<double> time_budget_seconds;
  // Idempotency key (JobSpec.request_id); empty: a random one, so that a SubmitJob retried after a
  // deadline does not queue the job twice.
  std::string request_id;
};

/// Cancels a JobClient call from another thread (e.g. a watch when the user presses Ctrl-C). Once
/// cancelled it stays cancelled: calls that use it afterwards fail at once with CANCELLED.
class CallCanceller {
 public:
  void cancel() EPR_EXCLUDES(mu_);
  bool cancelled() const EPR_EXCLUDES(mu_);

 private:
  friend class JobClient;
  // Registers the context of the call in flight; false if already cancelled.
  bool attach(grpc::ClientContext* ctx) EPR_EXCLUDES(mu_);
  void detach() EPR_EXCLUDES(mu_);

  mutable Mutex mu_;
  grpc::ClientContext* active_ EPR_GUARDED_BY(mu_) = nullptr;
  bool cancelled_ EPR_GUARDED_BY(mu_) = false;
};

/// One result file written by fetch.
struct FetchedFile {
  v1::ResultKind kind = v1::RESULT_KIND_UNSPECIFIED;
  std::string path;
  uint64_t bytes = 0;
  uint32_t round = 0;    // the committed round the file reflects
  bool partial = false;  // the job was not in a terminal state
};

using WatchCallback = std::function<bool(const v1::JobStatus&)>;  // false: stop watching

class JobClient {
 public:
  /// target is "HOST:PORT" (e.g. "localhost:50051", "127.0.0.1:41234"). No connection is made yet.
  /// Throws std::runtime_error if the CA file cannot be read or the token is not one token of
  /// printable ASCII (rpc::is_valid_token).
  explicit JobClient(const std::string& target, JobClientOptions options = {});
  /// Over an existing channel (e.g. an in-process one); `target` only names it in messages.
  JobClient(std::shared_ptr<grpc::Channel> channel, const std::string& target, JobClientOptions options = {});

  const std::string& target() const { return target_; }
  const JobClientOptions& options() const { return options_; }

  /// Throws RpcError unless a connection to the master is established within options().timeout.
  /// Fails at once when the connection is refused.
  void check_reachable();

  /// The JobSpec for `opts` (scene: opts.scene). Built-ins go by name; files inline when small,
  /// otherwise they are uploaded first and referred to by hash. The camera is always set: the
  /// overrides when they name all of eye, look, up and fov, otherwise the scene's own camera (built-ins
  /// and scene JSON files are loaded locally for it) with the overrides applied. Throws SceneError for
  /// unreadable scenes or unknown built-ins, std::invalid_argument for a bad camera or name.
  v1::JobSpec make_job_spec(const RenderOptions& opts, const SubmitOptions& submit = {});
  /// The same with the scene already bundled (bundle_scene(opts.scene)).
  v1::JobSpec make_job_spec(const RenderOptions& opts, SceneBundleData bundle, const SubmitOptions& submit = {});
  /// Queues `opts` as a job; returns its id.
  std::string submit(const RenderOptions& opts, const SubmitOptions& submit = {});
  /// Queues a ready spec (retrying once after a deadline when spec.request_id is set); returns its id.
  /// The deadline allows for loading its file scene (inline, or uploaded by this client).
  std::string submit(const v1::JobSpec& spec);
  /// Streams a file scene to the master; returns its content hash (for SceneBundle.uploaded_hash).
  std::string upload_scene(const SceneBundleData& bundle);

  v1::JobStatus get(const std::string& job_id);
  /// Jobs newest first (all pages), optionally only those in `states` and of the batch `batch_id`
  /// (ListJobsRequest.batch_id); at most `limit` (0: all).
  std::vector<v1::JobStatus> list(const std::vector<v1::JobState>& states = {}, size_t limit = 0,
                                  const std::string& batch_id = "");
  /// The status after the call (unchanged for a job already in a terminal state).
  v1::JobStatus cancel(const std::string& job_id);
  /// The master's name and load (GetMasterInfo); an empty MasterInfo from a master without the call.
  v1::MasterInfo master_info();

  /// Calls `on_status` with the job's status now and after every committed round and state change,
  /// until the job reaches a terminal state or `on_status` returns false. Returns the last status
  /// received. min_interval_ms spaces updates (state changes always come). Throws RpcError for an
  /// unknown job, an unreachable master, or CANCELLED when `canceller` fires.
  v1::JobStatus watch(const std::string& job_id, const WatchCallback& on_status, uint32_t min_interval_ms = 0,
                      CallCanceller* canceller = nullptr);

  /// Downloads one result to `path` atomically (temporary file beside it, then rename), checking the
  /// offsets, total size and SHA-256 announced in the header. allow_partial: also a RUNNING job's
  /// latest committed round.
  FetchedFile fetch(const std::string& job_id, v1::ResultKind kind, const std::string& path,
                    bool allow_partial = false);
  /// Downloads every result kind the job has (common/result_kinds.h) as PREFIX + its suffix, the
  /// files `epr render` writes. Kinds the master answers with NOT_FOUND or FAILED_PRECONDITION (not
  /// produced by the job's mode) or INVALID_ARGUMENT (unknown to an older master) are skipped, except
  /// the EXR, whose error is thrown.
  std::vector<FetchedFile> fetch_all(const std::string& job_id, const std::string& prefix, bool allow_partial = false);

 private:
  void prepare(grpc::ClientContext* ctx, std::chrono::milliseconds timeout) const;
  /// `timeout`, cut to what is left before options().end_by (at least 1 ms).
  std::chrono::milliseconds bounded(std::chrono::milliseconds timeout) const;
  bool past_end_by() const;
  [[noreturn]] void fail(const grpc::Status& status, const std::string& call) const;
  template <class Call>
  v1::JobStatus job_id_call(const std::string& job_id, const char* what, Call&& call) const;
  FetchedFile fetch_to(const std::string& job_id, v1::ResultKind kind,
                       const std::function<std::string(const v1::ResultHeader&)>& path_for, bool allow_partial);

  std::string target_;
  JobClientOptions options_;
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<v1::JobService::Stub> stub_;
  mutable Mutex mu_;
  std::map<std::string, uint64_t> uploaded_bytes_ EPR_GUARDED_BY(mu_);  // scenes this client uploaded, by hash
};

/// "DONE", "RUNNING", ... for messages and tables.
std::string state_name(v1::JobState state);
bool is_terminal(v1::JobState state);

}  // namespace epr
