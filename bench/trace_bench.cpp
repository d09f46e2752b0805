// Path tracer throughput against Embree's own limit, side by side in one run.
//
// For each scene: a raw rtcIntersect1 loop of incoherent random rays (origins uniform in the
// scene's bounds, directions uniform on the sphere) and the path tracer on the same scene, both on
// ONE thread, so the figures are per core. Prints medians over repeated runs and the ratio
// path vertices/s : raw rays/s (bar: >= 0.40).
//
//   trace_bench [--runs N] [--scene SPEC ...]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "common/rng.h"
#include "common/scene_loader.h"
#include "worker/tile_renderer.h"

using namespace epr;
using Clock = std::chrono::steady_clock;

namespace {

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

// Rays per second of closest-hit queries with random origins and directions.
double raw_ray_rate(const EmbreeScene& es, const Bounds3& b, int count, uint64_t seed) {
  std::vector<Ray> rays(size_t(count));
  for (int i = 0; i < count; ++i) {
    SampleStream s(seed, uint32_t(i), 0);
    const Vec3 o = b.lo + b.diagonal() * Vec3(s.next(), s.next(), s.next());
    const float z = 1 - 2 * s.next(), phi = 2 * kPi * s.next();
    const float r = std::sqrt(std::max(0.f, 1 - z * z));
    rays[size_t(i)] = {o, Vec3(r * std::cos(phi), r * std::sin(phi), z)};
  }
  const auto t = Clock::now();
  size_t hits = 0;
  Hit h;
  for (const Ray& ray : rays) hits += es.intersect(ray, 0.f, 1e30f, &h);
  const double s = std::chrono::duration<double>(Clock::now() - t).count();
  if (hits == 0) std::fprintf(stderr, "warning: no ray hit anything\n");
  return count / s;
}

struct TraceRate {
  double vertices_per_s, rays_per_s, paths_per_s;
};

TraceRate trace_rate(const EmbreeScene& es, const Camera& cam, int spp, uint64_t seed) {
  PathTracer tracer(es, cam, seed, RussianRoulette::paper());
  TileRenderer tr(tracer, {VertexFilter::Mode::kNone});
  TileRequest req{{0, 0, cam.width(), cam.height()}, {}, {}, spp};
  const auto t = Clock::now();
  const TileResult r = tr.render(req);
  const double s = std::chrono::duration<double>(Clock::now() - t).count();
  return {r.stats.paths.vertices / s, r.stats.paths.rays / s, r.stats.paths.paths / s};
}

}  // namespace

int main(int argc, char** argv) {
  int runs = 5;
  std::vector<std::string> scenes;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--runs") && i + 1 < argc) runs = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--scene") && i + 1 < argc) scenes.push_back(argv[++i]);
  }
  if (scenes.empty()) scenes = {"builtin:cornell", "builtin:hall?tess=11", "builtin:hall?tess=18"};
  std::printf("%-32s %10s %12s %12s %12s %12s %8s\n", "scene", "triangles", "raw rays/s", "pt rays/s",
              "pt verts/s", "pt paths/s", "ratio");
  for (const std::string& spec : scenes) {
    const Scene scene = load_scene(spec);
    EmbreeScene es(scene);
    const Camera cam(scene.camera, 128, 128);
    std::vector<double> raw, rays, verts, paths;
    for (int r = 0; r < runs; ++r) {
      raw.push_back(raw_ray_rate(es, scene.bounds(), 400000, uint64_t(r) + 1));
      const TraceRate t = trace_rate(es, cam, 4, uint64_t(r) + 1);
      rays.push_back(t.rays_per_s);
      verts.push_back(t.vertices_per_s);
      paths.push_back(t.paths_per_s);
    }
    std::printf("%-32s %10zu %12.3g %12.3g %12.3g %12.3g %8.2f\n", spec.c_str(), scene.triangle_count(), median(raw),
                median(rays), median(verts), median(paths), median(verts) / median(raw));
  }
  std::printf("(one thread; medians of %d runs; ratio = path vertices/s : raw rays/s, bar >= 0.40)\n", runs);
  return 0;
}
