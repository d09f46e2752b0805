#include "client/remote_commands.h"

#include <fmt/format.h>
#include <google/protobuf/util/json_util.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <map>

#include "client/batch.h"
#include "client/batch_commands.h"
#include "client/farm.h"
#include "client/render_flags.h"
#include "common/scene_loader.h"
#include "common/tile.h"
#include "wire/rpc/token.h"

namespace epr {
namespace {

// A problem with what the user typed (exit kExitUsage).
struct UsageError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// ---- connection flags ---------------------------------------------------------------------------

struct ConnectionFlags {
  std::string master;
  std::string token_file;
  double timeout_seconds = 10;
  bool whole_job = false;  // submit: --timeout bounds the whole submission (JobClientOptions::end_by)
  bool tls = false;
  std::string ca_file;
};

std::string default_master() {
  const char* env = std::getenv("EPR_MASTER");
  return env && *env ? env : "localhost:50051";
}

void add_connection_flags(CLI::App* cmd, ConnectionFlags& f, bool whole_job = false) {
  f.master = default_master();
  cmd->add_option("--master", f.master,
                  "master address HOST:PORT, or several comma-separated (jobs are spread over them and found by the "
                  "master name in their ids), or a name resolving to several (default: $EPR_MASTER, else "
                  "localhost:50051)")
      ->capture_default_str();
  cmd->add_option("--token-file", f.token_file,
                  "file holding the bearer token for the master (default: $EPR_TOKEN; never pass tokens as flags)");
  f.whole_job = whole_job;
  if (whole_job) {
    f.timeout_seconds = 0;
    cmd->add_option("--timeout", f.timeout_seconds,
                    "seconds the whole submission may take: scene upload, SubmitJob and, with --wait, the job and "
                    "its results; 0: no limit (each request still has a deadline that grows with its size)")
        ->check(CLI::Range(0.0, 1e9))
        ->capture_default_str();
  } else {
    cmd->add_option("--timeout", f.timeout_seconds, "deadline of each request to the master, seconds")
        ->check(CLI::Range(0.001, 86400.0))
        ->capture_default_str();
  }
  cmd->add_flag("--tls", f.tls, "connect with TLS (system CA roots unless --ca-file)");
  cmd->add_option("--ca-file", f.ca_file, "PEM file of CA roots for TLS (implies --tls)")->check(CLI::ExistingFile);
}

// --token-file, else $EPR_TOKEN, under the rule of wire/rpc/token.h.
std::string read_token(const ConnectionFlags& f) {
  try {
    return rpc::configured_token(f.token_file).value_or("");
  } catch (const rpc::TokenError& e) {
    throw UsageError(e.what());
  }
}

JobClientOptions client_options(const ConnectionFlags& f) {
  JobClientOptions o;
  o.tls = f.tls || !f.ca_file.empty();
  o.ca_file = f.ca_file;
  o.token = read_token(f);
  const auto timeout = std::chrono::milliseconds(std::llround(f.timeout_seconds * 1000));
  if (!f.whole_job)
    o.timeout = timeout;
  else if (f.timeout_seconds > 0)
    o.end_by = std::chrono::system_clock::now() + timeout;
  return o;
}

// The masters of --master: one, a list, or names resolving to several (client/farm.h).
std::unique_ptr<Farm> make_farm(const ConnectionFlags& f) {
  std::unique_ptr<Farm> farm;
  try {
    farm = std::make_unique<Farm>(f.master, client_options(f));
  } catch (const std::invalid_argument& e) {
    throw UsageError(e.what());
  }
  // Asked once first: a master given under two addresses is used once by every command.
  if (farm->several()) farm->probe();
  return farm;
}

// The client of the master a command goes to: for a submission (no job_id) the least loaded one,
// noting on stderr the masters that did not answer; otherwise the one that holds job_id.
std::unique_ptr<JobClient> take_client(Farm& farm, const std::string& job_id = "") {
  FarmMaster& m = job_id.empty() ? farm.least_loaded() : farm.locate(job_id);
  if (job_id.empty()) print_failed(farm, "submit", "skipped");
  return std::move(m.client);
}

// ---- formatting ---------------------------------------------------------------------------------

std::string duration_text(double seconds) {
  if (!(seconds >= 0)) return "?";
  if (seconds < 60) return fmt::format("{:.1f}s", seconds);
  const long s = std::lround(seconds);
  if (s < 3600) return fmt::format("{}m{:02d}s", s / 60, s % 60);
  return fmt::format("{}h{:02d}m", s / 3600, (s % 3600) / 60);
}

std::string rounds_text(const v1::JobStatus& s) {
  return s.rounds_planned() ? fmt::format("{}/{}", s.round(), s.rounds_planned()) : fmt::format("{}", s.round());
}

bool stderr_is_tty() { return isatty(STDERR_FILENO) == 1; }

std::string join_paths(const std::vector<FetchedFile>& files) {
  std::string s;
  for (const auto& f : files) s += (s.empty() ? "" : ", ") + f.path;
  return s;
}

// Runs a command body, turning exceptions into a message on stderr and an exit code.
int guarded(const std::string& cmd, const std::function<int()>& body) {
  try {
    return body();
  } catch (const RpcError& e) {
    std::fprintf(stderr, "epr %s: %s\n", cmd.c_str(), e.what());
    if (e.code() == grpc::StatusCode::UNAUTHENTICATED)
      std::fprintf(stderr, "epr %s: give the master's token with --token-file or $EPR_TOKEN\n", cmd.c_str());
    return e.unreachable() ? kExitUnreachable : kExitRefused;
  } catch (const UsageError& e) {
    std::fprintf(stderr, "epr %s: %s\n", cmd.c_str(), e.what());
    return kExitUsage;
  } catch (const CLI::ValidationError& e) {
    std::fprintf(stderr, "epr %s: %s\n", cmd.c_str(), e.what());
    return kExitUsage;
  } catch (const SceneError& e) {
    std::fprintf(stderr, "epr %s: %s\n", cmd.c_str(), e.what());
    return kExitUsage;
  } catch (const std::invalid_argument& e) {
    std::fprintf(stderr, "epr %s: %s\n", cmd.c_str(), e.what());
    return kExitUsage;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "epr %s: %s\n", cmd.c_str(), e.what());
    return kExitJobFailed;
  }
}

}  // namespace

