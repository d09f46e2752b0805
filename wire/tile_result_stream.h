// Both ends of WorkerService.SubmitTile's client stream (proto/epr/v1/worker_service.proto), as pure
// code without gRPC so that every rule of the stream can be tested on its own:
//
//   worker  TileResultWriter: a TileResult (common/tile.h) -> header, PixelPaths chunks,
//           VertexBatch chunks (VERTEX_ENCODING_PACKED16), ExactSamples chunks, trailer.
//   master  TileResultAssembler: checks chunk by chunk and rebuilds the tile; a protocol violation
//           gives the reason for INVALID_ARGUMENT, non-finite radiance is dropped and counted.
//
// Chunk sizes. Every chunk the writer produces serialises to at most max_chunk_bytes and carries at
// most max_vertices_per_chunk vertices / exact samples and kMaxPixelsPerChunk pixels. Worst-case
// wire sizes per item: a packed vertex 16 bytes; a pixel 12 bytes of radiance + a <= 5-byte varint
// count; an exact sample 12 bytes of radiance + a <= 5-byte varint subpixel; plus a fixed framing
// allowance per chunk (kChunkFramingBytes).
//
// What the worker does not send (and counts in TileWorkerStats instead):
//   * vertices the codec refuses: non-finite radiance -> non_finite_dropped; everything else
//     (outside codec_bounds, bad normal, negative or overflowing radiance, unknown flags) ->
//     encode_rejected;
//   * exact samples whose radiance is non-finite or negative -> non_finite_dropped;
//   * a pixel sum that is non-finite or negative is sent as 0 (its paths still count: their sample
//     indices are used up) -> non_finite_dropped.
// The header announces exactly what is sent.
//
// Memory: the writer keeps the tile's accepted vertices packed (16 bytes each, less than the 40-byte
// records it reads; nothing when the renderer packed them already) and produces one chunk at a time;
// the assembler holds one tile.
#pragma once

#include <grpcpp/support/sync_stream.h>

#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "common/math.h"
#include "common/vertex_codec.h"
#include "common/vertex_record.h"
#include "epr/v1/worker_service.pb.h"

namespace epr {

struct TileResult;  // common/tile.h

/// The limits of RegisterResponse, plus the PixelPaths limit fixed by the proto.
struct TileResultLimits {
  static constexpr uint32_t kMaxPixelsPerChunk = 65536;
  /// Room for the oneof tag, length prefixes and the small fields of one chunk, bytes.
  static constexpr uint32_t kChunkFramingBytes = 64;

  uint32_t max_vertices_per_chunk = 65536;  // vertices per VertexBatch, samples per ExactSamples
  uint32_t max_chunk_bytes = 2u << 20;      // serialised TileResultChunk, bytes
};

/// Who sends the result and for which lease (TileResultHeader's identity fields).
struct TileResultIdentity {
  uint64_t lease_id = 0;
  std::string job_id;
  uint32_t round = 0;
  uint32_t tile_index = 0;
  std::string worker_id;
};

// ---- worker side ---------------------------------------------------------------------------------

/// Turns one TileResult into the chunks of a SubmitTile stream, one chunk at a time:
///     TileResultWriter w(result, id, codec_bounds, limits);
///     v1::TileResultChunk c;
///     while (w.next(&c)) stream->Write(c);
/// `result` must outlive the writer. Vertices come either as records (encoded here) or already packed
/// by the tile renderer (TileResult::packed_vertices: copied once, straight into the chunks). Throws
/// std::invalid_argument if the result has records and `codec_bounds` are unusable (VertexCodec's
/// constructor), or has packed vertices encoded with other bounds than `codec_bounds`.
class TileResultWriter {
 public:
  TileResultWriter(const TileResult& result, TileResultIdentity identity, const Bounds3& codec_bounds,
                   const TileResultLimits& limits);
  TileResultWriter(const TileResultWriter&) = delete;  // points into itself
  TileResultWriter& operator=(const TileResultWriter&) = delete;

