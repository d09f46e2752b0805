// A master's name: the prefix of its job ids (NAME.j000123-abcd), by which a client given several
// masters finds the one holding a job (JobService.GetMasterInfo). It must outlive restarts, since jobs
// resume under their ids, so it is kept in STATE_DIR/master-name.
#pragma once

#include <string>

namespace epr {

/// [A-Za-z0-9_-]{1,40}: no dot, so that a job id's prefix ends at its first dot.
bool is_valid_master_name(const std::string& name);

/// The name for this start: `flag` when given, else the one saved in `state_dir`, else one made from
/// the host name and the listening port ("HOST-50051"; "HOST-" and 6 random hex digits when the port
/// is 0). With a state_dir the name is saved there for the next start (a given flag replaces the
/// saved name: new jobs get the new prefix, existing ones keep their ids). Throws
/// std::invalid_argument for an invalid flag or saved name, std::runtime_error when the file cannot
/// be written.
std::string choose_master_name(const std::string& flag, const std::string& state_dir, int listen_port);

/// The port of a listen address "HOST:PORT" or "[V6]:PORT"; 0 when it has none.
int listen_port(const std::string& listen);

}  // namespace epr