std::string progress_line(const v1::JobStatus& s, int bar_width) {
  switch (s.state()) {
    case v1::JOB_STATE_QUEUED:
      return fmt::format("job {} queued (priority {})", s.id(), s.priority());
    case v1::JOB_STATE_RUNNING:
    case v1::JOB_STATE_DONE:
    case v1::JOB_STATE_CANCELLED:
      break;
    default:
      return fmt::format("job {} {}", s.id(), state_name(s.state()));
  }
  // Completion: SKIP ends when every pixel has M + M' >= P, so its slowest pixel measures it; PT and
  // RP run exactly rounds_planned rounds (their M + M' overshoots P long before the end in RP).
  const double target = std::max<uint32_t>(1, s.target_spp());
  double frac = s.rounds_planned() ? double(s.round()) / s.rounds_planned() : s.spp_mean() / target;
  if (s.effective().mode() == v1::RENDER_MODE_SKIP) frac = s.spp_min() / target;
  if (s.state() == v1::JOB_STATE_DONE) frac = 1.0;
  frac = std::clamp(frac, 0.0, 1.0);
  const int filled = int(frac * bar_width);
  const std::string bar = std::string(size_t(filled), '#') + std::string(size_t(bar_width - filled), '.');
  const uint64_t pixels = uint64_t(s.effective().width()) * s.effective().height();
  const std::string skipped = pixels ? fmt::format("{:3.0f}%", 100.0 * s.pixels_skipped() / double(pixels)) : "  ?";
  const std::string eta = s.eta_seconds() >= 0 ? duration_text(s.eta_seconds()) : "?";
  return fmt::format("[{}] round {:>7}  spp {:6.1f}/{} (min {})  M' {:5.1f}  skipped {}  {:>7}  ETA {}", bar,
                     rounds_text(s), s.spp_mean(), s.target_spp(), s.spp_min(), s.reprojected_per_pixel_mean(), skipped,
                     duration_text(s.seconds_elapsed()), eta);
}

