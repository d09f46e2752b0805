// A minimal WorkerService client for benchmarks: Register, LeaseTile, SubmitTile, with none of
// WorkerNode's heartbeats, retries or scene cache, and with the retry interval after a Wait under the
// benchmark's control. Used by ingest_bench (synthetic tile results) and round_bench (real tracing).
#pragma once

#include <grpcpp/grpcpp.h>
#include <sys/resource.h>

#include <chrono>
#include <cstdint>
#include <cstdlib>
#include <memory>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <thread>
#include <variant>

#include "common/cpu_time.h"
#include "epr/v1/worker_service.grpc.pb.h"
#include "wire/tile_result_stream.h"

namespace epr::bench {

inline double load_average() {
  double l[3] = {0, 0, 0};
  getloadavg(l, 3);
  return l[0];
}

class BenchWorker {
 public:
  /// Registers on `target` ("127.0.0.1:PORT"). Throws std::runtime_error if that fails.
  BenchWorker(const std::string& target, const std::string& name, uint32_t threads) {
    grpc::ChannelArguments args;
    args.SetMaxSendMessageSize(-1);
    // One channel (one HTTP/2 connection) per bench worker, as separate worker processes would have.
    args.SetInt("grpc.use_local_subchannel_pool", 1);
    stub_ = v1::WorkerService::NewStub(grpc::CreateCustomChannel(target, grpc::InsecureChannelCredentials(), args));
    v1::WorkerInfo info;
    info.set_protocol_version(v1::PROTOCOL_VERSION_V1);
    info.set_name(name);
    info.set_threads(threads);
    v1::RegisterResponse resp;
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
    const grpc::Status s = stub_->Register(&ctx, info, &resp);
    if (!s.ok()) throw std::runtime_error("Register: " + s.error_message());
    id_ = resp.worker_id().id();
    limits_.max_vertices_per_chunk = resp.max_vertices_per_chunk();
    limits_.max_chunk_bytes = resp.max_chunk_bytes();
  }

  ~BenchWorker() {
    v1::WorkerId wid;
    wid.set_id(id_);
    v1::UnregisterResponse resp;
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(2));
    (void)stub_->Unregister(&ctx, wid, &resp);
  }
  BenchWorker(const BenchWorker&) = delete;
  BenchWorker& operator=(const BenchWorker&) = delete;

  const std::string& id() const { return id_; }
  const TileResultLimits& limits() const { return limits_; }

  /// A tile, or the Wait's retry_after_ms. Throws on an RPC error or a Shutdown.
  std::variant<v1::TileLease, uint32_t> lease() {
    v1::LeaseRequest req;
    req.mutable_worker_id()->set_id(id_);
    v1::Lease lease;
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
    const grpc::Status s = stub_->LeaseTile(&ctx, req, &lease);
    if (!s.ok()) throw std::runtime_error("LeaseTile: " + s.error_message());
    if (lease.has_tile()) return std::move(*lease.mutable_tile());
    if (lease.has_wait()) return lease.wait().retry_after_ms();
    throw std::runtime_error("LeaseTile: shutdown");
  }

  /// One SubmitTile stream: `first` (usually the header), then `rest`. Returns the ack; throws on an
  /// RPC error (the master refused the stream).
  v1::SubmitAck submit(const v1::TileResultChunk& first, std::span<const v1::TileResultChunk> rest) {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
    v1::SubmitAck ack;
    auto stream = stub_->SubmitTile(&ctx, &ack);
    // As WorkerNode does: the last chunk goes with the half-close.
    bool ok = rest.empty() ? stream->Write(first, grpc::WriteOptions().set_last_message()) : stream->Write(first);
    for (size_t i = 0; ok && i < rest.size(); ++i)
      ok = i + 1 == rest.size() ? stream->Write(rest[i], grpc::WriteOptions().set_last_message())
                                : stream->Write(rest[i]);
    const grpc::Status s = stream->Finish();
    if (!s.ok()) throw std::runtime_error("SubmitTile: " + s.error_message());
    return ack;
  }

  /// Streams a TileResult with TileResultWriter (encoding as it goes, as WorkerNode does).
  v1::SubmitAck submit(TileResultWriter& writer) {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
    v1::SubmitAck ack;
    auto stream = stub_->SubmitTile(&ctx, &ack);
    write_tile_result(writer, *stream);
    const grpc::Status s = stream->Finish();
    if (!s.ok()) throw std::runtime_error("SubmitTile: " + s.error_message());
    return ack;
  }

 private:
  std::unique_ptr<v1::WorkerService::Stub> stub_;
  std::string id_;
  TileResultLimits limits_;
};

}  // namespace epr::bench
