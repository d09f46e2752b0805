// How the programs connect: channel credentials for the client and the worker, server credentials
// for the master (TLS or plaintext, as their flags allow), and the options every client call carries
// (a deadline, and the bearer token when one is configured, wire/rpc/token.h).
#pragma once

#include <grpcpp/grpcpp.h>

#include <chrono>
#include <cstdint>
#include <memory>
#include <string>

namespace epr::rpc {

/// The client side of TLS. enabled = false: plaintext (the files are ignored).
struct ClientTls {
  bool enabled = false;
  std::string ca_file;    // PEM roots that sign the master's certificate; empty: the system's roots
  std::string cert_file;  // PEM client certificate and its key, for masters that require one
  std::string key_file;
};

/// Throws std::runtime_error naming a PEM file that cannot be read.
std::shared_ptr<grpc::ChannelCredentials> channel_credentials(const ClientTls& tls);

/// The server side of TLS: all empty means plaintext.
struct ServerTls {
  std::string cert_file, key_file;  // PEM certificate chain and private key
  std::string client_ca_file;       // PEM CA client certificates must chain to; empty: none asked for
  bool enabled() const { return !cert_file.empty() || !key_file.empty(); }
};

/// Throws std::runtime_error naming a PEM file that cannot be read.
std::shared_ptr<grpc::ServerCredentials> server_credentials(const ServerTls& tls);

/// Sets the call's deadline to now + `timeout` and, if `token` is not empty, adds
/// "authorization: Bearer <token>".
void prepare_call(grpc::ClientContext& ctx, std::chrono::milliseconds timeout, const std::string& token);

/// The deadline of a call whose work grows with `bytes` (a transfer, a scene the master parses):
/// `base` plus the time `bytes` take at `bytes_per_second`, the slowest rate still accepted.
std::chrono::milliseconds scaled_deadline(std::chrono::milliseconds base, uint64_t bytes, double bytes_per_second);

}  // namespace epr::rpc
