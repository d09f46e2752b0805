// Reading files and resolving the names a scene gives them inside its folder (path_sandbox.h).
#include "common/scene_loader/path_sandbox.h"

#include <fcntl.h>
#include <fmt/format.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
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

std::string errno_text(int e) { return std::error_code(e, std::generic_category()).message(); }

std::string kind_problem(mode_t mode) {
  if (S_ISDIR(mode)) return "is a directory";
  if (S_ISFIFO(mode)) return "is a FIFO (named pipe), not a regular file";
  if (S_ISCHR(mode)) return "is a character device, not a regular file";
  if (S_ISBLK(mode)) return "is a block device, not a regular file";
  if (S_ISSOCK(mode)) return "is a socket, not a regular file";
  return "is not a regular file";
}

/// An open file descriptor, closed with it.
struct Fd {
  int fd = -1;
  Fd() = default;
  Fd(const Fd&) = delete;
  Fd& operator=(const Fd&) = delete;
  ~Fd() {
    if (fd >= 0) ::close(fd);
  }
};

/// Opens `p` if it is a regular file of at most max_bytes (its size in *size), else the problem. The
/// type is checked with stat() before the open, so nothing else is opened, and again with fstat() on
/// what was opened (O_NONBLOCK: a FIFO put in its place meanwhile cannot block the open).
std::optional<std::string> open_regular(const fs::path& p, size_t max_bytes, Fd* fd, size_t* size) {
  const std::string& name = p.native();
  if (name.find('\0') != std::string::npos) return "the path contains a NUL byte";
  struct stat st {};
  if (::stat(name.c_str(), &st) != 0)
    return errno == ENOENT || errno == ENOTDIR ? std::string("does not exist") : "cannot open: " + errno_text(errno);
  if (!S_ISREG(st.st_mode)) return kind_problem(st.st_mode);
  fd->fd = ::open(name.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC | O_NOCTTY);
  if (fd->fd < 0) return "cannot open: " + errno_text(errno);
  if (::fstat(fd->fd, &st) != 0) return "cannot read its size: " + errno_text(errno);
  if (!S_ISREG(st.st_mode)) return kind_problem(st.st_mode);
  if (uint64_t(st.st_size) > max_bytes) return fmt::format("has {} bytes, over the limit of {}", st.st_size, max_bytes);
  *size = size_t(st.st_size);
  return std::nullopt;
}

/// `s` for a message: control characters (a NUL byte among them) as '?'.
std::string printable(std::string s) {
  std::replace_if(
      s.begin(), s.end(), [](char c) { return static_cast<unsigned char>(c) < 0x20 || c == 0x7f; }, '?');
  return s;
}

}  // namespace

std::optional<std::string> file_problem(const fs::path& p, size_t max_bytes) {
  Fd fd;
  size_t size = 0;
  return open_regular(p, max_bytes, &fd, &size);
}

std::string read_file(const FileRef& f, size_t max_bytes, LoadReport* report) {
  Fd fd;
  size_t size = 0;
  if (auto problem = open_regular(f.real, max_bytes, &fd, &size)) fail_file(printable(f.display), *problem);
  // Never more than the size checked: a file that grows meanwhile is read up to it.
  std::string text(size, '\0');
  size_t got = 0;
  while (got < size) {
    const ssize_t n = ::read(fd.fd, text.data() + got, size - got);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) fail_file(f.display, "cannot read: " + errno_text(errno));
    if (n == 0) break;
    got += size_t(n);
  }
  text.resize(got);
  record_file(f, report);
  return text;
}

void record_file(const FileRef& f, LoadReport* report) {
  if (!report) return;
  const auto same = [&](const FileRef& r) { return r.real == f.real; };
  if (std::none_of(report->files.begin(), report->files.end(), same)) report->files.push_back(f);
}

fs::path canonical_or_fail(const fs::path& p, const std::string& display) {
  if (p.native().find('\0') != std::string::npos) fail_file(printable(display), "the path contains a NUL byte");
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
