// Deep framebuffer: the GL rasteriser and the CPU ray caster agree at interior texels, the texel
// grid follows Camera's raster convention (y down, texel centres at (i + 0.5) / S), planes are exact.
#include "master/deep_framebuffer.h"

#include <gtest/gtest.h>

#include "master/gl_context.h"
#include "test_scenes.h"

namespace epr {
namespace {

// A quad in the plane z = 0 covering [x0, x1] x [y0, y1], facing +z.
Scene quad_scene(float x0, float x1, float y0, float y1, float z = 0) {
  Scene s;
  const uint32_t m = add_material(s, Material{});
  add_quad(s, {x0, y0, z}, {x1, y0, z}, {x1, y1, z}, {x0, y1, z}, m);
  return s;
}

CameraSpec head_on() {
  CameraSpec c;
  c.eye = {0, 0, 3};
  c.look = {0, 0, 0};
  c.up = {0, 1, 0};
  c.fov_y_degrees = 40;
  return c;
}

// Texels whose 3x3 neighbourhood is covered by a single triangle in `a` (interior of a triangle).
bool interior(const DeepFramebuffer& a, int x, int y) {
  const uint32_t t = a.triangle[a.index(x, y)];
  if (t == DeepFramebuffer::kNoTriangle) return false;
  for (int dy = -1; dy <= 1; ++dy)
    for (int dx = -1; dx <= 1; ++dx) {
      const int xx = x + dx, yy = y + dy;
      if (xx < 0 || yy < 0 || xx >= a.width || yy >= a.height || a.triangle[a.index(xx, yy)] != t) return false;
    }
  return true;
}

void expect_interior_agreement(const DeepFramebuffer& gl, const DeepFramebuffer& cpu, const Scene& scene) {
  ASSERT_EQ(gl.width, cpu.width);
  ASSERT_EQ(gl.height, cpu.height);
  size_t compared = 0, differ = 0;
  float worst = 0;
  for (int y = 0; y < gl.height; ++y)
    for (int x = 0; x < gl.width; ++x) {
      const size_t k = gl.index(x, y);
      const bool in_gl = interior(gl, x, y), in_cpu = interior(cpu, x, y);
      if (in_gl != in_cpu && (gl.covered[k] != cpu.covered[k])) ++differ;  // coverage disagreement inside
      if (!(in_gl && in_cpu)) continue;
      ++compared;
      if (gl.triangle[k] != cpu.triangle[k]) {
        ++differ;
        continue;
      }
      EXPECT_EQ(gl.normal_at(k), cpu.normal_at(k));
      EXPECT_EQ(gl.plane_offset[k], cpu.plane_offset[k]);
      worst = std::max(worst, length(gl.position_at(k) - cpu.position_at(k)));
    }
  EXPECT_GT(compared, gl.texel_count() / 4) << "too few interior texels to compare";
  EXPECT_EQ(differ, 0u);
  EXPECT_LT(worst, 1e-4f * scene.bounds().diagonal_length()) << "positions of the same texel differ";
}

class DeepFramebufferGl : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(gl_available()) << "OSMesa unavailable: run scripts/setup.sh (libosmesa6)";
    ctx_ = std::make_unique<GlContext>();
  }
  std::unique_ptr<GlContext> ctx_;
};

TEST_F(DeepFramebufferGl, AgreesWithCpuAtInteriorTexelsOnCornell) {
  const Scene scene = test::scene_named("cornell");
  const Camera cam(scene.camera, 96, 80);
  const DeepFramebuffer gl = build_deep_framebuffer_gl(*ctx_, scene, cam, 4);
  const DeepFramebuffer cpu = build_deep_framebuffer_cpu(scene, cam, 4);
  EXPECT_EQ(gl.width, 96 * 4);
  EXPECT_EQ(gl.height, 80 * 4);
  expect_interior_agreement(gl, cpu, scene);
  // Coverage differs at most along edges: a small fraction of the texels.
  size_t cov_diff = 0;
  for (size_t k = 0; k < gl.texel_count(); ++k) cov_diff += gl.covered[k] != cpu.covered[k];
  EXPECT_LT(cov_diff, gl.texel_count() / 100);
}

TEST_F(DeepFramebufferGl, AgreesWithCpuOnHallWithOcclusionAndNearClipping) {
  const Scene scene = test::scene_named("hall");
  const Camera cam(scene.camera, 64, 48);
  const DeepFramebuffer gl = build_deep_framebuffer_gl(*ctx_, scene, cam, 2);
  const DeepFramebuffer cpu = build_deep_framebuffer_cpu(scene, cam, 2);
  expect_interior_agreement(gl, cpu, scene);
}

