// The failure-mode study (docs/FAILURE_MODES.md): where eye path reprojection does not pay, and
// whether it stays stable there. One sweep per case, each setting rendered with reprojection and no
// skipping (mode rp, so it traces exactly the paths plain path tracing traces at the same P) and
// compared with:
//   - a converged path-traced reference (bench_reference.h: two cached halves, rMSE minus the
//     reference's own noise floor), or the analytic radiance where one exists (furnace);
//   - plain path tracing with the same options (same P, seed, roulette): "pt rMSE" at equal paths.
//
// Cases (scene: settings):
//   glossy    builtin:glossy: glossy vertices culled (default) / forced into the reprojection
//   epsilon   builtin:cornell: plane-test epsilon 0 / default (3e-4 of the diagonal) / 10x / 100x, and
//             100x with the plane test alone (no joint test: the paper's transparency)
//   subpixels builtin:cornell: S = 1 / 2 / 4
//   wall      builtin:wall: almost every vertex culled
//   thinwall  builtin:thinwall: zero-thickness partition, light on the far side; the same without
//             the joint test (the leak at the joints it stops) and with the back-facing test defeated (records' normals
//             turned towards the camera, i.e. the paper's behaviour) to show what the test protects
//   rr        builtin:cornell and an analytic furnace: Russian roulette paper / off (fixed depth 8)
//   hidden    builtin:hiddenlight: the only emitter is hidden from the camera
//   grazing   builtin:grazing: floor seen at grazing angles, silhouettes; S = 1, epsilon 100x
// Exact mode (visibility rays, no discretisation) is rendered beside the deep-framebuffer settings
// where it separates discretisation error from the method's own.
//
// Columns: rMSE over the whole image, over the case's telling region (the crop) and over the edge
// pixels (five camera rays per pixel disagree on material or depth); bias over the whole image;
// rMSE x 1e3 with the reference floor subtracted, mean without the largest --trim of pixels
// (fireflies); bias = (mean(x) - mean(ref)) / mean(ref) (at P = 16 plain path tracing's own "bias"
// is a few % low: the NEE fireflies that make the mean are rare, so they are under-represented in
// one image) and rp-pt = (mean(rp) - mean(pt)) / mean(pt), the shift reprojection adds to the same
// traced paths, which cancels most of that noise; nonfinite = NaN or infinite values in the
// combined, path-traced and reprojection images (the worker drops non-finite path samples and counts
// them: "dropped"); culled / accepted = % of the recorded vertices x_n, n >= 2; dark = the largest
// radiance on pixels that are exactly black in the reference (light leak), over how many pixels.
// Outputs: a table on stdout, --csv, and one PNG strip per case under --out: reference | pt | each
// setting, cropped to the telling region and enlarged 3x (same exposure across a strip: the mean lit
// pixel of the reference at 0.3); for the thin wall also at 20x that exposure (NAME_boost.png).
//
//   failure_study [--size 128] [--spp 16] [--ref-spp 512] [--case NAME ...] [--out DIR] [--csv FILE]
//                 [--cache DIR] [--threads 2] [--full DIR]
#include <fmt/format.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <string>
#include <thread>
#include <vector>

#include "bench_reference.h"
#include "client/local_render.h"
#include "common/image.h"
#include "common/log.h"
#include "common/scene_loader.h"
#include "master/frame_state.h"
#include "tests/study/unfiltered_render.h"
#include "worker/embree_scene.h"
#include "worker/tile_renderer.h"

using namespace epr;
using namespace epr::bench;
namespace fs = std::filesystem;

