#include "wire/rpc/auth_interceptor.h"

#include <google/protobuf/message_lite.h>
#include <grpc/grpc.h>
#include <grpcpp/server_context.h>

#include <algorithm>
#include <cctype>

namespace epr::rpc {
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

// One call of a guarded method: checked on its initial metadata; refused, it is cancelled and every
// request message it receives is cleared (auth_interceptor.h says why).
class AuthInterceptor final : public grpc::experimental::Interceptor {
 public:
  AuthInterceptor(const BearerTokenCheck& check, grpc::experimental::ServerRpcInfo* info)
      : check_(check), info_(info) {}

  void Intercept(grpc::experimental::InterceptorBatchMethods* methods) override {
    using grpc::experimental::InterceptionHookPoints;
    if (methods->QueryInterceptionHookPoint(InterceptionHookPoints::POST_RECV_INITIAL_METADATA)) {
      const grpc::Status status = check_.check(*methods->GetRecvInitialMetadata());
      if (!status.ok()) {
        refused_ = true;
        grpc_call_cancel_with_status(info_->server_context()->c_call(), GRPC_STATUS_UNAUTHENTICATED,
                                     status.error_message().c_str(), nullptr);
      }
    }
    if (refused_ && methods->QueryInterceptionHookPoint(InterceptionHookPoints::POST_RECV_MESSAGE)) {
      // Guarded methods are protobuf methods: the message is the generated request type, whose
      // MessageLite base sits at its start (single, non-virtual inheritance).
      if (void* message = methods->GetRecvMessage()) static_cast<google::protobuf::MessageLite*>(message)->Clear();
    }
    methods->Proceed();
  }

 private:
  const BearerTokenCheck& check_;
  grpc::experimental::ServerRpcInfo* info_;
  bool refused_ = false;
};

class AuthInterceptorFactory final : public grpc::experimental::ServerInterceptorFactoryInterface {
 public:
  explicit AuthInterceptorFactory(std::string token) : check_(std::move(token)) {}
  grpc::experimental::Interceptor* CreateServerInterceptor(grpc::experimental::ServerRpcInfo* info) override {
    if (info->method() && is_open_method(info->method())) return nullptr;
    return new AuthInterceptor(check_, info);
  }

 private:
  BearerTokenCheck check_;
};

}  // namespace

grpc::Status BearerTokenCheck::check(const std::multimap<grpc::string_ref, grpc::string_ref>& metadata) const {
  const auto it = metadata.find("authorization");
  if (it == metadata.end())
    return {grpc::StatusCode::UNAUTHENTICATED, "this master requires a bearer token (authorization metadata)"};
  std::string_view value(it->second.data(), it->second.size());
  // "Bearer" 1*SP token, the scheme case-insensitive (RFC 7235 section 2.1).
  constexpr std::string_view kScheme = "bearer";
  const bool bearer = value.size() > kScheme.size() && value[kScheme.size()] == ' ' &&
                      std::equal(kScheme.begin(), kScheme.end(), value.begin(),
                                 [](char a, char b) { return a == std::tolower(static_cast<unsigned char>(b)); });
  if (bearer) value.remove_prefix(std::min(value.find_first_not_of(' ', kScheme.size()), value.size()));
  if (!bearer || !constant_time_equal(value, token_))
    return {grpc::StatusCode::UNAUTHENTICATED, "the bearer token is not valid for this master"};
  return grpc::Status::OK;
}

bool is_open_method(std::string_view method) {
  static constexpr std::string_view kOpenServices[] = {
      "/grpc.health.v1.Health/",
      "/grpc.reflection.v1alpha.ServerReflection/",
      "/grpc.reflection.v1.ServerReflection/",
  };
  return std::any_of(std::begin(kOpenServices), std::end(kOpenServices),
                     [&](std::string_view s) { return method.substr(0, s.size()) == s; });
}

std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface> make_auth_interceptor(std::string token) {
  if (token.empty()) return nullptr;
  return std::make_unique<AuthInterceptorFactory>(std::move(token));
}

}  // namespace epr::rpc
