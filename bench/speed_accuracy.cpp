// Speed against accuracy: progressive renders of the built-in scenes in every mode, with the error
// against a converged path-traced reference after every round, plus Blender Cycles' renders of the
// same scenes scored against the same reference; everything is also scored against an independent
// Cycles reference when one is given. Driven by scripts/bench.sh (docs/RESULTS.md).
//
// Modes (one single-process render each, client/local_render.h, tracer on --threads threads):
//   pt     plain path tracing                      (RenderMode::kPathTrace)
//   rp     path tracing plus reprojection (GL)     (RenderMode::kReproject, ReprojectMethod::kGl)
//   skip   reprojection plus pixel skipping (GL)   (RenderMode::kSkip, ReprojectMethod::kGl)
//   exact  reprojection with visibility rays       (RenderMode::kReproject, ReprojectMethod::kExact)
// A reprojecting mode may name a variant: "skip:w=0.5:m=32" runs skip with --reprojected-weight 0.5 and
// --min-paths 32 (unnamed values: --reprojected-weight and --min-paths, by default epr's), and is
// called skip_w0.5_m32 in file names and tables; a value at epr's default is left out of the name
// (plain "skip" is skip as `epr render` runs it). Every mode, pt included, may name its Russian
// roulette (common/roulette.h) and the depth it starts at: "pt:rr=albedo", "skip:rr=reuse:rs=3" (pt_albedo,
// skip_reuse_s3; the default roulette is left out of the name).
//
// The baseline is the best plain path tracer: every pt run (plain "pt" is always run, and
// --pt-rr adds "pt:rr=NAME" for each NAME) is a candidate, and at each --target P the one with the
// least error x CPU seconds at P is the one the time-to-error columns compare with ("pt*" in the
// tables and summary.json's "baseline").
//
// Per run, OUT/csv/SCENE_WxH_MODE.csv has one row per round:
//   round, wall_s, cpu_s, eye_paths, reprojected_samples, mean_spp, rel_mse, rel_mse_trim, rmse,
//   rel_mse_raw, rel_mse_trim_raw, rmse_raw, spp, rel_mse_cy, rel_mse_trim_cy, rmse_cy
// wall_s / cpu_s: seconds since the render started (scene load and BVH included) -- wall clock and
// process CPU (getrusage) -- with the time this harness spends reading the images and scoring them
// left out. eye_paths = sum of M, reprojected_samples = sum of M' over the pixels.
//
// Error (same metric as paper_table): relative MSE, mean over pixels and channels of
//   (x - r)^2 / (r^2 + 0.01); rel_mse_trim leaves out the 1 % (--trim) largest per-pixel terms (NEE
// fireflies); rmse = sqrt(mean (x - r)^2). The reference r is path tracing at --ref-spp rendered as two
// independent halves a, b (seeds 1000001, 1000002); (a - b)^2 / 4 estimates r's own variance per pixel
// and its contribution (the "floor") is subtracted from every figure (the *_raw columns keep it).
// References are cached as EXR under --cache, the file name carrying a hash of everything that shapes
// the image (scene, size, spp, seed, roulette, renderer version tag). A missing reference at W x H is
// derived from a cached one at 2W x 2H by 2 x 2 box averaging when one exists (the pixel filter is a
// one-pixel box, so the result is a reference at W x H with 4x the samples); otherwise it is rendered.
//
// --list-references prints the cache file names of the references for the given settings.
// --export-obj DIR writes each scene as DIR/NAME.obj + NAME.mtl (Kd, Ke, emit; glossy lobes are not
// exported) and DIR/NAME.camera (eye, look, up, vertical fov) for scripts/cycles_sweep.py, and exits.
// --cycles DIR scores DIR/SCENE_WxH/times.csv (written by cycles_sweep.py) into OUT/csv/SCENE_WxH_cycles.csv,
// and DIR/SCENE_WxH_adaptive (Cycles' adaptive sampling) into SCENE_WxH_cycles_adaptive.csv. When
// DIR/SCENE_WxH_reference/{a,b}.exr exist (two independent Cycles halves, scripts/bench.sh), every
// round of every run and every Cycles render is scored against (a + b) / 2 too, its floor subtracted
// the same way: the *_cy columns (nan without that reference).
//
// OUT/summary.json and OUT/tables.md: vertex fates and reprojection overhead (rp), share of eye paths
// traced (skip), converged errors, and the CPU time at which each mode (and Cycles) reaches plain path
// tracing's error at P = 64 and P = 256, first and for good, as a ratio to path tracing's CPU time there
// (bench/charts/tables.py writes the same tables from the CSVs for docs/RESULTS.md).
// OUT/strip/: the equal-time images (pt, rp, skip at half of pt's CPU time for P = --strip-p) and skip's M'.
#include <fmt/format.h>
#include <fmt/ranges.h>
#include <sys/resource.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "bench_reference.h"
#include "client/local_render.h"
#include "common/builtin_scenes.h"
#include "common/image.h"
#include "common/log.h"
#include "common/scene_loader.h"
#include "error_curves.h"
#include "master/frame_state.h"

