#include "client/batch_commands.h"

#include <fmt/format.h>
#include <google/protobuf/util/json_util.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <map>
#include <optional>
#include <set>
#include <thread>

#include "client/batch.h"
#include "client/exit_codes.h"
#include "client/render_flags.h"

namespace epr {
namespace {

std::string frame_label(const v1::JobStatus& s) {
  return s.has_frame() ? "frame " + frame_file_name("", s.frame()).substr(1) : "job " + s.id();
}

std::string summary_line(const BatchSummary& b, int bar_width = 30) {
  const int filled = int(b.progress * bar_width);
  const std::string bar = std::string(size_t(filled), '#') + std::string(size_t(bar_width - filled), '.');
  std::string rest;
  for (const auto& [n, what] :
       {std::pair{b.running, "running"},
        {b.queued + (b.frames - std::min(b.frames, b.done + b.running + b.queued + b.failed + b.cancelled)), "queued"},
        {b.failed, "failed"},
        {b.cancelled, "cancelled"}})
    if (n) rest += fmt::format(", {} {}", n, what);
  return fmt::format("batch {} ({}) [{}] {:3.0f}%  frames {}/{} done{}", b.id, b.name, bar, 100 * b.progress, b.done,
                     b.frames, rest);
}

// The event line of a frame that reached `s`'s state.
std::string event_line(const v1::JobStatus& s) {
  std::string line = fmt::format("{} (job {}) {}", frame_label(s), s.id(), state_name(s.state()));
  if (s.state() == v1::JOB_STATE_FAILED)
    line += ": " + (s.error_message().empty() ? std::string("(no reason given)") : s.error_message());
  else if (s.state() == v1::JOB_STATE_DONE)
    line += fmt::format(" after {} round(s), {:.1f}s", s.round(), s.seconds_elapsed());
  return line;
}

// For each frame of `batch`, the index in farm.masters() of the master it goes to: the one with the
// least work, counting its samples left at the probe and the frames given to it so far. A window
// run's frames go together, to where its first goes.
std::vector<size_t> spread_frames(Farm& farm, const FrameBatch& batch) {
  std::vector<size_t> where(batch.specs.size(), 0);
  if (!farm.several()) return where;
  farm.probe();
  std::vector<std::optional<double>> load;
  for (const FarmMaster& m : farm.masters())
    load.push_back(m.info ? std::optional<double>(double(m.info->samples_left())) : std::nullopt);
  if (std::none_of(load.begin(), load.end(), [](const auto& l) { return l.has_value(); }))
    throw *farm.masters()[0].error;
  for (size_t i = 0; i < batch.specs.size(); ++i) {
    const v1::JobSpec& spec = batch.specs[i];
    size_t best = load.size();
    const bool same_run = i > 0 && spec.frame_window() > 0 && spec.window_first() == batch.specs[i - 1].window_first();
    if (same_run) best = where[i - 1];
    for (size_t m = 0; m < load.size() && !same_run; ++m)
      if (load[m] && (best == load.size() || *load[m] < *load[best])) best = m;
    where[i] = best;
    *load[best] += double(spec.width()) * spec.height() * spec.target_spp();
  }
  return where;
}

}  // namespace

int submit_frames(Farm& farm, const RenderOptions& opts, const SubmitOptions& submit, const std::string& frames,
                  bool wait, const std::string& out_prefix, const WindowOptions& window) {
  const FrameBatch batch = plan_batch(opts, submit, parse_frame_list(frames), "", window);
  if (wait)  // the frames are fetched into out_prefix
    if (auto err = output_replaces_input(out_prefix, batch.bundle.sources)) throw OutputError("--out " + *err);
  const std::vector<size_t> where = spread_frames(farm, batch);
  print_failed(farm, "submit", "no frame goes to it");
  // Each master's frames in frame order, its scene uploaded once before them.
  std::vector<std::string> ids(batch.specs.size());
  std::string placed;
  for (size_t m = 0; m < farm.masters().size(); ++m) {
    JobClient& client = *farm.masters()[m].client;
    std::optional<v1::SceneBundle> scene;
    size_t count = 0;
    for (size_t i = 0; i < batch.specs.size(); ++i) {
      if (where[i] != m) continue;
      if (!scene) scene = scene_for(client, batch.bundle);
      v1::JobSpec spec = batch.specs[i];
      *spec.mutable_scene() = *scene;
      ids[i] = client.submit(spec);
      ++count;
    }
    if (count) placed += fmt::format("{}{} at {}", placed.empty() ? "" : ", ", count, farm.masters()[m].label());
  }
  std::printf("%s\n", batch.id.c_str());  // alone on its line, for scripts: BATCH=$(epr submit ... --frames 1-9)
  std::fflush(stdout);
  if (farm.several())
    std::fprintf(stderr, "batch %s (%s): %zu frame(s), %u to %u, queued: %s\n", batch.id.c_str(), batch.name.c_str(),
                 ids.size(), batch.frames.front(), batch.frames.back(), placed.c_str());
  else
    std::fprintf(stderr, "batch %s (%s): %zu frame(s), %u to %u, queued at %s as jobs %s .. %s\n", batch.id.c_str(),
                 batch.name.c_str(), ids.size(), batch.frames.front(), batch.frames.back(),
                 farm.masters()[0].client->target().c_str(), ids.front().c_str(), ids.back().c_str());
  if (!wait) return kExitOk;
  BatchFollowOptions follow;
  follow.fetch = true;
  follow.out_prefix = out_prefix;
  return follow_batch(farm, batch.id, follow);
}

bool is_batch(Farm& farm, const std::string& id) {
  if (!valid_batch_id(id)) return false;
  bool found = false;
  farm.for_each([&](FarmMaster& m) {
    m.error.reset();
    if (!list_batch(*m.client, id).empty()) found = true;
  });
  return found;
}

int follow_batch(Farm& farm, const std::string& batch_id, const BatchFollowOptions& options) {
  using Clock = std::chrono::steady_clock;
  const bool tty = isatty(STDERR_FILENO) == 1;
  const auto interval = std::chrono::milliseconds(options.interval_ms ? options.interval_ms : tty ? 500 : 1000);
  const std::string prefix = options.out_prefix.empty() ? batch_id : options.out_prefix;
  auto& masters = farm.masters();
  // Every frame's job as last seen, with the index of its master: a master that does not answer
  // keeps its frames as they were.
  std::map<std::string, std::pair<v1::JobStatus, size_t>> last;
  std::vector<std::optional<Clock::time_point>> down_since(masters.size());
  std::map<std::string, v1::JobState> seen;  // by job id: the state last reported
  std::set<std::string> written, unwritten;  // DONE frames whose files were (not) fetched
  std::string last_summary;
  bool line_open = false;
  auto say = [&](const std::string& line) {
    std::fprintf(stderr, "%s%s\n", line_open ? "\r\x1b[K" : "", line.c_str());
    line_open = false;
  };
  BatchSummary summary;
  for (bool first = true;; first = false) {
    std::vector<std::vector<v1::JobStatus>> per(masters.size());
    farm.for_each([&](FarmMaster& m) {
      m.error.reset();
      per[size_t(&m - masters.data())] = list_batch(*m.client, batch_id);
    });
    if (first && farm.failed().size() == masters.size()) throw *masters[0].error;
    for (size_t m = 0; m < masters.size(); ++m) {
      const FarmMaster& fm = masters[m];
      if (fm.error) {
        if (!down_since[m]) {
          down_since[m] = Clock::now();
          say(fmt::format("master {} did not answer ({}); its frames stay as last seen until it is back", fm.label(),
                          fm.error->what()));
        } else if (Clock::now() - *down_since[m] > fm.client->options().watch_reconnect_timeout) {
          throw *fm.error;
        }
        continue;
      }
      if (down_since[m]) say(fmt::format("master {} answers again", fm.label()));
      down_since[m].reset();
      for (auto& s : per[m]) {
        const std::string id = s.id();  // before the move: the right side of = is evaluated first
        last[id] = {std::move(s), m};
      }
    }
    std::vector<v1::JobStatus> jobs;
    for (const auto& [id, seen] : last) jobs.push_back(seen.first);
    std::stable_sort(jobs.begin(), jobs.end(),
                     [](const v1::JobStatus& a, const v1::JobStatus& b) { return a.frame() < b.frame(); });
    if (jobs.empty() && farm.failed().empty())
      throw RpcError(grpc::Status(grpc::StatusCode::NOT_FOUND, "no such batch"),
                     farm.several()
                         ? fmt::format("no master has a job of batch '{}'", batch_id)
                         : fmt::format("master at {} has no job of batch '{}'", masters[0].client->target(), batch_id));
    for (const auto& s : jobs) {
      auto [it, fresh] = seen.emplace(s.id(), s.state());
      if ((fresh && s.state() != v1::JOB_STATE_QUEUED) || (!fresh && it->second != s.state())) say(event_line(s));
      it->second = s.state();
      if (!options.fetch || s.state() != v1::JOB_STATE_DONE || written.count(s.id()) || unwritten.count(s.id()))
        continue;
      const std::string frame_prefix = s.has_frame() ? frame_file_name(prefix, s.frame()) : prefix + "." + s.id();
      try {
        const auto files = masters[last.at(s.id()).second].client->fetch_all(s.id(), frame_prefix);
        std::string names;
        for (const auto& f : files) names += (names.empty() ? "" : ", ") + f.path;
        say("wrote " + names);
        written.insert(s.id());
      } catch (const RpcError& e) {
        if (e.unreachable()) continue;  // its master is away: fetched at a later look
        say(fmt::format("{}: no results: {}", frame_label(s), e.what()));
        unwritten.insert(s.id());
      }
    }
    summary = summarize_batch(jobs);
    const std::string line = summary_line(summary);
    if (tty) {
      std::fprintf(stderr, "\r%s\x1b[K", line.c_str());
      line_open = true;
    } else if (line != last_summary) {
      std::fprintf(stderr, "%s\n", line.c_str());
    }
    std::fflush(stderr);
    last_summary = line;
    if (summary.finished() || !options.wait) break;
    std::this_thread::sleep_for(interval);
  }
  if (line_open) std::fprintf(stderr, "\n");
  const bool all_done = summary.done == summary.frames && unwritten.empty();
  if (!summary.finished())
    std::fprintf(stderr, "batch %s: %u of %u frame(s) done so far\n", batch_id.c_str(), summary.done, summary.frames);
  return all_done ? kExitOk : kExitJobFailed;
}

int print_batch_json(Farm& farm, const std::string& batch_id) {
  google::protobuf::util::JsonPrintOptions opts;
  opts.add_whitespace = true;
  opts.preserve_proto_field_names = true;
  std::string out = "[";
  std::vector<std::vector<v1::JobStatus>> per(farm.masters().size());
  farm.for_each([&](FarmMaster& m) {
    m.error.reset();
    per[size_t(&m - farm.masters().data())] = list_batch(*m.client, batch_id);
  });
  if (!farm.several() && farm.masters()[0].error) throw *farm.masters()[0].error;
  print_failed(farm, "get", "its frames are missing below");
  std::vector<v1::JobStatus> jobs;
  for (auto& p : per) jobs.insert(jobs.end(), p.begin(), p.end());
  std::stable_sort(jobs.begin(), jobs.end(),
                   [](const v1::JobStatus& a, const v1::JobStatus& b) { return a.frame() < b.frame(); });
  for (const auto& s : jobs) {
    std::string json;
    (void)google::protobuf::util::MessageToJsonString(s, &json, opts);
    out += (out.size() > 1 ? ",\n" : "\n") + json;
  }
  std::printf("%s]\n", out.c_str());
  return kExitOk;
}

int cancel_batch(Farm& farm, const std::string& batch_id) {
  // Every master's frames of the batch, then each running or queued one cancelled on its master.
  std::vector<std::vector<v1::JobStatus>> per(farm.masters().size());
  std::vector<size_t> cancelled(per.size(), 0), ended(per.size(), 0);
  farm.for_each([&](FarmMaster& m) {
    m.error.reset();
    const size_t i = size_t(&m - farm.masters().data());
    per[i] = list_batch(*m.client, batch_id);
    for (const v1::JobStatus& s : per[i]) {
      if (is_terminal(s.state())) {
        ++ended[i];
        continue;
      }
      const v1::JobState after = m.client->cancel(s.id()).state();
      ++(after == v1::JOB_STATE_CANCELLED ? cancelled[i] : ended[i]);
    }
  });
  if (!farm.several() && farm.masters()[0].error) throw *farm.masters()[0].error;
  print_failed(farm, "cancel", "its frames of the batch may still run");
  size_t total_cancelled = 0, total_ended = 0, frames = 0;
  for (size_t i = 0; i < per.size(); ++i) {
    total_cancelled += cancelled[i];
    total_ended += ended[i];
    frames += per[i].size();
  }
  if (frames == 0 && farm.failed().empty())
    throw RpcError(grpc::Status(grpc::StatusCode::NOT_FOUND, "unknown batch"),
                   fmt::format("no master knows job or batch {}", batch_id));
  std::printf("%s CANCELLED\n", batch_id.c_str());
  std::fprintf(stderr, "batch %s: %zu job(s) cancelled, %zu had already ended\n", batch_id.c_str(), total_cancelled,
               total_ended);
  const auto failed = farm.failed();
  if (failed.empty()) return kExitOk;
  return std::any_of(failed.begin(), failed.end(), [](const FarmMaster* m) { return m->error->unreachable(); })
             ? kExitUnreachable
             : kExitRefused;
}

}  // namespace epr
