// glTF's KHR_lights_punctual (scenes/README.md, "Lamps"): the file's lights checked and converted to
// the scene's radiometric units, and placed by the nodes that refer to them.
#pragma once

#include <array>
#include <string>
#include <vector>

#include "common/lights.h"
#include "common/scene_loader/gltf_files.h"

namespace epr::loader {

/// The model's KHR_lights_punctual lights in light space (at the origin, shining along -Z), intensities
/// converted (see the .cpp). Bad values raise SceneError "file: KHR_lights_punctual.lights[i] ('name'):
/// reason"; `note` receives the approximations (a range ignored), once each.
std::vector<PunctualLight> read_gltf_lights(const tinygltf::Model& model, const std::string& display,
                                            std::vector<std::string>* notes);

/// The light node `n` refers to through its KHR_lights_punctual extension, placed by the node's world
/// transform `world` (column-major), appended to *out; nothing if the node has no light.
void place_gltf_light(const tinygltf::Node& node, int n, const std::array<double, 16>& world,
                      const std::vector<PunctualLight>& lights, const std::string& display,
                      std::vector<PunctualLight>* out);

}  // namespace epr::loader
