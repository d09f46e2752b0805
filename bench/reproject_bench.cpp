// Reprojection throughput: the GL compute back-end (OSMesa/llvmpipe) against the CPU back-end (TBB),
// side by side, on "real-like" vertex sets at 512 x 512 pixels, S = 4 (a 2048 x 2048 subpixel grid).
//
// Vertex sets (tests/master/test_scenes.h): points on the surfaces of a Cornell-like box and of a
// hall-like scene (the built-ins when common/builtin_scenes.h exists), area-weighted, normals towards
// the scene's inside; mixed with points jittered around visible deep-framebuffer texels and random
// points in and around the scene. --vertices FILE reads raw VertexRecord arrays (40 bytes each, as in
// common/vertex_record.h) instead, e.g. vertex sets dumped by the path tracer.
//
// Each figure is the median over --runs runs of: reset, reproject all points (in the back-end's
// batches, upload included), read the counts back (GL: waits for the GPU). The "packed" rows take
// the same points in their 16-byte wire form (reproject_packed, decoding included) in calls of 2^20
// vertices, of 15 000 (one 64 x 64 tile, the master's calling pattern) and (GL) of 3 800 (32 x 32
// tiles). The CPU back-end runs calls of fewer than 32768 vertices on the calling thread, so its
// 15 000-vertex rows do not change with --cpu-threads. Printed per
// back-end: wall-clock points/s and points per CPU-second of the whole process (robust when other processes share the
// machine: divide by the cores you have for an idle-machine estimate). LP_NUM_THREADS is read by llvmpipe once per
// process, so --lp-threads re-runs this program with each value.
//
//   reproject_bench [--runs 5] [--points 4000000] [--width 512] [--height 512] [-S 4]
//                   [--lp-threads 1,2,4] [--cpu-threads 1,2] [--sweep] [--vertices FILE] [--cpu-only]
//                   [--band-cells N] (GL: split the grid into bands of at most N subpixels)
#include <sys/resource.h>
#include <tbb/global_control.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>
#include <string_view>
#include <vector>

#include "common/vertex_codec.h"
#include "master/deep_framebuffer.h"
#include "master/gl_context.h"
#include "master/gl_reprojector.h"
#include "master/make_reprojector.h"
#include "master/reprojector.h"
#include "tests/master/test_scenes.h"

using namespace epr;

