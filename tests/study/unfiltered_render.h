// rp with the worker's vertex filter off, shared by tests/study and bench/failure_study: every x_n,
// n >= 2, reaches the reprojector, so only the master's tests protect the image; with
// `defeat_facing`, each normal is also turned towards the camera, which disables the master's
// back-facing test (the paper's behaviour). Same rounds and sample indices as render_local.
#pragma once

#include <nlohmann/json.hpp>
#include <vector>

#include "common/camera.h"
#include "common/render_options.h"
#include "common/scene_loader.h"
#include "master/frame_state.h"
#include "worker/embree_scene.h"
#include "worker/path_tracer.h"
#include "worker/tile_renderer.h"

namespace epr {

struct UnfilteredRender {
  FrameImages images;
  ReprojectionCounts counts;
  nlohmann::json stats;  // FrameState::statistics
};

inline UnfilteredRender render_unfiltered(RenderOptions o, bool defeat_facing, bool reproject_glossy = false) {
  o.mode = RenderMode::kReproject;
  o.reproject = ReprojectMethod::kCpu;
  const Scene scene = load_scene(o.scene);
  const Camera camera(o.camera_for(scene.camera), o.width, o.height);
  EmbreeScene embree(scene);
  FrameState frame(o, camera, scene, nullptr);
  PathTracer tracer(embree, camera, o.seed, o.rr, o.mis, o.sampler);
  TileRenderer renderer(tracer, VertexFilter{VertexFilter::Mode::kAll, o.subpixels, reproject_glossy});
  const TileRect all{0, 0, o.width, o.height};
  while (!frame.done()) {
    std::vector<uint8_t> skip;
    std::vector<uint32_t> first;
    frame.tile_inputs(0, 0, o.width, o.height, &skip, &first);
    TileResult res = renderer.render({all, skip, first, frame.next_paths_per_pixel()});
    if (defeat_facing)
      for (VertexRecord& v : res.vertices)
        if (dot(v.normal, camera.eye() - v.position) < 0) v.normal = -v.normal;
    frame.add_paths(0, 0, o.width, o.height, res.path_sum, res.path_count);
    frame.reproject(res.vertices);
    frame.finish_round();
  }
  UnfilteredRender r{frame.images(), frame.counts(), frame.statistics(o, 0)};  // kAll: nothing culled before
  r.images.combined = combined_image(r.images);
  r.images.pathtrace = pathtrace_image(r.images);
  return r;
}

}  // namespace epr
