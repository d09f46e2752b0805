// Names of gRPC status codes for messages and logs, and which failures are worth retrying, shared by
// the client, the worker and the master.
#pragma once

#include <grpcpp/support/status.h>

#include <string>

namespace epr::rpc {

/// "UNAVAILABLE", "DEADLINE_EXCEEDED", ...; "status N" for a code gRPC does not define.
std::string status_code_name(grpc::StatusCode code);

/// "NAME: message", or "NAME" when the status has no message.
std::string describe(const grpc::Status& status);

/// True for the codes that mean no answer came (UNAVAILABLE, DEADLINE_EXCEEDED), as opposed to an
/// answer that refused the call.
bool is_unreachable(grpc::StatusCode code);

/// True for failures that may pass if the same call is made again later: the master is away, busy or
/// restarting (UNAVAILABLE, DEADLINE_EXCEEDED, RESOURCE_EXHAUSTED, ABORTED, CANCELLED, UNKNOWN,
/// INTERNAL). Callers retry these with backoff. Every other error code is permanent: the same request
/// is refused again (INVALID_ARGUMENT, UNAUTHENTICATED, PERMISSION_DENIED, FAILED_PRECONDITION,
/// UNIMPLEMENTED, NOT_FOUND, ...), so the caller stops and reports the reason. False for OK.
bool is_transient(grpc::StatusCode code);

}  // namespace epr::rpc
