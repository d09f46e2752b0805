// The OpenGL 4.5 core entry points the master uses, loaded at run time through OSMesaGetProcAddress.
//
// A tiny hand-written loader (no glad/glew dependency): every function is listed once in
// EPR_GL_FUNCTIONS as (return type, name without the "gl" prefix, parameter list). GlFunctions holds
// one pointer per entry, named like the GL function without its prefix (gl.DispatchCompute(...)).
// Pointers are only valid while the OSMesa context that loaded them is alive; with Mesa they are
// context-independent dispatch stubs, but we never rely on that. Add a line here to use a new call.
#pragma once

#include <GL/gl.h>  // GL types and enums (Mesa's gl.h pulls in glext.h for the 4.5 enums)

namespace epr::gl {

#define EPR_GL_FUNCTIONS(X)                                                                                           \
  X(const GLubyte*, GetString, (GLenum name))                                                                         \
  X(const GLubyte*, GetStringi, (GLenum name, GLuint index))                                                          \
  X(void, GetIntegerv, (GLenum pname, GLint * data))                                                                  \
  X(void, GetIntegeri_v, (GLenum target, GLuint index, GLint * data))                                                 \
  X(GLenum, GetError, (void))                                                                                         \
  X(void, Finish, (void))                                                                                             \
  X(void, Enable, (GLenum cap))                                                                                       \
  X(void, Disable, (GLenum cap))                                                                                      \
  X(void, DepthFunc, (GLenum func))                                                                                   \
  X(void, Viewport, (GLint x, GLint y, GLsizei w, GLsizei h))                                                         \
  X(void, ClipControl, (GLenum origin, GLenum depth))                                                                 \
  X(void, CreateBuffers, (GLsizei n, GLuint * buffers))                                                               \
  X(void, DeleteBuffers, (GLsizei n, const GLuint* buffers))                                                          \
  X(void, NamedBufferStorage, (GLuint buffer, GLsizeiptr size, const void* data, GLbitfield flags))                   \
  X(void, NamedBufferSubData, (GLuint buffer, GLintptr offset, GLsizeiptr size, const void* data))                    \
  X(void, GetNamedBufferSubData, (GLuint buffer, GLintptr offset, GLsizeiptr size, void* data))                       \
  X(void*, MapNamedBufferRange, (GLuint buffer, GLintptr offset, GLsizeiptr length, GLbitfield access))               \
  X(GLboolean, UnmapNamedBuffer, (GLuint buffer))                                                                     \
  X(void, FlushMappedNamedBufferRange, (GLuint buffer, GLintptr offset, GLsizeiptr length))                           \
  X(void, ClearNamedBufferData, (GLuint buffer, GLenum internalformat, GLenum format, GLenum type, const void* data)) \
  X(void, BindBufferBase, (GLenum target, GLuint index, GLuint buffer))                                               \
  X(void, BindBufferRange, (GLenum target, GLuint index, GLuint buffer, GLintptr offset, GLsizeiptr size))            \
  X(GLuint, CreateShader, (GLenum type))                                                                              \
  X(void, DeleteShader, (GLuint shader))                                                                              \
  X(void, ShaderSource, (GLuint shader, GLsizei count, const GLchar* const* string, const GLint* length))             \
  X(void, CompileShader, (GLuint shader))                                                                             \
  X(void, GetShaderiv, (GLuint shader, GLenum pname, GLint * params))                                                 \
  X(void, GetShaderInfoLog, (GLuint shader, GLsizei bufSize, GLsizei * length, GLchar * infoLog))                     \
  X(GLuint, CreateProgram, (void))                                                                                    \
  X(void, DeleteProgram, (GLuint program))                                                                            \
  X(void, AttachShader, (GLuint program, GLuint shader))                                                              \
  X(void, LinkProgram, (GLuint program))                                                                              \
  X(void, GetProgramiv, (GLuint program, GLenum pname, GLint * params))                                               \
  X(void, GetProgramInfoLog, (GLuint program, GLsizei bufSize, GLsizei * length, GLchar * infoLog))                   \
  X(void, UseProgram, (GLuint program))                                                                               \
  X(GLint, GetUniformLocation, (GLuint program, const GLchar* name))                                                  \
  X(void, ProgramUniform1f, (GLuint program, GLint location, GLfloat v0))                                             \
  X(void, ProgramUniform1i, (GLuint program, GLint location, GLint v0))                                               \
  X(void, ProgramUniform1ui, (GLuint program, GLint location, GLuint v0))                                             \
  X(void, ProgramUniform3f, (GLuint program, GLint location, GLfloat v0, GLfloat v1, GLfloat v2))                     \
  X(void, DispatchCompute, (GLuint x, GLuint y, GLuint z))                                                            \
  X(void, MemoryBarrier, (GLbitfield barriers))                                                                       \
  X(GLsync, FenceSync, (GLenum condition, GLbitfield flags))                                                          \
  X(GLenum, ClientWaitSync, (GLsync sync, GLbitfield flags, GLuint64 timeout))                                        \
  X(void, DeleteSync, (GLsync sync))                                                                                  \
  X(void, CreateVertexArrays, (GLsizei n, GLuint * arrays))                                                           \
  X(void, DeleteVertexArrays, (GLsizei n, const GLuint* arrays))                                                      \
  X(void, BindVertexArray, (GLuint array))                                                                            \
  X(void, DrawArrays, (GLenum mode, GLint first, GLsizei count))                                                      \
  X(void, CreateTextures, (GLenum target, GLsizei n, GLuint * textures))                                              \
  X(void, DeleteTextures, (GLsizei n, const GLuint* textures))                                                        \
  X(void, TextureBuffer, (GLuint texture, GLenum internalformat, GLuint buffer))                                      \
  X(void, TextureBufferRange,                                                                                         \
    (GLuint texture, GLenum internalformat, GLuint buffer, GLintptr offset, GLsizeiptr size))                         \
  X(void, BindTextureUnit, (GLuint unit, GLuint texture))                                                             \
  X(void, BindImageTexture,                                                                                           \
    (GLuint unit, GLuint texture, GLint level, GLboolean layered, GLint layer, GLenum access, GLenum format))         \
  X(void, TextureStorage2D, (GLuint texture, GLsizei levels, GLenum internalformat, GLsizei w, GLsizei h))            \
  X(void, GetTextureImage, (GLuint texture, GLint level, GLenum format, GLenum type, GLsizei bufSize, void* pixels))  \
  X(void, CreateFramebuffers, (GLsizei n, GLuint * framebuffers))                                                     \
  X(void, DeleteFramebuffers, (GLsizei n, const GLuint* framebuffers))                                                \
  X(void, BindFramebuffer, (GLenum target, GLuint framebuffer))                                                       \
  X(void, NamedFramebufferTexture, (GLuint framebuffer, GLenum attachment, GLuint texture, GLint level))              \
  X(void, NamedFramebufferDrawBuffers, (GLuint framebuffer, GLsizei n, const GLenum* bufs))                           \
  X(GLenum, CheckNamedFramebufferStatus, (GLuint framebuffer, GLenum target))                                         \
  X(void, ClearNamedFramebufferfv, (GLuint framebuffer, GLenum buffer, GLint drawbuffer, const GLfloat* value))       \
  X(void, ClearNamedFramebufferuiv, (GLuint framebuffer, GLenum buffer, GLint drawbuffer, const GLuint* value))       \
  X(void, ClearNamedFramebufferfi, (GLuint framebuffer, GLenum buffer, GLint drawbuffer, GLfloat depth, GLint stencil))

#define EPR_GL_DECLARE_POINTER(ret, name, params) ret(APIENTRY* name) params = nullptr;

/// One pointer per entry of EPR_GL_FUNCTIONS, filled by GlContext.
struct GlFunctions {
  EPR_GL_FUNCTIONS(EPR_GL_DECLARE_POINTER)
};

#undef EPR_GL_DECLARE_POINTER

}  // namespace epr::gl
