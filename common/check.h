// Invariant checks and the thread-safety annotations clang checks (-Wthread-safety).
//
// EPR_CHECK(cond): a broken invariant of the program (never bad input: that gets an error with a
// reason). Always on, also in release builds; aborts naming the condition and the place.
// EPR_CHECK_EQ/NE/LT/LE/GT/GE(a, b): EPR_CHECK(a op b) whose message also gives both operands'
// values (pbrt-v4's util/check.h). EPR_DCHECK and EPR_DCHECK_EQ...: the same in debug builds only;
// with NDEBUG (Release, RelWithDebInfo) their arguments are compiled but never evaluated, so they
// cost nothing on hot paths (pdfs and weights in the path tracer).
// Mutex / MutexLock: std::mutex and its scoped lock, annotated so that clang checks that fields
// marked EPR_GUARDED_BY(mu) are only touched with `mu` held and functions marked EPR_REQUIRES(mu)
// are only called with it held. GCC ignores the annotations.
#pragma once

#include <cstdio>
#include <cstdlib>
#include <limits>
#include <mutex>
#include <sstream>
#include <string>
#include <type_traits>

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

namespace epr::check_detail {

[[noreturn]] inline void fail(const char* file, int line, const char* cond, const std::string& values) {
  std::fprintf(stderr, "%s:%d: invariant broken: %s%s\n", file, line, cond, values.c_str());
  std::abort();
}

/// Writes `v` for a check's message: floats with every digit that tells them apart, one-byte
/// integers as numbers, enums as their underlying value.
template <typename T>
void write_operand(std::ostream& os, const T& v) {
  if constexpr (std::is_enum_v<T>) {
    write_operand(os, static_cast<std::underlying_type_t<T>>(v));
  } else if constexpr (std::is_integral_v<T> && sizeof(T) == 1) {
    os << int(v);
  } else if constexpr (std::is_floating_point_v<T>) {
    os.precision(std::numeric_limits<T>::max_digits10);
    os << v;
  } else {
    os << v;
  }
}

template <typename A, typename B>
[[noreturn]] __attribute__((noinline, cold)) void fail_op(const char* file, int line, const char* cond,
                                                          const char* a_text, const A& a, const char* b_text,
                                                          const B& b) {
  std::ostringstream os;
  os << " (" << a_text << " = ";
  write_operand(os, a);
  os << ", " << b_text << " = ";
  write_operand(os, b);
  os << ")";
  fail(file, line, cond, os.str());
}

}  // namespace epr::check_detail

#define EPR_CHECK(cond)                                                    \
  do {                                                                     \
    if (!(cond)) ::epr::check_detail::fail(__FILE__, __LINE__, #cond, ""); \
  } while (0)

// Each operand is evaluated once.
#define EPR_CHECK_OP(a, op, b)                                                                                 \
  do {                                                                                                         \
    const auto& epr_check_a_ = (a);                                                                            \
    const auto& epr_check_b_ = (b);                                                                            \
    if (!(epr_check_a_ op epr_check_b_))                                                                       \
      ::epr::check_detail::fail_op(__FILE__, __LINE__, #a " " #op " " #b, #a, epr_check_a_, #b, epr_check_b_); \
  } while (0)
#define EPR_CHECK_EQ(a, b) EPR_CHECK_OP(a, ==, b)
#define EPR_CHECK_NE(a, b) EPR_CHECK_OP(a, !=, b)
#define EPR_CHECK_LT(a, b) EPR_CHECK_OP(a, <, b)
#define EPR_CHECK_LE(a, b) EPR_CHECK_OP(a, <=, b)
#define EPR_CHECK_GT(a, b) EPR_CHECK_OP(a, >, b)
#define EPR_CHECK_GE(a, b) EPR_CHECK_OP(a, >=, b)

#ifdef NDEBUG
// Compiled (names stay used, expressions stay valid) but never run.
#define EPR_DCHECK_IGNORED(check) \
  do {                            \
    if (false) check;             \
  } while (0)
#define EPR_DCHECK(cond) EPR_DCHECK_IGNORED(EPR_CHECK(cond))
#define EPR_DCHECK_EQ(a, b) EPR_DCHECK_IGNORED(EPR_CHECK_EQ(a, b))
#define EPR_DCHECK_NE(a, b) EPR_DCHECK_IGNORED(EPR_CHECK_NE(a, b))
#define EPR_DCHECK_LT(a, b) EPR_DCHECK_IGNORED(EPR_CHECK_LT(a, b))
#define EPR_DCHECK_LE(a, b) EPR_DCHECK_IGNORED(EPR_CHECK_LE(a, b))
#define EPR_DCHECK_GT(a, b) EPR_DCHECK_IGNORED(EPR_CHECK_GT(a, b))
#define EPR_DCHECK_GE(a, b) EPR_DCHECK_IGNORED(EPR_CHECK_GE(a, b))
#else
#define EPR_DCHECK(cond) EPR_CHECK(cond)
#define EPR_DCHECK_EQ(a, b) EPR_CHECK_EQ(a, b)
#define EPR_DCHECK_NE(a, b) EPR_CHECK_NE(a, b)
#define EPR_DCHECK_LT(a, b) EPR_CHECK_LT(a, b)
#define EPR_DCHECK_LE(a, b) EPR_CHECK_LE(a, b)
#define EPR_DCHECK_GT(a, b) EPR_CHECK_GT(a, b)
#define EPR_DCHECK_GE(a, b) EPR_CHECK_GE(a, b)
#endif

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
