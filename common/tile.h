// The tile: the unit of work a worker leases, and what tracing one yields. Shared by the worker that
// traces tiles, the wire that carries their results and the master (and the single-process render)
// that leases them and applies their results.
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "common/math.h"
#include "common/render_options.h"
#include "common/vertex_codec.h"
#include "common/vertex_record.h"

namespace epr {

struct TileRect {
  int x0 = 0, y0 = 0, x1 = 0, y1 = 0;  // pixels, upper bounds exclusive
  int width() const { return x1 - x0; }
  int height() const { return y1 - y0; }
  int pixel_count() const { return width() * height(); }
};

/// Tiles of at most `tile_size` x `tile_size` pixels covering the image, row-major. Tapered: the
/// last quarter of the tile rows (at least one) in tiles of half the edge.
std::vector<TileRect> make_tiles(int width, int height, int tile_size, bool taper = false);
/// A job's tiles: its image, tile size and tapering.
inline std::vector<TileRect> make_tiles(const RenderOptions& o) {
  return make_tiles(o.width, o.height, o.tile_size, o.taper_tiles);
}

/// What a tile asks of the tracer.
struct TileRequest {
  TileRect rect;
  std::span<const uint8_t> skip;  // per tile pixel, row-major; non-zero: trace nothing. Empty: none.
  // Per tile pixel: the sample index of its next path. One entry: every pixel's. Empty: all 0.
  std::span<const uint32_t> first_sample;
  int paths_per_pixel = 1;
  // Per tile pixel: its paths this round, at most paths_per_pixel. Empty: paths_per_pixel each.
  std::span<const uint32_t> paths = {};
};

/// Counts of the path tracer.
struct PathStats {
  uint64_t paths = 0;
  uint64_t vertices = 0;           // surface hits, all depths
  uint64_t rays = 0;               // closest-hit plus shadow rays
  uint64_t nonfinite_dropped = 0;  // samples that came out NaN or infinite (dropped, counted)

  PathStats& operator+=(const PathStats& o);
};

/// Non-finite samples beyond a trace: more than this fraction of the paths traced (one per million).
inline constexpr double kNonFiniteWarnFraction = 1e-6;
/// Nullopt unless `dropped` samples (NaN or infinite radiance, dropped) exceed kNonFiniteWarnFraction of
/// `paths` traced; else the warning a render's end shows: the image lacks those samples' light.
std::optional<std::string> nonfinite_warning(uint64_t dropped, uint64_t paths);

struct TileStats {
  PathStats paths;
  uint64_t vertices_recorded = 0;  // x_n, n >= 2, before filtering
  uint64_t culled_frustum = 0;     // behind the eye or outside the image
  uint64_t culled_facing = 0;      // facing away from the eye
  uint64_t culled_glossy = 0;      // not diffuse
  uint64_t exact_occluded = 0;     // exact mode: the ray to the eye was blocked
  double seconds = 0;              // wall time spent tracing the tile

  TileStats& operator+=(const TileStats& o);
};

/// A vertex whose visibility from the eye was decided by a ray (exact mode).
struct VisibleSample {
  uint32_t subpixel;  // sy * (S * width) + sx in the S x S subpixel grid, y down
  Vec3 radiance;      // Le + R_n
};

struct TileResult {
  TileRect rect;
  std::vector<Vec3> path_sum;          // per tile pixel, linear RGB, sum over this tile's paths
  std::vector<Vec3> glossy_sum;        // per tile pixel, the sums' glossy parts (PathTracer::trace)
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

}  // namespace epr