  /// Sets `*chunk` to the next chunk; false (chunk untouched) once the trailer has been produced.
  bool next(v1::TileResultChunk* chunk);

  const v1::TileResultHeader& header() const { return header_; }
  const v1::TileWorkerStats& stats() const { return stats_; }
  /// Items per chunk the limits allow (at least 1 each).
  uint32_t pixels_per_chunk() const { return pixels_per_chunk_; }
  uint32_t vertices_per_chunk() const { return vertices_per_chunk_; }
  uint32_t exact_samples_per_chunk() const { return exact_per_chunk_; }

 private:
  enum class Phase { kHeader, kPixels, kVertices, kExact, kTrailer, kDone };

  const TileResult& result_;
  v1::TileResultHeader header_;
  v1::TileWorkerStats stats_;
  std::string packed_;                        // accepted vertices, 16 bytes each, in record order (from records)
  const std::string* packed_src_ = &packed_;  // what is sent: packed_ or the result's packed_vertices
  std::vector<uint32_t> exact_kept_;          // indices into result.visible of the samples sent
  uint32_t pixels_per_chunk_ = 1, vertices_per_chunk_ = 1, exact_per_chunk_ = 1;
  Phase phase_ = Phase::kHeader;
  size_t cursor_ = 0;  // next pixel / vertex / exact sample of the current phase
};

/// Writes every chunk of `writer` to a SubmitTile client stream (grpc::ClientWriter), the last one
/// (the trailer) with the half-close in one write. Stops at the first failed write: the master has
/// closed the stream, and the caller's Finish() says why.
template <class Stream>
void write_tile_result(TileResultWriter& writer, Stream& stream) {
  v1::TileResultChunk chunk, next;
  for (bool have = writer.next(&chunk); have;) {
    const bool more = writer.next(&next);
    if (!(more ? stream.Write(chunk) : stream.Write(chunk, grpc::WriteOptions().set_last_message()))) break;
    chunk.Swap(&next);
    next.Clear();
    have = more;
  }
}

/// All chunks at once (tests and small tiles; the worker streams with TileResultWriter).
std::vector<v1::TileResultChunk> split_tile_result(const TileResult& result, const TileResultIdentity& identity,
                                                   const Bounds3& codec_bounds, const TileResultLimits& limits);

// ---- master side ---------------------------------------------------------------------------------

/// What the master knows about a tile from its lease table, to check a result against.
struct TileExpectation {
  enum class Payload {
    kPathsOnly,     // RENDER_MODE_PT: no vertices, no exact samples
    kVertices,      // RP / SKIP with the GL or CPU method: VertexBatch chunks
    kExactSamples,  // REPROJECTION_METHOD_EXACT: ExactSamples chunks
  };

