// The cluster commands of `epr`, all through JobClient (client/job_client.h):
//
//   epr submit SCENE [render flags] [--priority N] [--name NAME] [--time-budget S] [--wait [--out PREFIX]]
//   epr watch JOB          progress until the job ends
//   epr get JOB [--out PREFIX] [--partial] [--json]
//   epr list [--state S]... [--limit N]
//   epr cancel JOB
//
// Every command takes --master HOST:PORT, or several comma-separated, or a name resolving to several
// (client/farm.h; default $EPR_MASTER, else localhost:50051), --token-file
// (else $EPR_TOKEN; tokens never go on the command line), --tls / --ca-file and --timeout SECONDS
// for unary calls (submit: for the whole submission, 0 = no limit). Exit codes: see ExitCode.
#pragma once

#include <CLI/CLI.hpp>
#include <memory>
#include <optional>
#include <string>

#include "client/exit_codes.h"
#include "client/job_client.h"

namespace epr {

/// Registers submit, watch, get, list and cancel on `app`; owns their flag values.
class RemoteCommands {
 public:
  explicit RemoteCommands(CLI::App& app);
  ~RemoteCommands();
  RemoteCommands(const RemoteCommands&) = delete;
  RemoteCommands& operator=(const RemoteCommands&) = delete;

  /// After app.parse: runs the remote subcommand that was given and returns its exit code, or
  /// nullopt when none of them was given.
  std::optional<int> run();

 private:
  struct State;
  std::unique_ptr<State> s_;
};

/// "[####......] round  3/16  spp  12.0/64 (min 8)  M'  4.0  skipped  12%  12.3s  ETA 20s" for a
/// RUNNING job; a short line for the other states. The bar shows rounds done (PT, RP) or the
/// slowest pixel's M + M' against P (SKIP, whose end that is).
std::string progress_line(const v1::JobStatus& status, int bar_width = 30);

struct FollowOptions {
  bool fetch = true;  // fetch the results once the job is DONE (or CANCELLED after a round)
  std::string out_prefix = "render";
  uint32_t min_interval_ms = 0;  // 0: 200 ms on a terminal, 1000 ms otherwise
};

/// Watches a job with a progress line on stderr until it ends, then (DONE, or CANCELLED with a
/// committed round) fetches its results to out_prefix. Returns kExitOk for DONE, kExitJobFailed
/// otherwise. Throws RpcError like JobClient.
int follow_job(JobClient& client, const std::string& job_id, const FollowOptions& options = {});

}  // namespace epr
