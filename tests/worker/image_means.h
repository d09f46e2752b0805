// Means over a whole image that a PathTracer renders tile by tile (16 x 16 tiles, every vertex
// recorded): the tests that check a render against radiance known in closed form read these.
#pragma once

#include <tbb/parallel_for.h>

#include <vector>

#include "worker/path_tracer.h"
#include "worker/tile_renderer.h"

namespace epr {

struct ImageMeans {
  double pixel = 0;   // mean over every path of (r + g + b) / 3
  double vertex = 0;  // mean over every recorded vertex of the same
  size_t vertices = 0;
};

inline ImageMeans render_image_means(const PathTracer& tracer, int size, int spp) {
  TileRenderer tiles(tracer, {VertexFilter::Mode::kAll});
  const auto rects = make_tiles(size, size, 16);
  std::vector<double> ps(rects.size()), pc(rects.size()), vs(rects.size());
  std::vector<size_t> vc(rects.size());
  tbb::parallel_for(size_t(0), rects.size(), [&](size_t t) {
    TileRequest req;
    req.rect = rects[t];
    req.paths_per_pixel = spp;
    const TileResult r = tiles.render(req);
    for (size_t i = 0; i < r.path_sum.size(); ++i) {
      ps[t] += (r.path_sum[i].x + r.path_sum[i].y + r.path_sum[i].z) / 3.0;
      pc[t] += r.path_count[i];
    }
    for (const VertexRecord& v : r.vertices) vs[t] += (v.radiance.x + v.radiance.y + v.radiance.z) / 3.0;
    vc[t] = r.vertices.size();
  });
  ImageMeans m;
  double p = 0, c = 0, v = 0;
  for (size_t t = 0; t < rects.size(); ++t) {
    p += ps[t];
    c += pc[t];
    v += vs[t];
    m.vertices += vc[t];
  }
  m.pixel = p / c;
  m.vertex = m.vertices ? v / double(m.vertices) : 0;
  return m;
}

}  // namespace epr