  std::string job_id;
  uint32_t round = 0;
  uint32_t tile_index = 0;
  uint32_t x0 = 0, y0 = 0, x1 = 0, y1 = 0;     // the tile, raster space, pixels, upper bounds exclusive
  uint32_t image_width = 0, image_height = 0;  // pixels
  uint32_t subpixels = 4;                      // S, for the range of exact-sample subpixel indices
  Bounds3 codec_bounds;                        // bit-identical to the lease's RenderSettings.codec_bounds
  Payload payload = Payload::kVertices;
  TileResultLimits limits;
  /// Optional stricter checks of PixelPaths.path_count. 0: a count may be any value <= 2^20.
  /// Otherwise a pixel's count must be paths_per_pixel (or its entry in `paths`, per tile pixel,
  /// row-major; empty = paths_per_pixel each), or 0 where `skip` (per tile pixel, row-major,
  /// non-zero = skipped; empty = none skipped) says so.
  uint32_t paths_per_pixel = 0;
  std::vector<uint8_t> skip;
  std::vector<uint32_t> paths;
  /// Cap on the header's vertex_count (memory bound per tile on the master). 0: no cap.
  uint64_t max_vertices_per_tile = 0;
  /// Keep the vertices in their 16-byte wire form (AssembledTile::packed_vertices) instead of
  /// decoding them into VertexRecords: the master's reprojector decodes them in place
  /// (Reprojector::reproject_packed). Every 16-byte pattern decodes to a valid record, so nothing
  /// per vertex needs checking here.
  bool keep_packed = false;
};

/// One complete, checked tile result.
struct AssembledTile {
  uint64_t lease_id = 0;
  std::string worker_id;
  uint32_t x0 = 0, y0 = 0, x1 = 0, y1 = 0;  // raster space, pixels, upper bounds exclusive
  std::vector<Vec3> path_sum;               // per tile pixel, row-major; linear RGB, finite, >= 0
  std::vector<Vec3> glossy_sum;             // per tile pixel, in [0, path_sum]; empty: all 0
  // Paths per pixel. With the lease's count (paths_per_pixel > 0, what the master always checks) every
  // pixel traced that many (or its entry in `paths`), or none where `skip` (per tile pixel; empty: none
  // skipped) is set, and path_count stays empty; without it, path_count holds each pixel's count.
  uint32_t paths_per_pixel = 0;
  std::vector<uint8_t> skip;
  std::vector<uint32_t> paths;
  std::vector<uint32_t> path_count;
  std::vector<VertexRecord> vertices;                    // decoded with the job's VertexCodec
  std::string packed_vertices;                           // instead, with keep_packed: 16 bytes each
  std::vector<std::pair<uint32_t, Vec3>> exact_samples;  // (subpixel, radiance), finite, >= 0
  v1::TileWorkerStats worker_stats;                      // as the worker reported them
  uint64_t dropped_pixel_sums = 0;                       // non-finite or negative sums set to 0 (counts kept)
  uint64_t dropped_exact_samples = 0;                    // non-finite or negative exact samples left out

  size_t vertex_count() const { return vertices.size() + packed_vertices.size() / VertexCodec::kPackedBytes; }
  /// Every tile pixel's path count, row-major.
  std::vector<uint32_t> path_counts() const;
};

/// Checks a SubmitTile stream chunk by chunk and rebuilds the tile. Usage in the service: read the
/// first chunk, look its header up in the lease table, construct the assembler from the lease, then
/// add() every chunk including that first one; commit only when complete().
/// Any error is final: later add() calls return the same reason.
class TileResultAssembler {
 public:
  /// Throws std::invalid_argument if the expectation itself is unusable (empty tile, tile outside the
  /// image, bad codec bounds, skip of the wrong length).
  explicit TileResultAssembler(TileExpectation expected);

  /// Empty if the chunk is acceptable, otherwise why not (for INVALID_ARGUMENT).
  std::optional<std::string> add(const v1::TileResultChunk& chunk);
  /// The same, but may move a vertex batch's bytes out of `chunk` instead of copying them.
  std::optional<std::string> add(v1::TileResultChunk* chunk);

  /// The trailer has been accepted: every count matched and every pixel was covered once.
  bool complete() const { return complete_; }
  /// The header, once one has been accepted (nullptr before).
  const v1::TileResultHeader* header() const { return header_seen_ ? &header_ : nullptr; }
  /// The tile; only valid once complete(). Leaves the assembler empty.
  AssembledTile take();

 private:
  std::optional<std::string> add_header(const v1::TileResultHeader& h);
  std::optional<std::string> add_pixels(const v1::PixelPaths& p);
  std::optional<std::string> add_vertices(const v1::VertexBatch& b, std::string* steal = nullptr);
  std::optional<std::string> add_exact(const v1::ExactSamples& e);
  std::optional<std::string> add_trailer(const v1::TileResultTrailer& t);
  std::optional<std::string> fail(std::string reason);

  TileExpectation expected_;
  VertexCodec codec_;
  uint32_t pixel_count_ = 0;
  v1::TileResultHeader header_;
  bool header_seen_ = false;
  bool complete_ = false;
  std::optional<std::string> error_;
  std::vector<uint8_t> covered_;  // per tile pixel: PixelPaths seen
  uint32_t pixels_covered_ = 0;
  AssembledTile tile_;
};

}  // namespace epr