using namespace epr;
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

using bench::at_spp, bench::cpu_seconds, bench::ErrorMeans, bench::errors, bench::load1, bench::metric;
using bench::Reach, bench::Reference, bench::reference, bench::reference_file, bench::Sample, bench::scene_name;
using bench::time_to;

// ---------------------------------------------------------------------------------------------------
// Runs
// ---------------------------------------------------------------------------------------------------

// An error of x against eprfarm's reference and, when there is one, against Cycles'.
void score(Sample& s, const Image& x, const Reference& ref, const Reference* cyref) {
  s.raw = errors(x, ref.image);
  s.err = s.raw - ref.floor;
  if (cyref) s.cy = errors(x, cyref->image) - cyref->floor;
}

struct Snapshot {
  double cpu = 0;
  int round = 0;
  Image combined, mprime;
};

struct Run {
  std::string mode;
  std::vector<Sample> samples;
  json stats;
  double eval_reprojecting = 0;  // seconds_reprojecting spent refreshing L_rp for this harness's reads
  std::vector<Snapshot> snapshots;
};

struct ModeSpec {
  RenderMode mode;
  ReprojectMethod reproject;
  float reprojected_weight = RenderOptions{}.reprojected_weight;
  int min_paths = RenderOptions{}.min_paths;
  CombineRule combine = RenderOptions{}.combine;
  RussianRoulette rr = RenderOptions{}.rr;
  std::string name;  // file names and tables
};

// Every reference is rendered with one roulette, whatever the runs' (all of them unbiased), so that
// changing the default does not re-render the cache.
const RussianRoulette kReferenceRoulette = RussianRoulette::albedo();

// The variant defaults of reprojecting runs (--reprojected-weight, --min-paths).
float g_reprojected_weight = RenderOptions{}.reprojected_weight;
int g_min_paths = RenderOptions{}.min_paths;

// "MODE[:w=W][:m=M][:c=fixed|variance]" (see the top of this file).
ModeSpec mode_spec(const std::string& spec) {
  const size_t colon = spec.find(':');
  const std::string m = spec.substr(0, colon);
  ModeSpec s;
  const auto set = [&](RenderMode mode, ReprojectMethod reproject) {
    s.mode = mode;
    s.reproject = reproject;
  };
  if (m == "pt")
    set(RenderMode::kPathTrace, ReprojectMethod::kGl);
  else if (m == "rp")
    set(RenderMode::kReproject, ReprojectMethod::kGl);
  else if (m == "skip")
    set(RenderMode::kSkip, ReprojectMethod::kGl);
  else if (m == "exact")
    set(RenderMode::kReproject, ReprojectMethod::kExact);
  else
    throw std::invalid_argument("unknown mode '" + m + "' (pt, rp, skip, exact)");
  if (s.mode != RenderMode::kPathTrace) {
    s.reprojected_weight = g_reprojected_weight;
    s.min_paths = g_min_paths;
  }
  std::optional<int> start_depth;  // rs=, applied after rr=
  for (size_t at = colon; at != std::string::npos;) {
    const size_t next = spec.find(':', at + 1);
    const std::string part = spec.substr(at + 1, next == std::string::npos ? std::string::npos : next - at - 1);
    at = next;
    try {
      if (part.rfind("rr=", 0) == 0) {
        const auto rr = roulette_named(part.substr(3));
        if (!rr) throw std::invalid_argument("");
        s.rr = *rr;
        continue;
      }
      if (part.rfind("rs=", 0) == 0) {
        start_depth = std::stoi(part.substr(3));
        continue;
      }
      if (s.mode == RenderMode::kPathTrace) throw std::invalid_argument("");
      if (part.rfind("w=", 0) == 0)
        s.reprojected_weight = std::stof(part.substr(2));
      else if (part.rfind("m=", 0) == 0)
        s.min_paths = std::stoi(part.substr(2));
      else if (part == "c=fixed" || part == "c=variance")
        s.combine = part == "c=variance" ? CombineRule::kVariance : CombineRule::kFixed;
      else
        throw std::invalid_argument("");
    } catch (const std::exception&) {
      throw std::invalid_argument("mode '" + spec + "': '" + part + "' is not rr=ROULETTE (" + roulette_names() +
                                  "), rs=START_DEPTH" +
                                  (s.mode == RenderMode::kPathTrace ? "" : ", w=WEIGHT, m=MIN_PATHS or c=RULE"));
    }
  }
  if (start_depth) s.rr.start_depth = *start_depth;
  s.name = m;
  if (s.rr.mode != RenderOptions{}.rr.mode) s.name += "_" + std::string(roulette_name(s.rr.mode));
  if (s.rr.start_depth != roulette_named(roulette_name(s.rr.mode))->start_depth)
    s.name += fmt::format("_s{}", s.rr.start_depth);
  if (s.mode == RenderMode::kPathTrace) return s;
  if (s.reprojected_weight != RenderOptions{}.reprojected_weight) s.name += fmt::format("_w{:g}", s.reprojected_weight);
  if (s.min_paths != RenderOptions{}.min_paths) s.name += fmt::format("_m{}", s.min_paths);
  if (s.combine != RenderOptions{}.combine) s.name += std::string("_") + to_string(s.combine);
  return s;
}

