// The OBJ reader as the scene JSON reader and load_obj use it: an OBJ file, with the MTL files and
// textures it names, loaded inside a scene folder.
#pragma once

#include <filesystem>
#include <vector>

#include "common/scene.h"
#include "common/scene_error.h"
#include "common/scene_loader/path_sandbox.h"

namespace epr::loader {

/// MTL values that the Lambertian model ignores but a JSON "glossy" override starts from.
struct GlossyDefaults {
  Vec3 ks{0.f};
  float exponent = Material{}.exponent;
};

/// Loads `obj`, reading nothing outside `root`; the files read and the warnings go to `report`. With
/// `glossy`, appends each material's Ks and Ns (index for index with the scene's materials). The
/// scene is not yet validated (Scene::validate).
Scene load_obj_inside(const FileRef& obj, const std::filesystem::path& root, const LoadOptions& opts,
                      LoadReport& report, std::vector<GlossyDefaults>* glossy);

}  // namespace epr::loader
