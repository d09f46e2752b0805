// build_plane_grid: the plane grid built band of rows by band of rows (any band height, GL and CPU
// builders) is make_plane_grid of the full-frame deep framebuffer bit for bit; a 15360-texel-wide grid
// (3840 pixels at S = 4) builds with GL and agrees with the CPU builder.
#include "master/plane_grid_builder.h"

#include <gtest/gtest.h>

#include <cstring>

#include "master/deep_framebuffer.h"
#include "master/gl_context.h"
#include "test_scenes.h"

namespace epr {
namespace {

template <class T>
bool same_bits(const std::vector<T>& a, const std::vector<T>& b) {
  return a.size() == b.size() && (a.empty() || std::memcmp(a.data(), b.data(), a.size() * sizeof(T)) == 0);
}

void expect_identical(const detail::PlaneGrid& a, const detail::PlaneGrid& b) {
  EXPECT_EQ(a.width, b.width);
  EXPECT_EQ(a.height, b.height);
  EXPECT_EQ(a.subpixels, b.subpixels);
  EXPECT_EQ(a.crease_tolerance, b.crease_tolerance);
  EXPECT_EQ(a.has_creases, b.has_creases);
  EXPECT_EQ(a.first_creased, b.first_creased);
  EXPECT_TRUE(same_bits(a.planes, b.planes)) << a.planes.size() << " vs " << b.planes.size() << " plane floats";
  EXPECT_TRUE(same_bits(a.crease_range, b.crease_range));
  EXPECT_TRUE(same_bits(a.creases, b.creases));
  ASSERT_EQ(a.texel_plane.size(), b.texel_plane.size());
  size_t differ = 0, first = 0;
  for (size_t t = 0; t < a.texel_plane.size(); ++t)
    if (a.texel_plane[t] != b.texel_plane[t] && differ++ == 0) first = t;
  EXPECT_EQ(differ, 0u) << "first differing texel " << first << " (row " << first / size_t(a.width) << ")";
}

struct Case {
  const char* scene;
  int width, height, subpixels;
};

constexpr Case kCases[] = {{"cornell", 48, 40, 4}, {"thinwall", 40, 32, 4}, {"hall", 36, 28, 3}};
constexpr int kBandRows[] = {1, 2, 3, 7, 0};

float tolerance_of(const Scene& scene) {
  return 3e-4f * scene.bounds().diagonal_length() * detail::kCreaseToleranceFraction;
}

TEST(PlaneGridBuilder, CpuBandsEqualTheFullFrame) {
  for (const Case& c : kCases) {
    const Scene scene = test::scene_named(c.scene);
    const Camera cam(scene.camera, c.width, c.height);
    const DeepFramebuffer dfb = build_deep_framebuffer_cpu(scene, cam, c.subpixels);
    for (bool creases : {true, false}) {
      const detail::PlaneGrid ref = detail::make_plane_grid(dfb, cam.eye(), tolerance_of(scene), creases);
      if (creases) {
        EXPECT_GT(ref.creased_entries(), 0u) << c.scene;
      }
      for (int rows : kBandRows) {
        SCOPED_TRACE(::testing::Message() << c.scene << " creases " << creases << " band rows " << rows);
        expect_identical(detail::build_plane_grid(scene, cam, c.subpixels, tolerance_of(scene), creases, nullptr, rows),
                         ref);
      }
    }
  }
}

TEST(PlaneGridBuilder, CpuBandsOfAnyDeepFramebufferBandEqualTheFullFrame) {
  // The builder itself, fed from one full-frame deep framebuffer cut into bands with halos.
  const Scene scene = test::scene_named("thinwall");
  const Camera cam(scene.camera, 40, 32);
  const DeepFramebuffer dfb = build_deep_framebuffer_cpu(scene, cam, 2);
  const detail::PlaneGrid ref = detail::make_plane_grid(dfb, cam.eye(), tolerance_of(scene), true);
  for (int rows : {1, 5, 13, 64}) {
    detail::PlaneGridBuilder b(dfb.width, dfb.height, 2, cam.eye(), tolerance_of(scene), true);
    for (int r0 = 0; r0 < dfb.height; r0 += rows) {
      const int r1 = std::min(dfb.height, r0 + rows), b0 = std::max(0, r0 - 1), b1 = std::min(dfb.height, r1 + 1);
      DeepFramebuffer band;
      band.resize(dfb.width, b1 - b0, 2);
      band.first_row = b0;
      const size_t o = size_t(b0) * dfb.width, n = band.texel_count();
      std::copy_n(dfb.position.begin() + 3 * o, 3 * n, band.position.begin());
      std::copy_n(dfb.normal.begin() + 3 * o, 3 * n, band.normal.begin());
      std::copy_n(dfb.plane_offset.begin() + o, n, band.plane_offset.begin());
      std::copy_n(dfb.covered.begin() + o, n, band.covered.begin());
      std::copy_n(dfb.triangle.begin() + o, n, band.triangle.begin());
      b.add_band(band, r0, r1);
    }
    SCOPED_TRACE(rows);
    expect_identical(b.finish(), ref);
  }
}

TEST(PlaneGridBuilder, RefusesBandsWithoutTheirHaloOrOutOfOrder) {
  const Scene scene = test::scene_named("cornell");
  const Camera cam(scene.camera, 8, 8);
  auto bands = detail::cpu_deep_framebuffer_bands(scene, cam, 2);
  DeepFramebuffer band;
  bands->build(0, 4, &band);
  detail::PlaneGridBuilder b(16, 16, 2, cam.eye(), 0, true);
  EXPECT_THROW(b.add_band(band, 0, 4), std::invalid_argument);  // no row 4 below
  EXPECT_THROW(b.add_band(band, 1, 3), std::invalid_argument);  // not from row 0
  b.add_band(band, 0, 3);
  EXPECT_THROW(b.finish(), std::logic_error);  // rows 3-15 missing
}

class PlaneGridBuilderGl : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(gl_available()) << "OSMesa unavailable: run scripts/setup.sh (libosmesa6)";
    ctx_ = std::make_unique<GlContext>();
  }
  std::unique_ptr<GlContext> ctx_;
};

