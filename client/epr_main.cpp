// epr: the command-line client. `epr render` runs the whole system on this machine.
#include <unistd.h>

#include <cstdio>
#include <iostream>
#include <map>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include "client/local_render.h"
#include "common/log.h"

namespace {

using namespace epr;

// Parses "x,y,z" into a Vec3 (CLI11 validator-style: throws CLI::ValidationError).
Vec3 parse_vec3(const std::string& flag, const std::string& s) {
  Vec3 v;
  char extra;
  if (std::sscanf(s.c_str(), "%f,%f,%f%c", &v.x, &v.y, &v.z, &extra) != 3 || !is_finite(v))
    throw CLI::ValidationError(flag, "expects three finite numbers separated by commas, e.g. 0,1,3.9");
  return v;
}

void add_render_flags(CLI::App* cmd, RenderOptions& o, std::map<std::string, std::string>& extra) {
  cmd->add_option("scene", o.scene, "OBJ file, scene JSON file, or builtin:NAME (cornell, conference, hall, wall, glossy, furnace)")
      ->required();
  cmd->add_option("--width", o.width, "image width in pixels")->capture_default_str();
  cmd->add_option("--height", o.height, "image height in pixels")->capture_default_str();
  cmd->add_option("--spp", o.spp, "target samples per pixel P")->capture_default_str();
  cmd->add_option("--paths-per-round", o.paths_per_round, "paths per non-skipped pixel and round (k)")->capture_default_str();
  cmd->add_option("--seed", o.seed, "random seed")->capture_default_str();
  cmd->add_option("--out", o.out, "output prefix: writes PREFIX.exr, PREFIX.png, PREFIX.json")->capture_default_str();
  const std::map<std::string, RenderMode> modes{{"pt", RenderMode::kPathTrace}, {"rp", RenderMode::kReproject}, {"skip", RenderMode::kSkip}};
  cmd->add_option("--mode", o.mode, "pt: path tracing; rp: plus reprojection; skip: plus pixel skipping")
      ->transform(CLI::CheckedTransformer(modes, CLI::ignore_case))->capture_default_str();
  const std::map<std::string, ReprojectMethod> methods{{"gl", ReprojectMethod::kGl}, {"cpu", ReprojectMethod::kCpu}, {"exact", ReprojectMethod::kExact}};
  cmd->add_option("--reproject", o.reproject, "gl: OSMesa deep framebuffer; cpu: CPU reference; exact: visibility rays")
      ->transform(CLI::CheckedTransformer(methods, CLI::ignore_case))->capture_default_str();
  cmd->add_option("--subpixels", o.subpixels, "S: deep framebuffer has S x S subpixels per pixel")->capture_default_str();
  cmd->add_option("--epsilon", o.epsilon, "plane-test tolerance, fraction of the scene's bounding-box diagonal")->capture_default_str();
  cmd->add_option("--min-paths", o.min_paths, "real paths a pixel traces before it may be skipped")->capture_default_str();
  cmd->add_flag("--reproject-glossy", o.reproject_glossy, "also reproject glossy vertices (failure-mode study)");
  cmd->add_option("--rr", extra["rr"], "Russian roulette: paper (after 8 bounces, p=0.1), albedo, or off")
      ->check(CLI::IsMember({"paper", "albedo", "off"}))->default_str("paper");
  cmd->add_option("--max-depth", extra["max-depth"],
                  "hard cap on path vertices (default 1024; with --rr off the fixed depth, default 8)");
  cmd->add_option("--tile", o.tile_size, "tile size in pixels")->capture_default_str();
  cmd->add_option("--threads", o.threads, "worker threads, 0 = all cores")->capture_default_str();
  for (const char* v : {"--eye", "--look", "--up"})
    cmd->add_option(v, extra[v], fmt::format("camera override x,y,z ({})", v + 2));
  cmd->add_option("--fov", o.fov, "camera override: vertical field of view in degrees");
}

// Turns the flags that need more than a plain conversion into options.
void finish_options(RenderOptions& o, const std::map<std::string, std::string>& extra) {
  for (const char* flag : {"--eye", "--look", "--up"}) {
    const auto it = extra.find(flag);
    if (it == extra.end() || it->second.empty()) continue;
    const Vec3 v = parse_vec3(flag, it->second);
    (flag[2] == 'e' ? o.eye : flag[2] == 'l' ? o.look : o.up) = v;
  }
  const auto rr = extra.find("rr");
  const auto depth = extra.find("max-depth");
  const std::string mode = rr == extra.end() || rr->second.empty() ? "paper" : rr->second;
  o.rr = mode == "albedo" ? RussianRoulette::albedo() : mode == "off" ? RussianRoulette::off(8) : RussianRoulette::paper();
  if (depth != extra.end() && !depth->second.empty()) {
    try {
      o.rr.max_depth = std::stoi(depth->second);
    } catch (const std::exception&) {
      throw CLI::ValidationError("--max-depth", "expects a whole number");
    }
  }
}

void print_progress(const RoundProgress& p, int spp, bool tty) {
  const int width = 30;
  const double frac = std::min(1.0, p.mean_spp / std::max(1, spp));
  const int filled = int(frac * width);
  const std::string bar = std::string(size_t(filled), '#') + std::string(size_t(width - filled), '.');
  const std::string eta = p.eta_seconds >= 0 ? fmt::format("{:.0f}s", p.eta_seconds) : "?";
  const std::string line = fmt::format("[{}] round {:3d}  spp {:6.1f}/{} (min {:.0f})  M' {:5.1f}  active {:3.0f}%  {:6.1f}s  ETA {}",
                                       bar, p.round, p.mean_spp, spp, p.min_spp, p.mean_mprime, 100 * p.pixels_active,
                                       p.seconds, eta);
  std::fprintf(stderr, tty ? "\r%s" : "%s\n", line.c_str());
  std::fflush(stderr);
}

int run_render(RenderOptions& o, const std::map<std::string, std::string>& extra) {
  finish_options(o, extra);
  if (auto err = o.validate()) {
    std::fprintf(stderr, "epr render: %s\n", err->c_str());
    return 2;
  }
  const bool tty = isatty(STDERR_FILENO);
  try {
    const RenderOutputs out = render_local(o, [&](const RoundProgress& p) { print_progress(p, o.spp, tty); });
    if (tty) std::fprintf(stderr, "\n");
    write_outputs(o.out, out);
    std::fprintf(stderr, "wrote %s.exr, %s.png, %s.json (%.2f s, %.0f paths/s)\n", o.out.c_str(), o.out.c_str(),
                 o.out.c_str(), out.stats.value("seconds", 0.0), out.stats.value("paths_per_second", 0.0));
  } catch (const std::exception& e) {
    if (tty) std::fprintf(stderr, "\n");
    std::fprintf(stderr, "epr render: %s\n", e.what());
    return 1;
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"eprfarm: path tracing accelerated by eye path reprojection"};
  app.require_subcommand(1);
  std::string log_level = "warn";
  app.add_option("--log-level", log_level, "trace, debug, info, warn, error or off")
      ->check(CLI::IsMember({"trace", "debug", "info", "warn", "error", "off"}));

  RenderOptions render_opts;
  std::map<std::string, std::string> render_extra;
  CLI::App* render = app.add_subcommand("render", "render a scene on this machine (embedded master and workers)");
  add_render_flags(render, render_opts, render_extra);

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  set_log_level(log_level);
  try {
    if (render->parsed()) return run_render(render_opts, render_extra);
  } catch (const CLI::ValidationError& e) {
    std::fprintf(stderr, "epr: %s\n", e.what());
    return 2;
  }
  return 0;
}