int follow_job(JobClient& client, const std::string& job_id, const FollowOptions& options) {
  const bool tty = stderr_is_tty();
  const uint32_t interval = options.min_interval_ms ? options.min_interval_ms : tty ? 200 : 1000;
  bool line_open = false;
  const v1::JobStatus last = client.watch(
      job_id,
      [&](const v1::JobStatus& s) {
        const std::string line = progress_line(s);
        if (tty) {
          std::fprintf(stderr, "\r%s\x1b[K", line.c_str());  // overwrite the previous line
          line_open = true;
        } else {
          std::fprintf(stderr, "%s\n", line.c_str());
        }
        std::fflush(stderr);
        return true;
      },
      interval);
  if (line_open) std::fprintf(stderr, "\n");

  const std::string state = state_name(last.state());
  if (last.state() == v1::JOB_STATE_FAILED) {
    std::fprintf(stderr, "job %s FAILED: %s\n", job_id.c_str(),
                 last.error_message().empty() ? "(no reason given)" : last.error_message().c_str());
    return kExitJobFailed;
  }
  std::fprintf(stderr, "job %s %s after %d round(s), %s%s\n", job_id.c_str(), state.c_str(), int(last.round()),
               duration_text(last.seconds_elapsed()).c_str(), last.budget_exhausted() ? " (time budget used up)" : "");
  if (auto w = nonfinite_warning(last.non_finite_dropped(), last.paths_traced()))
    std::fprintf(stderr, "job %s: warning: %s\n", job_id.c_str(), w->c_str());
  // A cancelled job keeps the results of its last committed round.
  const bool has_results = last.state() == v1::JOB_STATE_DONE || last.round() > 0;
  if (options.fetch && has_results) {
    try {
      const auto files = client.fetch_all(job_id, options.out_prefix);
      std::fprintf(stderr, "wrote %s\n", join_paths(files).c_str());
    } catch (const RpcError& e) {
      if (last.state() == v1::JOB_STATE_DONE) throw;
      // The contract keeps a cancelled job's last round fetchable; a master may still refuse it.
      std::fprintf(stderr, "no results fetched for the cancelled job: %s\n", e.what());
    }
  }
  return last.state() == v1::JOB_STATE_DONE ? kExitOk : kExitJobFailed;
}

// ---- the commands -------------------------------------------------------------------------------

struct RemoteCommands::State {
  // submit
  CLI::App* submit = nullptr;
  ConnectionFlags submit_conn;
  RenderOptions render;
  std::map<std::string, std::string> render_extra;
  SubmitOptions submit_opts;
  std::optional<double> time_budget;
  bool wait = false;
  std::string frames;  // --frames: a batch (client/batch_commands.h)
  CLI::Option* frames_flag = nullptr;
  WindowOptions window;  // --frame-window, --window-run
  CLI::Option* window_flag = nullptr;
  // watch / get / cancel
  CLI::App* watch = nullptr;
  CLI::App* get = nullptr;
  CLI::App* cancel = nullptr;
  ConnectionFlags watch_conn, get_conn, cancel_conn;
  std::string watch_job, get_job, cancel_job;
  std::string get_out;
  bool get_partial = false, get_json = false;
  bool watch_batch = false, get_batch = false, get_no_wait = false, cancel_batch = false;
  std::string list_batch;
  CLI::Option* list_batch_flag = nullptr;
  // list
  CLI::App* list = nullptr;
  ConnectionFlags list_conn;
  std::vector<std::string> list_states;
  size_t list_limit = 0;

  int run_submit();
  int run_watch();
  int run_get();
  int run_list();
  int run_cancel();
};