TEST_F(PlaneGridBuilderGl, GlBandsEqualTheFullFrame) {
  for (const Case& c : kCases) {
    const Scene scene = test::scene_named(c.scene);
    const Camera cam(scene.camera, c.width, c.height);
    const DeepFramebuffer dfb = build_deep_framebuffer_gl(*ctx_, scene, cam, c.subpixels);
    for (bool creases : {true, false}) {
      const detail::PlaneGrid ref = detail::make_plane_grid(dfb, cam.eye(), tolerance_of(scene), creases);
      for (int rows : kBandRows) {
        SCOPED_TRACE(::testing::Message() << c.scene << " creases " << creases << " band rows " << rows);
        expect_identical(
            detail::build_plane_grid(scene, cam, c.subpixels, tolerance_of(scene), creases, ctx_.get(), rows), ref);
      }
    }
  }
}

TEST_F(PlaneGridBuilderGl, TallGridBandsEqualTheFullFrame) {
  // 4096 texel rows: the bands' shifted viewports place rows of every magnitude at framebuffer row 0.
  const Scene scene = test::scene_named("cornell");
  const Camera cam(scene.camera, 48, 1024);
  const DeepFramebuffer dfb = build_deep_framebuffer_gl(*ctx_, scene, cam, 4);
  const detail::PlaneGrid ref = detail::make_plane_grid(dfb, cam.eye(), tolerance_of(scene), true);
  for (int rows : {7, 0}) {
    SCOPED_TRACE(rows);
    expect_identical(detail::build_plane_grid(scene, cam, 4, tolerance_of(scene), true, ctx_.get(), rows), ref);
  }
}

// Per texel, the plane (N, d) it sees, or none.
bool plane_at(const detail::PlaneGrid& g, size_t t, float out[4]) {
  const uint32_t e = g.texel_plane[t];
  if (e == detail::PlaneGrid::kUncovered) return false;
  std::memcpy(out, &g.planes[4 * size_t(e)], 16);
  return true;
}

TEST_F(PlaneGridBuilderGl, GridOf15360TexelsPerRowBuildsAndAgreesWithCpu) {
  const Scene scene = test::scene_named("cornell");
  CameraSpec spec = scene.camera;
  spec.fov_y_degrees = 0.3f;         // ~64 degrees across at 240:1
  const Camera cam(spec, 3840, 16);  // 15360 x 64 texels
  const float tol = tolerance_of(scene);
  const detail::PlaneGrid gl = detail::build_plane_grid(scene, cam, 4, tol, true, ctx_.get());
  const detail::PlaneGrid cpu = detail::build_plane_grid(scene, cam, 4, tol, true, nullptr);
  ASSERT_EQ(gl.width, 15360);
  ASSERT_EQ(gl.height, 64);
  // Several bands, equal to the full frame (which still fits one framebuffer at this height).
  expect_identical(detail::build_plane_grid(scene, cam, 4, tol, true, ctx_.get(), 5), gl);
  expect_identical(gl, detail::make_plane_grid(build_deep_framebuffer_gl(*ctx_, scene, cam, 4), cam.eye(), tol, true));
  // GL and CPU: coverage and planes differ only where a triangle edge passes (nearly) through a texel
  // centre (deep_framebuffer.h): a thin fraction of the texels.
  size_t covered = 0, coverage_differs = 0, plane_differs = 0;
  for (size_t t = 0; t < gl.texel_plane.size(); ++t) {
    float a[4], b[4];
    const bool ca = plane_at(gl, t, a), cb = plane_at(cpu, t, b);
    covered += ca;
    if (ca != cb)
      ++coverage_differs;
    else if (ca && std::memcmp(a, b, 16) != 0)
      ++plane_differs;
  }
  EXPECT_GT(covered, gl.texel_plane.size() / 2);
  EXPECT_LT(coverage_differs, gl.texel_plane.size() / 1000);
  EXPECT_LT(plane_differs, gl.texel_plane.size() / 100);
}

TEST_F(PlaneGridBuilderGl, AutomaticBandsAreBoundedAndRefusalsAreClear) {
  EXPECT_LE(size_t(detail::automatic_band_rows(15360, 8640, true)) * 15360 * (33 + 4 + 12),
            detail::kPlaneGridBandBytes);
  EXPECT_GE(detail::automatic_band_rows(15360, 8640, true), 8);
  EXPECT_EQ(detail::automatic_band_rows(64, 48, false), 48);
  const Scene scene = test::scene_named("cornell");
  EXPECT_THROW(detail::build_plane_grid(scene, Camera(scene.camera, 4200, 8), 4, 0, true, ctx_.get()),
               std::invalid_argument);  // 16800 texels per row: over the grid's 16384
}

}  // namespace
}  // namespace epr
