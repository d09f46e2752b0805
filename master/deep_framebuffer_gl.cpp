// OpenGL deep-framebuffer builder (OSMesa/llvmpipe). See deep_framebuffer.h.
//
// Vertex pulling: the corners of every triangle are a RGB32F buffer texture read with gl_VertexID,
// one non-indexed GL_TRIANGLES draw. The clip-space transform reproduces Camera::project:
//   clip = (x_v / tan_half_x, -y_v / tan_half_y, near, z_v)   (x_v, y_v, z_v = camera-space coords)
// With glClipControl(GL_LOWER_LEFT, GL_ZERO_TO_ONE) the window position is (rx * S, ry * S) with
// ry measured DOWNWARDS: GL row j is raster row j, so glGetTextureImage's first row is the top of
// the image and no flip is needed. Depth is reversed Z (near / z_v, GL_GREATER, 32-bit float):
// ample precision at every distance; geometry closer than `near` to the eye plane is clipped.
// Output: the triangle index (R32UI, gl_VertexID/3). Planes are filled in on the CPU from plane_of() (per triangle)
// and positions from detail::ray_triangle on the texel-centre ray, exactly as the CPU builder does.
// Where the rasterised triangle is a hole of a cut-out at the texel centre, the CPU search behind it
// (deep_framebuffer.h, cut-outs) gives the texel's triangle and position.
// Bands: a framebuffer of the band's height; the viewport is the full grid's moved down by the band's
// first row, so the rasteriser sees every triangle where the full frame has it (whole-row shift).
#include <fmt/format.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <memory>
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
flat out uint tri;
void main() {
  vec3 p = texelFetch(corners, gl_VertexID).xyz;
  vec3 d = p - eye;
  float xv = d.x * right_.x + d.y * right_.y + d.z * right_.z;
  float yv = d.x * up_.x + d.y * up_.y + d.z * up_.z;
  float zv = d.x * forward_.x + d.y * forward_.y + d.z * forward_.z;
  gl_Position = vec4(xv / tan_half_x, -yv / tan_half_y, near_plane, zv);
  tri = uint(gl_VertexID) / 3u;
}
)";

constexpr const char* kFragmentShader = R"(#version 450
flat in uint tri;
layout(location = 0) out uint out_triangle;
void main() {
  out_triangle = tri;
}
)";

