// One tile of eye paths: the unit of work a worker leases (Embree tutorial layering: one path, the
// samples of a pixel, a tile; the frame is a parallel loop over tiles elsewhere).
//
// Per tile pixel it returns the sum and count of this tile's path samples, and the vertex records
// the reprojector needs, filtered for the camera (VertexFilter) so that nothing the master would
// cull crosses the network. Given the job's codec bounds (kAll / kCull), it encodes the kept vertices
// into their 16-byte wire form a few paths after they come out of the tracer (VertexCodec, the bytes
// TileResultWriter would produce from the records), so that no 40-byte record is kept for the tile and
// the worker makes no second pass over the tile's vertices before SubmitTile. In exact mode the
// worker decides visibility itself with a ray from each vertex to the eye and returns (subpixel,
// radiance) pairs instead of records.
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "common/render_options.h"
#include "common/vertex_codec.h"
#include "common/vertex_record.h"
#include "worker/path_tracer.h"

namespace epr {

struct TileRect {
  int x0 = 0, y0 = 0, x1 = 0, y1 = 0;  // pixels, upper bounds exclusive
  int width() const { return x1 - x0; }
  int height() const { return y1 - y0; }
  int pixel_count() const { return width() * height(); }
};

/// Tiles of at most `tile_size` x `tile_size` pixels covering the image, row-major.
std::vector<TileRect> make_tiles(int width, int height, int tile_size, bool taper = false);
/// A job's tiles: its image, tile size and tapering.
inline std::vector<TileRect> make_tiles(const RenderOptions& o) {
  return make_tiles(o.width, o.height, o.tile_size, o.taper_tiles);
}

struct VertexFilter {
  enum class Mode {
    kNone,   // record nothing (plain path tracing)
    kAll,    // every vertex x_n, n >= 2, unfiltered (tests)
    kCull,   // drop what the master would cull: outside the view, facing away, not diffuse
    kExact,  // kCull, then a visibility ray to the eye; visible ones become VisibleSamples
  };
  Mode mode = Mode::kNone;
  int subpixels = 4;              // S, for subpixel indices in exact mode
  bool reproject_glossy = false;  // keep non-diffuse vertices (failure-mode study only)
};

/// A vertex whose visibility from the eye was decided by a ray (exact mode).
struct VisibleSample {
  uint32_t subpixel;  // sy * (S * width) + sx in the S x S subpixel grid, y down
  Vec3 radiance;      // Le + R_n
};

struct TileRequest {
  TileRect rect;
  std::span<const uint8_t> skip;           // per tile pixel, row-major; non-zero: trace nothing. Empty: none.
  std::span<const uint32_t> first_sample;  // per tile pixel: sample index of its next path. Empty: all 0.
  int paths_per_pixel = 1;
};

struct TileStats {
  PathStats paths;
  uint64_t vertices_recorded = 0;  // x_n, n >= 2, before filtering
  uint64_t culled_frustum = 0;     // behind the eye or outside the image
  uint64_t culled_facing = 0;      // facing away from the eye
  uint64_t culled_glossy = 0;      // not diffuse
  uint64_t exact_occluded = 0;     // exact mode: the ray to the eye was blocked
  double seconds = 0;              // wall time spent in render()

  TileStats& operator+=(const TileStats& o);
};

struct TileResult {
  TileRect rect;
  std::vector<Vec3> path_sum;          // per tile pixel, linear RGB, sum over this tile's paths
  std::vector<uint32_t> path_count;    // per tile pixel
  std::vector<VertexRecord> vertices;  // kAll / kCull without codec bounds
  std::vector<VisibleSample> visible;  // kExact
  TileStats stats;
  /// kAll / kCull with codec bounds: the kept vertices the codec accepted, 16 bytes each
  /// (VertexCodec::encode_batch of what `vertices` would hold, in the same order), and the counts of
  /// what it refused. `vertices` stays empty. packed_bounds: the bounds they were encoded with
  /// (TileResultWriter checks them against the lease's); nullopt if nothing was encoded here.
  std::string packed_vertices;
  EncodeCounts encode_counts;
  std::optional<Bounds3> packed_bounds;
};

class TileRenderer {
 public:
  TileRenderer(const PathTracer& tracer, VertexFilter filter) : tracer_(tracer), filter_(filter) {}
  /// Encodes the vertices as they are produced (kAll / kCull; other modes ignore the bounds). Throws
  /// std::invalid_argument for bounds VertexCodec refuses.
  TileRenderer(const PathTracer& tracer, VertexFilter filter, const Bounds3& codec_bounds);
  TileResult render(const TileRequest& request) const;

  /// With codec bounds, kept records are encoded once at least this many have gathered (a few paths'
  /// worth, 2.5 KB: still in L1), so that the codec's four-record kernel runs on full groups.
  static constexpr size_t kEncodeBatch = 64;

 private:
  /// Applies the filter to `recs` in place (kCull / kExact) and fills `visible` in exact mode.
  void filter_vertices(std::vector<VertexRecord>& recs, size_t first, TileResult& out) const;

  const PathTracer& tracer_;
  VertexFilter filter_;
  std::optional<VertexCodec> codec_;  // set: encode kept vertices into TileResult::packed_vertices
  Bounds3 codec_bounds_;
};

}  // namespace epr