RemoteCommands::RemoteCommands(CLI::App& app) : s_(std::make_unique<State>()) {
  State& s = *s_;
  s.submit = app.add_subcommand("submit", "send a render job to a master (prints the job id)");
  add_render_flags(s.submit, s.render, s.render_extra, RenderFlagSet::kRemote);
  s.submit->add_option("--priority", s.submit_opts.priority, "scheduling priority, higher first")
      ->capture_default_str();
  s.submit->add_option("--name", s.submit_opts.name, "job name for listings (default: the scene's name)");
  s.submit
      ->add_option("--time-budget", s.time_budget, "wall-clock budget in seconds: the job ends DONE when it runs out")
      ->check(CLI::PositiveNumber);
  s.submit->add_flag("--wait", s.wait, "follow the job with a progress line and fetch its results to --out at the end");
  s.frames_flag =
      s.submit->add_option("--frames", s.frames,
                           "submit a batch of frames of the scene's camera animation: 1-240, 1-240x2 (step), 1,5,9; "
                           "prints the batch id (results: --out PREFIX gives PREFIX.0001.exr, ...)");
  s.window_flag = s.submit->add_option(
      "--frame-window", s.window.frame_window,
      "with --frames: each frame's vertices also feed the frames up to K away that its master renders with it "
      "(0: none; at most 16; modes skip and rp)");
  s.submit
      ->add_option("--window-run", s.window.run,
                   "with --frame-window: frames a master renders together (consecutive frame numbers; 1 to 64)")
      ->capture_default_str();
  s.submit->add_option("--window-halving", s.window.halving,
                       "with --frame-window: the distance in frames at which a neighbour's samples count half of the "
                       "frame's own (0, the default: all alike; at most 16)");
  add_connection_flags(s.submit, s.submit_conn, /*whole_job=*/true);

  s.watch = app.add_subcommand("watch", "follow a job's progress until it ends (exit 0 DONE, 1 FAILED/CANCELLED)");
  s.watch->add_option("job", s.watch_job, "job id, or batch id (epr submit --frames)")->required();
  s.watch->add_flag("--batch", s.watch_batch, "the id is a batch's");
  add_connection_flags(s.watch, s.watch_conn);

  s.get = app.add_subcommand("get", "fetch a job's results: PREFIX.exr, .png, .json and the statistics images");
  s.get->add_option("job", s.get_job, "job id, or batch id (epr submit --frames)")->required();
  s.get->add_option("--out", s.get_out,
                    "output prefix (default: the job id); a batch's frames go to PREFIX.0001.exr, ... as they finish");
  s.get->add_flag("--batch", s.get_batch, "the id is a batch's");
  s.get->add_flag("--no-wait", s.get_no_wait, "batch: write the frames done now, do not wait for the others");
  s.get->add_flag("--partial", s.get_partial, "also fetch a running job's latest committed round");
  s.get->add_flag("--json", s.get_json, "print the job's status as JSON on stdout instead of fetching results");
  add_connection_flags(s.get, s.get_conn);

  s.list = app.add_subcommand("list", "list the master's jobs, newest first");
  s.list->add_option("--state", s.list_states, "only jobs in this state (repeatable)")
      ->check(CLI::IsMember({"queued", "running", "done", "failed", "cancelled"}, CLI::ignore_case));
  s.list->add_option("--limit", s.list_limit, "at most this many jobs (0: all)")->capture_default_str();
  s.list_batch_flag = s.list->add_option("--batch", s.list_batch, "only the jobs of this batch");
  add_connection_flags(s.list, s.list_conn);

  s.cancel = app.add_subcommand("cancel", "stop a job; the results of its last committed round stay fetchable");
  s.cancel->add_option("job", s.cancel_job, "job id, or batch id (every job of the batch, on every master)")
      ->required();
  s.cancel->add_flag("--batch", s.cancel_batch, "the id is a batch's");
  add_connection_flags(s.cancel, s.cancel_conn);
}

