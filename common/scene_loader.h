// Loading scenes from files: Wavefront OBJ + MTL (+ Kd textures), glTF 2.0, the scene JSON format described in
// scenes/README.md, and the named built-in scenes (common/builtin_scenes.h).
//
// Every loader treats its input as untrusted (jobs arrive over the network and the loader is fuzzed):
// bad input raises SceneError, never a crash. Error messages have the form
//
//     path/to/file.obj:12: reason      (a problem on a line of a text file)
//     path/to/file.obj: reason         (a problem with the whole file: missing, too large, no faces)
//
// Files named by a scene (mtllib, map_Kd, the JSON's "obj") must stay inside the scene's folder:
// absolute paths and paths that leave the folder, also through symlinks, are rejected. Every file
// must be a regular file within LoadOptions::max_file_bytes, checked before it is read: FIFOs,
// devices, sockets and directories are refused (without blocking), as are paths with a NUL byte.
//
// Warnings (ignored statements, dropped triangles, clamped colours...) go to the LoadReport, naming
// the files as the user wrote them; the loader itself logs them at debug level only, so that the
// master and the workers, which load a job's scene again from their caches, stay quiet about them.
// load_job_scene() is the load a user sees: it shows them, once.
#pragma once

#include <optional>
#include <string>

#include "common/scene.h"
#include "common/scene_error.h"  // SceneError, LoadOptions

namespace epr {

/// spec is: an OBJ path; a glTF path (*.gltf, *.glb); a scene JSON path (*.json); or "builtin:NAME" /
/// "builtin:NAME?tess=N" (see builtin_scenes.h for the parameters).
Scene load_scene(const std::string& spec, const LoadOptions& = {}, LoadReport* = nullptr);

/// An OBJ file with its MTL files and Kd textures. Materials are Lambertian (Kd or map_Kd, Ke for
/// emitters); faces without a material get a grey default (kd 0.8). The camera is CameraSpec's
/// default (the Cornell box's conventional camera): OBJ files carry none. Zero-area triangles are
/// dropped with a warning that names the line of the first; an OBJ with nothing else is an error.
Scene load_obj(const std::string& obj_path, const LoadOptions& = {}, LoadReport* = nullptr);

/// A glTF 2.0 file (.gltf with its buffers and images, or .glb): the default scene's node tree as
/// world-space triangles, metallic-roughness materials mapped onto the scene's materials (scenes/
/// README.md, "glTF 2.0"; each approximation a warning naming the file and the material) and the
/// first camera node's perspective camera (else CameraSpec's default).
Scene load_gltf(const std::string& gltf_path, const LoadOptions& = {}, LoadReport* = nullptr);

/// A scene JSON file: an OBJ or a built-in scene plus camera and material overrides.
Scene load_scene_json(const std::string& json_path, const LoadOptions& = {}, LoadReport* = nullptr);

/// load_scene for a render the user asked for: applies the job's lighting (job_lighting), logs the
/// warnings (at warn level, once) and refuses a scene without light (unlit_reason) with SceneError.
/// `env_folder`: as for job_lighting. With `job_lit`, the scene keeps its own lighting and the job's
/// goes there instead.
Scene load_job_scene(const std::string& spec, const LoadOptions& = {}, LoadReport* = nullptr, const Lighting& job = {},
                     const std::string& env_folder = "", Lighting* job_lit = nullptr);

/// How many times this process has loaded a scene from files (load_scene of anything but a built-in):
/// each load parses the files and decodes the textures.
uint64_t scene_file_loads();
/// How many times it has checked one (load_scene with LoadOptions::decode_textures false): parsed the
/// files and read the textures' headers, not their texels.
uint64_t scene_file_checks();

/// The lighting a job renders `scene` with: the job's environment and sun where it sets them, else the
/// scene's. An environment image the job names is read inside scene.folder, or inside `env_folder`
/// for a scene without one (a built-in scene, on the client's side: RenderOptions::env_folder), and
/// recorded in `report`; failures raise SceneError naming `--env`.
Lighting job_lighting(const Scene& scene, const Lighting& job, LoadReport* report = nullptr,
                      const std::string& env_folder = "");

/// Nullopt if some triangle emits light (its material has a Ke other than 0 0 0) or the environment or
/// the sun gives light; else why the image would be black and how to light the scene, naming scene.name.
std::optional<std::string> unlit_reason(const Scene& scene);
/// The same with `lighting` in place of the scene's.
std::optional<std::string> unlit_reason(const Scene& scene, const Lighting& lighting);

/// The bytes of a scene file, read as the loader reads them: a regular file of at most max_bytes,
/// checked before anything is read; failures raise SceneError naming f.display.
std::string read_scene_file(const FileRef& f, size_t max_bytes);

}  // namespace epr
