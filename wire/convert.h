// Translation between the wire contract (epr.v1) and domain types. Service classes call these and
// nothing else touches generated proto types, so the domain code never depends on the wire.
#pragma once

#include <optional>
#include <string>

#include "common/job_state.h"
#include "common/render_options.h"
#include "common/result_kinds.h"
#include "epr/v1/job_service.pb.h"
#include "epr/v1/worker_service.pb.h"
#include "wire/scene_bundle.h"

namespace epr {

Vec3 from_proto(const v1::Vec3& v);
void to_proto(const Vec3& v, v1::Vec3* out);
CameraSpec from_proto(const v1::Camera& c);
void to_proto(const CameraSpec& c, v1::Camera* out);
Bounds3 from_proto(const v1::Bounds3& b);
void to_proto(const Bounds3& b, v1::Bounds3* out);
RussianRoulette from_proto(const v1::RussianRouletteSettings& rr);
/// Nullopt for RESULT_KIND_UNSPECIFIED and kinds this build does not know.
std::optional<ResultKind> from_proto(v1::ResultKind kind);
v1::ResultKind to_proto(ResultKind kind);
void to_proto(const RussianRoulette& rr, v1::RussianRouletteSettings* out);
/// The sampler a field names: UNSPECIFIED is INDEPENDENT (jobs, checkpoints and masters from before the
/// field existed); nullopt for a value this build does not know.
std::optional<SamplerKind> from_proto(v1::Sampler s);
v1::Sampler to_proto(SamplerKind s);
/// A job's state on the wire and back: nullopt for JOB_STATE_UNSPECIFIED and values this build does not know.
v1::JobState to_proto(JobState s);
std::optional<JobState> from_proto(v1::JobState s);

/// A JobSpec for `opts` with the scene carried as `bundle`. Camera overrides are applied to
/// `scene_camera` (the camera of the loaded scene) so the job names its camera explicitly.
v1::JobSpec to_job_spec(const RenderOptions& opts, const SceneBundleData& bundle, const CameraSpec& scene_camera);

/// RenderOptions from a JobSpec (defaults for unset fields); the scene is left to the caller.
/// Returns the reason if the spec is not usable (the INVALID_ARGUMENT message).
std::optional<std::string> from_job_spec(const v1::JobSpec& spec, RenderOptions* out, CameraSpec* camera);

/// The RenderSettings a worker needs for a job.
void to_render_settings(const RenderOptions& opts, const CameraSpec& camera, const Bounds3& codec_bounds,
                        v1::RenderSettings* out);

/// The job's lighting on the wire (JobSpec / RenderSettings environment and sun; unset: none) and back.
/// from_proto checks the values (the reason if unusable); an image is a safe relative path.
std::optional<std::string> from_proto(const v1::EnvironmentLight* env, const v1::SunLight* sun, Lighting* out);
void to_proto(const Lighting& l, v1::EnvironmentLight* env, v1::SunLight* sun);

SceneBundleData from_proto(const v1::SceneFiles& files);
void to_proto(const SceneBundleData& b, v1::SceneBundle* out);

}  // namespace epr
