// OpenGL deep-framebuffer builder (OSMesa/llvmpipe). See deep_framebuffer.h.
//
// Vertex pulling: the corners of every triangle are a RGB32F buffer texture read with gl_VertexID,
// one non-indexed GL_TRIANGLES draw. The clip-space transform reproduces Camera::project:
//   clip = (x_v / tan_half_x, -y_v / tan_half_y, near, z_v)   (x_v, y_v, z_v = camera-space coords)
// With glClipControl(GL_LOWER_LEFT, GL_ZERO_TO_ONE) the window position is (rx * S, ry * S) with
// ry measured DOWNWARDS: GL row j is raster row j, so glGetTextureImage's first row is the top of
// the image and no flip is needed. Depth is reversed Z (near / z_v, GL_GREATER, 32-bit float):
// ample precision at every distance; geometry closer than `near` to the eye plane is clipped.
// Outputs: the interpolated world position (RGBA32F) and the triangle index (R32UI, gl_VertexID/3).
// Planes are filled in on the CPU from plane_of(), exactly as the CPU builder does.
#include <fmt/format.h>
#include <tbb/parallel_for.h>

#include <cstring>
#include <stdexcept>
#include <vector>

#include "master/deep_framebuffer.h"
#include "master/gl_context.h"
#include "master/gl_program.h"

namespace epr {

namespace {

constexpr const char* kVertexShader = R"(#version 450
uniform samplerBuffer corners;  // xyz of corner gl_VertexID, world space
uniform vec3 eye, forward_, right_, up_;
uniform float tan_half_x, tan_half_y, near_plane;
out vec3 world;
flat out uint tri;
void main() {
  vec3 p = texelFetch(corners, gl_VertexID).xyz;
  vec3 d = p - eye;
  float xv = d.x * right_.x + d.y * right_.y + d.z * right_.z;
  float yv = d.x * up_.x + d.y * up_.y + d.z * up_.z;
  float zv = d.x * forward_.x + d.y * forward_.y + d.z * forward_.z;
  gl_Position = vec4(xv / tan_half_x, -yv / tan_half_y, near_plane, zv);
  world = p;
  tri = uint(gl_VertexID) / 3u;
}
)";

constexpr const char* kFragmentShader = R"(#version 450
in vec3 world;
flat in uint tri;
layout(location = 0) out vec4 out_position;
layout(location = 1) out uint out_triangle;
void main() {
  out_position = vec4(world, 1.0);
  out_triangle = tri;
}
)";

}  // namespace

