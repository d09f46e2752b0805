// The scene folder as a sandbox: files named by a scene (mtllib, map_Kd, the JSON's "obj") are
// resolved against the naming file's folder and must stay inside the scene's root folder, also
// through symlinks; absolute paths are refused. Files are read whole, with a size limit.
#pragma once

#include <cstddef>
#include <filesystem>
#include <string>

namespace epr::loader {

/// Where a file is read from and how messages name it.
struct FileRef {
  std::filesystem::path real;  // canonical path that is opened
  std::string display;         // path as the user wrote it (joined to the referring file's folder)
};

/// Whole file, checked to be a regular file of at most max_bytes; failures name f.display.
std::string read_file(const FileRef& f, size_t max_bytes);

/// The canonical form of `p` (symlinks resolved as far as the path exists); failures name `display`.
std::filesystem::path canonical_or_fail(const std::filesystem::path& p, const std::string& display);

/// Resolves `name`, written in `file` at `line`, relative to `dir` (whose display form is
/// `display_dir`), and checks that it stays inside `root` after resolving symlinks. `what` names the
/// kind of file in messages ("mtllib", "texture", "obj").
FileRef resolve_inside(const std::filesystem::path& root, const std::filesystem::path& dir,
                       const std::string& display_dir, const std::string& name, const std::string& file, size_t line,
                       const char* what);

}  // namespace epr::loader