RemoteCommands::~RemoteCommands() = default;

std::optional<int> RemoteCommands::run() {
  State& s = *s_;
  if (s.submit->parsed()) return guarded("submit", [&] { return s.run_submit(); });
  if (s.watch->parsed()) return guarded("watch", [&] { return s.run_watch(); });
  if (s.get->parsed()) return guarded("get", [&] { return s.run_get(); });
  if (s.list->parsed()) return guarded("list", [&] { return s.run_list(); });
  if (s.cancel->parsed()) return guarded("cancel", [&] { return s.run_cancel(); });
  return std::nullopt;
}

int RemoteCommands::State::run_submit() {
  finish_options(render, render_extra);
  if (auto err = render.validate()) throw UsageError(*err);
  submit_opts.time_budget_seconds = time_budget;
  auto farm = make_farm(submit_conn);
  if (window_flag->count() && !frames_flag->count()) throw UsageError("--frame-window needs --frames");
  // --frames '' is an empty frame list (parse_frame_list refuses it), not a plain job.
  if (frames_flag->count()) return submit_frames(*farm, render, submit_opts, frames, wait, render.out, window);
  SceneBundleData bundle = bundle_scene(render.scene, render.lighting, render.env_folder, BundleLoad::kUpload);
  if (wait)  // the results are fetched into render.out
    if (auto err = output_replaces_input(render.out, bundle.sources)) throw OutputError("--out " + *err);
  auto client = take_client(*farm);
  const std::string id = client->submit(client->make_job_spec(render, std::move(bundle), submit_opts));
  std::printf("%s\n", id.c_str());  // alone on its line, for scripts: ID=$(epr submit ...)
  std::fflush(stdout);
  if (!wait) {
    std::fprintf(stderr, "job %s queued at %s\n", id.c_str(), client->target().c_str());
    return kExitOk;
  }
  FollowOptions follow;
  follow.out_prefix = render.out;
  return follow_job(*client, id, follow);
}

int RemoteCommands::State::run_watch() {
  auto farm = make_farm(watch_conn);
  if (watch_batch || is_batch(*farm, watch_job)) return follow_batch(*farm, watch_job, {});
  auto client = take_client(*farm, watch_job);
  FollowOptions follow;
  follow.fetch = false;
  return follow_job(*client, watch_job, follow);
}

int RemoteCommands::State::run_get() {
  auto farm = make_farm(get_conn);
  if (get_batch || is_batch(*farm, get_job)) {
    if (get_json) return print_batch_json(*farm, get_job);
    BatchFollowOptions follow;
    follow.fetch = true;
    follow.out_prefix = output_prefix(get_out);
    follow.wait = !get_no_wait;
    return follow_batch(*farm, get_job, follow);
  }
  auto client = take_client(*farm, get_job);
  const v1::JobStatus status = client->get(get_job);
  if (get_json) {
    std::string json;
    google::protobuf::util::JsonPrintOptions opts;
    opts.add_whitespace = true;
    opts.preserve_proto_field_names = true;
    (void)google::protobuf::util::MessageToJsonString(status, &json, opts);
    std::printf("%s", json.c_str());
    return kExitOk;
  }
  if (status.state() == v1::JOB_STATE_FAILED) {
    std::fprintf(stderr, "epr get: job %s FAILED: %s\n", get_job.c_str(), status.error_message().c_str());
    return kExitJobFailed;
  }
  if (!is_terminal(status.state()) && !get_partial) {
    std::fprintf(stderr,
                 "epr get: job %s is %s (round %s): its results exist once it ends; --partial fetches the latest "
                 "committed round\n",
                 get_job.c_str(), state_name(status.state()).c_str(), rounds_text(status).c_str());
    return kExitJobFailed;
  }
  const std::string prefix = get_out.empty() ? get_job : output_prefix(get_out);
  if (auto err = output_replaces_input(prefix, {})) throw OutputError("--out " + *err);
  const auto files = client->fetch_all(get_job, prefix, get_partial);
  const bool partial = std::any_of(files.begin(), files.end(), [](const FetchedFile& f) { return f.partial; });
  std::fprintf(stderr, "wrote %s (round %d%s)\n", join_paths(files).c_str(), files.empty() ? 0 : int(files[0].round),
               partial ? ", partial" : "");
  return kExitOk;
}

