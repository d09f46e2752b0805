// Chunked transfers: blobs too large for one message travel as pieces of at most kChunkBytes at
// increasing offsets (proto/epr/v1: SceneChunk for UploadScene and FetchScene, ResultChunk for
// FetchResult). One rule on both sides: the sender cuts with for_each_chunk, the receiver checks
// each piece with ChunkTracker (in order, no gaps, nothing past the announced size), and a client
// reads a server stream with read_stream, which cancels the call on the first bad message.
#pragma once

#include <grpcpp/client_context.h>
#include <grpcpp/support/sync_stream.h>

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "epr/v1/scene.pb.h"
#include "wire/scene_bundle.h"

namespace epr::rpc {

/// The most bytes one data message carries (SceneFileData.data and ResultData.data: 1 MiB).
constexpr size_t kChunkBytes = size_t(1) << 20;

/// Calls send(offset, piece) for the consecutive pieces of `bytes` (at most kChunkBytes each; none
/// for an empty blob). Stops at the first false from `send` and returns false; true when all went.
bool for_each_chunk(std::string_view bytes, const std::function<bool(uint64_t offset, std::string_view piece)>& send);

/// The receiving side of one blob of announced size.
class ChunkTracker {
 public:
  explicit ChunkTracker(uint64_t size) : size_(size) {}
  /// Empty if `n` bytes at `offset` continue the blob (then they are counted); otherwise why not.
  std::optional<std::string> add(uint64_t offset, uint64_t n);
  uint64_t size() const { return size_; }
  uint64_t received() const { return received_; }
  bool complete() const { return received_ == size_; }

 private:
  uint64_t size_;
  uint64_t received_ = 0;
};

/// A file scene as its SceneChunk stream: the manifest (with the content hash), then every file's
/// bytes in manifest order. Stops at the first false from `send` and returns false.
bool send_scene(const SceneBundleData& bundle, const std::function<bool(const v1::SceneChunk&)>& send);
/// The same stream as a list (a server's ListWriter).
std::vector<v1::SceneChunk> scene_chunks(const SceneBundleData& bundle);

/// How a server stream read by read_stream ended: the call's status, and the error `take` reported
/// (the call was then cancelled and `status` is CANCELLED).
struct StreamEnd {
  grpc::Status status;
  std::optional<std::string> error;
  bool ok() const { return status.ok() && !error; }
};

/// Reads `reader` to its end, handing each message to `take`, which returns an error to stop. On an
/// error or an exception from `take` the call is cancelled and drained (the exception is rethrown
/// after Finish), so the call never outlives this function.
template <class Message>
StreamEnd read_stream(grpc::ClientContext& ctx, grpc::ClientReaderInterface<Message>& reader,
                      const std::function<std::optional<std::string>(const Message&)>& take) {
  Message m;
  StreamEnd end;
  try {
    while (reader.Read(&m)) {
      if ((end.error = take(m))) break;
    }
  } catch (...) {
    ctx.TryCancel();
    while (reader.Read(&m)) {
    }
    reader.Finish();
    throw;
  }
  if (end.error) {
    ctx.TryCancel();
    while (reader.Read(&m)) {
    }
  }
  end.status = reader.Finish();
  return end;
}

}  // namespace epr::rpc
