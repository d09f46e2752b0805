// Eye-path vertices as a worker sends them: one tile over the whole frame, 2 paths per pixel, every
// vertex kept (VertexFilter kAll). Shared by the master's and the server's tests.
#pragma once

#include <cstdint>
#include <vector>

#include "common/camera.h"
#include "common/scene.h"
#include "common/vertex_record.h"
#include "worker/embree_scene.h"
#include "worker/path_tracer.h"
#include "worker/tile_renderer.h"

namespace epr::test {

inline std::vector<VertexRecord> traced_vertices(const Scene& scene, const Camera& camera, uint64_t seed,
                                                 int subpixels) {
  EmbreeScene es(scene);
  PathTracer tracer(es, camera, seed, RussianRoulette::paper());
  VertexFilter f;
  f.mode = VertexFilter::Mode::kAll;
  f.subpixels = subpixels;
  TileRenderer tr(tracer, f);
  return tr.render({{0, 0, camera.width(), camera.height()}, {}, {}, 2}).vertices;
}

}  // namespace epr::test
