// Bearer-token authentication for the master's services (DESIGN.md section 4). When a token is
// configured, every JobService and WorkerService call must carry "authorization: Bearer <token>";
// others get UNAUTHENTICATED. The health service stays open for probes. The token comes from a file
// or the environment (never a command line, which `ps` shows) and is never logged.
#pragma once

#include <optional>
#include <string>

#include <grpcpp/grpcpp.h>

namespace epr {

class TokenAuth {
 public:
  TokenAuth() = default;  // no token: every call is allowed
  explicit TokenAuth(std::string token) : token_(std::move(token)) {}

  bool enabled() const { return !token_.empty(); }
  /// OK, or UNAUTHENTICATED with a reason that does not reveal the token.
  grpc::Status check(const grpc::CallbackServerContext* ctx) const;

 private:
  std::string token_;
};

/// The token in `path` (first line, surrounding white space removed); throws std::runtime_error if
/// the file cannot be read or is empty.
std::string read_token_file(const std::string& path);
/// `--token-file` if given, else $EPR_TOKEN, else none.
std::optional<std::string> configured_token(const std::string& token_file);

}  // namespace epr
