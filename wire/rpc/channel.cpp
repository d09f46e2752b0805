#include "wire/rpc/channel.h"

#include <fmt/format.h>

#include <algorithm>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace epr::rpc {
namespace {

// The PEM file at `path` ("" for an empty path).
std::string read_pem(const std::string& path, const char* what) {
  if (path.empty()) return {};
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error(fmt::format("cannot read the {} '{}'", what, path));
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

}  // namespace

std::shared_ptr<grpc::ChannelCredentials> channel_credentials(const ClientTls& tls) {
  if (!tls.enabled) return grpc::InsecureChannelCredentials();
  grpc::SslCredentialsOptions ssl;
  ssl.pem_root_certs = read_pem(tls.ca_file, "CA file");
  ssl.pem_cert_chain = read_pem(tls.cert_file, "TLS certificate");
  ssl.pem_private_key = read_pem(tls.key_file, "TLS key");
  return grpc::SslCredentials(ssl);
}

std::shared_ptr<grpc::ServerCredentials> server_credentials(const ServerTls& tls) {
  if (!tls.enabled()) return grpc::InsecureServerCredentials();
  grpc::SslServerCredentialsOptions ssl;
  ssl.pem_key_cert_pairs.push_back({read_pem(tls.key_file, "TLS key"), read_pem(tls.cert_file, "TLS certificate")});
  if (!tls.client_ca_file.empty()) {
    ssl.pem_root_certs = read_pem(tls.client_ca_file, "client CA file");
    ssl.client_certificate_request = GRPC_SSL_REQUEST_AND_REQUIRE_CLIENT_CERTIFICATE_AND_VERIFY;
  }
  return grpc::SslServerCredentials(ssl);
}

void prepare_call(grpc::ClientContext& ctx, std::chrono::milliseconds timeout, const std::string& token) {
  ctx.set_deadline(std::chrono::system_clock::now() + timeout);
  if (!token.empty()) ctx.AddMetadata("authorization", "Bearer " + token);
}

std::chrono::milliseconds scaled_deadline(std::chrono::milliseconds base, uint64_t bytes, double bytes_per_second) {
  const double ms = double(bytes) / std::max(1.0, bytes_per_second) * 1000.0;
  return base + std::chrono::milliseconds(int64_t(std::min(ms, 1e12)));  // at most ~30 years: no overflow
}

}  // namespace epr::rpc
