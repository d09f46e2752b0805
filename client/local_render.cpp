#include "client/local_render.h"

#include <chrono>
#include <cmath>
#include <fstream>
#include <memory>
#include <stdexcept>

#include <fmt/format.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>

#include "common/log.h"
#include "common/scene_loader.h"
#include "worker/tile_renderer.h"

namespace epr {
namespace {

using Clock = std::chrono::steady_clock;
double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

// Per-pixel path accumulation in double, applied tile by tile in tile order so that the result does
// not depend on which thread finished first.
struct PathFilm {
  int width, height;
  std::vector<double> sum;      // rgb
  std::vector<uint32_t> count;  // M

  PathFilm(int w, int h) : width(w), height(h), sum(size_t(w) * size_t(h) * 3, 0.0), count(size_t(w) * size_t(h), 0) {}

  void add(const TileResult& r) {
    size_t i = 0;
    for (int y = r.rect.y0; y < r.rect.y1; ++y)
      for (int x = r.rect.x0; x < r.rect.x1; ++x, ++i) {
        const size_t p = size_t(y) * size_t(width) + size_t(x);
        sum[3 * p + 0] += r.path_sum[i].x;
        sum[3 * p + 1] += r.path_sum[i].y;
        sum[3 * p + 2] += r.path_sum[i].z;
        count[p] += r.path_count[i];
      }
  }
};

}  // namespace

RenderOutputs render_local(const RenderOptions& opts, const ProgressCallback& progress) {
  if (auto err = opts.validate()) throw std::invalid_argument(*err);
  auto log = logger("client");
  const auto t_start = Clock::now();
  std::unique_ptr<tbb::global_control> threads;
  if (opts.threads > 0)
    threads = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, size_t(opts.threads));

  const Scene scene = load_scene(opts.scene);
  const Camera camera(opts.camera_for(scene.camera), opts.width, opts.height);
  const double t_load = since(t_start);
  const auto t_bvh = Clock::now();
  EmbreeScene embree(scene);
  const double seconds_bvh = since(t_bvh);
  log->info("scene {}: {} triangles, {} materials; BVH in {:.3f} s", scene.name, scene.triangle_count(),
            scene.materials.size(), seconds_bvh);

  PathTracer tracer(embree, camera, opts.seed, opts.rr);
  TileRenderer tile_renderer(tracer, {VertexFilter::Mode::kNone});
  const auto tiles = make_tiles(opts.width, opts.height, opts.tile_size);
  PathFilm film(opts.width, opts.height);
  TileStats totals;
  double seconds_tracing = 0;

  const auto t_render = Clock::now();
  int round = 0;
  for (int done = 0; done < opts.spp; ++round) {
    const int k = std::min(opts.paths_per_round, opts.spp - done);
    std::vector<TileResult> results(tiles.size());
    std::vector<uint32_t> first;
    const auto t_round = Clock::now();
    tbb::parallel_for(size_t(0), tiles.size(), [&](size_t t) {
      std::vector<uint32_t> first_sample(size_t(tiles[t].pixel_count()), uint32_t(done));
      results[t] = tile_renderer.render({tiles[t], {}, first_sample, k});
    });
    seconds_tracing += since(t_round);
    for (const TileResult& r : results) {
      film.add(r);
      totals += r.stats;
    }
    done += k;
    if (progress) {
      RoundProgress p;
      p.round = round + 1;
      p.seconds = since(t_start);
      p.mean_spp = p.min_spp = done;
      p.pixels_active = 1;
      p.eta_seconds = since(t_render) / done * (opts.spp - done);
      progress(p);
    }
  }

  RenderOutputs out;
  out.combined = Image(opts.width, opts.height, 3);
  out.path_count = Image(opts.width, opts.height, 1);
  for (int y = 0; y < opts.height; ++y)
    for (int x = 0; x < opts.width; ++x) {
      const size_t p = size_t(y) * size_t(opts.width) + size_t(x);
      const double m = film.count[p];
      const Vec3 c = m > 0 ? Vec3(float(film.sum[3 * p] / m), float(film.sum[3 * p + 1] / m), float(film.sum[3 * p + 2] / m))
                           : Vec3(0.f);
      out.combined.set_rgb(x, y, c);
      out.path_count.at(x, y)[0] = float(m);
    }
  out.pathtrace = out.combined;

  const double seconds = since(t_start);
  const double core_seconds = totals.seconds;
  out.stats = {
      {"scene", scene.name},
      {"triangles", scene.triangle_count()},
      {"width", opts.width},
      {"height", opts.height},
      {"spp", opts.spp},
      {"mode", to_string(opts.mode)},
      {"seed", opts.seed},
      {"rounds", round},
      {"paths", totals.paths.paths},
      {"vertices", totals.paths.vertices},
      {"rays", totals.paths.rays},
      {"nonfinite_dropped", totals.paths.nonfinite_dropped},
      {"seconds", seconds},
      {"seconds_load", t_load},
      {"seconds_bvh", seconds_bvh},
      {"seconds_tracing", seconds_tracing},
      {"paths_per_second", totals.paths.paths / std::max(seconds_tracing, 1e-9)},
      {"rays_per_second", totals.paths.rays / std::max(seconds_tracing, 1e-9)},
      {"vertices_per_second_per_core", totals.paths.vertices / std::max(core_seconds, 1e-9)},
  };
  return out;
}

void write_outputs(const std::string& prefix, const RenderOutputs& out) {
  write_exr(prefix + ".exr", out.combined);
  write_png_srgb(prefix + ".png", out.combined);
  if (out.mprime.width > 0) {
    write_exr(prefix + ".pathtrace.exr", out.pathtrace);
    write_exr(prefix + ".reprojection.exr", out.reprojection);
    write_exr(prefix + ".samples.exr", out.mprime);
    float max_m = 0;
    for (float v : out.mprime.data) max_m = std::max(max_m, v);
    write_png_srgb(prefix + ".samples.png", heat_map(out.mprime, max_m));
  }
  std::ofstream js(prefix + ".json");
  if (!js) throw std::runtime_error(fmt::format("cannot write '{}.json'", prefix));
  js << out.stats.dump(2) << "\n";
}

}  // namespace epr
