#include "master/server/job.h"

namespace epr {

bool Job::end(JobState final_state, std::string why, int64_t now_ms) {
  if (is_terminal(state)) return false;
  state = final_state;
  error = std::move(why);
  finished_ms = now_ms;
  round_open = false;
  preview.partial_pending = (final_state == JobState::kCancelled || final_state == JobState::kFailed) &&
                            !preview.images && progress.round > 0;
  ++version;
  return true;
}

JobSnapshot Job::snapshot(int64_t now_ms) const {
  JobSnapshot s;
  s.id = id;
  s.seq = seq;
  s.name = request.name;
  s.error = error;
  s.state = state;
  s.priority = request.priority;
  s.options = request.options;
  s.camera = request.camera;
  s.scene_hash = scene_hash;
  s.scene_builtin = bundle->builtin;
  s.scene_bytes = bundle->total_bytes();
  s.triangles = triangles;
  s.progress = progress;
  s.counts = counts;
  s.counters = counters;
  s.drops = drops;
  s.rounds_planned = rounds_planned(request.options);
  s.workers_blocked = leases ? uint32_t(leases->blocked_count()) : 0;
  s.submitted_ms = submitted_ms;
  s.started_ms = started_ms;
  s.finished_ms = finished_ms;
  const int64_t end_ms = finished_ms ? finished_ms : now_ms;
  s.seconds_elapsed = started_ms ? double(end_ms - started_ms) / 1000.0 : 0.0;
  if (state == JobState::kRunning && progress.round > 0 && progress.paths_traced > 0)
    s.eta_seconds = eta_seconds(progress, request.options.spp, s.seconds_elapsed);
  else if (state == JobState::kDone)
    s.eta_seconds = 0;
  s.seconds_round_backlog = seconds_round_backlog;
  s.seconds_round_closing = seconds_round_closing;
  s.seconds_writing_results = seconds_writing_results;
  s.round_checkpoints = round_checkpoints;
  s.budget_exhausted = budget_exhausted;
  s.version = version;
  s.batch = request.batch;
  s.fed_by_first = fed_by_first;
  s.fed_by_last = fed_by_last;
  return s;
}

void Job::add_statistics(nlohmann::json* stats, const JobCounters& c, int64_t now_ms) const {
  const RenderOptions& o = request.options;
  stats->update({{"job", id},
                 {"scene_hash", scene_hash},
                 {"triangles", triangles},
                 {"width", o.width},
                 {"height", o.height},
                 {"spp", o.spp},
                 {"seed", o.seed},
                 {"rays", c.rays},
                 {"vertices_received", c.vertices_received},
                 {"nonfinite_dropped", c.non_finite},
                 {"tiles_leased", c.tiles_leased},
                 {"tiles_committed", c.tiles_committed},
                 {"tiles_re_leased", c.tiles_re_leased},
                 {"tiles_dropped", c.tiles_dropped},
                 {"tiles_speculative", c.tiles_speculative},
                 {"worker_failures", c.worker_failures},
                 {"seconds", double(now_ms - started_ms) / 1000.0},
                 {"seconds_tracing", c.seconds_tracing},
                 {"seconds_scene_load", seconds_scene_load},
                 {"seconds_frame_build", seconds_frame_build},
                 {"budget_exhausted", budget_exhausted}});
  // A frame rendered in a window run says so: its window and the run it was rendered with.
  const BatchMembership& b = request.batch;
  if (b.window > 0) {
    nlohmann::json& w = (*stats)["frame_window"];
    w = {{"k", b.window},
         {"window_first", b.window_first},
         {"window_last", b.window_last},
         {"halving", b.window_halving}};
    // The frames that fed it (a cut stops the window) and how much its view shares with the
    // neighbouring frames' (null at the run's ends or without a measurement).
    if (run) {
      auto share = [](double x) { return x < 0 ? nlohmann::json(nullptr) : nlohmann::json(x); };
      w.update({{"fed_by_first", fed_by_first},
                {"fed_by_last", fed_by_last},
                {"view_share_previous", share(view_share_previous)},
                {"view_share_next", share(view_share_next)}});
    }
  }
}

}  // namespace epr
