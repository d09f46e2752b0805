// Loading scenes from files: Wavefront OBJ + MTL (+ Kd textures), the scene JSON format described in
// scenes/README.md, and the named built-in scenes (common/builtin_scenes.h).
//
// Every loader treats its input as untrusted (jobs arrive over the network and the loader is fuzzed):
// bad input raises SceneError, never a crash. Error messages have the form
//
//     path/to/file.obj:12: reason      (a problem on a line of a text file)
//     path/to/file.obj: reason         (a problem with the whole file: missing, too large, no faces)
//
// Files named by a scene (mtllib, map_Kd, the JSON's "obj") must stay inside the scene's folder:
// absolute paths and paths that leave the folder, also through symlinks, are rejected.
#pragma once

#include <string>

#include "common/scene.h"
#include "common/scene_error.h"  // SceneError, LoadOptions

namespace epr {

/// spec is: an OBJ path; a scene JSON path (*.json); or "builtin:NAME" / "builtin:NAME?tess=N" (see
/// builtin_scenes.h for the parameters).
Scene load_scene(const std::string& spec, const LoadOptions& = {});

/// An OBJ file with its MTL files and Kd textures. Materials are Lambertian (Kd or map_Kd, Ke for
/// emitters); faces without a material get a grey default (kd 0.8). The camera is CameraSpec's
/// default (the Cornell box's conventional camera): OBJ files carry none. Zero-area triangles are
/// dropped with a warning that names the line of the first; an OBJ with nothing else is an error.
Scene load_obj(const std::string& obj_path, const LoadOptions& = {});

/// A scene JSON file: an OBJ or a built-in scene plus camera and material overrides.
Scene load_scene_json(const std::string& json_path, const LoadOptions& = {});

}  // namespace epr
