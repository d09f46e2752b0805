#include "common/checked_file.h"

#include <fcntl.h>
#include <fmt/format.h>
#include <unistd.h>

#include <cerrno>
#include <system_error>

namespace epr {

CheckedFile::CheckedFile(std::string path) : path_(std::move(path)) {
  fd_ = ::open(path_.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd_ < 0)
    fail(errno);
  else
    failed_at_ = "write";
}

CheckedFile::~CheckedFile() {
  if (fd_ >= 0) ::close(fd_);
}

void CheckedFile::fail(int e) {
  int none = 0;
  errno_.compare_exchange_strong(none, e != 0 ? e : EIO);
}

size_t CheckedFile::pwrite(const void* data, size_t size, uint64_t offset) {
  if (fd_ < 0 || errno_.load() != 0) return 0;
  const char* p = static_cast<const char*>(data);
  size_t done = 0;
  while (done < size) {
    const ssize_t n = ::pwrite(fd_, p + done, size - done, off_t(offset + done));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      fail(n < 0 ? errno : ENOSPC);  // a write of 0 bytes: nothing fits
      break;
    }
    done += size_t(n);
  }
  uint64_t end = offset + done, seen = size_.load();
  while (end > seen && !size_.compare_exchange_weak(seen, end)) {
  }
  return done;
}

void CheckedFile::finish() {
  const char* what = errno_.load() != 0 ? failed_at_ : nullptr;
  if (fd_ >= 0) {
    if (!what && ::fsync(fd_) != 0 && errno != EINVAL) {  // EINVAL: a file that cannot sync (a pipe)
      fail(errno);
      what = "fsync";
    }
    if (::close(fd_) != 0 && !what) {
      fail(errno);
      what = "close";
    }
    fd_ = -1;
  }
  if (what) throw std::system_error(errno_.load(), std::generic_category(), fmt::format("cannot {} '{}'", what, path_));
}

void write_file_checked(const std::string& path, std::string_view bytes) {
  CheckedFile file(path);
  file.pwrite(bytes.data(), bytes.size(), 0);
  file.finish();
}

}  // namespace epr