class GlBands final : public detail::DeepFramebufferBands {
 public:
  GlBands(GlContext& ctx, const Scene& scene, const Camera& camera, int subpixels, int max_rows)
      : ctx_(ctx),
        scene_(scene),
        camera_(camera),
        S_(subpixels),
        W_(camera.width() * subpixels),
        H_(camera.height() * subpixels),
        prog_(ctx, kVertexShader, kFragmentShader),
        corner_buf_(ctx),
        corner_tex_(ctx, GL_TEXTURE_BUFFER),
        tri_tex_(ctx, GL_TEXTURE_2D),
        depth_tex_(ctx, GL_TEXTURE_2D) {
    ctx.check_thread();
    detail::check_deep_framebuffer_grid(camera, subpixels);
    const auto& gl = ctx.gl();
    rows_ = std::clamp(max_rows, 1, H_);
    const size_t ncorners = 3 * scene.triangle_count();
    ncorners_ = ncorners;
    planes_ = detail::triangle_planes(scene);
    GLint max_tbo = 0, max_tex = 0, max_fb[2] = {0, 0}, max_vp[2] = {0, 0}, vp_range[2] = {0, 0};
    gl.GetIntegerv(GL_MAX_TEXTURE_BUFFER_SIZE, &max_tbo);
    gl.GetIntegerv(GL_MAX_TEXTURE_SIZE, &max_tex);
    gl.GetIntegerv(GL_MAX_FRAMEBUFFER_WIDTH, &max_fb[0]);
    gl.GetIntegerv(GL_MAX_FRAMEBUFFER_HEIGHT, &max_fb[1]);
    gl.GetIntegerv(GL_MAX_VIEWPORT_DIMS, max_vp);
    gl.GetIntegerv(GL_VIEWPORT_BOUNDS_RANGE, vp_range);
    if (ncorners > size_t(max_tbo))
      throw std::runtime_error(fmt::format("scene has {} triangles; the GL deep framebuffer takes at most {}",
                                           scene.triangle_count(), max_tbo / 3));
    // The band's textures and framebuffer: W x rows. The viewport: the full W x H grid, its origin
    // at (0, -first row) -- the lowest origin is that of the last band.
    const int lowest_origin = rows_ < H_ ? -(H_ - 1) : 0;
    if (W_ > max_tex || rows_ > max_tex || W_ > max_fb[0] || rows_ > max_fb[1])
      throw std::runtime_error(
          fmt::format("deep framebuffer band {}x{} exceeds GL_MAX_TEXTURE_SIZE {} or GL_MAX_FRAMEBUFFER_WIDTH/HEIGHT "
                      "{}x{}",
                      W_, rows_, max_tex, max_fb[0], max_fb[1]));
    if (W_ > max_vp[0] || H_ > max_vp[1])
      throw std::runtime_error(
          fmt::format("deep framebuffer {}x{} exceeds GL_MAX_VIEWPORT_DIMS {}x{}", W_, H_, max_vp[0], max_vp[1]));
    if (lowest_origin < vp_range[0])
      throw std::runtime_error(
          fmt::format("deep framebuffer of {} rows in bands needs viewport origins down to {}; "
                      "GL_VIEWPORT_BOUNDS_RANGE starts at {}",
                      H_, lowest_origin, vp_range[0]));

    std::vector<float> corners(3 * ncorners);
    for (size_t t = 0; t < scene.triangle_count(); ++t)
      for (int c = 0; c < 3; ++c) std::memcpy(&corners[9 * t + 3 * c], &scene.positions[scene.triangles[t][c]], 12);
    gl.NamedBufferStorage(corner_buf_.id(), GLsizeiptr(std::max<size_t>(corners.size(), 3) * 4), corners.data(), 0);
    gl.TextureBuffer(corner_tex_.id(), GL_RGB32F, corner_buf_.id());

    gl.TextureStorage2D(tri_tex_.id(), 1, GL_R32UI, W_, rows_);
    gl.TextureStorage2D(depth_tex_.id(), 1, GL_DEPTH_COMPONENT32F, W_, rows_);
    gl.CreateFramebuffers(1, &fbo_);
    gl.NamedFramebufferTexture(fbo_, GL_COLOR_ATTACHMENT0, tri_tex_.id(), 0);
    gl.NamedFramebufferTexture(fbo_, GL_DEPTH_ATTACHMENT, depth_tex_.id(), 0);
    const GLenum bufs[] = {GL_COLOR_ATTACHMENT0};
    gl.NamedFramebufferDrawBuffers(fbo_, 1, bufs);
    if (gl.CheckNamedFramebufferStatus(fbo_, GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE)
      throw std::runtime_error("deep framebuffer: GL framebuffer incomplete");

    const float near = kNearPlane * scene.bounds().diagonal_length();
    const GLuint p = prog_.id();
    gl.ProgramUniform1i(p, prog_.uniform("corners"), 0);
    gl.ProgramUniform3f(p, prog_.uniform("eye"), camera.eye().x, camera.eye().y, camera.eye().z);
    gl.ProgramUniform3f(p, prog_.uniform("forward_"), camera.forward().x, camera.forward().y, camera.forward().z);
    gl.ProgramUniform3f(p, prog_.uniform("right_"), camera.right().x, camera.right().y, camera.right().z);
    gl.ProgramUniform3f(p, prog_.uniform("up_"), camera.up().x, camera.up().y, camera.up().z);
    gl.ProgramUniform1f(p, prog_.uniform("tan_half_x"), camera.tan_half_x());
    gl.ProgramUniform1f(p, prog_.uniform("tan_half_y"), camera.tan_half_y());
    gl.ProgramUniform1f(p, prog_.uniform("near_plane"), near > 0 ? near : 1e-6f);
    gl.CreateVertexArrays(1, &vao_);
    cut_ = detail::cut_out_triangles(scene);
    if (!cut_.empty()) resolver_ = std::make_unique<detail::CutoutResolver>(scene, camera, S_, near);
  }

  ~GlBands() override {
    const auto& gl = ctx_.gl();
    gl.BindFramebuffer(GL_FRAMEBUFFER, 0);
    gl.DeleteFramebuffers(1, &fbo_);
    gl.DeleteVertexArrays(1, &vao_);
  }

  int max_rows() const override { return rows_; }

  void build(int row0, int row1, DeepFramebuffer* out) override {
    ctx_.check_thread();
    if (row0 < 0 || row1 > H_ || row0 >= row1 || row1 - row0 > rows_)
      throw std::invalid_argument("deep framebuffer band outside the grid or taller than its textures");
    const auto& gl = ctx_.gl();
    const int rows = row1 - row0;
    const GLuint none[4] = {DeepFramebuffer::kNoTriangle, 0, 0, 0};
    gl.ClearNamedFramebufferuiv(fbo_, GL_COLOR, 0, none);
    const GLfloat far_depth = 0.0f;  // reversed Z: 0 is infinitely far
    gl.ClearNamedFramebufferfv(fbo_, GL_DEPTH, 0, &far_depth);

    gl.BindFramebuffer(GL_FRAMEBUFFER, fbo_);
    // The full grid's viewport moved up by row0: grid row j lands on framebuffer row j - row0.
    gl.Viewport(0, -row0, W_, H_);
    gl.ClipControl(GL_LOWER_LEFT, GL_ZERO_TO_ONE);
    gl.Enable(GL_DEPTH_TEST);
    gl.DepthFunc(GL_GREATER);
    gl.Disable(GL_CULL_FACE);
    gl.UseProgram(prog_.id());
    gl.BindTextureUnit(0, corner_tex_.id());
    gl.BindVertexArray(vao_);
    gl.DrawArrays(GL_TRIANGLES, 0, GLsizei(ncorners_));
    gl.BindVertexArray(0);
    gl.UseProgram(0);
    gl.ClipControl(GL_LOWER_LEFT, GL_NEGATIVE_ONE_TO_ONE);
    gl.BindFramebuffer(GL_FRAMEBUFFER, 0);

    DeepFramebuffer& dfb = *out;
    dfb.resize(W_, rows, S_);
    dfb.first_row = row0;
    // Whole textures (rows_ rows; a shorter last band uses the first `rows`).
    const size_t texels = size_t(W_) * size_t(rows_);
    tri_.resize(texels);
    gl.GetTextureImage(tri_tex_.id(), 0, GL_RED_INTEGER, GL_UNSIGNED_INT, GLsizei(tri_.size() * 4), tri_.data());
    ctx_.check_error("build_deep_framebuffer_gl");

    const Scene& scene = scene_;
    const Camera& camera = camera_;
    const int S = S_, W = W_;
    tbb::parallel_for(size_t(0), dfb.texel_count(), [&](size_t k) {
      const uint32_t t = tri_[k];
      if (t == DeepFramebuffer::kNoTriangle || t >= scene.triangle_count()) return;
      dfb.triangle[k] = t;
      const TrianglePlane& pl = planes_[t];
      dfb.covered[k] = 1;
      // The CPU builder's hit of the texel-centre ray (a corner if the ray runs in the plane).
      const int x = int(k % size_t(W)), y = row0 + int(k / size_t(W));
      const auto& idx = scene.triangles[t];
      const Vec3 a = scene.positions[idx[0]], b = scene.positions[idx[1]], c = scene.positions[idx[2]];
      const Ray r = camera.generate_ray((float(x) + 0.5f) / float(S), (float(y) + 0.5f) / float(S));
      float u, v, tt;
      Vec3 hit = a;
      if (detail::ray_triangle(r, a, b - a, c - a, &u, &v, &tt) && std::isfinite(tt)) {
        hit = r.origin + r.dir * tt;
        if (resolver_ && cut_[t] && scene.cut_out_at(t, u, v)) {  // a hole: the surface behind it
          const uint32_t behind = resolver_->nearest(x, y, &hit);
          if (behind == DeepFramebuffer::kNoTriangle) {
            dfb.triangle[k] = DeepFramebuffer::kNoTriangle;
            dfb.covered[k] = 0;
            return;
          }
          dfb.triangle[k] = behind;
          const TrianglePlane& pb = planes_[behind];
          dfb.position[3 * k] = hit.x, dfb.position[3 * k + 1] = hit.y, dfb.position[3 * k + 2] = hit.z;
          dfb.normal[3 * k] = pb.normal.x, dfb.normal[3 * k + 1] = pb.normal.y, dfb.normal[3 * k + 2] = pb.normal.z;
          dfb.plane_offset[k] = pb.offset;
          return;
        }
      }
      dfb.position[3 * k] = hit.x, dfb.position[3 * k + 1] = hit.y, dfb.position[3 * k + 2] = hit.z;
      dfb.normal[3 * k] = pl.normal.x, dfb.normal[3 * k + 1] = pl.normal.y, dfb.normal[3 * k + 2] = pl.normal.z;
      dfb.plane_offset[k] = pl.offset;
    });
  }

 private:
  GlContext& ctx_;
  const Scene& scene_;
  const Camera& camera_;
  int S_, W_, H_, rows_ = 0;
  size_t ncorners_ = 0;
  GlProgram prog_;
  GlBuffer corner_buf_;
  GlTexture corner_tex_, tri_tex_, depth_tex_;
  GLuint fbo_ = 0, vao_ = 0;
  std::vector<uint32_t> tri_;                         // read-back triangle indices of the current band
  std::vector<TrianglePlane> planes_;                 // per triangle
  std::vector<uint8_t> cut_;                          // per triangle: a cut-out (empty if the scene has none)
  std::unique_ptr<detail::CutoutResolver> resolver_;  // behind holes (null without cut-outs)
};

}  // namespace

std::unique_ptr<detail::DeepFramebufferBands> detail::gl_deep_framebuffer_bands(GlContext& gl, const Scene& scene,
                                                                                const Camera& camera, int subpixels,
                                                                                int max_rows) {
  return std::make_unique<GlBands>(gl, scene, camera, subpixels, max_rows);
}

DeepFramebuffer build_deep_framebuffer_gl(GlContext& ctx, const Scene& scene, const Camera& camera, int subpixels) {
  detail::check_deep_framebuffer_grid(camera, subpixels);
  const int H = camera.height() * subpixels;
  GlBands bands(ctx, scene, camera, subpixels, H);
  DeepFramebuffer dfb;
  bands.build(0, H, &dfb);
  return dfb;
}

}  // namespace epr
