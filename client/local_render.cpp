#include "client/local_render.h"

#include <fmt/format.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>
#include <stdexcept>

#include "client/render_flags.h"
#include "common/log.h"
#include "common/scene_loader.h"
#include "common/vertex_codec.h"
#include "master/frame_state.h"
#include "master/gl_context.h"
#include "master/result_files.h"
#include "master/round_driver.h"
#include "worker/tile_renderer.h"

namespace epr {
namespace {

double since(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

VertexFilter filter_for(const RenderOptions& o) {
  VertexFilter f;
  f.subpixels = o.subpixels;
  f.reproject_glossy = o.reproject_glossy;
  if (o.mode == RenderMode::kPathTrace)
    f.mode = VertexFilter::Mode::kNone;
  else if (o.reproject == ReprojectMethod::kExact)
    f.mode = VertexFilter::Mode::kExact;
  else
    f.mode = VertexFilter::Mode::kCull;
  return f;
}

}  // namespace

RenderOutputs render_local(const RenderOptions& opts, const ProgressCallback& progress) {
  if (auto err = opts.validate()) throw std::invalid_argument(*err);
  auto log = logger("client");
  const auto t_start = std::chrono::steady_clock::now();
  std::unique_ptr<tbb::global_control> threads;
  if (opts.threads > 0)
    threads = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, size_t(opts.threads));

  LoadReport report;
  const Scene scene =
      load_job_scene(opts.scene, {}, &report, opts.lighting, opts.env_folder);  // warnings once; unlit refused
  if (!opts.out.empty()) {
    std::vector<std::filesystem::path> inputs;
    for (const FileRef& f : report.files) inputs.push_back(f.real);
    if (auto err = output_replaces_input(opts.out, inputs)) throw OutputError("--out " + *err);
  }
  const Camera camera(opts.camera_for(scene.camera), opts.width, opts.height);
  const double t_load = since(t_start);
  const auto t_bvh = std::chrono::steady_clock::now();
  // One BVH for the tracing and the master's edge pixels.
  const auto bvh = std::make_shared<const SceneBvh>(scene);
  EmbreeScene embree(bvh);
  const double seconds_bvh = since(t_bvh);
  log->info("scene {}: {} triangles, {} materials; BVH in {:.3f} s", scene.name, scene.triangle_count(),
            scene.materials.size(), seconds_bvh);

  // The master's side, in this process: the GL context lives on this thread.
  std::unique_ptr<GlContext> gl;
  if (opts.mode != RenderMode::kPathTrace && opts.reproject == ReprojectMethod::kGl) gl = std::make_unique<GlContext>();
  RoundDriver driver(opts, camera, scene, gl.get(), bvh.get());
  FrameState& frame = driver.frame();
  // Vertices cross the same 16-byte quantisation as on the wire, so that this render and a cluster's
  // give the same M' (docs/DESIGN.md: determinism).
  const VertexCodec codec(scene.bounds());

  const SkyLight sky(scene.lighting, embree);
  PathTracer tracer(embree, camera, opts.seed, opts.rr, opts.mis, opts.sampler, &sky);
  TileRenderer tile_renderer(tracer, filter_for(opts));
  const auto tiles = make_tiles(opts);
  TileStats totals;
  double seconds_tracing = 0;
  uint64_t codec_rejected = 0;

  const auto t_render = std::chrono::steady_clock::now();
  while (!driver.done()) {
    const RoundPlan plan = driver.open(tiles);
    std::vector<TileResult> results(tiles.size());
    const auto t_round = std::chrono::steady_clock::now();
    tbb::parallel_for(size_t(0), plan.order.size(), [&](size_t i) {
      const uint32_t t = plan.order[i];
      TileResult res =
          tile_renderer.render({tiles[t], plan.skip[t], plan.first_sample[t], plan.paths_per_pixel, plan.paths[t]});
      // Quantise as the wire does; records the codec refuses are not sent.
      size_t kept = 0;
      for (const VertexRecord& v : res.vertices) {
        PackedVertex pv;
        if (codec.encode(v, &pv)) res.vertices[kept++] = codec.decode(pv);
      }
      res.vertices.resize(kept);
      results[t] = std::move(res);
    });
    seconds_tracing += since(t_round);
    // Commit in tile order (fixed order: results do not depend on which thread finished first).
    for (TileResult& r : results) {
      if (r.path_sum.empty()) continue;
      driver.apply(r);
      totals += r.stats;
      codec_rejected += r.stats.vertices_recorded - r.stats.culled_frustum - r.stats.culled_facing -
                        r.stats.culled_glossy - r.stats.exact_occluded - r.vertices.size() - r.visible.size();
    }
    driver.close();
    if (progress) {
      const FrameProgress& fp = frame.progress();
      RoundProgress p;
      p.round = fp.round;
      p.seconds = since(t_start);
      p.mean_spp = fp.mean_spp;
      p.min_spp = fp.min_spp;
      p.mean_mprime = fp.mean_reprojected;
      p.pixels_active = double(fp.pixels_active) / (double(opts.width) * opts.height);
      p.eta_seconds = frame.done() ? 0 : eta_seconds(fp, opts.spp, since(t_render));
      p.frame = &frame;
      progress(p);
    }
  }

  const FrameImages images = frame.images();
  RenderOutputs out;
  out.combined = combined_image(images);
  out.pathtrace = pathtrace_image(images);
  out.path_count = images.path_count;
  out.counts = counts_image(images);
  if (frame.reprojects()) {
    out.reprojection = images.reprojection;
    out.mprime = images.reprojected;
  }

  const double seconds = since(t_start);
  // The same vertices a master counts as culled on the workers (JobCounters::worker_culled).
  out.stats = frame.statistics(
      opts, totals.culled_frustum + totals.culled_facing + totals.culled_glossy + totals.exact_occluded);
  out.stats.update({
      {"scene", scene.name},
      {"triangles", scene.triangle_count()},
      {"width", opts.width},
      {"height", opts.height},
      {"spp", opts.spp},
      {"paths_per_round", opts.paths_per_round},
      {"seed", opts.seed},
      {"paths", totals.paths.paths},
      {"vertices", totals.paths.vertices},
      {"vertices_recorded", totals.vertices_recorded},
      {"culled_frustum_worker", totals.culled_frustum},
      {"culled_facing_worker", totals.culled_facing},
      {"culled_glossy_worker", totals.culled_glossy},
      {"exact_occluded", totals.exact_occluded},
      {"codec_rejected", codec_rejected},
      {"rays", totals.paths.rays},
      {"nonfinite_dropped", totals.paths.nonfinite_dropped},
      {"seconds", seconds},
      {"seconds_load", t_load},
      {"seconds_bvh", seconds_bvh},
      {"seconds_tracing", seconds_tracing},
      {"paths_per_second", double(totals.paths.paths) / std::max(seconds_tracing, 1e-9)},
      {"rays_per_second", double(totals.paths.rays) / std::max(seconds_tracing, 1e-9)},
      {"vertices_per_second_per_core", double(totals.paths.vertices) / std::max(totals.seconds, 1e-9)},
  });
  return out;
}

void write_outputs(const std::string& prefix, const RenderOutputs& out) {
  FrameImages images;
  images.combined = out.combined;
  images.pathtrace = out.pathtrace;
  images.path_count = out.path_count;
  images.reprojection = out.reprojection;
  images.reprojected = out.mprime;
  write_results(images, out.mprime.width > 0, out.stats,
                [&](const ResultKindInfo& k) { return prefix + std::string(k.suffix); });
}

}  // namespace epr
