// Denormal floats flushed to zero (FTZ) and read as zero (DAZ) for a scope, the mode Embree's
// documentation recommends for every thread that traces rays. Set per tile rather than per thread: a
// pool thread's mode is otherwise whatever the last task left (Embree's BVH builds set it in the
// threads they run on), and a sample would depend on the thread that traced it.
#pragma once

#if defined(__SSE__) || defined(__x86_64__)
#include <pmmintrin.h>
#include <xmmintrin.h>
#endif

namespace epr {

class ScopedFlushDenormals {
 public:
#if defined(__SSE__) || defined(__x86_64__)
  ScopedFlushDenormals() : saved_(_mm_getcsr()) { _mm_setcsr(saved_ | _MM_FLUSH_ZERO_ON | _MM_DENORMALS_ZERO_ON); }
  ~ScopedFlushDenormals() { _mm_setcsr(saved_); }
#endif
  ScopedFlushDenormals(const ScopedFlushDenormals&) = delete;
  ScopedFlushDenormals& operator=(const ScopedFlushDenormals&) = delete;

 private:
#if defined(__SSE__) || defined(__x86_64__)
  unsigned saved_;
#endif
};

}  // namespace epr
