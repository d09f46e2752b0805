// Environment images read for a scene (common/lighting.h): inside the scene's folder, as the path
// sandbox reads every file a scene names.
#pragma once

#include <string>

#include "common/lighting.h"
#include "common/scene_error.h"

namespace epr::loader {

/// Decodes e.image, resolved inside `folder` (the scene's folder), into e.pixels: checked against the
/// texture size limit; negative texel values read as 0 and values above limits::kMaxColour (+inf
/// included) capped, each kind a warning with its count; a NaN texel is refused. Throws SceneError naming `where` (e.g.
/// "scene.json:4" or "--env") and the file; a built-in scene (empty folder) is refused with how to
/// name the image instead. With `report`, records the file (so that it is bundled with the scene).
void load_environment_image(EnvironmentLight& e, const std::string& folder, const std::string& where,
                            LoadReport* report = nullptr);

}  // namespace epr::loader
