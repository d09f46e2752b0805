// Small reactors and helpers shared by the master's callback-API services. None of them blocks.
#pragma once

#include <grpcpp/grpcpp.h>

#include <string>
#include <vector>

namespace epr {

/// Ends a unary call with `status` through the context's default reactor.
inline grpc::ServerUnaryReactor* finish(grpc::CallbackServerContext* ctx, grpc::Status status) {
  auto* r = ctx->DefaultReactor();
  r->Finish(std::move(status));
  return r;
}

inline grpc::Status invalid(std::string why) { return {grpc::StatusCode::INVALID_ARGUMENT, std::move(why)}; }

/// A server-streaming reactor that writes a precomputed list of messages, one at a time (each
/// OnWriteDone starts the next write), then finishes with the given status.
template <typename Message>
class ListWriter final : public grpc::ServerWriteReactor<Message> {
 public:
  explicit ListWriter(std::vector<Message> messages, grpc::Status end = grpc::Status::OK)
      : messages_(std::move(messages)), end_(std::move(end)) {
    next();
  }
  void OnWriteDone(bool ok) override {
    if (!ok) return this->Finish(grpc::Status(grpc::StatusCode::CANCELLED, "client went away"));
    next();
  }
  void OnDone() override { delete this; }

 private:
  void next() {
    if (i_ == messages_.size()) return this->Finish(end_);
    this->StartWrite(&messages_[i_++]);
  }
  std::vector<Message> messages_;
  grpc::Status end_;
  size_t i_ = 0;
};

}  // namespace epr
