#include "worker/tile_renderer.h"

#include <chrono>
#include <cmath>

#include "common/denormals.h"
#include "worker/nonfinite_log.h"
#include "worker/view_test.h"

namespace epr {

TileRenderer::TileRenderer(const PathTracer& tracer, VertexFilter filter, const Bounds3& codec_bounds)
    : tracer_(tracer), filter_(filter), codec_bounds_(codec_bounds) {
  if (filter_.mode == VertexFilter::Mode::kAll || filter_.mode == VertexFilter::Mode::kCull)
    codec_.emplace(codec_bounds);
}

void TileRenderer::filter_vertices(std::vector<VertexRecord>& recs, size_t first, TileResult& out) const {
  const Camera& cam = tracer_.camera();
  const EmbreeScene& scene = tracer_.scene();
  const int S = filter_.subpixels;
  size_t kept = first;
  for (size_t i = first; i < recs.size(); ++i) {
    const VertexRecord& r = recs[i];
    if (!r.diffuse() && !filter_.reproject_glossy) {
      ++out.stats.culled_glossy;
      continue;
    }
    float sx = 0, sy = 0;
    ViewTest view = view_test(cam, r.position, r.normal, S, &sx, &sy);
    if (view != ViewTest::kVisible && filter_.mode == VertexFilter::Mode::kCull)
      for (const Camera& other : filter_.window_cameras) {
        float ox, oy;
        if (view_test(other, r.position, r.normal, S, &ox, &oy) == ViewTest::kVisible) {
          view = ViewTest::kVisible;
          break;
        }
      }
    if (view == ViewTest::kOutsideImage) {
      ++out.stats.culled_frustum;
      continue;
    }
    if (view == ViewTest::kBackFacing) {
      ++out.stats.culled_facing;
      continue;
    }
    const Vec3 to_eye = cam.eye() - r.position;
    if (filter_.mode == VertexFilter::Mode::kExact) {
      const float dist = length(to_eye);
      const float eps = scene.ray_epsilon();
      const Vec3 origin = r.position + r.normal * eps;
      if (scene.occluded(origin, to_eye / dist, 0.f, dist - 2 * eps)) {
        ++out.stats.exact_occluded;
        continue;
      }
      const uint32_t subpixel = uint32_t(std::floor(sy)) * uint32_t(cam.width() * S) + uint32_t(std::floor(sx));
      out.visible.push_back({subpixel, r.radiance});
      continue;
    }
    recs[kept++] = r;
  }
  recs.resize(kept);
}

TileResult TileRenderer::render(const TileRequest& req) const {
  TileResult out;
  out.rect = req.rect;
  render_into(req, out);
  return out;
}

void TileRenderer::render_into(const TileRequest& req, TileResult& out) const {
  const ScopedFlushDenormals flush_denormals;  // the same samples whichever thread traces the tile
  const auto start = std::chrono::steady_clock::now();
  const size_t n = size_t(req.rect.pixel_count()), at = out.path_sum.size();
  out.path_sum.resize(at + n, Vec3(0.f));
  out.glossy_sum.resize(at + n, Vec3(0.f));
  out.path_count.resize(at + n, 0);
  const bool record = filter_.mode != VertexFilter::Mode::kNone;
  const bool encode = codec_.has_value();
  // Exact mode keeps records only until they are turned into VisibleSamples; with a codec, kept
  // records wait only until kEncodeBatch of them can be packed together (still in cache).
  std::vector<VertexRecord> scratch;
  std::vector<VertexRecord>& recs = filter_.mode == VertexFilter::Mode::kExact || encode ? scratch : out.vertices;
  if (encode) out.packed_bounds = codec_bounds_;

  NonFiniteTileLog nonfinite;
  size_t i = 0;
  for (int y = req.rect.y0; y < req.rect.y1; ++y) {
    for (int x = req.rect.x0; x < req.rect.x1; ++x, ++i) {
      if (!req.skip.empty() && req.skip[i]) continue;
      const uint32_t first = req.first_sample.empty()       ? 0
                             : req.first_sample.size() == 1 ? req.first_sample[0]
                                                            : req.first_sample[i];
      const int paths = req.paths.empty() ? req.paths_per_pixel : int(req.paths[i]);
      Vec3 sum(0.f), glossy_sum(0.f);
      for (int k = 0; k < paths; ++k) {
        const size_t before = recs.size();
        const uint64_t dropped = out.stats.paths.nonfinite_dropped;
        Vec3 glossy;
        sum += tracer_.trace(x, y, first + uint32_t(k), record ? &recs : nullptr, &out.stats.paths, &glossy);
        glossy_sum += glossy;
        if (out.stats.paths.nonfinite_dropped != dropped) nonfinite.add(x, y, first + uint32_t(k));
        out.stats.vertices_recorded += recs.size() - before;
        if (filter_.mode == VertexFilter::Mode::kCull || filter_.mode == VertexFilter::Mode::kExact)
          filter_vertices(recs, before, out);
        if (filter_.mode == VertexFilter::Mode::kExact) recs.clear();
        if (encode && recs.size() >= kEncodeBatch) {
          codec_->encode_batch(recs, &out.packed_vertices, &out.encode_counts);
          recs.clear();
        }
      }
      out.path_sum[at + i] = sum;
      out.glossy_sum[at + i] = glossy_sum;
      out.path_count[at + i] = uint32_t(paths);
    }
  }
  if (encode) codec_->encode_batch(recs, &out.packed_vertices, &out.encode_counts);
  nonfinite.report(req.rect, tracer_.seed());
  out.stats.seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

}  // namespace epr