TEST_F(DeepFramebufferGl, RowZeroIsTheTopOfTheImage) {
  // Quad covering only the upper half of the view (y > 0 in world = top of image).
  const Scene scene = quad_scene(-10, 10, 0.05f, 10);
  const Camera cam(head_on(), 32, 32);
  for (const DeepFramebuffer& d :
       {build_deep_framebuffer_gl(*ctx_, scene, cam, 4), build_deep_framebuffer_cpu(scene, cam, 4)}) {
    EXPECT_TRUE(d.covered[d.index(5, 2)]) << "top row must be covered";
    EXPECT_FALSE(d.covered[d.index(5, d.height - 3)]) << "bottom row must be empty";
  }
}

TEST_F(DeepFramebufferGl, TexelCentresFollowCameraProjection) {
  // A small quad whose left edge sits exactly between two texel centres: texel columns left of
  // the projected edge are empty, right of it covered, for both builders.
  const Camera cam(head_on(), 40, 40);
  const int S = 4;
  // World x of raster x = 21.125 texels... choose raster x_edge = 83.0 / S (between centres 82.5 and 83.5).
  const float edge_rx = 83.0f / S;
  const Ray r = cam.generate_ray(edge_rx, 20.f);
  const float x_edge = r.origin.x + r.dir.x * (-r.origin.z / r.dir.z);
  const Scene scene = quad_scene(x_edge, 5, -5, 5);
  for (const DeepFramebuffer& d :
       {build_deep_framebuffer_gl(*ctx_, scene, cam, S), build_deep_framebuffer_cpu(scene, cam, S)}) {
    for (int y : {10, 80, 150}) {
      EXPECT_FALSE(d.covered[d.index(82, y)]) << "y " << y;
      EXPECT_TRUE(d.covered[d.index(83, y)]) << "y " << y;
    }
    // The stored position of a texel is the surface point under its centre.
    float rx, ry;
    const Vec3 p = d.position_at(d.index(100, 61));
    ASSERT_TRUE(cam.project(p, &rx, &ry));
    EXPECT_NEAR(rx * S, 100.5f, 1e-3f);
    EXPECT_NEAR(ry * S, 61.5f, 1e-3f);
  }
}

TEST(DeepFramebufferCpu, AxisAlignedPlanesAreExact) {
  const Scene scene = quad_scene(-1, 1, -1, 1, 0.3f);
  const Camera cam(head_on(), 16, 16);
  const DeepFramebuffer d = build_deep_framebuffer_cpu(scene, cam, 2);
  const size_t k = d.index(16, 16);
  ASSERT_TRUE(d.covered[k]);
  EXPECT_EQ(std::fabs(d.normal_at(k).x), 0.f);
  EXPECT_EQ(std::fabs(d.normal_at(k).y), 0.f);
  EXPECT_EQ(d.normal_at(k).z, 1.f);
  EXPECT_EQ(d.plane_offset[k], 0.3f);
}

TEST(DeepFramebufferCpu, NearestSurfaceWinsAndEmptyViewIsUncovered) {
  Scene scene = quad_scene(-1, 1, -1, 1, 0);
  const uint32_t m = 0;
  add_quad(scene, {-0.2f, -0.2f, 1}, {0.2f, -0.2f, 1}, {0.2f, 0.2f, 1}, {-0.2f, 0.2f, 1}, m);  // in front
  const Camera cam(head_on(), 16, 16);
  const DeepFramebuffer d = build_deep_framebuffer_cpu(scene, cam, 2);
  EXPECT_EQ(d.plane_offset[d.index(16, 16)], 1.f);
  EXPECT_EQ(d.plane_offset[d.index(16, 4)], 0.f);
  CameraSpec away = head_on();
  away.look = {0, 0, 6};  // looking away from everything
  const DeepFramebuffer e = build_deep_framebuffer_cpu(scene, Camera(away, 16, 16), 2);
  EXPECT_EQ(e.covered_count(), 0u);
}

TEST(DeepFramebufferCpu, RejectsBadGrids) {
  const Scene scene = quad_scene(-1, 1, -1, 1);
  EXPECT_THROW(build_deep_framebuffer_cpu(scene, Camera(head_on(), 16, 16), 0), std::invalid_argument);
  EXPECT_THROW(build_deep_framebuffer_cpu(scene, Camera(head_on(), 8192, 16), 4), std::invalid_argument);
}

}  // namespace
}  // namespace epr
