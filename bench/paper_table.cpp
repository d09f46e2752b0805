// The paper's table (Henrich et al. 2011, table 1) for the built-in scenes, measured with the
// single-process render (client/local_render.h), plus the embedded (gRPC) render of one scene to show
// the distributed overhead.
//
// Per scene, at --size x --size pixels, S = --subpixels:
//   rp   (reprojection, no skipping, P = --rp-spp, GL and CPU reprojector): where the vertices x_n,
//        n >= 2, went: accepted / occluded / culled, as a share of every vertex recorded. Culled
//        counts the worker's culling (frustum, facing away, glossy; those vertices never reach the
//        master) plus the master's frustum test; occluded includes the master's back-facing test.
//        Reprojection overhead = seconds_reprojecting / seconds_tracing (master time in the
//        reprojector, deep framebuffer build and downsampling included, against the wall time of
//        the tracing phase of the rounds).
//   skip (pixel skipping, P = --spp): share of eye paths traced = paths_traced / (P x pixels).
//   pt   (plain path tracing, P = --spp), and pt at the spp that costs the same CPU time as skip.
//   Error of each against a converged path-traced reference (see below).
//
// Error metric: relative MSE, averaged over pixels and the three channels,
//     rMSE(x) = mean_{p,c} (x_pc - r_pc)^2 / (r_pc^2 + 0.01)
// (0.01 keeps dark pixels from dominating; typical lit pixels here are 0.1 - 1). The reference r is
// path tracing at --ref-spp, rendered as two independent halves a and b (different seeds, --ref-spp/2
// each; r = (a + b) / 2) and cached as EXR under --cache keyed by scene, size, spp and seed (not
// committed: bench/.gitignore). The halves give the reference's own noise: E[(a - b)^2] / 4 is the
// variance of r, so "floor" = mean (a - b)^2 / 4 / (r^2 + 0.01) is what the reference adds to every
// rMSE; the table prints rMSE - floor (an estimate of the error against the true image) and the floor,
// for the full mean and for the mean without the largest --trim (1 %) of per-pixel terms (NEE
// fireflies next to the Cornell box's light dominate the full mean). pt is also rendered at P/4 and
// P/2; a log-log fit of its trimmed error gives the spp, hence CPU time, at which pt matches skip.
// Test renders use seed 1; the reference seeds differ, so their noise is independent.
//
// Time: wall seconds and process CPU seconds (getrusage) of each render; CPU seconds are what
// "same time" means for pt-equal-time, because other processes may share the machine. The load
// average is printed before and after.
//
//   paper_table [--size 256] [--spp 64] [--rp-spp 16] [--ref-spp 1024] [--scene builtin:cornell ...]
//               [--cache DIR] [--no-embedded] [--threads 0] [--trim 0.01]
#include <sys/resource.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <thread>
#include <vector>

#include "bench_reference.h"
#include "client/embedded_render.h"
#include "client/local_render.h"
#include "common/image.h"
#include "common/log.h"
#include "common/scene_loader.h"
#include "master/frame_state.h"
#include "master/gl_context.h"

using namespace epr;
using namespace epr::bench;
namespace fs = std::filesystem;

