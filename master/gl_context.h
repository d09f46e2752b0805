// Headless OpenGL 4.5 core-profile context on OSMesa (Mesa's llvmpipe software rasteriser).
//
// The master does its GPU-style work (deep framebuffer rasterisation, reprojection compute
// shaders) in such a context so that the same code runs on a GPU-less server and, later, on a real
// GL driver.
//
// Threading: an OpenGL context is current on at most ONE thread. GlContext makes itself current on
// the thread that constructs it and records that thread as its owner. Every object that issues GL
// calls through it (GlReprojector, build_deep_framebuffer_gl) calls check_thread() first, which
// throws std::logic_error when called from another thread. To move the context to another thread,
// call release() on the owner, then make_current() on the new thread.
//
// Caveats:
//  - llvmpipe runs shaders on its own worker threads; their number is LP_NUM_THREADS (read once,
//    when the first context of the process is created; default = number of cores).
//  - Creation throws GlUnavailable (a std::runtime_error) with a message naming OSMesa/llvmpipe and
//    what to install or set when the library or the requested profile is missing.
#pragma once

#include <memory>
#include <stdexcept>
#include <string>
#include <thread>

#include "master/gl_functions.h"

namespace epr {

/// Thrown when no OSMesa GL 4.5 core context can be created (use the CPU back-ends instead).
class GlUnavailable : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

class GlContext {
 public:
  /// Creates the context (4.5 core, no default framebuffer worth drawing to: a 1x1 RGBA dummy
  /// buffer), makes it current on the calling thread and loads the GL entry points.
  GlContext();
  ~GlContext();
  GlContext(const GlContext&) = delete;
  GlContext& operator=(const GlContext&) = delete;

  /// Binds the context to the calling thread, which becomes the owner.
  void make_current();
  /// Unbinds the context from the owner thread (call on the owner before handing it over).
  void release();
  /// Throws std::logic_error unless the calling thread is the owner. If another context was made
  /// current on this thread in the meantime, makes this one current again (so several contexts can
  /// share a thread, e.g. one per job on the master's GL thread).
  void check_thread() const;

  /// The entry points; only call them on the owner thread.
  const gl::GlFunctions& gl() const { return fns_; }

  std::string renderer() const;  // e.g. "llvmpipe (LLVM 15.0.6, 256 bits)"
  std::string version() const;   // e.g. "4.5 (Core Profile) Mesa 22.3.6"
  bool has_extension(const std::string& name) const;

  /// Throws std::runtime_error naming `what` and the GL error code if glGetError reports one.
  void check_error(const char* what) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  gl::GlFunctions fns_;
  std::thread::id owner_;
};

/// True if a GlContext can be created on this machine (tries once per process and caches the answer;
/// the probe context is destroyed again). Lets tests and the master fall back to the CPU back-end.
bool gl_available();

}  // namespace epr
