// Invariant checks and the thread-safety annotations clang checks (-Wthread-safety).
//
// EPR_CHECK(cond): a broken invariant of the program (never bad input: that gets an error with a
// reason). Always on, also in release builds; aborts naming the condition and the place.
// Mutex / MutexLock: std::mutex and its scoped lock, annotated so that clang checks that fields
// marked EPR_GUARDED_BY(mu) are only touched with `mu` held and functions marked EPR_REQUIRES(mu)
// are only called with it held. GCC ignores the annotations.
#pragma once

#include <cstdio>
#include <cstdlib>
#include <mutex>

#if defined(__clang__)
#define EPR_THREAD_ANNOTATION(x) __attribute__((x))
#else
#define EPR_THREAD_ANNOTATION(x)
#endif
#define EPR_CAPABILITY(x) EPR_THREAD_ANNOTATION(capability(x))
#define EPR_SCOPED_CAPABILITY EPR_THREAD_ANNOTATION(scoped_lockable)
#define EPR_GUARDED_BY(x) EPR_THREAD_ANNOTATION(guarded_by(x))
#define EPR_PT_GUARDED_BY(x) EPR_THREAD_ANNOTATION(pt_guarded_by(x))
#define EPR_REQUIRES(...) EPR_THREAD_ANNOTATION(requires_capability(__VA_ARGS__))
#define EPR_EXCLUDES(...) EPR_THREAD_ANNOTATION(locks_excluded(__VA_ARGS__))
#define EPR_ACQUIRE(...) EPR_THREAD_ANNOTATION(acquire_capability(__VA_ARGS__))
#define EPR_RELEASE(...) EPR_THREAD_ANNOTATION(release_capability(__VA_ARGS__))
#define EPR_NO_THREAD_SAFETY_ANALYSIS EPR_THREAD_ANNOTATION(no_thread_safety_analysis)

#define EPR_CHECK(cond)                                                                 \
  do {                                                                                  \
    if (!(cond)) {                                                                      \
      std::fprintf(stderr, "%s:%d: invariant broken: %s\n", __FILE__, __LINE__, #cond); \
      std::abort();                                                                     \
    }                                                                                   \
  } while (0)

namespace epr {

class EPR_CAPABILITY("mutex") Mutex {
 public:
  void lock() EPR_ACQUIRE() { mu_.lock(); }
  void unlock() EPR_RELEASE() { mu_.unlock(); }

 private:
  std::mutex mu_;
};

/// Holds a Mutex for its scope; unlock()/lock() let a condition_variable_any wait on it.
class EPR_SCOPED_CAPABILITY MutexLock {
 public:
  explicit MutexLock(Mutex& mu) EPR_ACQUIRE(mu) : mu_(mu) { mu_.lock(); }
  ~MutexLock() EPR_RELEASE() {
    if (held_) mu_.unlock();
  }
  MutexLock(const MutexLock&) = delete;
  MutexLock& operator=(const MutexLock&) = delete;
  void lock() EPR_ACQUIRE() {
    mu_.lock();
    held_ = true;
  }
  void unlock() EPR_RELEASE() {
    held_ = false;
    mu_.unlock();
  }

 private:
  Mutex& mu_;
  bool held_ = true;
};

}  // namespace epr
