#include "client/render_flags.h"

#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string_view>

#include "common/result_kinds.h"

namespace epr {
namespace {

// Parses "x,y,z" into a Vec3 (CLI11 validator-style: throws CLI::ValidationError).
Vec3 parse_vec3(const std::string& flag, const std::string& s) {
  Vec3 v;
  char extra;
  if (std::sscanf(s.c_str(), "%f,%f,%f%c", &v.x, &v.y, &v.z, &extra) != 3 || !is_finite(v))
    throw CLI::ValidationError(flag, "expects three finite numbers separated by commas, e.g. 0,1,3.9");
  return v;
}

// `file` (as the user wrote it) relative to the folder of the scene file `scene`, which it must lie
// in: it travels in the scene's bundle, whose paths are relative to that folder. A built-in scene has
// no folder: the image's own folder stands in for it (*folder), and the image is named by its file
// name (bundle_scene bundles the two).
std::string scene_relative_path(const char* flag, const std::string& scene, const std::string& file,
                                std::string* folder_out) {
  namespace fs = std::filesystem;
  std::error_code ec;
  const fs::path real = fs::weakly_canonical(file, ec);
  if (ec || !fs::is_regular_file(real, ec))
    throw CLI::ValidationError(flag, fmt::format("'{}' is not a readable file", file));
  if (scene.rfind("builtin:", 0) == 0) {
    *folder_out = real.parent_path().string();
    return real.filename().string();
  }
  const fs::path folder = fs::weakly_canonical(fs::absolute(scene).parent_path(), ec);
  const fs::path rel = real.lexically_relative(folder);
  if (ec || rel.empty() || *rel.begin() == "..")
    throw CLI::ValidationError(flag, fmt::format("'{}' lies outside the scene's folder {}: the image travels with the "
                                                 "scene's files, so copy it there",
                                                 file, folder.string()));
  return rel.generic_string();
}

}  // namespace

void add_render_flags(CLI::App* cmd, RenderOptions& o, std::map<std::string, std::string>& extra, RenderFlagSet set) {
  cmd->add_option("scene", o.scene,
                  "OBJ file, scene JSON file, or builtin:NAME (cornell, conference, hall, wall, glossy, furnace)")
      ->required();
  o.mode = RenderMode::kSkip;  // what the project is for; --mode pt is the plain path tracer
  cmd->add_option("--width", o.width, "image width in pixels")->capture_default_str();
  cmd->add_option("--height", o.height, "image height in pixels")->capture_default_str();
  cmd->add_option("--spp", o.spp, "target samples per pixel P")->capture_default_str();
  cmd->add_option("--paths-per-round", o.paths_per_round, "paths per non-skipped pixel and round (k)")
      ->capture_default_str();
  cmd->add_option("--round-growth", o.round_growth,
                  "later rounds trace floor(g x paths so far) paths (at least k); 0: k paths in every round")
      ->capture_default_str();
  cmd->add_option("--seed", o.seed, "random seed")->capture_default_str();
  cmd->add_option("--out", o.out,
                  "output prefix: writes PREFIX.exr, PREFIX.png, PREFIX.json (a name ending in .exr or .png is taken "
                  "without it)")
      ->check([](const std::string& v) { return output_prefix_error(v).value_or(""); })
      ->capture_default_str();
  const std::map<std::string, RenderMode> modes{
      {"pt", RenderMode::kPathTrace}, {"rp", RenderMode::kReproject}, {"skip", RenderMode::kSkip}};
  cmd->add_option("--mode", o.mode,
                  "skip: reprojection plus pixel skipping; rp: reprojection only; pt: path tracing only")
      ->transform(CLI::CheckedTransformer(modes, CLI::ignore_case))
      ->capture_default_str();
  const std::map<std::string, ReprojectMethod> methods{
      {"gl", ReprojectMethod::kGl}, {"cpu", ReprojectMethod::kCpu}, {"exact", ReprojectMethod::kExact}};
  cmd->add_option("--reproject", o.reproject, "gl: OSMesa deep framebuffer; cpu: CPU reference; exact: visibility rays")
      ->transform(CLI::CheckedTransformer(methods, CLI::ignore_case))
      ->capture_default_str();
  cmd->add_option("--subpixels", o.subpixels, "S: deep framebuffer has S x S subpixels per pixel")
      ->capture_default_str();
  cmd->add_option("--epsilon", o.epsilon, "plane-test tolerance, fraction of the scene's bounding-box diagonal")
      ->capture_default_str();
  cmd->add_option("--min-paths", o.min_paths, "real paths a pixel traces before it may be skipped")
      ->capture_default_str();
  cmd->add_option("--reprojected-weight", o.reprojected_weight,
                  "W in (0, 1]: what a reprojected sample counts for against a traced path, in the image "
                  "(sum + W M' L_rp) / (M + W M') and in the skip rule M + W M' >= spp")
      ->capture_default_str();
  const std::map<std::string, CombineRule> combine_rules{{"fixed", CombineRule::kFixed},
                                                         {"variance", CombineRule::kVariance}};
  cmd->add_option("--combine", o.combine,
                  "fixed: a reprojected sample counts for W of a path; variance: inverse-variance weights from the "
                  "pixel's second moments, skip once the effective sample count reaches spp")
      ->transform(CLI::CheckedTransformer(combine_rules, CLI::ignore_case))
      ->capture_default_str();
  cmd->add_flag("--path-budget", o.path_budget,
                "skip, fixed rule: a pixel traces only the paths that bring M + W M' to spp in a round, not the "
                "whole round's");
  cmd->add_flag("--reproject-glossy", o.reproject_glossy, "also reproject glossy vertices (failure-mode study)");
  cmd->add_flag_callback(
      "--no-joint-test", [&o] { o.joint_test = false; },
      "plane test without its normal and crease tests: thin walls leak at their joints (failure-mode study)");
  std::vector<std::string> rr_names;
  for (const NamedRoulette& n : named_roulettes()) rr_names.emplace_back(n.name);
  cmd->add_option("--rr", extra["rr"],
                  "Russian roulette (docs/DESIGN.md \"Russian roulette\"): reuse (throughput since the latest "
                  "vertex reprojection can show), throughput, albedo, paper (after 8 vertices, p=0.1) or off")
      ->check(CLI::IsMember(rr_names))
      ->default_str(std::string(roulette_name(RussianRoulette::standard().mode)));
  cmd->add_option("--max-depth", extra["max-depth"],
                  "hard cap on path vertices (default 1024; with --rr off the fixed depth, default 8)");
  cmd->add_flag("--mis,!--no-mis", o.mis,
                "direct light by MIS of light and BSDF samples (default); --no-mis: next event estimation only")
      ->capture_default_str();
  const std::map<std::string, SamplerKind> samplers{{"sobol-burley", SamplerKind::kSobolBurley},
                                                    {"independent", SamplerKind::kIndependent}};
  cmd->add_option("--sampler", o.sampler,
                  "eye paths' random numbers: sobol-burley (Owen-scrambled Sobol per pixel) or independent "
                  "(a hash per dimension, the sampler before sobol-burley)")
      ->transform(CLI::CheckedTransformer(samplers, CLI::ignore_case))
      ->default_str("sobol-burley");
  if (set == RenderFlagSet::kLocal) {
    o.tile_size = 0;  // auto: run_render picks auto_tile_size() for the threads it starts, tapered
    cmd->add_option("--tile", o.tile_size,
                    fmt::format("tile size in pixels (auto: the largest of 128, 64, 32, 16 giving each tracing "
                                "thread {} tiles a round, tapered)",
                                kTilesPerThread))
        ->default_str("auto");
  } else {
    cmd->add_option("--tile", o.tile_size, "tile size in pixels")->capture_default_str();
  }
  cmd->add_flag("--taper-tiles", o.taper_tiles,
                "the last quarter of the tile rows in tiles of half the size: rounds end on small tiles");
  if (set == RenderFlagSet::kLocal)
    cmd->add_option("--threads", o.threads, "worker threads, 0 = all cores")->capture_default_str();
  for (const char* v : {"--eye", "--look", "--up"})
    cmd->add_option(v, extra[v], fmt::format("camera override x,y,z ({})", v + 2));
  cmd->add_option("--fov", o.fov, "camera override: vertical field of view in degrees");
  cmd->add_option("--env", extra["--env"],
                  "environment light, replacing the scene's: an equirectangular .hdr/.exr inside the scene's folder "
                  "(anywhere with a builtin: scene), or a constant colour R,G,B (one number: a grey)");
  cmd->add_option("--sun", extra["--sun"],
                  "sun, replacing the scene's: DX,DY,DZ[,ANGLE_DEG[,E or ,R,G,B]]: direction towards the sun, "
                  "angular diameter (default 0.53) and irradiance in W/m^2 (default 1)");
}

std::optional<std::string> output_prefix_error(const std::string& prefix) {
  if (prefix.empty()) return "the output prefix is empty (files would be named .exr, .png, ...)";
  const std::string last = std::filesystem::path(prefix).filename().string();
  if (last.empty() || last == "." || last == "..")
    return fmt::format("'{}' names a folder, not a file prefix; give one such as '{}/render'", prefix,
                       prefix.back() == '/' ? prefix.substr(0, prefix.size() - 1) : prefix);
  std::error_code ec;
  if (std::filesystem::is_directory(prefix, ec))
    return fmt::format("'{}' is a folder; give a file prefix inside it such as '{}/render'", prefix, prefix);
  return std::nullopt;
}

std::optional<std::string> output_replaces_input(const std::string& prefix,
                                                 const std::vector<std::filesystem::path>& inputs) {
  namespace fs = std::filesystem;
  const fs::path out(prefix);
  const std::string stem = out.filename().string();
  const fs::path out_dir = out.parent_path().empty() ? fs::path(".") : out.parent_path();
  for (const fs::path& in : inputs) {
    const std::string name = in.filename().string();
    if (name.rfind(stem, 0) != 0) continue;
    // What follows the prefix: a result suffix, or ".NNNN" (a batch frame) and one.
    std::string_view rest = std::string_view(name).substr(stem.size());
    if (rest.size() > 1 && rest[0] == '.' && std::isdigit(static_cast<unsigned char>(rest[1]))) {
      size_t d = 1;
      while (d < rest.size() && std::isdigit(static_cast<unsigned char>(rest[d]))) ++d;
      rest = rest.substr(d);
    }
    const auto kinds = result_kinds();
    if (std::none_of(kinds.begin(), kinds.end(), [&](const ResultKindInfo& k) { return k.suffix == rest; })) continue;
    std::error_code ec;
    if (fs::equivalent(out_dir, in.parent_path(), ec))
      return fmt::format("'{}' would replace {}, which the scene reads; give another output prefix", prefix,
                         in.string());
  }
  // Nor a scene JSON beside the scene (garden.json next to the garden.gltf being rendered).
  const fs::path stats = prefix + std::string(result_kind(ResultKind::kJson).suffix);
  if (std::ifstream f(stats); f) {
    const nlohmann::json j = nlohmann::json::parse(f, nullptr, /*allow_exceptions=*/false, /*ignore_comments=*/true);
    if (j.is_object() && (j.contains("obj") || j.contains("builtin")))
      return fmt::format("'{}' would replace {}, a scene file; give another output prefix", prefix, stats.string());
  }
  return std::nullopt;
}

std::string output_prefix(const std::string& out) {
  for (const std::string_view ext : {".exr", ".png"}) {
    if (out.size() <= ext.size()) continue;
    const std::string tail = out.substr(out.size() - ext.size());
    if (std::equal(tail.begin(), tail.end(), ext.begin(), ext.end(),
                   [](char a, char b) { return std::tolower(static_cast<unsigned char>(a)) == b; }))
      return out.substr(0, out.size() - ext.size());
  }
  return out;
}

void finish_options(RenderOptions& o, const std::map<std::string, std::string>& extra) {
  o.out = output_prefix(o.out);
  for (const char* flag : {"--eye", "--look", "--up"}) {
    const auto it = extra.find(flag);
    if (it == extra.end() || it->second.empty()) continue;
    const Vec3 v = parse_vec3(flag, it->second);
    (flag[2] == 'e' ? o.eye : flag[2] == 'l' ? o.look : o.up) = v;
  }
  if (const auto env = extra.find("--env"); env != extra.end() && !env->second.empty()) {
    std::string file;
    try {
      o.lighting.environment = parse_env_flag(env->second, &file);
    } catch (const std::invalid_argument& e) {
      throw CLI::ValidationError(std::string(e.what()));
    }
    o.env_folder.clear();
    if (!file.empty()) o.lighting.environment->image = scene_relative_path("--env", o.scene, file, &o.env_folder);
  }
  if (const auto sun = extra.find("--sun"); sun != extra.end() && !sun->second.empty()) {
    try {
      o.lighting.sun = parse_sun_flag(sun->second);
    } catch (const std::invalid_argument& e) {
      throw CLI::ValidationError(std::string(e.what()));
    }
  }
  const auto rr = extra.find("rr");
  const auto depth = extra.find("max-depth");
  o.rr = rr == extra.end() || rr->second.empty() ? RussianRoulette::standard()
                                                 : roulette_named(rr->second).value_or(RussianRoulette::standard());
  if (depth != extra.end() && !depth->second.empty()) {
    try {
      o.rr.max_depth = std::stoi(depth->second);
    } catch (const std::exception&) {
      throw CLI::ValidationError("--max-depth", "expects a whole number");
    }
  }
}

}  // namespace epr
