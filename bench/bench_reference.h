// Shared by the benchmarks that measure error (paper_table, failure_study, speed_accuracy): timing of single-process
// renders, the relative MSE against a converged path-traced reference, and that reference, rendered
// as two independent halves and cached as EXR under bench/cache/ (not committed: bench/.gitignore).
//
// Error metric: relative MSE, averaged over pixels and the three channels,
//     rMSE(x) = mean_{p,c} (x_pc - r_pc)^2 / (r_pc^2 + 0.01)
// (0.01 keeps dark pixels from dominating). The halves a and b (seeds 1000001 and 1000002, spp/2
// each, r = (a + b) / 2) give the reference's own noise: (a - r)^2 = (a - b)^2 / 4 estimates the
// variance of r, so means(rel_sq_errors(a, r)) is the "floor" the reference adds to every rMSE.
// Cache files are keyed by a hash of everything that shapes the image (reference_file), so every
// benchmark shares them.
#pragma once

#include <sys/resource.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <string>
#include <vector>

#include "client/local_render.h"
#include "common/image.h"
#include "common/render_options.h"

#ifndef EPR_SOURCE_DIR
#define EPR_SOURCE_DIR "."
#endif

namespace epr::bench {

namespace fs = std::filesystem;

/// The reference cache folder of the source tree (bench/cache).
inline std::string default_cache_dir() { return std::string(EPR_SOURCE_DIR) + "/bench/cache"; }

/// The options every error-measuring benchmark takes: image size, reference spp and its cache folder,
/// tracing threads and the share of pixels the trimmed rMSE leaves out.
inline void add_common_options(CLI::App& app, int* size, int* ref_spp, std::string* cache, int* threads, double* trim) {
  app.add_option("--size", *size, "image side, pixels");
  app.add_option("--ref-spp", *ref_spp, "reference spp (two halves of ref-spp/2, cached)");
  app.add_option("--cache", *cache, "reference cache folder");
  app.add_option("--threads", *threads, "tracing threads (0: all cores)");
  app.add_option("--trim", *trim, "share of the largest per-pixel errors left out of the trimmed rMSE");
}

constexpr float kRelEps = 0.01f;  // the rMSE denominator's offset (radiance^2)

inline double cpu_seconds() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return double(u.ru_utime.tv_sec + u.ru_stime.tv_sec) + 1e-6 * double(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

inline double load1() {
  double l[3] = {0, 0, 0};
  getloadavg(l, 3);
  return l[0];
}

struct Run {
  RenderOutputs out;
  double wall = 0, cpu = 0;
};

inline Run run_local(const RenderOptions& o) {
  Run r;
  const double c0 = cpu_seconds();
  const auto t0 = std::chrono::steady_clock::now();
  r.out = render_local(o);
  r.wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  r.cpu = cpu_seconds() - c0;
  return r;
}

// Per-pixel error terms (mean over the three channels of (x - r)^2 / (r^2 + eps)).
inline std::vector<double> rel_sq_errors(const Image& x, const Image& ref) {
  if (x.width != ref.width || x.height != ref.height)
    throw std::runtime_error("image is " + std::to_string(x.width) + "x" + std::to_string(x.height) + ", reference " +
                             std::to_string(ref.width) + "x" + std::to_string(ref.height));
  const size_t n = size_t(ref.width) * size_t(ref.height);
  std::vector<double> e(n, 0.0);
  for (size_t p = 0; p < n; ++p)
    for (int c = 0; c < 3; ++c) {
      const double r = ref.data[p * size_t(ref.channels) + size_t(c)];
      const double d = double(x.data[p * size_t(x.channels) + size_t(c)]) - r;
      e[p] += d * d / (r * r + kRelEps) / 3;
    }
  return e;
}

// Mean of the terms, and the mean without the largest g_trim share of pixels (fireflies -- the NEE
// 1/d^2 singularity next to the Cornell box's light -- make the full mean unstable); mse is the plain
// mean of (x - r)^2 where errors() computes it.
inline double g_trim = 0.01;
struct ErrorMeans {
  double full = 0, trimmed = 0, mse = 0;
  ErrorMeans operator-(const ErrorMeans& o) const { return {full - o.full, trimmed - o.trimmed, mse - o.mse}; }
};
inline ErrorMeans means(std::vector<double> e) {
  ErrorMeans m;
  for (double v : e) m.full += v;
  m.full /= double(e.size());
  const size_t keep = e.size() - size_t(double(e.size()) * g_trim);
  std::nth_element(e.begin(), e.begin() + ptrdiff_t(keep), e.end());
  for (size_t i = 0; i < keep; ++i) m.trimmed += e[i];
  m.trimmed /= double(keep);
  return m;
}

/// Full and trimmed relative MSE of x against ref, and the plain MSE.
inline ErrorMeans errors(const Image& x, const Image& ref) {
  ErrorMeans m = means(rel_sq_errors(x, ref));
  const size_t n = size_t(ref.width) * size_t(ref.height);
  for (size_t p = 0; p < n; ++p)
    for (int c = 0; c < 3; ++c) {
      const double d =
          double(x.data[p * size_t(x.channels) + size_t(c)]) - ref.data[p * size_t(ref.channels) + size_t(c)];
      m.mse += d * d / 3;
    }
  m.mse /= double(n);
  return m;
}

struct Reference {
  Image image;       // (a + b) / 2
  ErrorMeans floor;  // of (a - b)^2 / 4: the reference's own contribution to every figure
  double cpu = 0;    // seconds spent rendering it in this run (0 when cached)
};

constexpr const char* kRendererTag = "pt-v3";  // bump when the path tracer's converged image changes

inline uint64_t fnv1a(const std::string& s) {
  uint64_t h = 1469598103934665603ull;
  for (unsigned char c : s) h = (h ^ c) * 1099511628211ull;
  return h;
}

inline std::string scene_name(const std::string& spec) {
  std::string s = spec.substr(spec.find(':') + 1);
  for (char& ch : s)
    if (!std::isalnum(static_cast<unsigned char>(ch))) ch = '_';
  return s;
}

/// The cache file of one reference half: readable parts, then a hash of everything that shapes the
/// image (renderer tag, scene, size, spp, seed, roulette, direct-light estimator).
inline std::string reference_file(const RenderOptions& o, int w, int h, int spp, uint64_t seed) {
  const std::string key = std::string(kRendererTag) + "|" + o.scene + "|" + std::to_string(w) + "x" +
                          std::to_string(h) + "|spp=" + std::to_string(spp) + "|seed=" + std::to_string(seed) +
                          "|rr=" + std::to_string(int(o.rr.mode)) + "," + std::to_string(o.rr.start_depth) + "," +
                          std::to_string(o.rr.termination) + "," + std::to_string(o.rr.max_depth) +
                          (o.mis ? "|mis" : "|nee");
  char hex[17];
  std::snprintf(hex, sizeof hex, "%016llx", static_cast<unsigned long long>(fnv1a(key)));
  return "ref_" + scene_name(o.scene) + "_" + std::to_string(w) + "x" + std::to_string(h) + "_pt" +
         std::to_string(spp) + "_seed" + std::to_string(seed) + "_" + (o.mis ? "mis_" : "nee_") + hex + ".exr";
}

inline Image downsample2(const Image& a) {
  Image out(a.width / 2, a.height / 2, 3);
  for (int y = 0; y < out.height; ++y)
    for (int x = 0; x < out.width; ++x)
      out.set_rgb(
          x, y,
          (a.rgb(2 * x, 2 * y) + a.rgb(2 * x + 1, 2 * y) + a.rgb(2 * x, 2 * y + 1) + a.rgb(2 * x + 1, 2 * y + 1)) *
              0.25f);
  return out;
}

inline void write_atomic(const fs::path& file, const Image& img) {
  fs::create_directories(file.parent_path());
  const fs::path tmp = file.parent_path() / ("." + file.filename().string());
  write_exr(tmp.string(), img);
  fs::rename(tmp, file);
}

// One half of a reference: from the cache, else the 2 x 2 box average of a cached one at twice the
// size (the pixel filter is a one-pixel box: a reference at W x H with 4x the samples), else rendered.
inline Image cached_half(const RenderOptions& base, int spp, uint64_t seed, const fs::path& cache, double* cpu) {
  const fs::path file = cache / reference_file(base, base.width, base.height, spp, seed);
  if (fs::exists(file)) return read_image(file.string());
  const fs::path twice = cache / reference_file(base, 2 * base.width, 2 * base.height, spp, seed);
  if (fs::exists(twice)) {
    std::printf("  reference %s: 2x2 box average of %s\n", file.filename().c_str(), twice.filename().c_str());
    const Image img = downsample2(read_image(twice.string()));
    write_atomic(file, img);
    return img;
  }
  RenderOptions o = base;
  o.mode = RenderMode::kPathTrace;
  o.spp = spp;
  o.seed = seed;
  o.paths_per_round = std::min(spp, 16);  // fewer round barriers; the sample indices are the same
  std::printf("  rendering reference %s (pt, %d spp) ...\n", file.filename().c_str(), spp);
  std::fflush(stdout);
  const Run r = run_local(o);
  *cpu += r.cpu;
  std::printf("  ... %.1f s wall, %.1f CPU-s\n", r.wall, r.cpu);
  write_atomic(file, r.out.combined);
  return r.out.combined;
}

inline Reference reference(const RenderOptions& base, int spp, const fs::path& cache) {
  Reference ref;
  const int half = std::max(1, spp / 2);
  const Image a = cached_half(base, half, 1000001, cache, &ref.cpu);
  const Image b = cached_half(base, half, 1000002, cache, &ref.cpu);
  ref.image = Image(a.width, a.height, 3);
  for (int y = 0; y < a.height; ++y)
    for (int x = 0; x < a.width; ++x) ref.image.set_rgb(x, y, (a.rgb(x, y) + b.rgb(x, y)) * 0.5f);
  ref.floor = errors(a, ref.image);  // (a - r)^2 = (a - b)^2 / 4: the per-pixel variance estimate of r
  return ref;
}

inline double num(const nlohmann::json& j, const char* key) { return j.contains(key) ? j[key].get<double>() : 0.0; }

}  // namespace epr::bench
