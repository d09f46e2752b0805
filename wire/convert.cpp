#include "wire/convert.h"

#include <fmt/format.h>

#include <cctype>
#include <cmath>

namespace epr {
namespace {

// The one table of job states and their wire values.
struct JobStateWire {
  JobState state;
  v1::JobState wire;
};
constexpr JobStateWire kJobStateWire[] = {{JobState::kQueued, v1::JOB_STATE_QUEUED},
                                          {JobState::kRunning, v1::JOB_STATE_RUNNING},
                                          {JobState::kDone, v1::JOB_STATE_DONE},
                                          {JobState::kFailed, v1::JOB_STATE_FAILED},
                                          {JobState::kCancelled, v1::JOB_STATE_CANCELLED}};

}  // namespace

v1::JobState to_proto(JobState s) {
  for (const auto& row : kJobStateWire)
    if (row.state == s) return row.wire;
  return v1::JOB_STATE_UNSPECIFIED;
}

std::optional<JobState> from_proto(v1::JobState s) {
  for (const auto& row : kJobStateWire)
    if (row.wire == s) return row.state;
  return std::nullopt;
}

Vec3 from_proto(const v1::Vec3& v) { return {v.x(), v.y(), v.z()}; }
void to_proto(const Vec3& v, v1::Vec3* out) {
  out->set_x(v.x);
  out->set_y(v.y);
  out->set_z(v.z);
}

CameraSpec from_proto(const v1::Camera& c) {
  return {from_proto(c.eye()), from_proto(c.look()), from_proto(c.up()), c.fov_y_degrees()};
}
void to_proto(const CameraSpec& c, v1::Camera* out) {
  to_proto(c.eye, out->mutable_eye());
  to_proto(c.look, out->mutable_look());
  to_proto(c.up, out->mutable_up());
  out->set_fov_y_degrees(c.fov_y_degrees);
}

Bounds3 from_proto(const v1::Bounds3& b) { return {from_proto(b.lo()), from_proto(b.hi())}; }
void to_proto(const Bounds3& b, v1::Bounds3* out) {
  to_proto(b.lo, out->mutable_lo());
  to_proto(b.hi, out->mutable_hi());
}

// A mode's policy is common/roulette.h's of the same name (tests/wire checks that every mode has one).
RussianRoulette from_proto(const v1::RussianRouletteSettings& rr) {
  const std::string name =
      rr.mode() == v1::RUSSIAN_ROULETTE_MODE_UNSPECIFIED || !v1::RussianRouletteMode_IsValid(rr.mode())
          ? std::string()
          : v1::RussianRouletteMode_Name(rr.mode()).substr(sizeof "RUSSIAN_ROULETTE_MODE_" - 1);
  RussianRoulette r = roulette_named(name).value_or(RussianRoulette::standard());
  if (rr.has_start_depth()) r.start_depth = int(rr.start_depth());
  if (rr.has_termination_probability()) r.termination = rr.termination_probability();
  if (rr.has_max_depth()) r.max_depth = int(std::min<uint32_t>(rr.max_depth(), 1u << 30));
  return r;
}
void to_proto(const RussianRoulette& r, v1::RussianRouletteSettings* out) {
  std::string name(roulette_name(r.mode));
  for (char& c : name) c = char(std::toupper(static_cast<unsigned char>(c)));
  v1::RussianRouletteMode mode = v1::RUSSIAN_ROULETTE_MODE_UNSPECIFIED;
  v1::RussianRouletteMode_Parse("RUSSIAN_ROULETTE_MODE_" + name, &mode);
  out->set_mode(mode);
  if (r.start_depth >= 0) out->set_start_depth(uint32_t(r.start_depth));  // AUTO's -1: unset
  out->set_termination_probability(r.termination);
  out->set_max_depth(uint32_t(std::max(0, r.max_depth)));
}

std::optional<SamplerKind> from_proto(v1::Sampler s) {
  switch (s) {
    case v1::SAMPLER_UNSPECIFIED:
    case v1::SAMPLER_INDEPENDENT:
      return SamplerKind::kIndependent;
    case v1::SAMPLER_SOBOL_BURLEY:
      return SamplerKind::kSobolBurley;
    default:
      return std::nullopt;
  }
}
v1::Sampler to_proto(SamplerKind s) {
  return s == SamplerKind::kIndependent ? v1::SAMPLER_INDEPENDENT : v1::SAMPLER_SOBOL_BURLEY;
}

std::optional<std::string> from_proto(const v1::EnvironmentLight* env, const v1::SunLight* sun, Lighting* out) {
  Lighting l;
  if (env) {
    EnvironmentLight e;
    if (env->has_color()) {
      e.color = from_proto(env->color());
    } else if (env->has_image()) {
      if (!is_safe_relative_path(env->image()))
        return fmt::format("environment image '{}' is not a safe relative path of the scene bundle", env->image());
      e.image = env->image();
    } else {
      return "environment: give a color or an image";
    }
    if (env->has_strength()) e.strength = env->strength();
    e.rotation_deg = env->rotation_degrees();
    if (auto err = check_environment(e)) return err;
    l.environment = e;
  }
  if (sun) {
    SunLight s;
    s.direction = from_proto(sun->direction());
    if (sun->has_angle_degrees()) s.angle_deg = sun->angle_degrees();
    if (sun->has_irradiance()) s.irradiance = from_proto(sun->irradiance());
    if (auto err = check_sun(s)) return err;
    s.direction = normalize(s.direction);
    l.sun = s;
  }
  *out = std::move(l);
  return std::nullopt;
}

void to_proto(const Lighting& l, v1::EnvironmentLight* env, v1::SunLight* sun) {
  if (l.environment && env) {
    if (l.environment->image.empty())
      to_proto(l.environment->color, env->mutable_color());
    else
      env->set_image(l.environment->image);
    env->set_strength(l.environment->strength);
    env->set_rotation_degrees(l.environment->rotation_deg);
  }
  if (l.sun && sun) {
    to_proto(l.sun->direction, sun->mutable_direction());
    sun->set_angle_degrees(l.sun->angle_deg);
    to_proto(l.sun->irradiance, sun->mutable_irradiance());
  }
}

namespace {
v1::RenderMode to_proto_mode(RenderMode m) {
  return m == RenderMode::kReproject ? v1::RENDER_MODE_RP
         : m == RenderMode::kSkip    ? v1::RENDER_MODE_SKIP
                                     : v1::RENDER_MODE_PT;
}
v1::ReprojectionMethod to_proto_method(ReprojectMethod m) {
  return m == ReprojectMethod::kCpu     ? v1::REPROJECTION_METHOD_CPU
         : m == ReprojectMethod::kExact ? v1::REPROJECTION_METHOD_EXACT
                                        : v1::REPROJECTION_METHOD_GL;
}
void to_proto_reprojection(const RenderOptions& o, v1::ReprojectionSettings* r) {
  r->set_method(to_proto_method(o.reproject));
  r->set_subpixels(uint32_t(o.subpixels));
  r->set_epsilon_fraction(o.epsilon);
  r->set_min_paths(uint32_t(o.min_paths));
  r->set_reprojected_weight(o.reprojected_weight);
  r->set_combine(o.combine == CombineRule::kVariance ? v1::COMBINE_RULE_VARIANCE : v1::COMBINE_RULE_FIXED);
  r->set_reproject_glossy(o.reproject_glossy);
  r->set_joint_test(o.joint_test);
  r->set_path_budget(o.path_budget);
}
}  // namespace

v1::JobSpec to_job_spec(const RenderOptions& o, const SceneBundleData& bundle, const CameraSpec& scene_camera) {
  v1::JobSpec spec;
  to_proto(bundle, spec.mutable_scene());
  to_proto(o.camera_for(scene_camera), spec.mutable_camera());
  spec.set_width(uint32_t(o.width));
  spec.set_height(uint32_t(o.height));
  spec.set_target_spp(uint32_t(o.spp));
  spec.set_paths_per_round(uint32_t(o.paths_per_round));
  spec.set_mode(to_proto_mode(o.mode));
  to_proto_reprojection(o, spec.mutable_reprojection());
  to_proto(o.rr, spec.mutable_russian_roulette());
  spec.set_seed(o.seed);
  spec.set_tile_size(uint32_t(o.tile_size));
  spec.set_round_growth(o.round_growth);
  spec.set_mis(o.mis);
  spec.set_sampler(to_proto(o.sampler));
  spec.set_taper_tiles(o.taper_tiles);
  to_proto(o.lighting, o.lighting.environment ? spec.mutable_environment() : nullptr,
           o.lighting.sun ? spec.mutable_sun() : nullptr);
  return spec;
}

std::optional<std::string> from_job_spec(const v1::JobSpec& spec, RenderOptions* out, CameraSpec* camera) {
  RenderOptions o;
  // Reject values that would not survive the narrowing to int before validate() sees them.
  constexpr uint32_t kMax = 1u << 24;
  if (spec.width() > kMax || spec.height() > kMax || spec.target_spp() > kMax || spec.paths_per_round() > kMax ||
      spec.tile_size() > kMax)
    return "a size or sample count is absurdly large";
  o.width = int(spec.width());
  o.height = int(spec.height());
  o.spp = int(spec.target_spp());
  o.paths_per_round = spec.has_paths_per_round() ? int(spec.paths_per_round()) : 1;
  switch (spec.mode()) {
    case v1::RENDER_MODE_PT:
      o.mode = RenderMode::kPathTrace;
      break;
    case v1::RENDER_MODE_RP:
      o.mode = RenderMode::kReproject;
      break;
    case v1::RENDER_MODE_SKIP:
      o.mode = RenderMode::kSkip;
      break;
    default:
      return fmt::format("unknown render mode {}", int(spec.mode()));
  }
  const auto& r = spec.reprojection();
  switch (r.method()) {
    case v1::REPROJECTION_METHOD_UNSPECIFIED:
    case v1::REPROJECTION_METHOD_GL:
      o.reproject = ReprojectMethod::kGl;
      break;
    case v1::REPROJECTION_METHOD_CPU:
      o.reproject = ReprojectMethod::kCpu;
      break;
    case v1::REPROJECTION_METHOD_EXACT:
      o.reproject = ReprojectMethod::kExact;
      break;
    default:
      return fmt::format("unknown reprojection method {}", int(r.method()));
  }
  if (r.has_subpixels()) {
    if (r.subpixels() > 64) return "subpixels must be between 1 and 8";
    o.subpixels = int(r.subpixels());
  }
  if (r.has_epsilon_fraction()) o.epsilon = r.epsilon_fraction();
  if (r.has_min_paths()) {
    if (r.min_paths() > kMax) return "min_paths is absurdly large";
    o.min_paths = int(r.min_paths());
  }
  o.path_budget = r.path_budget();  // unset: false
  // Unset is 1 whatever RenderOptions' default: a job or checkpoint written before the field existed
  // renders and resumes as it began.
  o.reprojected_weight = r.has_reprojected_weight() ? r.reprojected_weight() : 1.f;
  if (r.has_combine()) {
    if (r.combine() < 0 || r.combine() > v1::COMBINE_RULE_VARIANCE) return "unknown combine rule";
    o.combine = r.combine() == v1::COMBINE_RULE_VARIANCE ? CombineRule::kVariance : CombineRule::kFixed;
  } else {
    o.combine = CombineRule::kFixed;  // as before the field existed
  }
  if (r.has_reproject_glossy()) o.reproject_glossy = r.reproject_glossy();
  if (r.has_joint_test()) o.joint_test = r.joint_test();
  if (spec.has_russian_roulette()) {
    const auto& rr = spec.russian_roulette();
    if (!v1::RussianRouletteMode_IsValid(rr.mode())) return "unknown Russian roulette mode";
    o.rr = from_proto(rr);
    if (!std::isfinite(o.rr.termination) || o.rr.termination < 0 || o.rr.termination >= 1)
      return "Russian roulette termination probability must be in [0, 1)";
  }
  o.seed = spec.seed();
  if (spec.has_tile_size()) o.tile_size = int(spec.tile_size());
  if (spec.has_round_growth()) o.round_growth = spec.round_growth();
  if (spec.has_mis()) o.mis = spec.mis();
  if (auto sampler = from_proto(spec.sampler()))
    o.sampler = *sampler;
  else
    return fmt::format("unknown sampler {}", int(spec.sampler()));
  if (spec.has_taper_tiles()) o.taper_tiles = spec.taper_tiles();
  if (auto err = from_proto(spec.has_environment() ? &spec.environment() : nullptr,
                            spec.has_sun() ? &spec.sun() : nullptr, &o.lighting))
    return err;
  if (spec.has_time_budget_seconds() && !(spec.time_budget_seconds() > 0 && std::isfinite(spec.time_budget_seconds())))
    return "time budget must be a positive number of seconds";
  if (auto err = o.validate()) return err;
  if (spec.has_camera()) {
    const CameraSpec c = from_proto(spec.camera());
    if (auto err = c.validate()) return *err;
    *camera = c;
  }
  *out = o;
  return std::nullopt;
}

void to_render_settings(const RenderOptions& o, const CameraSpec& camera, const Bounds3& codec_bounds,
                        v1::RenderSettings* out) {
  to_proto(camera, out->mutable_camera());
  out->set_width(uint32_t(o.width));
  out->set_height(uint32_t(o.height));
  out->set_mode(to_proto_mode(o.mode));
  to_proto_reprojection(o, out->mutable_reprojection());
  to_proto(o.rr, out->mutable_russian_roulette());
  to_proto(codec_bounds, out->mutable_codec_bounds());
  out->set_mis(o.mis);
  out->set_sampler(to_proto(o.sampler));
  to_proto(o.lighting, o.lighting.environment ? out->mutable_environment() : nullptr,
           o.lighting.sun ? out->mutable_sun() : nullptr);
}

SceneBundleData from_proto(const v1::SceneFiles& files) {
  SceneBundleData b;
  b.entry_path = files.entry_path();
  for (const auto& f : files.files()) b.files.emplace_back(f.path(), f.data());
  return b;
}

void to_proto(const SceneBundleData& b, v1::SceneBundle* out) {
  if (!b.builtin.empty()) {
    out->set_builtin(b.builtin);
  } else {
    auto* files = out->mutable_files();
    files->set_entry_path(b.entry_path);
    for (const auto& [path, data] : b.files) {
      auto* f = files->add_files();
      f->set_path(path);
      f->set_data(data);
    }
  }
  out->set_content_hash(content_hash(b));
}

namespace {
constexpr std::pair<ResultKind, v1::ResultKind> kResultKinds[] = {
    {ResultKind::kExr, v1::RESULT_KIND_EXR},
    {ResultKind::kPng, v1::RESULT_KIND_PNG},
    {ResultKind::kJson, v1::RESULT_KIND_JSON},
    {ResultKind::kPathtrace, v1::RESULT_KIND_PATH_TRACED_EXR},
    {ResultKind::kReprojection, v1::RESULT_KIND_REPROJECTED_EXR},
    {ResultKind::kCounts, v1::RESULT_KIND_COUNTS_EXR},
    {ResultKind::kSamplesExr, v1::RESULT_KIND_SAMPLES_EXR},
    {ResultKind::kSamplesPng, v1::RESULT_KIND_STATS_IMAGE},
};
}  // namespace

std::optional<ResultKind> from_proto(v1::ResultKind kind) {
  for (const auto& [ours, wire] : kResultKinds)
    if (wire == kind) return ours;
  return std::nullopt;
}

v1::ResultKind to_proto(ResultKind kind) {
  for (const auto& [ours, wire] : kResultKinds)
    if (ours == kind) return wire;
  return v1::RESULT_KIND_UNSPECIFIED;
}

}  // namespace epr
