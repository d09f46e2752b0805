// Each back-end's downsample_pixels() (computed where the accumulation lives) equals the reference
// downsample(read()) of reprojection_image.h: M' identical, L_rp equal to float rounding.
#include <gtest/gtest.h>

#include <random>

#include "master/deep_framebuffer.h"
#include "master/gl_context.h"
#include "master/reprojection_image.h"
#include "master/reprojector.h"
#include "test_scenes.h"

namespace epr {
namespace {

void expect_same(const PixelReprojection& a, const PixelReprojection& b) {
  ASSERT_EQ(a.count, b.count);
  ASSERT_EQ(a.radiance.data.size(), b.radiance.data.size());
  for (size_t i = 0; i < a.radiance.data.size(); ++i)
    ASSERT_NEAR(a.radiance.data[i], b.radiance.data[i], 1e-5f * std::max(1.f, std::abs(b.radiance.data[i]))) << i;
}

TEST(DownsamplePixels, EveryBackendMatchesTheReference) {
  const Scene scene = test::scene_named("cornell");
  const Camera cam(scene.camera, 64, 48);
  GlContext gl;
  const DeepFramebuffer dfb = build_deep_framebuffer_gl(gl, scene, cam, 4);
  const auto points = test::real_like_points(scene, dfb, cam, 200000, 7);
  ReprojectorSettings rs;
  rs.epsilon = default_epsilon(scene.bounds());
  for (const char* backend : {"cpu", "gl"}) {
    auto r = make_reprojector(backend, cam, dfb, rs, &gl);
    r->reproject(points);
    const PixelReprojection fast = r->downsample_pixels();
    const PixelReprojection ref = downsample(r->read());
    SCOPED_TRACE(backend);
    expect_same(fast, ref);
    uint64_t total = 0;
    for (uint64_t n : fast.count) total += n;
    EXPECT_EQ(total, r->counts().accepted);
    EXPECT_GT(total, 0u);
  }
}

}  // namespace
}  // namespace epr
