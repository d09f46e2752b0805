// What every source of scenes shares: the error bad scene input raises and the limits against giant
// input. Included by the file loader (common/scene_loader.h) and the built-in scenes
// (common/builtin_scenes.h), neither of which includes the other's header.
#pragma once

#include <cstddef>
#include <stdexcept>

namespace epr {

/// Raised for bad scene input: message names the file and line ("path/to/x.obj:12: reason").
struct SceneError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

/// Limits against hostile or accidental giant inputs. Each file (OBJ, MTL, texture) is checked
/// against max_file_bytes on its own (scene JSON files against at most 16 MiB).
struct LoadOptions {
  size_t max_triangles = 10'000'000;
  size_t max_file_bytes = 1ull << 30;
  size_t max_texture_pixels = 1ull << 26;  // all textures of a scene together: 64 Mpixel, ~800 MB as float RGB
};

}  // namespace epr