namespace {

// The one-time part of seconds_reprojecting: FrameState's constructor (deep framebuffer build,
// reprojector and its GL programs), measured on its own with the same options.
double setup_seconds(const RenderOptions& o) {
  const Scene scene = load_scene(o.scene);
  const Camera camera(o.camera_for(scene.camera), o.width, o.height);
  std::unique_ptr<GlContext> gl;
  if (o.reproject == ReprojectMethod::kGl) gl = std::make_unique<GlContext>();
  FrameState frame(o, camera, scene, gl.get());
  // One vertex through the reprojector, read back: llvmpipe compiles the shader at its first dispatch.
  const VertexRecord v{scene.bounds().centre(), {0, 0, 1}, {1, 1, 1}, VertexRecord::kDiffuse};
  frame.reproject(std::span(&v, 1));
  (void)frame.counts();
  return frame.seconds_reprojecting();
}

// Vertex fates of an rp render, as fractions of the vertices recorded.
struct Fates {
  double accepted = 0, occluded = 0, culled = 0, culled_worker = 0, not_diffuse = 0;
  double recorded = 0, per_path = 0;
};

Fates fates(const nlohmann::json& s) {
  Fates f;
  const double worker =
      num(s, "culled_frustum_worker") + num(s, "culled_facing_worker") + num(s, "culled_glossy_worker");
  const double recorded = num(s, "vertices_recorded");
  f.recorded = recorded;
  if (recorded <= 0) return f;
  f.accepted = 100 * num(s, "accepted") / recorded;
  f.occluded = 100 * num(s, "occluded") / recorded;
  f.culled = 100 * (num(s, "culled_master") + worker) / recorded;
  f.culled_worker = 100 * worker / recorded;
  f.not_diffuse = 100 * (num(s, "not_diffuse") + num(s, "invalid") + num(s, "codec_rejected")) / recorded;
  f.per_path = recorded / std::max(1.0, num(s, "paths"));
  return f;
}

struct Row {
  std::string scene;
  size_t triangles = 0;
  Fates rp;
  double rp_overhead_gl = 0, rp_overhead_cpu = 0, rp_ns_per_vertex_gl = 0, rp_ns_per_vertex_cpu = 0;
  double rp_setup_gl = 0, rp_setup_cpu = 0;  // one-time share of the overhead, % of tracing
  double skip_share = 0, skip_wall = 0, skip_cpu = 0;
  double pt_wall = 0, pt_cpu = 0;
  int eq_spp = 0;
  double eq_wall = 0, eq_cpu = 0;
  ErrorMeans skip_err, pt_err, eq_err, floor;
  double vertices_per_path = 0, paths_per_cpu_s_pt = 0;
  std::vector<std::pair<int, double>> pt_curve;  // (spp, trimmed rMSE) of plain path tracing
  double fit_slope = 0, fit_spp = 0;             // log-log fit of the curve; spp where pt reaches skip's error
};

// Least-squares line through (log spp, log err); the spp at which it reaches `target`.
void fit_curve(Row& r, double target) {
  double sx = 0, sy = 0, sxx = 0, sxy = 0;
  int n = 0;
  for (const auto& [spp, err] : r.pt_curve) {
    if (!(err > 0)) continue;
    const double x = std::log(double(spp)), y = std::log(err);
    sx += x;
    sy += y;
    sxx += x * x;
    sxy += x * y;
    ++n;
  }
  if (n < 2 || !(target > 0)) return;
  const double b = (n * sxy - sx * sy) / (n * sxx - sx * sx), a = (sy - b * sx) / n;
  r.fit_slope = b;
  r.fit_spp = std::exp((std::log(target) - a) / b);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"The paper's table: vertex fates, reprojection overhead, pixel skipping against path tracing"};
  int size = 256, spp = 64, rp_spp = 16, ref_spp = 1024, threads = 0, subpixels = 4;
  std::vector<std::string> scenes = {"builtin:cornell", "builtin:conference", "builtin:hall"};
  std::string cache = default_cache_dir();
  bool no_embedded = false;
  add_common_options(app, &size, &ref_spp, &cache, &threads, &g_trim);
  app.add_option("--spp", spp, "P for skip and pt");
  app.add_option("--rp-spp", rp_spp, "P for the rp (statistics) renders");
  app.add_option("--scene", scenes, "scene specs");
  app.add_option("-S,--subpixels", subpixels);
  app.add_flag("--no-embedded", no_embedded, "skip the embedded (gRPC) comparison");
  CLI11_PARSE(app, argc, argv);
  set_log_level("warn");

  const double t_start = cpu_seconds();
  const auto w_start = std::chrono::steady_clock::now();
  std::printf(
      "paper_table: %dx%d, S=%d, P=%d (skip, pt), rp stats at P=%d, reference pt %d spp (2 halves), "
      "%u hardware threads, load average %.2f\n",
      size, size, subpixels, spp, rp_spp, ref_spp, std::thread::hardware_concurrency(), load1());
  std::fflush(stdout);