namespace {

struct Region {
  float x0, y0, x1, y1;  // fractions of the image, y down
};

struct Setting {
  std::string name;
  RenderOptions opts;
  bool facing_defeated = false;  // reproject every vertex with its normal turned towards the camera
};

struct Case {
  std::string name;
  std::string scene;
  Region crop;
  float analytic = -1;  // > 0: the reference is this radiance everywhere
  std::vector<Setting> settings;
  float boost = 0;  // > 0: also write NAME_boost.png, the strip at this many times the exposure
};

struct Metrics {
  ErrorMeans err, region_err, edge_err;
  double bias = 0, region_bias = 0;
  double mean = 0;  // mean radiance of the combined image
  uint64_t nonfinite = 0, dropped = 0;
  double culled = 0, accepted = 0;
  double dark_max = 0;
  size_t dark_pixels = 0;
  double wall = 0, cpu = 0;
};

struct Row {
  std::string case_name, setting;
  Metrics rp, pt;
};

Image crop(const Image& img, const Region& r, int scale) {
  const int x0 = int(r.x0 * float(img.width)), x1 = int(r.x1 * float(img.width));
  const int y0 = int(r.y0 * float(img.height)), y1 = int(r.y1 * float(img.height));
  Image out((x1 - x0) * scale, (y1 - y0) * scale, 3);
  for (int y = 0; y < out.height; ++y)
    for (int x = 0; x < out.width; ++x) out.set_rgb(x, y, img.rgb(x0 + x / scale, y0 + y / scale));
  return out;
}

Image only_region(const Image& img, const Region& r) { return crop(img, r, 1); }

double mean(const Image& img) {
  double s = 0;
  for (int y = 0; y < img.height; ++y)
    for (int x = 0; x < img.width; ++x) {
      const Vec3 c = img.rgb(x, y);
      s += (double(c.x) + c.y + c.z) / 3;
    }
  return s / std::max(1.0, double(img.width) * img.height);
}

uint64_t nonfinite(const Image& img) {
  uint64_t n = 0;
  for (float v : img.data) n += !std::isfinite(v);
  return n;
}

// Pixels exactly black in the reference whose 8 neighbours are black too (away from the edges of
// lit regions, where a pixel's footprint may legitimately catch some light).
std::vector<uint8_t> dark_mask(const Image& ref) {
  std::vector<uint8_t> m(size_t(ref.width) * size_t(ref.height), 0);
  auto black = [&](int x, int y) {
    if (x < 0 || y < 0 || x >= ref.width || y >= ref.height) return true;
    const Vec3 c = ref.rgb(x, y);
    return c.x == 0 && c.y == 0 && c.z == 0;
  };
  for (int y = 0; y < ref.height; ++y)
    for (int x = 0; x < ref.width; ++x) {
      bool all = true;
      for (int dy = -1; dy <= 1 && all; ++dy)
        for (int dx = -1; dx <= 1 && all; ++dx) all = black(x + dx, y + dy);
      m[size_t(y) * size_t(ref.width) + size_t(x)] = all;
    }
  return m;
}

// Edge pixels: five camera rays per pixel (centre and corners inset by 0.02 px) hit different
// materials or depths more than 5 % apart -- where discretisation and aliasing show.
std::vector<uint8_t> edge_mask(const RenderOptions& o) {
  const Scene scene = load_scene(o.scene);
  const Camera camera(o.camera_for(scene.camera), o.width, o.height);
  const EmbreeScene embree(scene);
  std::vector<uint8_t> m(size_t(o.width) * size_t(o.height), 0);
  constexpr float kIn = 0.02f;
  const float offsets[5][2] = {{0.5f, 0.5f}, {kIn, kIn}, {1 - kIn, kIn}, {kIn, 1 - kIn}, {1 - kIn, 1 - kIn}};
  for (int y = 0; y < o.height; ++y)
    for (int x = 0; x < o.width; ++x) {
      bool hit0 = false, edge = false;
      float t0 = 0;
      uint32_t mat0 = 0;
      for (int k = 0; k < 5 && !edge; ++k) {
        Hit h;
        const bool hit = embree.intersect(camera.generate_ray(float(x) + offsets[k][0], float(y) + offsets[k][1]), 0.f,
                                          std::numeric_limits<float>::infinity(), &h);
        const uint32_t mat = hit ? scene.material_of[h.prim] : 0;
        if (k == 0) {
          hit0 = hit, t0 = h.t, mat0 = mat;
          continue;
        }
        edge = hit != hit0 || (hit && (mat != mat0 || std::abs(h.t - t0) > 0.05f * t0));
      }
      m[size_t(y) * size_t(o.width) + size_t(x)] = edge;
    }
  return m;
}

std::vector<uint8_t> region_mask(const Region& r, int w, int h) {
  std::vector<uint8_t> m(size_t(w) * size_t(h), 0);
  for (int y = int(r.y0 * float(h)); y < int(r.y1 * float(h)); ++y)
    for (int x = int(r.x0 * float(w)); x < int(r.x1 * float(w)); ++x) m[size_t(y) * size_t(w) + size_t(x)] = 1;
  return m;
}

std::vector<double> select(const std::vector<double>& e, const std::vector<uint8_t>& mask) {
  std::vector<double> out;
  for (size_t i = 0; i < e.size(); ++i)
    if (mask[i]) out.push_back(e[i]);
  return out;
}

// means() over a selection; zero when the selection is empty (a scene without edges).
ErrorMeans masked_means(const std::vector<double>& e, const std::vector<uint8_t>& mask) {
  const std::vector<double> sel = select(e, mask);
  return sel.empty() ? ErrorMeans{} : means(sel);
}

struct Masks {
  std::vector<uint8_t> region, edges, dark;
  ErrorMeans floor, region_floor, edge_floor;  // the reference's own noise over each
};

Metrics measure(const Run& r, const Image& ref, const Masks& k, const Region& region) {
  Metrics m;
  const Image& x = r.out.combined;
  const std::vector<double> e = rel_sq_errors(x, ref);
  m.err = means(e) - k.floor;
  m.region_err = masked_means(e, k.region) - k.region_floor;
  m.edge_err = masked_means(e, k.edges) - k.edge_floor;
  const double mr = mean(ref), mrr = mean(only_region(ref, region));
  m.mean = mean(x);
  m.bias = mr > 0 ? (m.mean - mr) / mr : 0;
  m.region_bias = mrr > 0 ? (mean(only_region(x, region)) - mrr) / mrr : 0;
  m.nonfinite = nonfinite(r.out.combined) + nonfinite(r.out.pathtrace) + nonfinite(r.out.reprojection);
  const auto& s = r.out.stats;
  m.dropped = uint64_t(num(s, "nonfinite_dropped"));
  const double recorded = num(s, "vertices_recorded");
  if (recorded > 0) {
    m.culled = 100 *
               (num(s, "culled_master") + num(s, "culled_frustum_worker") + num(s, "culled_facing_worker") +
                num(s, "culled_glossy_worker")) /
               recorded;
    m.accepted = 100 * (num(s, "accepted") + num(s, "exact_samples")) / recorded;
  }
  for (size_t p = 0; p < k.dark.size(); ++p) {
    if (!k.dark[p]) continue;
    ++m.dark_pixels;
    for (int c = 0; c < 3; ++c) m.dark_max = std::max(m.dark_max, double(x.data[p * size_t(x.channels) + size_t(c)]));
  }
  m.wall = r.wall;
  m.cpu = r.cpu;
  return m;
}

// Reprojection with the back-facing test defeated: every vertex x_n, n >= 2, unfiltered by the
// worker, reaches the CPU reprojector with its normal turned towards the camera, as if the
// reprojector ignored the side a point was lit from (the paper's behaviour). Otherwise the same
// rounds as render_local (no wire quantisation: it does not change which side a normal is on).
Run render_facing_defeated(const RenderOptions& o) {
  Run run;
  const double c0 = cpu_seconds();
  const auto t0 = std::chrono::steady_clock::now();
  const UnfilteredRender r = render_unfiltered(o, /*defeat_facing=*/true, /*reproject_glossy=*/true);
  run.out.combined = r.images.combined;
  run.out.pathtrace = r.images.pathtrace;
  run.out.reprojection = r.images.reprojection;
  run.out.stats = r.stats;
  run.out.stats["vertices_recorded"] = r.counts.total();
  run.wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  run.cpu = cpu_seconds() - c0;
  return run;
}

// a / b, or 0 where b is (nearly) 0 (regions that are black in the reference, scenes without edges).
double ratio(double a, double b) { return b > 1e-9 ? a / b : 0.0; }

std::string rr_key(const RussianRoulette& rr) {
  return fmt::format("{}/{}/{}", int(rr.mode), rr.start_depth, rr.max_depth);
}

std::vector<Case> make_cases(const RenderOptions& base) {
  auto with = [&](const std::string& scene, auto&& edit) {
    RenderOptions o = base;
    o.scene = scene;
    o.mode = RenderMode::kReproject;
    edit(o);
    return o;
  };
  auto exact = [](RenderOptions& o) { o.reproject = ReprojectMethod::kExact; };
  auto same = [](RenderOptions&) {};
  std::vector<Case> cases;

  const std::string cornell = "builtin:cornell", glossy = "builtin:glossy";
  cases.push_back({"glossy",
                   glossy,
                   {0.2f, 0.25f, 0.55f, 0.8f},
                   -1,
                   {
                       {"default (glossy culled)", with(glossy, same)},
                       {"glossy forced", with(glossy, [](RenderOptions& o) { o.reproject_glossy = true; })},
                       {"exact, glossy forced", with(glossy,
                                                     [&](RenderOptions& o) {
                                                       exact(o);
                                                       o.reproject_glossy = true;
                                                     })},
                   }});
  Case eps{"epsilon", cornell, {0.45f, 0.55f, 0.8f, 0.9f}, -1, {}};
  for (float f : {0.f, 1.f, 10.f, 100.f})
    eps.settings.push_back({f == 1 ? "3e-4 (default)" : fmt::format("{:g} x default", f),
                            with(cornell, [&](RenderOptions& o) { o.epsilon = 3e-4f * f; })});
  eps.settings.push_back({"100 x, no joint test", with(cornell, [](RenderOptions& o) {
                            o.epsilon = 3e-2f;
                            o.joint_test = false;
                          })});
  eps.settings.push_back({"exact", with(cornell, exact)});
  cases.push_back(eps);
  Case sub{"subpixels", cornell, {0.2f, 0.25f, 0.55f, 0.6f}, -1, {}};
  for (int s : {1, 2, 4})
    sub.settings.push_back({fmt::format("S={}", s), with(cornell, [&](RenderOptions& o) { o.subpixels = s; })});
  sub.settings.push_back({"exact", with(cornell, exact)});
  cases.push_back(sub);
  cases.push_back({"wall",
                   "builtin:wall",
                   {0.3f, 0.3f, 0.7f, 0.7f},
                   -1,
                   {
                       {"default", with("builtin:wall", same)},
                       {"exact", with("builtin:wall", exact)},
                   }});
  Case thin{"thinwall",
            "builtin:thinwall",
            {0.4f, 0.1f, 0.95f, 0.9f},
            -1,
            {
                {"default", with("builtin:thinwall", same)},
                {"no joint test", with("builtin:thinwall", [](RenderOptions& o) { o.joint_test = false; })},
                {"exact", with("builtin:thinwall", exact)},
            }};
  thin.settings.push_back({"facing test defeated", with("builtin:thinwall", same), true});
  thin.boost = 20;
  cases.push_back(thin);
  cases.push_back({"rr",
                   cornell,
                   {0.3f, 0.5f, 0.8f, 0.95f},
                   -1,
                   {
                       {"paper", with(cornell, same)},
                       {"off (depth 8)", with(cornell, [](RenderOptions& o) { o.rr = RussianRoulette::off(8); })},
                       {"off (depth 3)", with(cornell, [](RenderOptions& o) { o.rr = RussianRoulette::off(3); })},
                   }});
  const std::string furnace = "builtin:furnace?albedo=0.8";
  cases.push_back({"rr-furnace",
                   furnace,
                   {0.3f, 0.3f, 0.7f, 0.7f},
                   5.f,
                   {
                       {"paper", with(furnace, same)},
                       {"off (depth 8)", with(furnace, [](RenderOptions& o) { o.rr = RussianRoulette::off(8); })},
                   }});
  cases.push_back({"hidden",
                   "builtin:hiddenlight",
                   {0.2f, 0.35f, 0.8f, 0.85f},
                   -1,
                   {
                       {"default", with("builtin:hiddenlight", same)},
                       {"exact", with("builtin:hiddenlight", exact)},
                   }});
  cases.push_back({"grazing",
                   "builtin:grazing",
                   {0.25f, 0.4f, 0.75f, 0.65f},
                   -1,
                   {
                       {"default", with("builtin:grazing", same)},
                       {"S=1", with("builtin:grazing", [](RenderOptions& o) { o.subpixels = 1; })},
                       {"100 x epsilon", with("builtin:grazing", [](RenderOptions& o) { o.epsilon = 3e-2f; })},
                       {"exact", with("builtin:grazing", exact)},
                   }});
  return cases;
}

void write_strip(const fs::path& file, const std::vector<const Image*>& images, const Region& r, float exposure) {
  constexpr int kScale = 3, kGap = 2;
  std::vector<Image> crops;
  int w = 0, h = 0;
  for (const Image* img : images) {
    crops.push_back(crop(*img, r, kScale));
    w += crops.back().width + kGap;
    h = std::max(h, crops.back().height);
  }
  Image strip(std::max(1, w - kGap), h, 3);
  std::fill(strip.data.begin(), strip.data.end(), 1.f);  // white gaps
  int x0 = 0;
  for (const Image& c : crops) {
    for (int y = 0; y < c.height; ++y)
      for (int x = 0; x < c.width; ++x) {
        Vec3 v = c.rgb(x, y) * exposure;
        if (!std::isfinite(v.x + v.y + v.z)) v = Vec3(1.f, 0.f, 1.f);  // non-finite: magenta
        strip.set_rgb(x0 + x, y, v);
      }
    x0 += c.width + kGap;
  }
  write_png_srgb(file.string(), strip);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Failure-mode study: stability and error of reprojection where it does not pay"};
  int size = 128, spp = 16, ref_spp = 512, threads = 2;
  std::vector<std::string> only;
  std::string out_dir = std::string(EPR_SOURCE_DIR) + "/docs/results/failure";
  std::string csv_file, full_dir;
  std::string cache = default_cache_dir();
  add_common_options(app, &size, &ref_spp, &cache, &threads, &g_trim);
  app.add_option("--spp", spp, "P: paths per pixel for every render (rp and pt alike)");
  app.add_option("--case", only, "run only these cases");
  app.add_option("--out", out_dir, "folder for the PNG strips ('' for none)");
  app.add_option("--csv", csv_file, "CSV file (default OUT/failure_study.csv)");
  app.add_option("--full", full_dir, "also write every full image as PNG to this folder");
  CLI11_PARSE(app, argc, argv);
  set_log_level("warn");
  if (csv_file.empty() && !out_dir.empty()) csv_file = out_dir + "/failure_study.csv";
  if (!out_dir.empty()) fs::create_directories(out_dir);
  if (!full_dir.empty()) fs::create_directories(full_dir);

  const auto w_start = std::chrono::steady_clock::now();
  const double c_start = cpu_seconds();
  std::printf(
      "failure_study: %dx%d, P=%d (rp without skipping and pt alike), reference pt %d spp (2 halves), "
      "%d threads of %u, load average %.2f\n",
      size, size, spp, ref_spp, threads, std::thread::hardware_concurrency(), load1());
  std::fflush(stdout);

  RenderOptions base;
  base.width = base.height = size;
  base.spp = spp;
  base.paths_per_round = 1;
  base.seed = 1;
  base.threads = threads;
  base.edge_pixels = false;  // the study measures the deep framebuffer's discretisation at edges

  std::vector<Row> rows;
  for (const Case& c : make_cases(base)) {
    if (!only.empty() && std::find(only.begin(), only.end(), c.name) == only.end()) continue;
    std::printf("\n== %s (%s), load %.2f\n", c.name.c_str(), c.scene.c_str(), load1());
    std::fflush(stdout);
    RenderOptions rbase = base;
    rbase.scene = c.scene;
    Image ref;
    Masks masks;
    masks.region = region_mask(c.crop, size, size);
    masks.edges = edge_mask(rbase);
    if (c.analytic > 0) {
      ref = Image(size, size, 3);
      std::fill(ref.data.begin(), ref.data.end(), c.analytic);
    } else {
      const int half = std::max(1, ref_spp / 2);
      double ref_cpu = 0;
      const Image a = cached_half(rbase, half, 1000001, cache, &ref_cpu);
      const Reference r = reference(rbase, ref_spp, cache);
      ref = r.image;
      const std::vector<double> ea = rel_sq_errors(a, ref);
      masks.floor = r.floor;
      masks.region_floor = masked_means(ea, masks.region);
      masks.edge_floor = masked_means(ea, masks.edges);
    }
    masks.dark = dark_mask(ref);
    if (!full_dir.empty()) {
      write_png_srgb((fs::path(full_dir) / (c.name + "_ref.png")).string(), ref);
      write_exr((fs::path(full_dir) / (c.name + "_ref.exr")).string(), ref);
    }

    std::map<std::string, std::pair<Run, Metrics>> pt_runs;  // by roulette
    std::vector<Run> runs;
    for (const Setting& s : c.settings) {
      RenderOptions pto = s.opts;
      pto.mode = RenderMode::kPathTrace;
      const std::string key = rr_key(pto.rr);
      if (!pt_runs.count(key)) {
        Run pr = run_local(pto);
        Metrics pm = measure(pr, ref, masks, c.crop);
        pt_runs.emplace(key, std::make_pair(std::move(pr), pm));
      }
      Run r = s.facing_defeated ? render_facing_defeated(s.opts) : run_local(s.opts);
      Row row{c.name, s.name, measure(r, ref, masks, c.crop), pt_runs.at(key).second};
      std::printf(
          "  %-26s rMSE %8.3f (pt %8.3f)  region %8.3f (pt %8.3f)  edges %8.3f (pt %8.3f)  bias %+7.2f%% (pt "
          "%+7.2f%%)  culled %5.1f%%  nonfinite %llu  dark max %.3g  %5.1f s\n",
          s.name.c_str(), 1e3 * row.rp.err.trimmed, 1e3 * row.pt.err.trimmed, 1e3 * row.rp.region_err.trimmed,
          1e3 * row.pt.region_err.trimmed, 1e3 * row.rp.edge_err.trimmed, 1e3 * row.pt.edge_err.trimmed,
          100 * row.rp.bias, 100 * row.pt.bias, row.rp.culled, (unsigned long long)row.rp.nonfinite, row.rp.dark_max,
          row.rp.wall);
      std::fflush(stdout);
      if (!full_dir.empty()) {
        std::string f = c.name + "_" + s.name;
        for (char& ch : f)
          if (!std::isalnum(static_cast<unsigned char>(ch))) ch = '_';
        write_png_srgb((fs::path(full_dir) / (f + ".png")).string(), r.out.combined);
        write_exr((fs::path(full_dir) / (f + ".exr")).string(), r.out.combined);
      }
      rows.push_back(row);
      runs.push_back(std::move(r));
    }
    if (!out_dir.empty()) {
      std::vector<const Image*> strip = {&ref, &pt_runs.at(rr_key(c.settings.front().opts.rr)).first.out.combined};
      for (const Run& r : runs) strip.push_back(&r.out.combined);
      // Mid-grey for the mean lit pixel of the reference (black pixels left out: the dark room).
      double lit_sum = 0;
      size_t lit = 0;
      for (int y = 0; y < ref.height; ++y)
        for (int x = 0; x < ref.width; ++x) {
          const Vec3 v = ref.rgb(x, y);
          if (v.x + v.y + v.z > 0) lit_sum += (double(v.x) + v.y + v.z) / 3, ++lit;
        }
      const float exposure = float(0.3 / std::max(1e-6, lit ? lit_sum / double(lit) : 1.0));
      write_strip(fs::path(out_dir) / (c.name + ".png"), strip, c.crop, exposure);
      if (c.boost > 0) write_strip(fs::path(out_dir) / (c.name + "_boost.png"), strip, c.crop, exposure * c.boost);
    }
  }

  std::printf(
      "\n==== rMSE x 1e3 against the reference (floor subtracted, largest %.1f%% of pixels left out); rp and "
      "pt trace the same %d paths per pixel\n",
      100 * g_trim, spp);
  std::printf("%-11s %-26s | %8s %8s %6s | %8s %8s %6s | %8s %8s %6s | %7s %7s %7s %7s | %6s %6s | %9s %6s | %6s %6s\n",
              "case", "setting", "rMSE", "pt", "rp/pt", "region", "pt", "rp/pt", "edges", "pt", "rp/pt", "bias%", "pt",
              "rp-pt%", "reg b%", "culled", "accept", "dark max", "px", "nonfin", "s");
  for (const Row& r : rows)
    std::printf(
        "%-11s %-26s | %8.3f %8.3f %6.2f | %8.3f %8.3f %6.2f | %8.3f %8.3f %6.2f | %+7.2f %+7.2f %+7.2f %+7.2f | %6.1f "
        "%6.1f | "
        "%9.3g %6zu | %6llu %6.1f\n",
        r.case_name.c_str(), r.setting.c_str(), 1e3 * r.rp.err.trimmed, 1e3 * r.pt.err.trimmed,
        ratio(r.rp.err.trimmed, r.pt.err.trimmed), 1e3 * r.rp.region_err.trimmed, 1e3 * r.pt.region_err.trimmed,
        ratio(r.rp.region_err.trimmed, r.pt.region_err.trimmed), 1e3 * r.rp.edge_err.trimmed,
        1e3 * r.pt.edge_err.trimmed, ratio(r.rp.edge_err.trimmed, r.pt.edge_err.trimmed), 100 * r.rp.bias,
        100 * r.pt.bias, 100 * (r.rp.mean - r.pt.mean) / std::max(1e-12, r.pt.mean), 100 * r.rp.region_bias,
        r.rp.culled, r.rp.accepted, r.rp.dark_max, r.rp.dark_pixels,
        (unsigned long long)(r.rp.nonfinite + r.pt.nonfinite), r.rp.wall);

  if (!csv_file.empty()) {
    std::ofstream csv(csv_file);
    csv << "case,setting,rmse_1e3,rmse_full_1e3,pt_rmse_1e3,pt_rmse_full_1e3,region_rmse_1e3,pt_region_rmse_1e3,edge_"
           "rmse_1e3,pt_edge_rmse_1e3,"
           "bias_percent,pt_bias_percent,rp_minus_pt_percent,region_bias_percent,pt_region_bias_percent,nonfinite,pt_"
           "nonfinite,"
           "dropped,culled_percent,accepted_percent,dark_max,dark_pixels,seconds,cpu_seconds,pt_seconds\n";
    for (const Row& r : rows)
      csv << fmt::format(
          "{},\"{}\",{:.4f},{:.4f},{:.4f},{:.4f},{:.4f},{:.4f},{:.4f},{:.4f},{:.3f},{:.3f},{:.3f},{:.3f},{:.3f},{},{},{"
          "},{:.2f},"
          "{:.2f},{:.4g},{},{:.2f},{:.2f},{:.2f}\n",
          r.case_name, r.setting, 1e3 * r.rp.err.trimmed, 1e3 * r.rp.err.full, 1e3 * r.pt.err.trimmed,
          1e3 * r.pt.err.full, 1e3 * r.rp.region_err.trimmed, 1e3 * r.pt.region_err.trimmed,
          1e3 * r.rp.edge_err.trimmed, 1e3 * r.pt.edge_err.trimmed, 100 * r.rp.bias, 100 * r.pt.bias,
          100 * (r.rp.mean - r.pt.mean) / std::max(1e-12, r.pt.mean), 100 * r.rp.region_bias, 100 * r.pt.region_bias,
          r.rp.nonfinite, r.pt.nonfinite, r.rp.dropped, r.rp.culled, r.rp.accepted, r.rp.dark_max, r.rp.dark_pixels,
          r.rp.wall, r.rp.cpu, r.pt.wall);
    std::printf("\nwrote %s\n", csv_file.c_str());
  }
  std::printf("(total %.0f s wall, %.0f CPU-s; load average at end %.2f)\n",
              std::chrono::duration<double>(std::chrono::steady_clock::now() - w_start).count(),
              cpu_seconds() - c_start, load1());
  return 0;
}