int RemoteCommands::State::run_list() {
  static const std::map<std::string, v1::JobState> kStates{{"queued", v1::JOB_STATE_QUEUED},
                                                           {"running", v1::JOB_STATE_RUNNING},
                                                           {"done", v1::JOB_STATE_DONE},
                                                           {"failed", v1::JOB_STATE_FAILED},
                                                           {"cancelled", v1::JOB_STATE_CANCELLED}};
  std::vector<v1::JobState> states;
  for (std::string st : list_states) {
    std::transform(st.begin(), st.end(), st.begin(), [](unsigned char c) { return char(std::tolower(c)); });
    states.push_back(kStates.at(st));
  }
  // Every master's jobs in one table (a MASTER column when there are several); a master that does
  // not answer is named on stderr and the exit code says the list is partial.
  if (list_batch_flag->count() && !valid_batch_id(list_batch))  // '' would list every job
    throw UsageError(fmt::format("--batch '{}': a batch id is 1 to 64 of A-Z a-z 0-9 _ -", list_batch));
  auto farm = make_farm(list_conn);
  const std::vector<FarmJob> jobs = farm->list(states, list_limit, list_batch);
  print_failed(*farm, "list", "its jobs are not listed");

  // Column widths from the content, names shortened to keep the table readable.
  std::vector<std::vector<std::string>> rows{{"ID", "NAME", "STATE", "ROUND", "SPP", "ELAPSED", "BATCH", "FRAME"}};
  if (farm->several()) rows[0].push_back("MASTER");
  for (const auto& [master, j] : jobs) {
    std::string name = j.name().size() > 28 ? j.name().substr(0, 27) + "~" : j.name();
    rows.push_back({j.id(), name, state_name(j.state()), rounds_text(j),
                    fmt::format("{:.1f}/{}", j.spp_mean(), j.target_spp()),
                    j.state() == v1::JOB_STATE_QUEUED ? "-" : duration_text(j.seconds_elapsed()),
                    j.batch_id().empty() ? "-" : j.batch_id(), j.has_frame() ? std::to_string(j.frame()) : "-"});
    if (farm->several()) rows.back().push_back(master->endpoint.name);
  }
  std::vector<size_t> width(rows[0].size(), 0);
  for (const auto& r : rows)
    for (size_t c = 0; c < r.size(); ++c) width[c] = std::max(width[c], r[c].size());
  for (const auto& r : rows) {
    std::string line;
    for (size_t c = 0; c < r.size(); ++c) line += fmt::format("{:<{}}", r[c], c + 1 < r.size() ? width[c] + 2 : 0);
    std::printf("%s\n", line.c_str());
  }
  const auto failed = farm->failed();
  if (failed.empty()) return kExitOk;
  const bool away =
      std::any_of(failed.begin(), failed.end(), [](const FarmMaster* m) { return m->error->unreachable(); });
  return away ? kExitUnreachable : kExitRefused;
}

int RemoteCommands::State::run_cancel() {
  auto farm = make_farm(cancel_conn);
  if (cancel_batch || is_batch(*farm, cancel_job)) return epr::cancel_batch(*farm, cancel_job);
  auto client = take_client(*farm, cancel_job);
  const v1::JobStatus before_or_after = client->cancel(cancel_job);
  std::printf("%s %s\n", cancel_job.c_str(), state_name(before_or_after.state()).c_str());
  if (before_or_after.state() != v1::JOB_STATE_CANCELLED)
    std::fprintf(stderr, "epr cancel: job %s had already ended %s\n", cancel_job.c_str(),
                 state_name(before_or_after.state()).c_str());
  return kExitOk;
}

}  // namespace epr
