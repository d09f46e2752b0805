// The glTF 2.0 reader as load_gltf and the scene JSON reader use it (scenes/README.md, "glTF 2.0").
#pragma once

#include <filesystem>

#include "common/scene.h"
#include "common/scene_error.h"

namespace epr::loader {

/// Loads the .gltf or .glb file `f`, reading nothing outside `root`; the files read and the warnings
/// go to `report`. The scene is not yet validated (Scene::validate).
Scene load_gltf_inside(const FileRef& f, const std::filesystem::path& root, const LoadOptions& opts,
                       LoadReport& report);

/// True if `path` ends in .gltf or .glb (any case).
bool is_gltf_path(const std::string& path);

}  // namespace epr::loader
