// Names of gRPC status codes for messages and logs, shared by the client, the worker and the master.
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

}  // namespace epr::rpc
