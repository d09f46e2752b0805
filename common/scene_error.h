// What every source of scenes shares: the error bad scene input raises, the limits against giant
// input and what a load reports besides the scene. Included by the file loader
// (common/scene_loader.h) and the built-in scenes (common/builtin_scenes.h), neither of which
// includes the other's header.
#pragma once

#include <cstddef>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <vector>

namespace epr {

/// Raised for bad scene input: message names the file and line ("path/to/x.obj:12: reason").
struct SceneError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

/// Limits against hostile or accidental giant inputs. Each file (OBJ, MTL, texture) is checked
/// against max_file_bytes on its own, before it is read (scene JSON files against at most 16 MiB).
struct LoadOptions {
  size_t max_triangles = 10'000'000;
  size_t max_file_bytes = 1ull << 30;
  size_t max_texture_pixels = 1ull << 26;  // all textures of a scene together: 64 Mpixel, ~800 MB as float RGB
  // False: texture files are checked (file, header, limits) but not decoded, except where the load
  // itself needs their texels (scene_loader.h, load_scene: a scene to check, not to render).
  bool decode_textures = true;
};

/// A file of a scene: where it is read from and how messages name it.
struct FileRef {
  std::filesystem::path real;  // canonical path that is opened
  std::string display;         // path as the user wrote it (joined to the referring file's folder)
};

/// What loading a scene found besides the scene.
struct LoadReport {
  /// "file:line: text" (or "file: text"), files named as the user wrote them (FileRef::display).
  /// The loader logs them at debug level only: whoever shows them to the user does it once.
  std::vector<std::string> warnings;
  /// Every file the load read, each once, the entry file (OBJ or scene JSON) first.
  std::vector<FileRef> files;
};

}  // namespace epr
