#include "master/server/auth.h"

#include <cstdlib>
#include <fstream>
#include <stdexcept>

#include <fmt/format.h>

namespace epr {
namespace {

// Compares without an early exit, so the time taken does not tell how much of a guess was right.
bool constant_time_equal(std::string_view a, std::string_view b) {
  unsigned char diff = a.size() == b.size() ? 0 : 1;
  const size_t n = std::max(a.size(), b.size());
  for (size_t i = 0; i < n; ++i) {
    const unsigned char x = i < a.size() ? static_cast<unsigned char>(a[i]) : 0;
    const unsigned char y = i < b.size() ? static_cast<unsigned char>(b[i]) : 0;
    diff |= x ^ y;
  }
  return diff == 0;
}

}  // namespace

grpc::Status TokenAuth::check(const grpc::CallbackServerContext* ctx) const {
  if (!enabled()) return grpc::Status::OK;
  const auto& md = ctx->client_metadata();
  const auto it = md.find("authorization");
  if (it == md.end()) return {grpc::StatusCode::UNAUTHENTICATED, "this master requires a bearer token (authorization metadata)"};
  const std::string_view value(it->second.data(), it->second.size());
  constexpr std::string_view kPrefix = "Bearer ";
  if (value.substr(0, kPrefix.size()) != kPrefix || !constant_time_equal(value.substr(kPrefix.size()), token_))
    return {grpc::StatusCode::UNAUTHENTICATED, "the bearer token is not valid for this master"};
  return grpc::Status::OK;
}

std::string read_token_file(const std::string& path) {
  std::ifstream in(path);
  std::string line;
  if (!in || !std::getline(in, line)) throw std::runtime_error(fmt::format("cannot read the token file '{}'", path));
  const auto first = line.find_first_not_of(" \t\r\n");
  const auto last = line.find_last_not_of(" \t\r\n");
  if (first == std::string::npos) throw std::runtime_error(fmt::format("the token file '{}' is empty", path));
  return line.substr(first, last - first + 1);
}

std::optional<std::string> configured_token(const std::string& token_file) {
  if (!token_file.empty()) return read_token_file(token_file);
  if (const char* t = std::getenv("EPR_TOKEN"); t && *t) return std::string(t);
  return std::nullopt;
}

}  // namespace epr
