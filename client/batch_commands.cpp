#include "client/batch_commands.h"

#include <fmt/format.h>
#include <google/protobuf/util/json_util.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <map>
#include <set>
#include <thread>

#include "client/batch.h"
#include "client/exit_codes.h"

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

}  // namespace

int submit_frames(JobClient& client, const RenderOptions& opts, const SubmitOptions& submit, const std::string& frames,
                  bool wait, const std::string& out_prefix) {
  const FrameBatch batch = plan_batch(opts, submit, parse_frame_list(frames));
  const std::vector<std::string> ids = submit_batch(client, batch);
  std::printf("%s\n", batch.id.c_str());  // alone on its line, for scripts: BATCH=$(epr submit ... --frames 1-9)
  std::fflush(stdout);
  std::fprintf(stderr, "batch %s (%s): %zu frame(s), %u to %u, queued at %s as jobs %s .. %s\n", batch.id.c_str(),
               batch.name.c_str(), ids.size(), batch.frames.front(), batch.frames.back(), client.target().c_str(),
               ids.front().c_str(), ids.back().c_str());
  if (!wait) return kExitOk;
  BatchFollowOptions follow;
  follow.fetch = true;
  follow.out_prefix = out_prefix;
  return follow_batch(client, batch.id, follow);
}

bool is_batch(JobClient& client, const std::string& id) {
  return valid_batch_id(id) && !list_batch(client, id).empty();
}

int follow_batch(JobClient& client, const std::string& batch_id, const BatchFollowOptions& options) {
  const bool tty = isatty(STDERR_FILENO) == 1;
  const auto interval = std::chrono::milliseconds(options.interval_ms ? options.interval_ms : tty ? 500 : 1000);
  const std::string prefix = options.out_prefix.empty() ? batch_id : options.out_prefix;
  std::map<std::string, v1::JobState> seen;  // by job id
  std::set<std::string> written, unwritten;  // DONE frames whose files were (not) fetched
  std::string last_summary;
  bool line_open = false;
  auto say = [&](const std::string& line) {
    std::fprintf(stderr, "%s%s\n", line_open ? "\r\x1b[K" : "", line.c_str());
    line_open = false;
  };
  BatchSummary summary;
  for (;;) {
    const std::vector<v1::JobStatus> jobs = list_batch(client, batch_id);
    if (jobs.empty())
      throw RpcError(grpc::Status(grpc::StatusCode::NOT_FOUND, "no such batch"),
                     fmt::format("master at {} has no job of batch '{}'", client.target(), batch_id));
    for (const auto& s : jobs) {
      auto [it, fresh] = seen.emplace(s.id(), s.state());
      if ((fresh && s.state() != v1::JOB_STATE_QUEUED) || (!fresh && it->second != s.state())) say(event_line(s));
      it->second = s.state();
      if (!options.fetch || s.state() != v1::JOB_STATE_DONE || written.count(s.id()) || unwritten.count(s.id()))
        continue;
      const std::string frame_prefix = s.has_frame() ? frame_file_name(prefix, s.frame()) : prefix + "." + s.id();
      try {
        const auto files = client.fetch_all(s.id(), frame_prefix);
        std::string names;
        for (const auto& f : files) names += (names.empty() ? "" : ", ") + f.path;
        say("wrote " + names);
        written.insert(s.id());
      } catch (const RpcError& e) {
        if (e.unreachable()) throw;
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

int print_batch_json(JobClient& client, const std::string& batch_id) {
  google::protobuf::util::JsonPrintOptions opts;
  opts.add_whitespace = true;
  opts.preserve_proto_field_names = true;
  std::string out = "[";
  for (const auto& s : list_batch(client, batch_id)) {
    std::string json;
    (void)google::protobuf::util::MessageToJsonString(s, &json, opts);
    out += (out.size() > 1 ? ",\n" : "\n") + json;
  }
  std::printf("%s]\n", out.c_str());
  return kExitOk;
}

}  // namespace epr
