// The loader's entry points (scene_loader.h): a spec names a built-in scene, a scene JSON or an OBJ.
// The formats are read in common/scene_loader/: obj.cpp (with polygon.cpp), mtl.cpp, textures.cpp,
// gltf.cpp (with gltf_files.cpp), scene_json.cpp, on top of text.cpp (lines, tokens, numbers, errors) and
// path_sandbox.cpp.
#include "common/scene_loader.h"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <vector>

#include "common/builtin_scenes.h"
#include "common/scene_loader/environment.h"
#include "common/scene_loader/gltf.h"
#include "common/scene_loader/obj.h"
#include "common/scene_loader/path_sandbox.h"
#include "common/scene_loader/text.h"

namespace epr {
namespace {

std::atomic<uint64_t> file_loads{0}, file_checks{0};  // scene_file_loads(), scene_file_checks()

bool ends_with_json(const std::string& s) {
  if (s.size() < 5) return false;
  std::string ext = s.substr(s.size() - 5);
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return ext == ".json";
}

}  // namespace

Scene load_obj(const std::string& obj_path, const LoadOptions& opts, LoadReport* report) {
  LoadReport local;
  const std::filesystem::path real = loader::canonical_or_fail(obj_path, obj_path);
  Scene scene = loader::load_obj_inside({real, obj_path}, real.parent_path(), opts, report ? *report : local, nullptr);
  loader::validate_or_fail(scene, obj_path);
  scene.folder = real.parent_path().string();
  return scene;
}

Scene load_gltf(const std::string& gltf_path, const LoadOptions& opts, LoadReport* report) {
  LoadReport local;
  const std::filesystem::path real = loader::canonical_or_fail(gltf_path, gltf_path);
  Scene scene = loader::load_gltf_inside({real, gltf_path}, real.parent_path(), opts, report ? *report : local);
  loader::validate_or_fail(scene, gltf_path);
  scene.folder = real.parent_path().string();
  return scene;
}

uint64_t scene_file_loads() { return file_loads.load(); }
uint64_t scene_file_checks() { return file_checks.load(); }

Scene load_scene(const std::string& spec, const LoadOptions& opts, LoadReport* report) {
  if (spec.find('\0') != std::string::npos)
    throw SceneError(fmt::format("scene path {} contains a NUL byte", loader::quote_token(spec)));
  if (spec.rfind("builtin:", 0) == 0) return make_builtin_scene(parse_builtin_spec(spec.substr(8)), opts.max_triangles);
  ++(opts.decode_textures ? file_loads : file_checks);
  if (ends_with_json(spec)) return load_scene_json(spec, opts, report);
  if (loader::is_gltf_path(spec)) return load_gltf(spec, opts, report);
  return load_obj(spec, opts, report);
}

Scene load_job_scene(const std::string& spec, const LoadOptions& opts, LoadReport* report, const Lighting& job,
                     const std::string& env_folder, Lighting* job_lit) {
  LoadReport local;
  LoadReport& r = report ? *report : local;
  const size_t first = r.warnings.size();
  Scene scene = load_scene(spec, opts, &r);
  Lighting lit = job_lighting(scene, job, &r, env_folder);
  for (size_t i = first; i < r.warnings.size(); ++i) loader::scene_log()->warn("{}", r.warnings[i]);
  if (auto reason = unlit_reason(scene, lit)) throw SceneError(*reason);
  if (job_lit)
    *job_lit = std::move(lit);
  else
    scene.lighting = std::move(lit);
  return scene;
}

Lighting job_lighting(const Scene& scene, const Lighting& job, LoadReport* report, const std::string& env_folder) {
  Lighting out = scene.lighting;
  if (job.environment) {
    out.environment = job.environment;
    if (!out.environment->image.empty() && !out.environment->pixels)
      loader::load_environment_image(*out.environment, scene.folder.empty() ? env_folder : scene.folder, "--env",
                                     report);
  }
  if (job.sun) out.sun = job.sun;
  return out;
}

std::optional<std::string> unlit_reason(const Scene& scene) { return unlit_reason(scene, scene.lighting); }

std::optional<std::string> unlit_reason(const Scene& scene, const Lighting& lighting) {
  if (lighting.lights()) return std::nullopt;
  for (const PunctualLight& l : scene.lights)
    if (!is_black(l.intensity)) return std::nullopt;
  std::vector<bool> used(scene.materials.size(), false);
  for (uint32_t m : scene.material_of)
    if (m < used.size()) used[m] = true;
  std::vector<std::string> unused_emitters;
  for (size_t m = 0; m < scene.materials.size(); ++m) {
    if (!scene.materials[m].emissive()) continue;
    if (used[m]) return std::nullopt;
    unused_emitters.push_back("'" + scene.materials[m].name + "'");
  }
  const std::string how =
      "light it with a sky or a sun: `--env 1,1,1` (a white sky; or --env sky.hdr, an image beside the scene) or "
      "`--sun 1,2,1` on epr render and epr submit, or \"environment\" / \"sun\" in a scene JSON; or give the "
      "material of the faces that should glow an emission: a line `Ke r g b` (e.g. `Ke 10 10 10`) after its "
      "`newmtl` in the MTL file, or \"ke\": [10, 10, 10] for it under \"materials\" in a scene JSON";
  if (!unused_emitters.empty())
    return fmt::format("{} has no light: no face uses the emitting material{} {}, so the image would be black; {}",
                       scene.name, unused_emitters.size() > 1 ? "s" : "", fmt::join(unused_emitters, ", "), how);
  return fmt::format("{} has no light: no material has an emission (Ke), so the image would be black; {}", scene.name,
                     how);
}

std::string read_scene_file(const FileRef& f, size_t max_bytes) { return loader::read_file(f, max_bytes); }

}  // namespace epr