  std::vector<Row> rows;
  for (const std::string& spec : scenes) {
    RenderOptions base;
    base.scene = spec;
    base.width = base.height = size;
    base.subpixels = subpixels;
    base.threads = threads;
    base.seed = 1;
    Row row;
    row.scene = spec.substr(spec.find(':') + 1);
    row.triangles = load_scene(spec).triangle_count();
    std::printf("\n== %s (%zu triangles), load %.2f\n", row.scene.c_str(), row.triangles, load1());
    std::fflush(stdout);
    const Reference ref = reference(base, ref_spp, cache);
    row.floor = ref.floor;

    for (ReprojectMethod m : {ReprojectMethod::kGl, ReprojectMethod::kCpu}) {
      RenderOptions o = base;
      o.mode = RenderMode::kReproject;
      o.reproject = m;
      o.spp = rp_spp;
      const Run r = run_local(o);
      const auto& s = r.out.stats;
      const double tracing = std::max(1e-9, num(s, "seconds_tracing"));
      const double overhead = 100 * num(s, "seconds_reprojecting") / tracing;
      const double setup = setup_seconds(o);
      const double recv = num(s, "accepted") + num(s, "occluded") + num(s, "culled_master") + num(s, "not_diffuse");
      const double ns = 1e9 * std::max(0.0, num(s, "seconds_reprojecting") - setup) / std::max(1.0, recv);
      if (m == ReprojectMethod::kGl) {
        row.rp = fates(s);
        row.rp_overhead_gl = overhead;
        row.rp_ns_per_vertex_gl = ns;
        row.rp_setup_gl = 100 * setup / tracing;
      } else {
        row.rp_setup_cpu = 100 * setup / tracing;
        row.rp_overhead_cpu = overhead;
        row.rp_ns_per_vertex_cpu = ns;
      }
      std::printf(
          "  rp %-3s P=%-3d %6.1f s wall %6.1f CPU-s  tracing %.2f s, reprojecting %.3f s (%.1f%%; "
          "one-time setup %.3f s)\n",
          to_string(m), rp_spp, r.wall, r.cpu, tracing, num(s, "seconds_reprojecting"), overhead, setup);
      std::fflush(stdout);
    }

    RenderOptions sk = base;
    sk.mode = RenderMode::kSkip;
    sk.spp = spp;
    const Run skip = run_local(sk);
    row.skip_share = 100 * num(skip.out.stats, "paths_traced") / (double(spp) * size * size);
    row.skip_wall = skip.wall;
    row.skip_cpu = skip.cpu;
    row.skip_err = errors(skip.out.combined, ref.image) - ref.floor;
    std::printf("  skip P=%-3d %6.1f s wall %6.1f CPU-s  traced %.1f%% of P x pixels\n", spp, skip.wall, skip.cpu,
                row.skip_share);
    std::fflush(stdout);

    RenderOptions pt = base;
    pt.mode = RenderMode::kPathTrace;
    pt.spp = spp;
    const Run ptr = run_local(pt);
    row.pt_wall = ptr.wall;
    row.pt_cpu = ptr.cpu;
    row.pt_err = errors(ptr.out.combined, ref.image) - ref.floor;
    row.vertices_per_path = num(ptr.out.stats, "vertices") / std::max(1.0, num(ptr.out.stats, "paths"));
    row.paths_per_cpu_s_pt = num(ptr.out.stats, "paths") / ptr.cpu;
    std::printf("  pt   P=%-3d %6.1f s wall %6.1f CPU-s\n", spp, ptr.wall, ptr.cpu);
    std::fflush(stdout);

    // Plain path tracing given skip's CPU time (pt's cost is linear in spp).
    row.eq_spp = std::max(1, int(std::lround(double(spp) * skip.cpu / ptr.cpu)));
    pt.spp = row.eq_spp;
    const Run eq = run_local(pt);
    row.eq_wall = eq.wall;
    row.eq_cpu = eq.cpu;
    row.eq_err = errors(eq.out.combined, ref.image) - ref.floor;
    std::printf("  pt   P=%-3d %6.1f s wall %6.1f CPU-s  (same CPU time as skip)\n", row.eq_spp, eq.wall, eq.cpu);
    std::fflush(stdout);
    // pt's error curve: P/4, P/2, the equal-time spp and P, for the spp at which pt matches skip.
    row.pt_curve = {{spp, row.pt_err.trimmed}, {row.eq_spp, row.eq_err.trimmed}};
    for (int q : {spp / 4, spp / 2}) {
      if (q < 1 || q == row.eq_spp || q == spp) continue;
      pt.spp = q;
      const Run c = run_local(pt);
      row.pt_curve.emplace_back(q, (errors(c.out.combined, ref.image) - ref.floor).trimmed);
      std::printf("  pt   P=%-3d %6.1f s wall %6.1f CPU-s  (error curve)\n", q, c.wall, c.cpu);
      std::fflush(stdout);
    }
    fit_curve(row, row.skip_err.trimmed);
    rows.push_back(row);
  }

