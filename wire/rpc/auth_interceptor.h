// Bearer-token authentication for a gRPC server, as a server interceptor (registered by
// master/server/master_server.cpp). With a token configured, every call must carry
// "authorization: Bearer <token>" (wire/rpc/token.h reads it), except the open services: the
// standard health service (probes) and server reflection. A refused call ends with UNAUTHENTICATED
// and a reason that does not echo what was sent.
//
// How a call is refused: gRPC 1.51's server interceptors cannot keep a handler from being invoked
// (only client interceptors may hijack a call). So the interceptor, on the call's initial metadata,
// cancels the call with UNAUTHENTICATED, which the client receives as the call's status (nothing the
// handler sends reaches it), and clears every request message the call receives before the handler
// sees it. A handler therefore runs on an empty request, which the services refuse as invalid
// without acting (tests/server/auth_test.cpp checks every method of JobService and WorkerService).
#pragma once

#include <grpcpp/support/server_interceptor.h>
#include <grpcpp/support/status.h>
#include <grpcpp/support/string_ref.h>

#include <map>
#include <memory>
#include <string>
#include <string_view>

namespace epr::rpc {

/// Checks the "authorization" metadata of a call against one token, in time that does not depend on
/// how much of a guess was right.
class BearerTokenCheck {
 public:
  explicit BearerTokenCheck(std::string token) : token_(std::move(token)) {}
  /// OK, or UNAUTHENTICATED with a reason that does not reveal the token.
  grpc::Status check(const std::multimap<grpc::string_ref, grpc::string_ref>& metadata) const;

 private:
  std::string token_;
};

/// True for the methods anyone may call: grpc.health.v1.Health and server reflection.
bool is_open_method(std::string_view method);

/// The interceptor factory for ServerBuilder::experimental().SetInterceptorCreators; nullptr when
/// `token` is empty (every call is allowed, nothing to register).
std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface> make_auth_interceptor(std::string token);

}  // namespace epr::rpc
