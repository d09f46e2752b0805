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
#include "common/tile.h"
#include "common/vertex_codec.h"
#include "common/vertex_record.h"
#include "worker/path_tracer.h"

namespace epr {

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
  // kCull: a vertex the tracer's camera culls is kept if one of these shows it (the other frames of
  // a frame window, TileLease.window_cameras).
  std::vector<Camera> window_cameras = {};
};

class TileRenderer {
 public:
  TileRenderer(const PathTracer& tracer, VertexFilter filter) : tracer_(tracer), filter_(filter) {}
  /// Encodes the vertices as they are produced (kAll / kCull; other modes ignore the bounds). Throws
  /// std::invalid_argument for bounds VertexCodec refuses.
  TileRenderer(const PathTracer& tracer, VertexFilter filter, const Bounds3& codec_bounds);
  TileResult render(const TileRequest& request) const;
  /// Appends `request`'s pixels to `out` (after the ones it holds, in row-major order), its vertices
  /// after `out`'s, and adds to its stats: rendering a tile strip by strip into one result gives the
  /// bits one render() of the whole tile gives, with no copy of the strips afterwards.
  void render_into(const TileRequest& request, TileResult& out) const;

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