// keep_snapshot(round, cpu): whether to keep this round's image for the equal-time strip.
Run run_mode(const RenderOptions& base, const ModeSpec& ms, const Reference& ref, const Reference* cyref,
             const std::function<bool(int, double)>& keep_snapshot) {
  RenderOptions o = base;
  o.mode = ms.mode;
  o.reproject = ms.reproject;
  o.reprojected_weight = ms.reprojected_weight;
  o.min_paths = ms.min_paths;
  o.combine = ms.combine;
  o.rr = ms.rr;
  if (auto err = o.validate()) throw std::invalid_argument("mode '" + ms.name + "': " + *err);
  Run run;
  run.mode = ms.name;
  const double pixels = double(o.width) * o.height;
  double excluded_wall = 0, excluded_cpu = 0;
  const double c0 = cpu_seconds();
  const auto t0 = std::chrono::steady_clock::now();
  auto callback = [&](const RoundProgress& p) {
    const auto t_in = std::chrono::steady_clock::now();
    const double c_in = cpu_seconds();
    Sample s;
    s.round = p.round;
    s.wall = std::chrono::duration<double>(t_in - t0).count() - excluded_wall;
    s.cpu = c_in - c0 - excluded_cpu;
    const double rp0 = p.frame->seconds_reprojecting();
    FrameImages img = p.frame->images();  // also brings skip mode's M' of skipped pixels up to date
    run.eval_reprojecting += p.frame->seconds_reprojecting() - rp0;
    const FrameProgress& fp = p.frame->progress();
    s.eye_paths = double(fp.paths_traced);
    s.reprojected = fp.mean_reprojected * pixels;
    s.mean_spp = fp.mean_spp;
    s.spp = double(fp.paths_traced + fp.paths_skipped) / pixels;
    Image combined = combined_image(img);
    score(s, combined, ref, cyref);
    run.samples.push_back(s);
    if (keep_snapshot && keep_snapshot(int(std::lround(s.spp)), s.cpu))
      run.snapshots.push_back({s.cpu, s.round, std::move(combined), std::move(img.reprojected)});
    excluded_wall += std::chrono::duration<double>(std::chrono::steady_clock::now() - t_in).count();
    excluded_cpu += cpu_seconds() - c_in;
  };
  const RenderOutputs out = render_local(o, callback);
  run.stats = out.stats;
  return run;
}

void write_csv(const fs::path& file, const std::vector<Sample>& samples) {
  std::ofstream f(file);
  if (!f) throw std::runtime_error("cannot write " + file.string());
  f << "round,wall_s,cpu_s,eye_paths,reprojected_samples,mean_spp,rel_mse,rel_mse_trim,rmse,rel_mse_raw,"
       "rel_mse_trim_raw,rmse_raw,spp,rel_mse_cy,rel_mse_trim_cy,rmse_cy\n";
  for (const Sample& s : samples) {
    f << fmt::format("{},{:.4f},{:.4f},{:.0f},{:.0f},{:.4f},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g},{:.6g},{:.4f},", s.round,
                     s.wall, s.cpu, s.eye_paths, s.reprojected, s.mean_spp, s.err.full, s.err.trimmed,
                     std::sqrt(std::max(0.0, s.err.mse)), s.raw.full, s.raw.trimmed, std::sqrt(s.raw.mse), s.spp);
    if (s.cy)
      f << fmt::format("{:.6g},{:.6g},{:.6g}\n", s.cy->full, s.cy->trimmed, std::sqrt(std::max(0.0, s.cy->mse)));
    else
      f << "nan,nan,nan\n";
  }
}

double num(const json& j, const char* key) {
  return j.contains(key) && j[key].is_number() ? j[key].get<double>() : 0.0;
}

// ---------------------------------------------------------------------------------------------------
// Cycles
// ---------------------------------------------------------------------------------------------------

