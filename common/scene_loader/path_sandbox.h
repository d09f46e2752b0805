// The scene folder as a sandbox: files named by a scene (mtllib, map_Kd, the JSON's "obj") are
// resolved against the naming file's folder and must stay inside the scene's root folder, also
// through symlinks; absolute paths are refused. Files are read whole, with a size limit, and only
// if they are regular files: FIFOs, devices, sockets and directories are refused without blocking.
#pragma once

#include <cstddef>
#include <filesystem>
#include <optional>
#include <string>

#include "common/scene_error.h"  // FileRef, LoadReport

namespace epr::loader {

/// Why `p` cannot be read as a scene file of at most max_bytes ("does not exist", "is a directory",
/// "is a FIFO (named pipe), not a regular file", "has N bytes, over the limit of M"), or nullopt.
/// Never blocks, and never opens what is not a regular file.
std::optional<std::string> file_problem(const std::filesystem::path& p, size_t max_bytes);

/// Whole file, checked as file_problem() does before anything is read; failures name f.display.
/// With `report`, adds f to report->files.
std::string read_file(const FileRef& f, size_t max_bytes, LoadReport* report = nullptr);

/// Adds `f` to report->files unless it is there.
void record_file(const FileRef& f, LoadReport* report);

/// The canonical form of `p` (symlinks resolved as far as the path exists); failures (also a NUL byte
/// in the path) name `display`.
std::filesystem::path canonical_or_fail(const std::filesystem::path& p, const std::string& display);

/// Resolves `name`, written in `file` at `line`, relative to `dir` (whose display form is
/// `display_dir`), and checks that it stays inside `root` after resolving symlinks. `what` names the
/// kind of file in messages ("mtllib", "texture", "obj").
FileRef resolve_inside(const std::filesystem::path& root, const std::filesystem::path& dir,
                       const std::string& display_dir, const std::string& name, const std::string& file, size_t line,
                       const char* what);

}  // namespace epr::loader
