// Small RAII helpers for GL objects used by the master: shader programs built from GLSL source
// strings (compile/link errors become std::runtime_error with the info log), buffers and textures.
// All of them must be created, used and destroyed on the thread their GlContext is current on.
#pragma once

#include <string>

#include "master/gl_context.h"

namespace epr {

/// A linked program of one compute shader, or of a vertex + fragment shader pair.
class GlProgram {
 public:
  GlProgram(GlContext& ctx, const std::string& compute_source);
  GlProgram(GlContext& ctx, const std::string& vertex_source, const std::string& fragment_source);
  ~GlProgram();
  GlProgram(const GlProgram&) = delete;
  GlProgram& operator=(const GlProgram&) = delete;

  GLuint id() const { return id_; }
  /// Uniform location; throws if the uniform does not exist (or was optimised away).
  GLint uniform(const char* name) const;

 private:
  GLuint compile(GLenum type, const std::string& source);
  void link();
  GlContext& ctx_;
  GLuint id_ = 0;
};

/// Owns GL object names and deletes them with the matching glDelete* call.
class GlBuffer {
 public:
  explicit GlBuffer(GlContext& ctx) : ctx_(ctx) { ctx.gl().CreateBuffers(1, &id_); }
  ~GlBuffer() { ctx_.gl().DeleteBuffers(1, &id_); }
  GlBuffer(const GlBuffer&) = delete;
  GlBuffer& operator=(const GlBuffer&) = delete;
  GLuint id() const { return id_; }

 private:
  GlContext& ctx_;
  GLuint id_ = 0;
};

class GlTexture {
 public:
  GlTexture(GlContext& ctx, GLenum target) : ctx_(ctx) { ctx.gl().CreateTextures(target, 1, &id_); }
  ~GlTexture() { ctx_.gl().DeleteTextures(1, &id_); }
  GlTexture(const GlTexture&) = delete;
  GlTexture& operator=(const GlTexture&) = delete;
  GLuint id() const { return id_; }

 private:
  GlContext& ctx_;
  GLuint id_ = 0;
};

}  // namespace epr
