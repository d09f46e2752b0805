// The masters an `epr` command talks to: `--master A,B,C` (or $EPR_MASTER), each entry a master or a
// name resolving to several (wire/rpc/master_list.h), one JobClient each. Masters share nothing; a
// job id names its master (NAME.j000123-abcd, MasterInfo.name), so a command on one job asks every
// master its name (GetMasterInfo, all at once) and goes to the one whose name the id carries. An id
// without a name, or a name no master answers to, is looked for with GetJob on every master.
// A submission goes to the master with the fewest samples left to trace (MasterInfo.samples_left).
//
// With a single master nothing is asked beforehand: every command goes to it, as it always did.
// Nothing is cached between commands.
#pragma once

#include <functional>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "client/job_client.h"
#include "wire/rpc/master_list.h"

namespace epr {

struct FarmMaster {
  MasterEndpoint endpoint;
  std::unique_ptr<JobClient> client;
  std::optional<v1::MasterInfo> info;  // its answer to the last probe
  std::optional<RpcError> error;       // why it did not answer the last call made to it

  /// "NAME (TARGET)" once the master told its name, else the endpoint's name.
  std::string label() const;
};

/// A job found on one master.
struct FarmJob {
  FarmMaster* master = nullptr;
  v1::JobStatus status;
};

/// The master-name part of a job id ("alpha" of "alpha.j000001-beef"); empty when it has none.
std::string job_id_master(const std::string& job_id);

class Farm {
 public:
  /// Parses and resolves `list` (std::invalid_argument when malformed). `options` applies to every
  /// master; a master reached by address checks its TLS certificate against the name it came from.
  Farm(const std::string& list, const JobClientOptions& options, const MasterResolver& resolver = nullptr);

  bool several() const { return masters_.size() > 1; }
  std::vector<FarmMaster>& masters() { return masters_; }
  const std::vector<FarmMaster>& masters() const { return masters_; }

  /// Runs fn for every master at once (a thread each) and waits for them all. What fn throws is kept
  /// in the master's `error` (an RpcError; UNKNOWN for other exceptions). Callers clear `error` first.
  void for_each(const std::function<void(FarmMaster&)>& fn);
  /// GetMasterInfo of every master (for_each); `info` is set for those that answered. A master
  /// reached under two addresses (one MasterInfo.instance) is kept once, with a note on stderr; two
  /// masters sharing a name get a note too (locate() then asks both).
  void probe();
  /// The masters the last for_each could not use, e.g. for "master X is down" notes.
  std::vector<const FarmMaster*> failed() const;

  /// The master a new job goes to: the single one, else the probed master with the fewest samples
  /// left (then the fewest jobs, then list order). Throws the first master's RpcError when none answered.
  FarmMaster& least_loaded();
  /// The master that holds `job_id` (single master: that one, unasked). Throws RpcError NOT_FOUND
  /// when every master answered and none has it, and the down masters' error (UNAVAILABLE...) when
  /// the job's master may be one of those.
  FarmMaster& locate(const std::string& job_id);
  /// Every master's jobs (ListJobs, at most `limit` each, 0: all; only those of batch_id unless
  /// empty), newest first by submission time, at most `limit` in all. The masters that failed are in
  /// failed(); a single master's error is thrown.
  std::vector<FarmJob> list(const std::vector<v1::JobState>& states, size_t limit, const std::string& batch_id = "");

 private:
  std::vector<FarmMaster> masters_;
  std::set<std::string> warned_clashes_;  // master names already said to be shared by two masters
};

/// For each master the last call could not use: "epr CMD: master LABEL did not answer (ERROR); WHAT"
/// on stderr ("refused" instead of "did not answer" when it answered with an error).
void print_failed(const Farm& farm, const std::string& cmd, const std::string& what);

}  // namespace epr