// scripts/bench.sh renders Cycles alongside: wait for the folder's "done" file.
void wait_done(const fs::path& dir) {
  for (int waited = 0; !fs::exists(dir / "done"); waited += 5) {
    if (waited % 60 == 0) std::printf("  waiting for %s/done (Cycles still rendering)\n", dir.c_str());
    std::fflush(stdout);
    std::this_thread::sleep_for(std::chrono::seconds(5));
  }
}

// DIR/SCENE_WxH_reference/{a,b}.exr: an independent Cycles reference as two halves of different seeds,
// combined and given a floor exactly as eprfarm's (bench_reference.h); nullopt when absent.
std::optional<Reference> cycles_reference(const fs::path& dir) {
  if (!fs::exists(dir)) return std::nullopt;
  wait_done(dir);
  if (!fs::exists(dir / "a.exr") || !fs::exists(dir / "b.exr")) return std::nullopt;
  const Image a = read_image((dir / "a.exr").string()), b = read_image((dir / "b.exr").string());
  if (a.width != b.width || a.height != b.height) throw std::runtime_error(dir.string() + ": halves differ in size");
  Reference ref;
  ref.image = Image(a.width, a.height, 3);
  for (int y = 0; y < a.height; ++y)
    for (int x = 0; x < a.width; ++x) ref.image.set_rgb(x, y, (a.rgb(x, y) + b.rgb(x, y)) * 0.5f);
  ref.floor = errors(a, ref.image);
  return ref;
}

// DIR/SCENE_WxH/times.csv: spp,wall_s,cpu_s,file (one render per row, file relative to the folder).
std::vector<Sample> score_cycles(const fs::path& dir, const Reference& ref, const Reference* cyref) {
  std::vector<Sample> out;
  if (!fs::exists(dir)) return out;
  wait_done(dir);
  std::ifstream f(dir / "times.csv");
  if (!f) return out;
  std::string line;
  std::getline(f, line);  // header
  while (std::getline(f, line)) {
    std::stringstream ss(line);
    std::string spp, wall, cpu, file;
    if (!std::getline(ss, spp, ',') || !std::getline(ss, wall, ',') || !std::getline(ss, cpu, ',') ||
        !std::getline(ss, file))
      throw std::runtime_error((dir / "times.csv").string() + ": bad line '" + line + "'");
    Sample s;
    s.round = std::stoi(spp);
    s.wall = std::stod(wall);
    s.cpu = std::stod(cpu);
    s.mean_spp = s.round;
    s.spp = s.round;
    s.eye_paths = double(s.round) * ref.image.width * ref.image.height;
    score(s, read_image((dir / file).string()), ref, cyref);
    out.push_back(s);
  }
  std::sort(out.begin(), out.end(), [](const Sample& a, const Sample& b) { return a.round < b.round; });
  return out;
}

// ---------------------------------------------------------------------------------------------------
// OBJ export
// ---------------------------------------------------------------------------------------------------

void export_obj(const std::string& spec, const fs::path& dir) {
  const Scene s = load_scene(spec);
  const std::string name = scene_name(spec);
  fs::create_directories(dir);
  std::ofstream mtl(dir / (name + ".mtl")), obj(dir / (name + ".obj")), cam(dir / (name + ".camera"));
  if (!mtl || !obj || !cam) throw std::runtime_error("cannot write to " + dir.string());
  mtl << "# " << spec << ": Kd, Ke and emit only (glossy lobes are not exported)\n";
  for (size_t m = 0; m < s.materials.size(); ++m) {
    const Material& mat = s.materials[m];
    mtl << fmt::format("newmtl m{}_{}\nKd {:.9g} {:.9g} {:.9g}\nKe {:.9g} {:.9g} {:.9g}\n", m, mat.name, mat.kd.x,
                       mat.kd.y, mat.kd.z, mat.ke.x, mat.ke.y, mat.ke.z);
    if (mat.emits_front_only) mtl << "emit front\n";
    if (!mat.diffuse()) mtl << "# glossy: Ks " << mat.ks.x << " exponent " << mat.exponent << " dropped\n";
  }
  obj << "# " << spec << " (" << s.triangle_count() << " triangles)\nmtllib " << name << ".mtl\n";
  for (const Vec3& p : s.positions) obj << fmt::format("v {:.9g} {:.9g} {:.9g}\n", p.x, p.y, p.z);
  uint32_t current = ~0u;
  for (size_t t = 0; t < s.triangles.size(); ++t) {
    if (s.material_of[t] != current) {
      current = s.material_of[t];
      obj << "usemtl m" << current << "_" << s.materials[current].name << "\n";
    }
    const auto& tri = s.triangles[t];
    obj << "f " << tri[0] + 1 << " " << tri[1] + 1 << " " << tri[2] + 1 << "\n";
  }
  const CameraSpec& c = s.camera;
  cam << fmt::format("--eye={:.9g},{:.9g},{:.9g} --look={:.9g},{:.9g},{:.9g} --up={:.9g},{:.9g},{:.9g} --fov={:.9g}\n",
                     c.eye.x, c.eye.y, c.eye.z, c.look.x, c.look.y, c.look.z, c.up.x, c.up.y, c.up.z, c.fov_y_degrees);
  std::printf("exported %s: %zu triangles, %zu materials -> %s\n", spec.c_str(), s.triangle_count(), s.materials.size(),
              (dir / (name + ".obj")).c_str());
}

