// One master per state directory: an exclusive lock (flock) on STATE_DIR/lock, held for the life of
// the object, with the holder's pid written in the file for the message a second master gets. The
// kernel drops the lock when the process ends however it ends, so a killed master never leaves a
// stale lock behind; the file itself stays (it is only ever locked, never trusted by its content).
#pragma once

#include <optional>
#include <stdexcept>
#include <string>

namespace epr {

/// Another process holds the state directory's lock.
class StateDirLocked : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

class StateDirLock {
 public:
  /// Creates `dir` if needed and locks it. Throws StateDirLocked when another process holds the
  /// lock, std::runtime_error naming the file when it cannot be created or locked.
  explicit StateDirLock(const std::string& dir);
  ~StateDirLock();
  StateDirLock(const StateDirLock&) = delete;
  StateDirLock& operator=(const StateDirLock&) = delete;

  const std::string& path() const { return path_; }  // the lock file

  /// When some process holds `dir`'s lock: the pid written in its lock file (0 if none is written).
  /// nullopt when the lock is free or there is no lock file. Does not keep the lock.
  static std::optional<long> holder(const std::string& dir);

 private:
  std::string path_;
  int fd_ = -1;
};

}  // namespace epr
