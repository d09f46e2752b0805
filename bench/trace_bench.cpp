// Path tracer throughput against Embree's own limit, side by side in one run.
//
// For each scene: a raw rtcIntersect1 loop of incoherent random rays (origins uniform in the
// scene's bounds, directions uniform on the sphere) and the path tracer on the same scene (a
// 128 x 128 image, 4 paths per pixel, VertexFilter kNone), both on ONE thread, alternating run by run,
// so the figures are per core. Each rate is measured twice: against wall time and against the
// thread's CPU time (CLOCK_THREAD_CPUTIME_ID), which stays meaningful when other processes share
// the machine. The ratio (path vertices/s : raw rays/s, bar >= 0.40) is taken per run from the two
// measurements made back to back, and the median over runs is printed.
//
// Also printed: vertices and rays per path, and the path tracer's rays/s (closest-hit plus shadow
// rays) against the raw loop's, which separates "Embree is slower on path rays" from "the tracer
// spends time outside Embree".
//
//   trace_bench [--runs 5] [--scene SPEC ...] [--size 128] [--spp 4] [--rays 400000] [--profile-pt]

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "common/cpu_time.h"
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

// Wall and CPU seconds of one measured section.
struct Timing {
  double wall = 0, cpu = 0;
};

template <class F>
Timing timed(F&& f) {
  const double c0 = thread_cpu_seconds();
  const auto t0 = Clock::now();
  f();
  return {std::chrono::duration<double>(Clock::now() - t0).count(), thread_cpu_seconds() - c0};
}

// Closest-hit queries with random origins and directions; returns the timing of `count` rays.
Timing raw_rays(const EmbreeScene& es, const Bounds3& b, int count, uint64_t seed) {
  std::vector<Ray> rays(static_cast<size_t>(count));
  for (int i = 0; i < count; ++i) {
    SampleStream s(seed, uint32_t(i), 0);
    const Vec3 o = b.lo + b.diagonal() * Vec3(s.next(), s.next(), s.next());
    const float z = 1 - 2 * s.next(), phi = 2 * kPi * s.next();
    const float r = std::sqrt(std::max(0.f, 1 - z * z));
    rays[size_t(i)] = {o, Vec3(r * std::cos(phi), r * std::sin(phi), z)};
  }
  size_t hits = 0;
  const Timing t = timed([&] {
    Hit h;
    for (const Ray& ray : rays) hits += es.intersect(ray, 0.f, 1e30f, &h);
  });
  if (hits == 0) std::fprintf(stderr, "warning: no ray hit anything\n");
  return t;
}

struct TraceRun {
  Timing t;
  PathStats stats;
};

TraceRun trace(const EmbreeScene& es, const Camera& cam, int spp, uint64_t seed, bool mis) {
  PathTracer tracer(es, cam, seed, RussianRoulette::paper(), mis);
  TileRenderer tr(tracer, {VertexFilter::Mode::kNone});
  TileRequest req{{0, 0, cam.width(), cam.height()}, {}, {}, spp};
  TileResult r;
  const Timing t = timed([&] { r = tr.render(req); });
  return {t, r.stats.paths};
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Path vertices/s per core against a raw rtcIntersect1 loop"};
  int runs = 5, size = 128, spp = 4, nrays = 400000;
  std::vector<std::string> scenes;
  app.add_option("--runs", runs, "runs per scene (median)");
  app.add_option("--scene", scenes, "scene specs (default: cornell, hall tess 11, hall tess 18)");
  app.add_option("--size", size, "image side of the traced frame, pixels");
  app.add_option("--spp", spp, "paths per pixel");
  app.add_option("--rays", nrays, "rays in the raw loop");
  bool profile_pt = false, mis = true;
  app.add_flag("--mis,!--no-mis", mis, "direct-light estimator: MIS (default) or next event estimation only");
  app.add_flag("--profile-pt", profile_pt, "only run the path tracer, --runs times (for perf record)");
  CLI11_PARSE(app, argc, argv);
  if (scenes.empty()) scenes = {"builtin:cornell", "builtin:hall?tess=11", "builtin:hall?tess=18"};

  double load[3] = {0, 0, 0};
  getloadavg(load, 3);
  std::printf(
      "trace_bench: one thread, %dx%d pixels x %d spp per run (%s), %d raw rays, %d runs (medians); "
      "load average %.2f %.2f %.2f\n",
      size, size, spp, mis ? "MIS" : "NEE only", nrays, runs, load[0], load[1], load[2]);
  std::printf("%-22s %9s | %-23s | %-23s | %-23s | %7s %7s | %-13s\n", "", "", "raw rays/s (M)", "pt rays/s (M)",
              "pt vertices/s (M)", "verts", "rays", "ratio verts:raw");
  std::printf("%-22s %9s | %11s %11s | %11s %11s | %11s %11s | %7s %7s | %6s %6s\n", "scene", "triangles", "wall",
              "cpu", "wall", "cpu", "wall", "cpu", "/path", "/path", "wall", "cpu");
  for (const std::string& spec : scenes) {
    const Scene scene = load_scene(spec);
    EmbreeScene es(scene);
    const Camera cam(scene.camera, size, size);
    trace(es, cam, 1, 99, mis);  // warm-up: page faults, caches
    if (profile_pt) {
      for (int r = 0; r < runs; ++r) trace(es, cam, spp, uint64_t(r) + 1, mis);
      continue;
    }
    std::vector<double> raw_w, raw_c, rays_w, rays_c, verts_w, verts_c, ratio_w, ratio_c, vpp, rpp;
    for (int r = 0; r < runs; ++r) {
      const Timing raw = raw_rays(es, scene.bounds(), nrays, uint64_t(r) + 1);
      const TraceRun pt = trace(es, cam, spp, uint64_t(r) + 1, mis);
      const double v = double(pt.stats.vertices), ry = double(pt.stats.rays);
      raw_w.push_back(nrays / raw.wall);
      raw_c.push_back(nrays / raw.cpu);
      rays_w.push_back(ry / pt.t.wall);
      rays_c.push_back(ry / pt.t.cpu);
      verts_w.push_back(v / pt.t.wall);
      verts_c.push_back(v / pt.t.cpu);
      ratio_w.push_back(verts_w.back() / raw_w.back());
      ratio_c.push_back(verts_c.back() / raw_c.back());
      vpp.push_back(v / double(pt.stats.paths));
      rpp.push_back(ry / double(pt.stats.paths));
    }
    std::printf("%-22s %9zu | %11.3f %11.3f | %11.3f %11.3f | %11.3f %11.3f | %7.2f %7.2f | %6.2f %6.2f\n",
                spec.substr(spec.find(':') + 1).c_str(), scene.triangle_count(), median(raw_w) / 1e6,
                median(raw_c) / 1e6, median(rays_w) / 1e6, median(rays_c) / 1e6, median(verts_w) / 1e6,
                median(verts_c) / 1e6, median(vpp), median(rpp), median(ratio_w), median(ratio_c));
    std::fflush(stdout);
  }
  getloadavg(load, 3);
  std::printf("(ratio = path vertices/s : raw rays/s, per run then median; bar >= 0.40; load average at end %.2f)\n",
              load[0]);
  return 0;
}