DeepFramebuffer build_deep_framebuffer_gl(GlContext& ctx, const Scene& scene, const Camera& camera, int subpixels) {
  ctx.check_thread();
  detail::check_deep_framebuffer_grid(camera, subpixels);
  const auto& gl = ctx.gl();
  const int S = subpixels, W = camera.width() * S, H = camera.height() * S;
  const size_t ncorners = 3 * scene.triangle_count();
  GLint max_tbo = 0, max_tex = 0;
  gl.GetIntegerv(GL_MAX_TEXTURE_BUFFER_SIZE, &max_tbo);
  gl.GetIntegerv(GL_MAX_TEXTURE_SIZE, &max_tex);
  if (ncorners > size_t(max_tbo))
    throw std::runtime_error(fmt::format("scene has {} triangles; the GL deep framebuffer takes at most {}",
                                         scene.triangle_count(), max_tbo / 3));
  if (W > max_tex || H > max_tex)
    throw std::runtime_error(fmt::format("deep framebuffer {}x{} exceeds GL_MAX_TEXTURE_SIZE {}", W, H, max_tex));

  std::vector<float> corners(3 * ncorners);
  for (size_t t = 0; t < scene.triangle_count(); ++t)
    for (int c = 0; c < 3; ++c) std::memcpy(&corners[9 * t + 3 * c], &scene.positions[scene.triangles[t][c]], 12);

  GlProgram prog(ctx, kVertexShader, kFragmentShader);
  GlBuffer corner_buf(ctx);
  gl.NamedBufferStorage(corner_buf.id(), GLsizeiptr(std::max<size_t>(corners.size(), 3) * 4), corners.data(), 0);
  GlTexture corner_tex(ctx, GL_TEXTURE_BUFFER);
  gl.TextureBuffer(corner_tex.id(), GL_RGB32F, corner_buf.id());

  GlTexture pos_tex(ctx, GL_TEXTURE_2D), tri_tex(ctx, GL_TEXTURE_2D), depth_tex(ctx, GL_TEXTURE_2D);
  gl.TextureStorage2D(pos_tex.id(), 1, GL_RGBA32F, W, H);
  gl.TextureStorage2D(tri_tex.id(), 1, GL_R32UI, W, H);
  gl.TextureStorage2D(depth_tex.id(), 1, GL_DEPTH_COMPONENT32F, W, H);
  GLuint fbo = 0;
  gl.CreateFramebuffers(1, &fbo);
  gl.NamedFramebufferTexture(fbo, GL_COLOR_ATTACHMENT0, pos_tex.id(), 0);
  gl.NamedFramebufferTexture(fbo, GL_COLOR_ATTACHMENT1, tri_tex.id(), 0);
  gl.NamedFramebufferTexture(fbo, GL_DEPTH_ATTACHMENT, depth_tex.id(), 0);
  const GLenum bufs[] = {GL_COLOR_ATTACHMENT0, GL_COLOR_ATTACHMENT1};
  gl.NamedFramebufferDrawBuffers(fbo, 2, bufs);
  struct FboGuard {
    const gl::GlFunctions& gl;
    GLuint fbo;
    ~FboGuard() {
      gl.BindFramebuffer(GL_FRAMEBUFFER, 0);
      gl.DeleteFramebuffers(1, &fbo);
    }
  } guard{gl, fbo};
  if (gl.CheckNamedFramebufferStatus(fbo, GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE)
    throw std::runtime_error("deep framebuffer: GL framebuffer incomplete");

  const GLfloat zero[4] = {0, 0, 0, 0};
  const GLuint none[4] = {DeepFramebuffer::kNoTriangle, 0, 0, 0};
  gl.ClearNamedFramebufferfv(fbo, GL_COLOR, 0, zero);
  gl.ClearNamedFramebufferuiv(fbo, GL_COLOR, 1, none);
  const GLfloat far_depth = 0.0f;  // reversed Z: 0 is infinitely far
  gl.ClearNamedFramebufferfv(fbo, GL_DEPTH, 0, &far_depth);

  const float near = kNearPlane * scene.bounds().diagonal_length();
  const GLuint p = prog.id();
  gl.ProgramUniform1i(p, prog.uniform("corners"), 0);
  gl.ProgramUniform3f(p, prog.uniform("eye"), camera.eye().x, camera.eye().y, camera.eye().z);
  gl.ProgramUniform3f(p, prog.uniform("forward_"), camera.forward().x, camera.forward().y, camera.forward().z);
  gl.ProgramUniform3f(p, prog.uniform("right_"), camera.right().x, camera.right().y, camera.right().z);
  gl.ProgramUniform3f(p, prog.uniform("up_"), camera.up().x, camera.up().y, camera.up().z);
  gl.ProgramUniform1f(p, prog.uniform("tan_half_x"), camera.tan_half_x());
  gl.ProgramUniform1f(p, prog.uniform("tan_half_y"), camera.tan_half_y());
  gl.ProgramUniform1f(p, prog.uniform("near_plane"), near > 0 ? near : 1e-6f);

  GLuint vao = 0;
  gl.CreateVertexArrays(1, &vao);
  gl.BindFramebuffer(GL_FRAMEBUFFER, fbo);
  gl.Viewport(0, 0, W, H);
  gl.ClipControl(GL_LOWER_LEFT, GL_ZERO_TO_ONE);
  gl.Enable(GL_DEPTH_TEST);
  gl.DepthFunc(GL_GREATER);
  gl.Disable(GL_CULL_FACE);
  gl.UseProgram(p);
  gl.BindTextureUnit(0, corner_tex.id());
  gl.BindVertexArray(vao);
  gl.DrawArrays(GL_TRIANGLES, 0, GLsizei(ncorners));
  gl.BindVertexArray(0);
  gl.UseProgram(0);
  gl.ClipControl(GL_LOWER_LEFT, GL_NEGATIVE_ONE_TO_ONE);
  gl.DeleteVertexArrays(1, &vao);

  DeepFramebuffer dfb;
  dfb.resize(W, H, S);
  std::vector<float> rgba(4 * dfb.texel_count());
  gl.GetTextureImage(pos_tex.id(), 0, GL_RGBA, GL_FLOAT, GLsizei(rgba.size() * 4), rgba.data());
  gl.GetTextureImage(tri_tex.id(), 0, GL_RED_INTEGER, GL_UNSIGNED_INT, GLsizei(dfb.triangle.size() * 4),
                     dfb.triangle.data());
  ctx.check_error("build_deep_framebuffer_gl");

  tbb::parallel_for(size_t(0), dfb.texel_count(), [&](size_t k) {
    const uint32_t t = dfb.triangle[k];
    if (t == DeepFramebuffer::kNoTriangle || t >= scene.triangle_count()) {
      dfb.triangle[k] = DeepFramebuffer::kNoTriangle;
      return;
    }
    const TrianglePlane pl = plane_of(scene, t);
    dfb.covered[k] = 1;
    for (int c = 0; c < 3; ++c) dfb.position[3 * k + c] = rgba[4 * k + c];
    dfb.normal[3 * k] = pl.normal.x, dfb.normal[3 * k + 1] = pl.normal.y, dfb.normal[3 * k + 2] = pl.normal.z;
    dfb.plane_offset[k] = pl.offset;
  });
  return dfb;
}

}  // namespace epr