// ---------------------------------------------------------------------------------------------------
// Tables
// ---------------------------------------------------------------------------------------------------

std::string fmt_time(std::optional<double> t) { return t ? fmt::format("{:.3g}", *t) : "-"; }

std::string fmt_ratio(std::optional<double> t, double pt) { return t && pt > 0 ? fmt::format("{:.2f}", *t / pt) : "-"; }

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Error against time for every mode and built-in scene, against a cached path-traced reference"};
  int size = 128, height = 0, spp = 256, ref_spp = 1024, threads = 0, subpixels = 4, strip_p = 64;
  std::vector<std::string> scenes = {"builtin:cornell", "builtin:conference", "builtin:hall", "builtin:wall",
                                     "builtin:glossy"};
  std::vector<std::string> modes = {"pt", "rp", "skip", "exact"};
  std::vector<int> targets = {64, 256};
  std::vector<std::string> pt_rr;
  std::string cache = bench::default_cache_dir(), out_dir = "bench_out", export_dir, cycles_dir;
  bool no_strip = false, list_references = false;
  bench::add_common_options(app, &size, &ref_spp, &cache, &threads, &bench::g_trim);
  app.add_option("--height", height, "image height (default: --size, square)");
  app.add_option("--spp", spp, "P: samples per pixel of every run");
  app.add_option("--scene", scenes, "scene specs (builtin:NAME[?tess=N], or a scene file's path)");
  app.add_option("--mode", modes,
                 "modes: pt, rp, skip, exact (pt is always run first); rp, skip and exact may name a variant: "
                 "skip:w=0.5:m=32");
  app.add_option("--reprojected-weight", g_reprojected_weight,
                 "W of every reprojecting run that does not name its own (w=), in (0, 1]");
  app.add_option("--min-paths", g_min_paths, "min-paths of every skip run that does not name its own (m=)");
  app.add_option("--pt-rr", pt_rr,
                 "more baseline candidates: pt with each of these roulettes (" + roulette_names() + ")");
  app.add_option("--target", targets, "the P of plain path tracing whose error the time-to-error columns use");
  app.add_option("--out", out_dir, "output folder (csv/, strip/, summary.json, tables.md)");
  app.add_option("--cycles", cycles_dir, "folder of cycles_sweep.py results to score (SCENE_WxH/times.csv)");
  app.add_option("--export-obj", export_dir, "write the scenes as OBJ+MTL+camera into this folder and exit");
  app.add_option("-S,--subpixels", subpixels);
  app.add_option("--strip-p", strip_p, "equal-time strip at half of pt's CPU time for this P");
  app.add_flag("--no-strip", no_strip, "no equal-time images");
  app.add_flag("--list-references", list_references, "print the reference cache file names and exit");
  SamplerKind sampler = SamplerKind::kSobolBurley;
  app.add_option("--sampler", sampler, "eye paths' random numbers of every run: sobol-burley or independent")
      ->transform(
          CLI::CheckedTransformer(std::map<std::string, SamplerKind>{{"sobol-burley", SamplerKind::kSobolBurley},
                                                                     {"independent", SamplerKind::kIndependent}},
                                  CLI::ignore_case))
      ->default_str("sobol-burley");
  CLI11_PARSE(app, argc, argv);
  set_log_level("warn");
  if (height <= 0) height = size;

  if (!export_dir.empty()) {
    for (const std::string& s : scenes) export_obj(s, export_dir);
    return 0;
  }
  if (list_references) {
    for (const std::string& s : scenes) {
      RenderOptions o;
      o.scene = s;
      o.rr = kReferenceRoulette;
      for (uint64_t seed : {1000001u, 1000002u})
        std::puts((fs::path(cache) / reference_file(o, size, height, std::max(1, ref_spp / 2), seed)).c_str());
    }
    return 0;
  }
  // pt first: its error at the target P and its CPU time for the strip are needed by the others.
  // The other pt runs follow it: all of them are baseline candidates.
  modes.erase(std::remove(modes.begin(), modes.end(), "pt"), modes.end());
  for (auto it = pt_rr.rbegin(); it != pt_rr.rend(); ++it) modes.insert(modes.begin(), "pt:rr=" + *it);
  modes.insert(modes.begin(), "pt");
  std::stable_partition(modes.begin(), modes.end(), [](const std::string& m) { return m.rfind("pt", 0) == 0; });
  // Runs are known by their variant names from here on.
  std::map<std::string, ModeSpec> specs;
  std::vector<std::string> named, pt_runs;  // pt_runs: the baseline candidates
  for (const std::string& m : modes) {
    const ModeSpec s = mode_spec(m);
    const bool pt = s.mode == RenderMode::kPathTrace;
    if (specs.count(s.name)) {
      if (pt) continue;  // --pt-rr naming the default roulette
      std::fprintf(stderr, "speed_accuracy: mode %s is named twice\n", s.name.c_str());
      return 2;
    }
    if (pt) pt_runs.push_back(s.name);
    named.push_back(s.name);
    specs[s.name] = s;
  }
  modes = named;

  const fs::path out(out_dir);
  fs::create_directories(out / "csv");
  if (!no_strip) fs::create_directories(out / "strip");
  const auto w_start = std::chrono::steady_clock::now();
  const double c_start = cpu_seconds();
  json summary = {{"size", size},           {"spp", spp},
                  {"ref_spp", ref_spp},     {"subpixels", subpixels},
                  {"threads", threads},     {"hardware_threads", std::thread::hardware_concurrency()},
                  {"trim", bench::g_trim},  {"load_start", load1()},
                  {"scenes", json::array()}};
  summary["sampler"] = to_string(sampler);
  summary["height"] = height;
  std::printf("speed_accuracy: %dx%d, P=%d, reference %d spp, %u hardware threads, tracer threads %s, load %.2f\n",
              size, height, spp, ref_spp, std::thread::hardware_concurrency(),
              threads > 0 ? std::to_string(threads).c_str() : "all", load1());
  std::fflush(stdout);

  // First every scene's runs, then Cycles' renders and the tables: scripts/bench.sh renders Cycles
  // alongside, so its sweeps may still be running while eprfarm's runs go on.
  struct SceneResult {
    std::string tag;
    json js;
    std::map<std::string, Run> runs;
    Reference ref;
    std::optional<Reference> cyref;
  };
  std::vector<SceneResult> done;
  for (const std::string& spec : scenes) {
    RenderOptions base;
    base.scene = spec;
    base.width = size, base.height = height;
    base.spp = spp;
    base.subpixels = subpixels;
    base.threads = threads;
    base.seed = 1;
    base.sampler = sampler;
    const std::string tag = fmt::format("{}_{}x{}", scene_name(spec), size, height);
    std::printf("\n== %s, load %.2f\n", tag.c_str(), load1());
    std::fflush(stdout);
    RenderOptions ref_options = base;
    ref_options.rr = kReferenceRoulette;
    const Reference ref = reference(ref_options, ref_spp, cache);
    const std::optional<Reference> cyref =
        cycles_dir.empty() ? std::nullopt : cycles_reference(fs::path(cycles_dir) / (tag + "_reference"));
    const Reference* cy = cyref ? &*cyref : nullptr;
    if (cy) std::printf("  scored against the Cycles reference too (floor %.3g trimmed)\n", cy->floor.trimmed);
    json js = {{"scene", spec},
               {"tag", tag},
               {"triangles", load_scene(spec).triangle_count()},
               {"floor", {{"rel_mse", ref.floor.full}, {"rel_mse_trim", ref.floor.trimmed}, {"mse", ref.floor.mse}}},
               {"load_start", load1()},
               {"modes", json::object()}};

    std::map<std::string, Run> runs;
    double strip_cpu = -1;  // half of pt's CPU time at P = strip_p
    for (const std::string& mode : modes) {
      std::function<bool(int, double)> keep;
      if (!no_strip && (mode == "pt" || mode == "skip" || mode == "rp")) {
        if (mode == "pt")
          keep = [&](int round, double) { return round <= strip_p; };
        else
          keep = [&](int, double cpu) { return cpu <= 1.5 * strip_cpu; };
      }
      const double l0 = load1();
      Run run = run_mode(base, specs.at(mode), ref, cy, keep);
      const Sample& last = run.samples.back();
      std::printf("  %-5s %4d rounds  %7.1f s wall %7.1f CPU-s  paths %.3g  M' %.3g  rMSE(trim) %.4g  load %.2f\n",
                  mode.c_str(), last.round, last.wall, last.cpu, last.eye_paths, last.reprojected, last.err.trimmed,
                  load1());
      std::fflush(stdout);
      write_csv(out / "csv" / (tag + "_" + mode + ".csv"), run.samples);
      if (mode == "pt")
        if (const auto at = at_spp(run.samples, strip_p)) strip_cpu = 0.5 * at->cpu;
      json stats = run.stats;
      stats["seconds_reprojecting_harness_reads"] = run.eval_reprojecting;
      stats["load_before"] = l0;
      stats["load_after"] = load1();
      stats["final_wall_s"] = last.wall;
      stats["final_cpu_s"] = last.cpu;
      stats["final_rel_mse"] = last.err.full;
      stats["final_rel_mse_trim"] = last.err.trimmed;
      stats["final_rmse"] = std::sqrt(std::max(0.0, last.err.mse));
      js["modes"][mode] = stats;
      runs[mode] = std::move(run);
    }

    // Equal-time strip: the last round each run finished within strip_cpu.
    if (!no_strip && strip_cpu > 0) {
      json strip = {{"cpu_s", strip_cpu}};
      for (const std::string mode : {"pt", "rp", "skip"}) {
        if (!runs.count(mode)) continue;
        const Snapshot* best = nullptr;
        for (const Snapshot& s : runs[mode].snapshots)
          if (s.cpu <= strip_cpu) best = &s;
        if (!best && !runs[mode].snapshots.empty()) best = &runs[mode].snapshots.front();
        if (!best) continue;
        write_exr((out / "strip" / (tag + "_" + mode + ".exr")).string(), best->combined);
        strip[mode] = {{"round", best->round},
                       {"cpu_s", best->cpu},
                       {"rel_mse_trim", (errors(best->combined, ref.image) - ref.floor).trimmed}};
        if (mode == "skip") {
          float max_m = 0;
          for (float v : best->mprime.data) max_m = std::max(max_m, v);
          write_png_srgb((out / "strip" / (tag + "_skip_mprime.png")).string(), heat_map(best->mprime, max_m));
          strip["mprime_max"] = max_m;
        }
      }
      write_exr((out / "strip" / (tag + "_reference.exr")).string(), ref.image);
      js["strip"] = strip;
      for (auto& [m, r] : runs) r.snapshots.clear();
    }
    js["load_end"] = load1();
    done.push_back({tag, std::move(js), std::move(runs), ref, cyref});
  }
  summary["load_end"] = load1();
  summary["wall_s"] = std::chrono::duration<double>(std::chrono::steady_clock::now() - w_start).count();
  summary["cpu_s"] = cpu_seconds() - c_start;

  std::ofstream md(out / "tables.md");
  for (SceneResult& sr : done) {
    const std::string& tag = sr.tag;
    json& js = sr.js;
    std::map<std::string, Run>& runs = sr.runs;
    const Reference& ref = sr.ref;
    const Reference* cy = sr.cyref ? &*sr.cyref : nullptr;
    std::map<std::string, std::vector<Sample>> cycles;  // "cycles", "cycles_adaptive"
    for (const std::string suffix : {"", "_adaptive"}) {
      if (cycles_dir.empty()) break;
      const std::string name = "cycles" + suffix;
      std::vector<Sample> c = score_cycles(fs::path(cycles_dir) / (tag + suffix), ref, cy);
      if (c.empty()) continue;
      write_csv(out / "csv" / (tag + "_" + name + ".csv"), c);
      json cj = json::array();
      for (const Sample& s : c)
        cj.push_back({{"spp", s.round},
                      {"wall_s", s.wall},
                      {"cpu_s", s.cpu},
                      {"rel_mse_trim", s.err.trimmed},
                      {"rel_mse", s.err.full}});
      js[name] = cj;
      std::printf("  %s: %zu renders scored\n", name.c_str(), c.size());
      cycles[name] = std::move(c);
    }

    // ---- tables
    const json& rp = js["modes"].contains("rp") ? js["modes"]["rp"] : json::object();
    md << "### " << tag << " (" << js["triangles"].get<size_t>() << " triangles)\n\n";
    if (!rp.empty()) {
      const double rec = std::max(1.0, num(rp, "vertices_recorded"));
      const double worker =
          num(rp, "culled_frustum_worker") + num(rp, "culled_facing_worker") + num(rp, "culled_glossy_worker");
      const double tracing = std::max(1e-9, num(rp, "seconds_tracing"));
      const double reproj = num(rp, "seconds_reprojecting") - num(rp, "seconds_reprojecting_harness_reads");
      md << fmt::format(
          "| accepted | occluded | culled | reprojection overhead (rp, GL) | eye paths traced (skip) "
          "|\n|---|---|---|---|---|\n"
          "| {:.1f} % | {:.1f} % | {:.1f} % | {:.1f} % | {} |\n\n",
          100 * num(rp, "accepted") / rec, 100 * num(rp, "occluded") / rec,
          100 * (num(rp, "culled_master") + worker) / rec, 100 * reproj / tracing,
          js["modes"].contains("skip")
              ? fmt::format("{:.1f} %", 100 * num(js["modes"]["skip"], "paths_traced") / (double(spp) * size * height))
              : "-");
      js["fates"] = {{"accepted", 100 * num(rp, "accepted") / rec},
                     {"occluded", 100 * num(rp, "occluded") / rec},
                     {"culled", 100 * (num(rp, "culled_master") + worker) / rec},
                     {"overhead", 100 * reproj / tracing}};
    }
    std::vector<std::pair<std::string, const std::vector<Sample>*>> curves;
    for (const std::string& m : modes) curves.emplace_back(m, &runs[m].samples);
    for (const auto& [name, c] : cycles) curves.emplace_back(name, &c);
    json tte = json::object();
    for (const bool trimmed : {true, false}) {
      const char* name = trimmed ? "rel_mse_trim" : "rel_mse";
      md << (trimmed ? "Trimmed relative MSE (without the 1 % largest pixel terms):\n\n"
                     : "Full relative MSE (every pixel, fireflies included):\n\n");
      // The baseline at each target: the pt run of least error x CPU seconds at P = t.
      std::map<int, std::string> best_pt;
      for (int t : targets) {
        double best = std::numeric_limits<double>::infinity();
        for (const std::string& p : pt_runs)
          if (const auto at = at_spp(runs[p].samples, t); at && metric(*at, trimmed) * at->cpu < best) {
            best = metric(*at, trimmed) * at->cpu;
            best_pt[t] = p;
          }
        if (best_pt.count(t)) js["baseline"][name][std::to_string(t)] = best_pt[t];
      }
      md << "Baseline pt* (least error x CPU-s among " << fmt::format("{}", fmt::join(pt_runs, ", ")) << "):";
      for (int t : targets) md << fmt::format(" P = {}: {};", t, best_pt.count(t) ? best_pt[t] : "-");
      md << "\n\n| mode | final error | CPU-s | wall s |";
      for (int t : targets) md << fmt::format(" error x CPU-s at P = {} | x pt* |", t);
      for (int t : targets) md << fmt::format(" to pt*@{}: CPU-s first / stays | x pt* first / stays |", t);
      md << "\n|---|---|---|---|";
      for (size_t i = 0; i < 2 * targets.size(); ++i) md << "---|---|";
      md << "\n";
      for (const auto& [m, s] : curves) {
        const Sample& last = s->back();
        md << fmt::format("| {} | {:.4g} | {:.1f} | {:.1f} |", m, metric(last, trimmed), last.cpu, last.wall);
        for (int t : targets) {
          const std::optional<Sample> at = at_spp(*s, t);
          const std::optional<Sample> base = best_pt.count(t) ? at_spp(runs[best_pt[t]].samples, t) : std::nullopt;
          if (!at || !base) {
            md << " - | - |";
            continue;
          }
          const double product = metric(*at, trimmed) * at->cpu, base_product = metric(*base, trimmed) * base->cpu;
          md << fmt::format(" {:.4g} | {:.2f} |", product, product / base_product);
          tte[name][m][std::to_string(t)]["error_x_cpu_s"] = product;
          tte[name][m][std::to_string(t)]["error_x_cpu_s_vs_best_pt"] = product / base_product;
        }
        for (int t : targets) {
          // The target and the time it is compared with: the best plain path tracer's error and CPU
          // time at t paths per pixel.
          const std::optional<Sample> base = best_pt.count(t) ? at_spp(runs[best_pt[t]].samples, t) : std::nullopt;
          if (!base) {
            md << " - | - |";
            continue;
          }
          const Reach c = time_to(*s, metric(*base, trimmed), true, trimmed);
          const Reach w = time_to(*s, metric(*base, trimmed), false, trimmed);
          md << fmt::format(" {} / {} | {} / {} |", fmt_time(c.first), fmt_time(c.stays), fmt_ratio(c.first, base->cpu),
                            fmt_ratio(c.stays, base->cpu));
          auto opt = [](std::optional<double> v) { return v ? json(*v) : json(nullptr); };
          tte[name][m][std::to_string(t)].update({{"baseline", best_pt[t]},
                                                  {"target", metric(*base, trimmed)},
                                                  {"pt_cpu_s", base->cpu},
                                                  {"pt_wall_s", base->wall},
                                                  {"cpu_s_first", opt(c.first)},
                                                  {"cpu_s_stays", opt(c.stays)},
                                                  {"wall_s_first", opt(w.first)},
                                                  {"wall_s_stays", opt(w.stays)}});
        }
        md << "\n";
      }
      md << "\n";
    }
    md.flush();
    js["time_to_error"] = tte;
    summary["scenes"].push_back(js);
  }
  std::ofstream(out / "summary.json") << summary.dump(2) << "\n";
  std::printf("\n(total %.0f s wall, %.0f CPU-s; load at end %.2f) -> %s\n", summary["wall_s"].get<double>(),
              summary["cpu_s"].get<double>(), load1(), out.c_str());
  return 0;
}
