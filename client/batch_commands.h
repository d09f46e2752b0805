// The `epr` commands on frame sequences (client/batch.h), called by RemoteCommands:
//
//   epr submit SCENE --frames 1-240 [--wait [--out DIR/name]]   one job per frame, one scene upload
//   epr watch BATCH                  frames done / running / queued and each frame's state changes
//   epr get BATCH --out DIR/name     DIR/name.0001.exr, .png, ... as frames finish (waits for the rest)
//
// With several masters (client/farm.h) a batch's frames are spread over those that answer, each
// frame to the one with the least work then (its samples left plus the frames given to it so far),
// and watch and get gather the frames from every master. A master that stops answering meanwhile
// keeps its frames as last seen until it is back (its jobs resume from their checkpoints), for at
// most the client's watch_reconnect_timeout.
// Errors are thrown as in RemoteCommands (RpcError, SceneError, std::invalid_argument).
#pragma once

#include <cstdint>
#include <string>

#include "client/batch.h"
#include "client/farm.h"
#include "client/job_client.h"
#include "common/render_options.h"

namespace epr {

/// Plans and submits the batch; prints its id alone on stdout. With `wait`, follows it and fetches
/// every frame to frame_file_name(out_prefix, frame). With a frame window, each run of frames goes to
/// one master. Returns an ExitCode.
int submit_frames(Farm& farm, const RenderOptions& opts, const SubmitOptions& submit, const std::string& frames,
                  bool wait, const std::string& out_prefix, const WindowOptions& window = {});

/// True when some master holds jobs of batch `id`.
bool is_batch(Farm& farm, const std::string& id);

struct BatchFollowOptions {
  bool fetch = false;        // write each DONE frame's results to frame_file_name(out_prefix, frame)
  std::string out_prefix;    // empty: the batch id
  bool wait = true;          // false: one look (and the frames done now), no waiting
  uint32_t interval_ms = 0;  // between looks; 0: 500 ms on a terminal, 1000 ms otherwise
};

/// Follows a batch until every frame has ended: a summary line on stderr (overwritten on a terminal)
/// and a line per frame that changes state; with `fetch`, each frame's files as soon as it is DONE.
/// kExitOk when every frame ended DONE (and was written), kExitJobFailed otherwise; an unknown batch
/// is RpcError NOT_FOUND.
int follow_batch(Farm& farm, const std::string& batch_id, const BatchFollowOptions& options);

/// Cancels every job of the batch still queued or running, on every master that holds some (`epr
/// cancel BATCH`); prints "BATCH CANCELLED" on stdout and the counts on stderr. An unknown batch is
/// RpcError NOT_FOUND; kExitUnreachable when a master did not answer (its frames may still run).
int cancel_batch(Farm& farm, const std::string& batch_id);

/// Prints the batch's jobs' statuses as a JSON array on stdout (`epr get BATCH --json`).
int print_batch_json(Farm& farm, const std::string& batch_id);

}  // namespace epr
