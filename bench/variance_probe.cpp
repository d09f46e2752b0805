// Where a path tracer's error per sample comes from: per-pixel variance of P-sample pixel estimates
// over independent seeds, without a reference, so that paths can be cut at a depth or the scene's
// emitters moved and the change in noise read directly.
//
// For each of --seeds seeds (1000, 1001, ...) the image is rendered with P paths per pixel (plain path
// tracing, MIS, the paper's roulette). Per pixel and channel, the unbiased variance over seeds s^2
// gives the term s^2 / (m^2 + 0.01) (m the mean over seeds), the relative MSE of one P-sample
// estimate (the metric of bench_reference.h without its reference); printed are the mean over
// pixels of the channels' mean ("full") and that mean without the 1 % largest pixel terms
// ("trimmed"), and the image mean.
//   --max-depth N    paths stop after N vertices (1: direct light at the first hit only)
//   --emitter-y Y    every emitting triangle's corners moved to height Y (Cornell box: the light
//                    hangs at 1.98 m, 1 cm under the ceiling; 1.9899 closes the gap to 0.1 mm)
//   --env, --sun     a sky and a sun replacing the scene's, as epr render's flags (an image file: read
//                    from its own folder)
//   --share S        the triangles' share of the light selection fixed at S when there is also a sky
//                    (default: the power-based share, worker/sky_light.h)
//
//   variance_probe --scene builtin:cornell [--size 128] [--spp 64] [--seeds 4] [--sampler sobol-burley]
#include <tbb/parallel_for.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "common/scene_loader.h"
#include "worker/path_tracer.h"
#include "worker/sky_light.h"

using namespace epr;

int main(int argc, char** argv) {
  CLI::App app{"Per-pixel variance of path-traced pixel estimates over seeds"};
  std::string spec = "builtin:cornell", sampler_name = "sobol-burley";
  int size = 128, spp = 64, seeds = 4, max_depth = 0;
  std::optional<float> emitter_y, share;
  std::string env, sun;
  app.add_option("--scene", spec, "scene spec");
  app.add_option("--size", size, "image side, pixels");
  app.add_option("--spp", spp, "P: paths per pixel of each seed's image");
  app.add_option("--seeds", seeds, "independent images (at least 2)")->check(CLI::Range(2, 1000));
  app.add_option("--max-depth", max_depth, "stop paths after this many vertices (0: the roulette's cap)");
  app.add_option("--emitter-y", emitter_y, "move every emitting triangle's corners to this height, metres");
  app.add_option("--sampler", sampler_name, "sobol-burley or independent");
  app.add_option("--env", env, "environment replacing the scene's: R,G,B or an image file");
  app.add_option("--sun", sun, "sun replacing the scene's: DX,DY,DZ[,ANGLE_DEG[,E]]");
  app.add_option("--share", share, "fixed triangle share of the light selection (default: power-based)")
      ->check(CLI::Range(0.0, 1.0));
  CLI11_PARSE(app, argc, argv);
  const std::optional<SamplerKind> sampler = parse_sampler(sampler_name);
  if (!sampler) {
    std::fprintf(stderr, "unknown sampler '%s'\n", sampler_name.c_str());
    return 2;
  }

  Scene scene = load_scene(spec);
  if (emitter_y)
    for (size_t t = 0; t < scene.triangles.size(); ++t)
      if (scene.materials[scene.material_of[t]].emissive())
        for (uint32_t v : scene.triangles[t]) scene.positions[v].y = *emitter_y;
  Lighting job;
  std::string env_folder;
  if (!env.empty()) {
    std::string file;
    job.environment = parse_env_flag(env, &file);
    if (!file.empty()) {
      const std::filesystem::path real = std::filesystem::canonical(file);
      job.environment->image = real.filename().string();
      env_folder = real.parent_path().string();
    }
  }
  if (!sun.empty()) job.sun = parse_sun_flag(sun);
  if (!env_folder.empty()) scene.folder = env_folder;  // the image is read from its own folder
  scene.lighting = job_lighting(scene, job);
  EmbreeScene es(scene);
  const SkyLight sky(scene.lighting, es.emitted_power(), SkyLight::scene_radius(scene), share);
  const Camera cam(scene.camera, size, size);
  RussianRoulette rr = RussianRoulette::paper();
  if (max_depth > 0) rr.max_depth = max_depth;

  const size_t n = size_t(size) * size_t(size);
  std::vector<std::vector<Vec3>> images(size_t(seeds), std::vector<Vec3>(n, Vec3(0.f)));
  for (int k = 0; k < seeds; ++k) {
    const PathTracer tracer(es, cam, uint64_t(1000 + k), rr, true, *sampler, &sky);
    tbb::parallel_for(0, size, [&](int y) {
      for (int x = 0; x < size; ++x) {
        Vec3 sum(0.f);
        for (int s = 0; s < spp; ++s) sum += tracer.trace(x, y, uint32_t(s), nullptr, nullptr);
        images[size_t(k)][size_t(y) * size_t(size) + size_t(x)] = sum / float(spp);
      }
    });
  }

  std::vector<double> terms(n);
  double image_mean = 0;
  for (size_t i = 0; i < n; ++i) {
    double t = 0;
    for (int c = 0; c < 3; ++c) {
      double m = 0, v = 0;
      for (const auto& img : images) m += img[i][c];
      m /= seeds;
      for (const auto& img : images) v += (img[i][c] - m) * (img[i][c] - m);
      v /= seeds - 1;
      t += v / (m * m + 0.01);
      image_mean += m;
    }
    terms[i] = t / 3;
  }
  std::sort(terms.begin(), terms.end());
  const size_t keep = n - n / 100;
  double full = 0, trimmed = 0;
  for (size_t i = 0; i < n; ++i) {
    full += terms[i];
    if (i < keep) trimmed += terms[i];
  }
  std::printf(
      "%s %dx%d P=%d seeds=%d sampler=%s max_depth=%d%s triangle_share=%.3f (power %.4g : sky %.4g): relvar "
      "full %.5f trimmed %.5f, image mean %.5f\n",
      spec.c_str(), size, size, spp, seeds, to_string(*sampler), max_depth,
      emitter_y ? (" emitter_y=" + std::to_string(*emitter_y)).c_str() : "", sky.triangle_share(), sky.triangle_power(),
      sky.sky_power(), full / double(n), trimmed / double(keep), image_mean / (3.0 * double(n)));
  return 0;
}