namespace {

double cpu_seconds() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return double(u.ru_utime.tv_sec + u.ru_stime.tv_sec) + 1e-6 * double(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

struct Figure {
  double wall = 0, cpu = 0;  // points per wall second, points per CPU second (medians)
  ReprojectionCounts counts;
};

Figure measure(Reprojector& r, const std::vector<VertexRecord>& pts, int runs) {
  std::vector<double> wall, cpu;
  Figure f;
  r.reproject(std::span(pts.data(), std::min<size_t>(pts.size(), 1 << 16)));  // warm-up (JIT, page faults)
  for (int i = 0; i < runs; ++i) {
    r.reset();
    const double c0 = cpu_seconds();
    const auto t0 = std::chrono::steady_clock::now();
    r.reproject(pts);
    f.counts = r.counts();  // GL: synchronises
    const double dt = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    wall.push_back(double(pts.size()) / dt);
    cpu.push_back(double(pts.size()) / std::max(1e-9, cpu_seconds() - c0));
  }
  f.wall = median(wall);
  f.cpu = median(cpu);
  return f;
}

// The same, for the points in their 16-byte wire form (Reprojector::reproject_packed) in calls of
// `call_points` vertices: the master's calling pattern is one call per tile (~3 800-15 000 vertices).
Figure measure_packed(Reprojector& r, const std::string& packed, const VertexCodec& codec, size_t call_points,
                      int runs) {
  std::vector<double> wall, cpu;
  Figure f;
  const size_t n = packed.size() / VertexCodec::kPackedBytes, call = call_points * VertexCodec::kPackedBytes;
  r.reproject_packed(std::string_view(packed).substr(0, size_t(1) << 20), codec);  // warm-up
  for (int i = 0; i < runs; ++i) {
    r.reset();
    const double c0 = cpu_seconds();
    const auto t0 = std::chrono::steady_clock::now();
    for (size_t off = 0; off < packed.size(); off += call)
      r.reproject_packed(std::string_view(packed).substr(off, call), codec);
    f.counts = r.counts();
    const double dt = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    wall.push_back(double(n) / dt);
    cpu.push_back(double(n) / std::max(1e-9, cpu_seconds() - c0));
  }
  f.wall = median(wall);
  f.cpu = median(cpu);
  return f;
}

std::vector<VertexRecord> read_vertices(const std::string& path) {
  std::ifstream in(path, std::ios::binary | std::ios::ate);
  if (!in) throw std::runtime_error("cannot open " + path);
  const size_t bytes = size_t(in.tellg());
  std::vector<VertexRecord> v(bytes / sizeof(VertexRecord));
  in.seekg(0);
  in.read(reinterpret_cast<char*>(v.data()), std::streamsize(v.size() * sizeof(VertexRecord)));
  return v;
}

void print_counts(const ReprojectionCounts& c, size_t n) {
  std::printf(
      "    decisions: accepted %.1f%%, occluded %.1f%% (back-facing %.1f%%), culled %.1f%%, not diffuse %.1f%%\n",
      100.0 * double(c.accepted) / double(n), 100.0 * double(c.occluded) / double(n),
      100.0 * double(c.backfacing) / double(n), 100.0 * double(c.culled) / double(n),
      100.0 * double(c.not_diffuse) / double(n));
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Reprojection throughput, GL (OSMesa) vs CPU"};
  int runs = 5, width = 512, height = 512, S = 4;
  size_t points = 4'000'000;
  std::vector<int> lp_threads, cpu_threads = {1, 2};
  bool sweep = false, gl_only = false, cpu_only = false;
  std::vector<size_t> gl_batches;
  size_t band_cells = 0;
  std::string vertices, scene_filter;
  app.add_option("--runs", runs, "runs per figure (median)");
  app.add_option("--points", points, "points per vertex set");
  app.add_option("--width", width);
  app.add_option("--height", height);
  app.add_option("-S,--subpixels", S);
  app.add_option("--lp-threads", lp_threads, "re-run the GL figures with these LP_NUM_THREADS values")->delimiter(',');
  app.add_option("--cpu-threads", cpu_threads, "TBB thread counts for the CPU back-end")->delimiter(',');
  app.add_flag("--sweep", sweep, "also sweep GL workgroup shapes and prefetch");
  app.add_option("--gl-batches", gl_batches,
                 "GL: packed throughput (2^20-vertex calls, the master's) with these upload batch sizes, alternating, "
                 "each --runs times")
      ->delimiter(',');
  app.add_flag("--gl-only", gl_only, "only the GL back-end (used by --lp-threads)");
  app.add_flag("--cpu-only", cpu_only,
               "only the CPU back-end (the deep framebuffer is still built with GL if available)");
  app.add_option("--vertices", vertices, "raw VertexRecord file instead of generated sets (scene: --scene)");
  app.add_option("--scene", scene_filter, "only this scene (cornell or hall)");
  app.add_option("--band-cells", band_cells,
                 "GL: at most this many subpixels per band (gl_max_band_cells; 0: GL's limits)");
  CLI11_PARSE(app, argc, argv);

  if (!lp_threads.empty()) {
    for (int t : lp_threads) {
      std::printf("==== LP_NUM_THREADS=%d\n", t);
      std::fflush(stdout);
      std::string cmd = "LP_NUM_THREADS=" + std::to_string(t) + " /proc/" + std::to_string(getpid()) +
                        "/exe --gl-only" + " --runs " + std::to_string(runs) + " --points " + std::to_string(points) +
                        " --width " + std::to_string(width) + " --height " + std::to_string(height) + " -S " +
                        std::to_string(S) + " --band-cells " + std::to_string(band_cells);
      if (!scene_filter.empty()) cmd += " --scene " + scene_filter;
      if (!vertices.empty()) cmd += " --vertices '" + vertices + "'";
      if (std::system(cmd.c_str()) != 0) return 1;
    }
    return 0;
  }

  const char* lp = std::getenv("LP_NUM_THREADS");
  double load[3] = {0, 0, 0};
  getloadavg(load, 3);
  std::printf(
      "reproject_bench: %dx%d pixels, S=%d (%dx%d subpixels), %d runs, median; LP_NUM_THREADS=%s; "
      "%ld cores; load average %.2f\n",
      width, height, S, width * S, height * S, runs, lp ? lp : "(unset = cores)", sysconf(_SC_NPROCESSORS_ONLN),
      load[0]);

  std::unique_ptr<GlContext> ctx;
  if (gl_available()) {
    ctx = std::make_unique<GlContext>();
    std::printf("GL: %s / %s\n", ctx->version().c_str(), ctx->renderer().c_str());
  } else {
    std::printf("GL: unavailable, CPU figures only\n");
  }

  for (const std::string name : {"cornell", "hall"}) {
    if (!scene_filter.empty() && scene_filter != name) continue;
    const Scene scene = test::scene_named(name);
    const Camera cam(scene.camera, width, height);
    const DeepFramebuffer dfb =
        ctx ? build_deep_framebuffer_gl(*ctx, scene, cam, S) : build_deep_framebuffer_cpu(scene, cam, S);
    const std::vector<VertexRecord> pts =
        vertices.empty() ? test::real_like_points(scene, dfb, cam, points, 42) : read_vertices(vertices);
    ReprojectorSettings settings;
    settings.epsilon = default_epsilon(scene.bounds());
    settings.gl_max_band_cells = band_cells;
    const VertexCodec codec(scene.bounds());
    std::string packed;  // the representable points in their wire form
    codec.encode_batch(pts, &packed);
    const size_t tile_call = 15000;  // one call per 64 x 64 tile (section 4 of docs/BENCHMARKS.md)
    std::printf("\n%s (%s, %zu triangles, %.1f%% of texels covered): %zu points\n", name.c_str(), scene.name.c_str(),
                scene.triangle_count(), 100.0 * double(dfb.covered_count()) / double(dfb.texel_count()), pts.size());

    Figure gl_fig;
    if (ctx && !cpu_only) {
      auto gl = make_reprojector("gl", cam, dfb, settings, ctx.get());
      gl_fig = measure(*gl, pts, runs);
      const auto* glr = dynamic_cast<const GlReprojector*>(gl.get());
      std::printf("  gl  (wg %d x %d, prefetch %s, %zu band%s): %7.2f M points/s wall, %7.2f M points/CPU-s\n",
                  settings.workgroups, settings.workgroup_size, settings.prefetch ? "on" : "off",
                  glr ? glr->band_count() : 0, glr && glr->band_count() == 1 ? "" : "s", gl_fig.wall / 1e6,
                  gl_fig.cpu / 1e6);
      print_counts(gl_fig.counts, pts.size());
      for (size_t call : {size_t(1) << 20, tile_call, size_t(3800)}) {
        const Figure f = measure_packed(*gl, packed, codec, call, runs);
        std::printf(
            "  gl  packed, %7zu-vertex calls:  %7.2f M points/s wall, %7.2f M points/CPU-s (%.1f ns/vertex CPU)\n",
            call, f.wall / 1e6, f.cpu / 1e6, 1e9 / f.cpu);
      }
      if (!gl_batches.empty()) {
        // One reprojector per batch size; the runs alternate between them so that load drifts hit all alike.
        std::vector<std::unique_ptr<Reprojector>> rs;
        for (size_t batch : gl_batches) {
          ReprojectorSettings s = settings;
          s.batch_points = batch;
          rs.push_back(make_reprojector("gl", cam, dfb, s, ctx.get()));
        }
        std::vector<std::vector<double>> wall(gl_batches.size());
        for (int run = 0; run < runs; ++run)
          for (size_t k = 0; k < rs.size(); ++k)
            wall[k].push_back(measure_packed(*rs[k], packed, codec, size_t(1) << 20, 1).wall);
        for (size_t k = 0; k < rs.size(); ++k) {
          std::sort(wall[k].begin(), wall[k].end());
          std::printf("  gl  packed, batch %8zu: %7.2f M points/s wall (median of %d, %.2fx the first)\n",
                      gl_batches[k], wall[k][wall[k].size() / 2] / 1e6, runs,
                      wall[k][wall[k].size() / 2] / wall[0][wall[0].size() / 2]);
        }
      }
      if (sweep) {
        for (int wg : {8, 16, 32, 64, 128})
          for (int groups : {4, 16, 64})
            for (bool pf : {true, false}) {
              ReprojectorSettings s = settings;
              s.workgroup_size = wg;
              s.workgroups = groups;
              s.prefetch = pf;
              auto r = make_reprojector("gl", cam, dfb, s, ctx.get());
              const Figure f = measure(*r, pts, std::max(1, runs / 2));
              std::printf("    sweep wg %3d x %3d prefetch %-3s: %7.2f M/s wall, %7.2f M/CPU-s\n", groups, wg,
                          pf ? "on" : "off", f.wall / 1e6, f.cpu / 1e6);
            }
        for (size_t batch : {size_t(1) << 16, size_t(1) << 20}) {
          ReprojectorSettings s = settings;
          s.batch_points = batch;
          auto r = make_reprojector("gl", cam, dfb, s, ctx.get());
          const Figure f = measure(*r, pts, std::max(1, runs / 2));
          std::printf("    sweep batch %zu: %7.2f M/s wall, %7.2f M/CPU-s\n", batch, f.wall / 1e6, f.cpu / 1e6);
        }
      }
    }
    if (gl_only) continue;
    for (int threads : cpu_threads) {
      tbb::global_control limit(tbb::global_control::max_allowed_parallelism, size_t(std::max(1, threads)));
      auto cpu = make_reprojector("cpu", cam, dfb, settings);
      const Figure f = measure(*cpu, pts, runs);
      std::printf("  cpu (%d TBB thread%s):            %7.2f M points/s wall, %7.2f M points/CPU-s", threads,
                  threads == 1 ? " " : "s", f.wall / 1e6, f.cpu / 1e6);
      if (ctx && !cpu_only) std::printf("   GL/CPU = %.2f", gl_fig.wall / f.wall);
      std::printf("\n");
      if (!ctx || cpu_only) print_counts(f.counts, pts.size());
      for (size_t call : {size_t(1) << 20, tile_call}) {
        const Figure fp = measure_packed(*cpu, packed, codec, call, runs);
        std::printf(
            "  cpu packed, %7zu-vertex calls:  %7.2f M points/s wall, %7.2f M points/CPU-s (%.1f ns/vertex CPU)\n",
            call, fp.wall / 1e6, fp.cpu / 1e6, 1e9 / fp.cpu);
      }
    }
  }
  return 0;
}
