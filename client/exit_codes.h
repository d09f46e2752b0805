// The exit codes of the `epr` cluster commands (client/remote_commands.h, client/batch_commands.h).
#pragma once

namespace epr {

enum ExitCode : int {
  kExitOk = 0,           // done; for watch and submit --wait: the job ended DONE
  kExitJobFailed = 1,    // the job ended FAILED or CANCELLED; or a local error (an output not writable)
  kExitUsage = 2,        // bad flag values, unreadable scene or token file
  kExitUnreachable = 3,  // the master could not be reached or did not answer in time; list: some master
                         // did not answer (the others' jobs are listed)
  kExitRefused = 4,      // the master answered with an error (unknown job, invalid spec, no token...); list:
                         // some master refused and every other one answered
};

}  // namespace epr