  std::printf(
      "\n==== Vertex fates (rp, P=%d; %% of vertices x_n, n >= 2, recorded) and reprojection overhead "
      "(%% of tracing wall time)\n",
      rp_spp);
  std::printf("%-12s %9s %8s | %8s %8s %8s %9s %7s | %15s %15s | %8s %8s\n", "scene", "triangles", "vtx/path",
              "accepted", "occluded", "culled", "(worker)", "other", "ovh gl (setup)", "ovh cpu (setup)", "ns/v gl",
              "ns/v cpu");
  for (const Row& r : rows)
    std::printf(
        "%-12s %9zu %8.2f | %7.1f%% %7.1f%% %7.1f%% %8.1f%% %6.2f%% | %6.1f%% (%5.1f%%) %6.1f%% (%5.1f%%) | %8.1f "
        "%8.1f\n",
        r.scene.c_str(), r.triangles, r.rp.per_path, r.rp.accepted, r.rp.occluded, r.rp.culled, r.rp.culled_worker,
        r.rp.not_diffuse, r.rp_overhead_gl, r.rp_setup_gl, r.rp_overhead_cpu, r.rp_setup_cpu, r.rp_ns_per_vertex_gl,
        r.rp_ns_per_vertex_cpu);
  std::printf(
      "(vtx/path: vertices x_n, n >= 2, recorded per path; setup: the one-time deep framebuffer build and "
      "reprojector creation inside the overhead; ns/v: the rest per vertex received)\n");

