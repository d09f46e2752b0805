// A file written whole or not at all as far as the caller can tell: every write's failure is kept
// with its errno, and finish() fsyncs and closes, throwing std::system_error that names the file and
// the errno ("cannot write 'x.exr': No space left on device"). Result files are written this way to
// a temporary name and renamed into place only when finish() succeeded (master/result_files.cpp).
#pragma once

#include <atomic>
#include <cstdint>
#include <string>
#include <string_view>

namespace epr {

class CheckedFile {
 public:
  /// Creates (or truncates) `path`; a failure is kept and thrown by finish().
  explicit CheckedFile(std::string path);
  ~CheckedFile();
  CheckedFile(const CheckedFile&) = delete;
  CheckedFile& operator=(const CheckedFile&) = delete;

  /// Writes `size` bytes at `offset`; returns how many were written (all, unless it failed). Safe
  /// to call from several threads at once.
  size_t pwrite(const void* data, size_t size, uint64_t offset);
  /// One past the furthest byte written.
  uint64_t size() const { return size_.load(); }
  /// The errno of the first failure, 0 if none.
  int error() const { return errno_.load(); }
  /// Fsyncs and closes the file; throws std::system_error naming the file and the errno of the
  /// first failure (of a write, the fsync or the close).
  void finish();
  const std::string& path() const { return path_; }

 private:
  void fail(int e);

  std::string path_;
  int fd_ = -1;
  std::atomic<uint64_t> size_{0};
  std::atomic<int> errno_{0};
  const char* failed_at_ = "create";
};

/// Writes `bytes` to `path` with a CheckedFile (fsynced; throws naming the errno).
void write_file_checked(const std::string& path, std::string_view bytes);

}  // namespace epr
