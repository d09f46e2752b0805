#include "master/server/state_dir_lock.h"

#include <fcntl.h>
#include <fmt/format.h>
#include <sys/file.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <stdexcept>

namespace epr {
namespace fs = std::filesystem;
namespace {

constexpr const char* kLockFile = "lock";

// The pid in an open lock file ("" or garbage: nullopt).
std::optional<long> read_pid(int fd) {
  char buf[32] = {};
  const ssize_t n = ::pread(fd, buf, sizeof buf - 1, 0);
  if (n <= 0) return std::nullopt;
  char* end = nullptr;
  const long pid = std::strtol(buf, &end, 10);
  return pid > 0 && end != buf ? std::optional<long>(pid) : std::nullopt;
}

}  // namespace

StateDirLock::StateDirLock(const std::string& dir) : path_((fs::path(dir) / kLockFile).string()) {
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) throw std::runtime_error(fmt::format("cannot create the state directory {}: {}", dir, ec.message()));
  fd_ = ::open(path_.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd_ < 0) throw std::runtime_error(fmt::format("cannot open the lock file {}: {}", path_, std::strerror(errno)));
  if (::flock(fd_, LOCK_EX | LOCK_NB) != 0) {
    const int err = errno;
    const std::optional<long> pid = read_pid(fd_);
    ::close(fd_);
    fd_ = -1;
    if (err == EWOULDBLOCK)
      throw StateDirLocked(fmt::format("the state directory {} is in use by another master{} (lock file {})", dir,
                                       pid ? fmt::format(", pid {}", *pid) : "", path_));
    throw std::runtime_error(fmt::format("cannot lock {}: {}", path_, std::strerror(err)));
  }
  const std::string pid = fmt::format("{}\n", ::getpid());
  if (::ftruncate(fd_, 0) != 0 || ::pwrite(fd_, pid.data(), pid.size(), 0) != ssize_t(pid.size())) {
    // The lock holds without the pid; only the message of a second master is poorer.
  }
}

StateDirLock::~StateDirLock() {
  if (fd_ >= 0) ::close(fd_);  // releases the lock
}

std::optional<long> StateDirLock::holder(const std::string& dir) {
  const std::string path = (fs::path(dir) / kLockFile).string();
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return std::nullopt;
  std::optional<long> pid;
  if (::flock(fd, LOCK_SH | LOCK_NB) != 0)
    pid = read_pid(fd).value_or(0);
  else
    ::flock(fd, LOCK_UN);
  ::close(fd);
  return pid;
}

}  // namespace epr