  std::printf("\n==== Pixel skipping (P=%d) against path tracing: time\n", spp);
  std::printf("%-12s | %7s %8s %8s | %8s %8s | %5s %8s %8s | %11s | %9s %12s\n", "scene", "traced", "skip s", "CPU-s",
              "pt s", "CPU-s", "eq N", "s", "CPU-s", "skip/pt CPU", "pt v/path", "pt paths/CPU-s");
  for (const Row& r : rows)
    std::printf("%-12s | %6.1f%% %8.1f %8.1f | %8.1f %8.1f | %5d %8.1f %8.1f | %11.2f | %9.2f %12.3g\n",
                r.scene.c_str(), r.skip_share, r.skip_wall, r.skip_cpu, r.pt_wall, r.pt_cpu, r.eq_spp, r.eq_wall,
                r.eq_cpu, r.skip_cpu / r.pt_cpu, r.vertices_per_path, r.paths_per_cpu_s_pt);
  std::printf(
      "(pt v/path: surface vertices per path, x_1 included; pt paths/CPU-s: paths per process CPU-second of "
      "the whole pt render)\n");
  std::printf(
      "\n==== Error: rMSE x 1e3 against the reference (its floor subtracted): full mean / without the "
      "largest %.1f%% of pixels\n",
      100 * g_trim);
  std::printf("%-12s | %19s | %19s | %19s | %19s | %7s %7s | %6s %7s %9s\n", "scene", "skip P", "pt P", "pt same CPU",
              "ref floor", "pt/skip", "eq/skip", "slope", "pt N*", "skip/pt*");
  for (const Row& r : rows) {
    const double pt_cpu_star = r.pt_cpu * r.fit_spp / spp;  // pt's CPU time is linear in spp
    std::printf("%-12s | %9.3f %9.3f | %9.3f %9.3f | %9.3f %9.3f | %9.4f %9.4f | %7.2f %7.2f | %6.2f %7.1f %9.2f\n",
                r.scene.c_str(), 1e3 * r.skip_err.full, 1e3 * r.skip_err.trimmed, 1e3 * r.pt_err.full,
                1e3 * r.pt_err.trimmed, 1e3 * r.eq_err.full, 1e3 * r.eq_err.trimmed, 1e3 * r.floor.full,
                1e3 * r.floor.trimmed, r.pt_err.trimmed / std::max(1e-12, r.skip_err.trimmed),
                r.eq_err.trimmed / std::max(1e-12, r.skip_err.trimmed), r.fit_slope, r.fit_spp,
                pt_cpu_star > 0 ? r.skip_cpu / pt_cpu_star : 0.0);
  }
  std::printf(
      "(trimmed errors: pt/skip, eq/skip = pt's error at P and at equal CPU time over skip's; slope: log-log "
      "fit of pt's trimmed error over spp (P/4, P/2, eq N, P; -1 for pure variance); pt N*: the spp at which "
      "the fit reaches skip's error; skip/pt*: skip's CPU time over pt's at N* -- the paper's claim: ~0.5)\n");

  if (!no_embedded && !scenes.empty()) {
    std::printf(
        "\n==== Distributed overhead: %s, local (one process, direct calls) vs embedded (in-process "
        "master + 1 worker node over loopback gRPC), load %.2f\n",
        scenes.front().c_str(), load1());
    std::printf("%-6s %4s | %9s %9s | %9s %9s | %9s %9s | %12s\n", "mode", "P", "local s", "CPU-s", "embed s", "CPU-s",
                "wall x", "CPU x", "max |diff|");
    const fs::path tmp = fs::temp_directory_path() / ("paper_table_" + std::to_string(::getpid()));
    fs::create_directories(tmp);
    for (RenderMode mode : {RenderMode::kPathTrace, RenderMode::kSkip}) {
      RenderOptions o;
      o.scene = scenes.front();
      o.width = o.height = size;
      o.subpixels = subpixels;
      o.threads = threads;
      o.mode = mode;
      o.spp = spp;
      o.out = (tmp / to_string(mode)).string();
      const Run local = run_local(o);
      const double c0 = cpu_seconds();
      const auto t0 = std::chrono::steady_clock::now();
      render_embedded(o, EmbeddedOptions{});
      const double ew = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      const double ec = cpu_seconds() - c0;
      const Image e = read_image(o.out + ".exr");
      double maxdiff = 0;
      for (size_t i = 0; i < local.out.combined.data.size() && i < e.data.size(); ++i)
        maxdiff = std::max(maxdiff, double(std::abs(local.out.combined.data[i] - e.data[i])));
      std::printf("%-6s %4d | %9.2f %9.2f | %9.2f %9.2f | %9.2f %9.2f | %12.3g\n", to_string(mode), spp, local.wall,
                  local.cpu, ew, ec, ew / local.wall, ec / local.cpu, maxdiff);
      std::fflush(stdout);
    }
    fs::remove_all(tmp);
  }

  std::printf("\n(total %.0f s wall, %.0f CPU-s; load average at end %.2f)\n",
              std::chrono::duration<double>(std::chrono::steady_clock::now() - w_start).count(),
              cpu_seconds() - t_start, load1());
  return 0;
}
