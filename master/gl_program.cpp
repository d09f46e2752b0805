// See gl_program.h.
#include "master/gl_program.h"

#include <fmt/format.h>

#include <stdexcept>
#include <vector>

namespace epr {

GlProgram::GlProgram(GlContext& ctx, const std::string& compute_source) : ctx_(ctx) {
  ctx.check_thread();
  id_ = ctx.gl().CreateProgram();
  const GLuint cs = compile(GL_COMPUTE_SHADER, compute_source);
  ctx.gl().AttachShader(id_, cs);
  link();
  ctx.gl().DeleteShader(cs);
}

GlProgram::GlProgram(GlContext& ctx, const std::string& vertex_source, const std::string& fragment_source) : ctx_(ctx) {
  ctx.check_thread();
  id_ = ctx.gl().CreateProgram();
  const GLuint vs = compile(GL_VERTEX_SHADER, vertex_source);
  GLuint fs = 0;
  try {
    fs = compile(GL_FRAGMENT_SHADER, fragment_source);
  } catch (...) {
    ctx.gl().DeleteShader(vs);
    throw;
  }
  ctx.gl().AttachShader(id_, vs);
  ctx.gl().AttachShader(id_, fs);
  link();
  ctx.gl().DeleteShader(vs);
  ctx.gl().DeleteShader(fs);
}

GlProgram::~GlProgram() {
  if (id_) ctx_.gl().DeleteProgram(id_);
}

GLuint GlProgram::compile(GLenum type, const std::string& source) {
  const auto& gl = ctx_.gl();
  const GLuint sh = gl.CreateShader(type);
  const char* src = source.c_str();
  gl.ShaderSource(sh, 1, &src, nullptr);
  gl.CompileShader(sh);
  GLint ok = 0, len = 0;
  gl.GetShaderiv(sh, GL_COMPILE_STATUS, &ok);
  if (!ok) {
    gl.GetShaderiv(sh, GL_INFO_LOG_LENGTH, &len);
    std::vector<char> log(size_t(std::max(len, 1)));
    gl.GetShaderInfoLog(sh, GLsizei(log.size()), nullptr, log.data());
    gl.DeleteShader(sh);
    gl.DeleteProgram(id_);
    id_ = 0;
    throw std::runtime_error(fmt::format("GLSL compile error: {}", log.data()));
  }
  return sh;
}

void GlProgram::link() {
  const auto& gl = ctx_.gl();
  gl.LinkProgram(id_);
  GLint ok = 0, len = 0;
  gl.GetProgramiv(id_, GL_LINK_STATUS, &ok);
  if (!ok) {
    gl.GetProgramiv(id_, GL_INFO_LOG_LENGTH, &len);
    std::vector<char> log(size_t(std::max(len, 1)));
    gl.GetProgramInfoLog(id_, GLsizei(log.size()), nullptr, log.data());
    gl.DeleteProgram(id_);
    id_ = 0;
    throw std::runtime_error(fmt::format("GLSL link error: {}", log.data()));
  }
}

GLint GlProgram::uniform(const char* name) const {
  const GLint loc = ctx_.gl().GetUniformLocation(id_, name);
  if (loc < 0) throw std::logic_error(fmt::format("GLSL uniform '{}' not found", name));
  return loc;
}

}  // namespace epr
