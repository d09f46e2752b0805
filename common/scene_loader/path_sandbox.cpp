// Reading files and resolving the names a scene gives them inside its folder (path_sandbox.h).
#include "common/scene_loader/path_sandbox.h"

#include <fmt/format.h>

#include <fstream>
#include <system_error>

#include "common/scene_loader/text.h"

namespace epr::loader {
namespace {

namespace fs = std::filesystem;

bool is_inside(const fs::path& root, const fs::path& p) {
  auto r = root.begin(), q = p.begin();
  for (; r != root.end(); ++r, ++q) {
    if (r->empty()) continue;  // trailing separator of the root
    if (q == p.end() || *r != *q) return false;
  }
  return true;
}

}  // namespace

std::string read_file(const FileRef& f, size_t max_bytes) {
  std::error_code ec;
  const auto status = fs::status(f.real, ec);
  if (ec || !fs::exists(status)) fail_file(f.display, "cannot open: no such file");
  if (!fs::is_regular_file(status)) fail_file(f.display, "cannot open: not a regular file");
  const auto size = fs::file_size(f.real, ec);
  if (ec) fail_file(f.display, "cannot read its size: " + ec.message());
  if (size > max_bytes) fail_file(f.display, fmt::format("file has {} bytes, over the limit of {}", size, max_bytes));
  std::ifstream in(f.real, std::ios::binary);
  if (!in) fail_file(f.display, "cannot open for reading");
  std::string text(size_t(size), '\0');
  in.read(text.data(), std::streamsize(size));
  text.resize(size_t(in.gcount()));
  return text;
}

fs::path canonical_or_fail(const fs::path& p, const std::string& display) {
  std::error_code ec;
  fs::path c = fs::weakly_canonical(fs::absolute(p, ec), ec);
  if (ec) fail_file(display, "cannot resolve path: " + ec.message());
  return c;
}

FileRef resolve_inside(const fs::path& root, const fs::path& dir, const std::string& display_dir,
                       const std::string& name, const std::string& file, size_t line, const char* what) {
  if (name.empty()) fail(file, line, fmt::format("empty {} path", what));
  if (name.find('\0') != std::string::npos) fail(file, line, fmt::format("{} path contains a NUL byte", what));
  const fs::path rel(name);
  if (rel.is_absolute() || rel.has_root_directory() || rel.has_root_name())
    fail(file, line,
         fmt::format("{} '{}' is an absolute path; scene files must name files inside the scene folder", what, name));
  std::error_code ec;
  const fs::path real = fs::weakly_canonical(dir / rel, ec);
  if (ec) fail(file, line, fmt::format("cannot resolve {} '{}': {}", what, name, ec.message()));
  if (!is_inside(root, real)) fail(file, line, fmt::format("{} '{}' leaves the scene folder", what, name));
  const std::string display = display_dir.empty() ? name : (fs::path(display_dir) / rel).lexically_normal().string();
  return {real, display};
}

}  // namespace epr::loader
