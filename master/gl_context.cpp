// OSMesa context creation and the function loader. See gl_context.h.
#include "master/gl_context.h"

#include <GL/osmesa.h>
#include <fmt/format.h>

#include <array>
#include <mutex>

#include "common/log.h"

namespace epr {

struct GlContext::Impl {
  OSMesaContext ctx = nullptr;
  std::array<unsigned char, 4> dummy{};  // the 1x1 RGBA colour buffer OSMesa insists on
};

namespace {

constexpr const char* kHelp =
    "install Mesa's OSMesa (Debian: libosmesa6, which renders with llvmpipe) or run the master with "
    "the CPU reprojector (--reprojector cpu)";

}  // namespace

GlContext::GlContext() : impl_(std::make_unique<Impl>()) {
  const int attribs[] = {OSMESA_FORMAT,
                         OSMESA_RGBA,
                         OSMESA_DEPTH_BITS,
                         0,
                         OSMESA_PROFILE,
                         OSMESA_CORE_PROFILE,
                         OSMESA_CONTEXT_MAJOR_VERSION,
                         4,
                         OSMESA_CONTEXT_MINOR_VERSION,
                         5,
                         0};
  impl_->ctx = OSMesaCreateContextAttribs(attribs, nullptr);
  if (!impl_->ctx)
    throw GlUnavailable(
        fmt::format("OSMesa could not create an OpenGL 4.5 core-profile context (llvmpipe needs Mesa >= 20 built with "
                    "LLVM; check that GALLIUM_DRIVER is unset or 'llvmpipe', not 'softpipe'): {}",
                    kHelp));
  make_current();
#define EPR_GL_LOAD(ret, name, params)                                                           \
  fns_.name = reinterpret_cast<decltype(fns_.name)>(OSMesaGetProcAddress("gl" #name));           \
  if (!fns_.name) {                                                                              \
    OSMesaDestroyContext(impl_->ctx);                                                            \
    impl_->ctx = nullptr;                                                                        \
    throw GlUnavailable(fmt::format("OSMesa/llvmpipe does not provide gl{}; {}", #name, kHelp)); \
  }
  EPR_GL_FUNCTIONS(EPR_GL_LOAD)
#undef EPR_GL_LOAD
  logger("master")->debug("OSMesa context: {} / {}", version(), renderer());
}

GlContext::~GlContext() {
  if (impl_ && impl_->ctx) {
    if (OSMesaGetCurrentContext() == impl_->ctx) OSMesaMakeCurrent(nullptr, nullptr, GL_UNSIGNED_BYTE, 0, 0);
    OSMesaDestroyContext(impl_->ctx);
  }
}

void GlContext::make_current() {
  if (!OSMesaMakeCurrent(impl_->ctx, impl_->dummy.data(), GL_UNSIGNED_BYTE, 1, 1))
    throw GlUnavailable(fmt::format("OSMesaMakeCurrent failed; {}", kHelp));
  owner_ = std::this_thread::get_id();
}

void GlContext::release() {
  check_thread();
  OSMesaMakeCurrent(nullptr, nullptr, GL_UNSIGNED_BYTE, 0, 0);
  owner_ = std::thread::id();
}

void GlContext::check_thread() const {
  if (owner_ != std::this_thread::get_id())
    throw std::logic_error("GlContext used from a thread it is not current on (call make_current() there first)");
  // Another context may have been made current on this thread since: bind ours again.
  if (OSMesaGetCurrentContext() != impl_->ctx &&
      !OSMesaMakeCurrent(impl_->ctx, impl_->dummy.data(), GL_UNSIGNED_BYTE, 1, 1))
    throw GlUnavailable("OSMesaMakeCurrent failed");
}

std::string GlContext::renderer() const {
  check_thread();
  const GLubyte* s = fns_.GetString(GL_RENDERER);
  return s ? reinterpret_cast<const char*>(s) : "";
}

std::string GlContext::version() const {
  check_thread();
  const GLubyte* s = fns_.GetString(GL_VERSION);
  return s ? reinterpret_cast<const char*>(s) : "";
}

bool GlContext::has_extension(const std::string& name) const {
  check_thread();
  GLint n = 0;
  fns_.GetIntegerv(GL_NUM_EXTENSIONS, &n);
  for (GLint i = 0; i < n; ++i) {
    const GLubyte* s = fns_.GetStringi(GL_EXTENSIONS, GLuint(i));
    if (s && name == reinterpret_cast<const char*>(s)) return true;
  }
  return false;
}

void GlContext::check_error(const char* what) const {
  const GLenum e = fns_.GetError();
  if (e != GL_NO_ERROR) throw std::runtime_error(fmt::format("OpenGL error 0x{:04x} in {}", unsigned(e), what));
}

bool gl_available() {
  static std::once_flag once;
  static bool available = false;
  std::call_once(once, [] {
    // Probe on a thread of its own so that the caller's current context (if any) is left alone.
    std::thread probe([] {
      try {
        GlContext ctx;
        available = true;
      } catch (const std::exception& e) {
        logger("master")->warn("OpenGL unavailable: {}", e.what());
      }
    });
    probe.join();
  });
  return available;
}

}  // namespace epr
