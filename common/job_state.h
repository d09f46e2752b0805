// A job's life: queued, running, then one of three ends. Shared by the master, its checkpoints and
// the monitoring endpoint.
#pragma once

namespace epr {

enum class JobState { kQueued, kRunning, kDone, kFailed, kCancelled };

const char* to_string(JobState s);
inline bool is_terminal(JobState s) { return s != JobState::kQueued && s != JobState::kRunning; }

}  // namespace epr
