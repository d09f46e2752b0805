// Each back-end's downsample_pixels() (computed where the accumulation lives) equals the reference
// downsample(read()) of reprojection_image.h: M' identical, L_rp equal to float rounding.
#include <gtest/gtest.h>

#include <random>

#include "master/deep_framebuffer.h"
#include "master/gl_context.h"
#include "master/make_reprojector.h"
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

// The Cornell box at 64 x 48 (S = 4), its GL deep framebuffer and the default epsilon.
class DownsamplePixels : public ::testing::Test {
 protected:
  DownsamplePixels() : dfb(build_deep_framebuffer_gl(gl, scene, cam, 4)) {
    rs.epsilon = default_epsilon(scene.bounds());
  }
  const Scene scene = test::scene_named("cornell");
  const Camera cam{scene.camera, 64, 48};
  GlContext gl;
  const DeepFramebuffer dfb;
  ReprojectorSettings rs;

  // Pixel p skipped when (p * mul + p / 64) % mod == 0: about 1 / mod of them, scattered.
  std::vector<uint8_t> scattered_skips(size_t mul, size_t mod) const {
    std::vector<uint8_t> skip(size_t(cam.width()) * size_t(cam.height()));
    for (size_t p = 0; p < skip.size(); ++p) skip[p] = (p * mul + p / 64) % mod == 0;
    return skip;
  }
};

TEST_F(DownsamplePixels, EveryBackendMatchesTheReference) {
  const auto points = test::real_like_points(scene, dfb, cam, 200000, 7);
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

// downsample_pixels_into with a skip mask: the pixels not skipped are brought up to date, the
// skipped ones keep what they had (a skip-mode round refreshes only the active pixels).
TEST_F(DownsamplePixels, SkippedPixelsKeepTheirValues) {
  const auto first = test::real_like_points(scene, dfb, cam, 100000, 8);
  const auto second = test::real_like_points(scene, dfb, cam, 100000, 9);
  const std::vector<uint8_t> skip = scattered_skips(7, 3);
  for (const char* backend : {"cpu", "gl"}) {
    SCOPED_TRACE(backend);
    auto r = make_reprojector(backend, cam, dfb, rs, &gl);
    r->reproject(first);
    PixelReprojection partial;
    r->downsample_pixels_into(&partial, skip);  // empty *out: every pixel, mask or not
    const PixelReprojection before = partial;
    expect_same(before, downsample(r->read()));
    r->reproject(second);
    r->downsample_pixels_into(&partial, skip);
    const PixelReprojection now = downsample(r->read());
    size_t changed_skipped = 0, updated = 0;
    for (size_t p = 0; p < skip.size(); ++p) {
      if (skip[p]) {
        ASSERT_EQ(partial.count[p], before.count[p]) << p;
        changed_skipped += now.count[p] != before.count[p];
      } else {
        ASSERT_EQ(partial.count[p], now.count[p]) << p;
        for (int c = 0; c < 3; ++c)
          ASSERT_NEAR(partial.radiance.data[3 * p + size_t(c)], now.radiance.data[3 * p + size_t(c)],
                      1e-5f * std::max(1.f, std::abs(now.radiance.data[3 * p + size_t(c)])));
        updated += now.count[p] != before.count[p];
      }
    }
    EXPECT_GT(changed_skipped, 100u) << "skipped pixels must have received samples, or the test shows nothing";
    EXPECT_GT(updated, 100u);
    r->downsample_pixels_into(&partial);  // no mask: every pixel
    expect_same(partial, now);
  }
}

// DownsampleParts::kCounts (a skip round's refresh): the active pixels' M' is brought up to date, every L_rp and
// the skipped pixels' M' stay as they were; a full refresh afterwards gives the reference.
TEST_F(DownsamplePixels, CountsOnlyRefreshesTheActivePixelsCounts) {
  const auto first = test::real_like_points(scene, dfb, cam, 100000, 10);
  const auto second = test::real_like_points(scene, dfb, cam, 100000, 11);
  const std::vector<uint8_t> skip = scattered_skips(5, 4);
  for (const char* backend : {"cpu", "gl"}) {
    SCOPED_TRACE(backend);
    auto r = make_reprojector(backend, cam, dfb, rs, &gl);
    r->reproject(first);
    PixelReprojection out;
    r->downsample_pixels_into(&out, skip, DownsampleParts::kCounts);  // empty *out: every pixel's M', no L_rp
    EXPECT_EQ(out.count, downsample(r->read()).count);
    EXPECT_TRUE(out.radiance.data.empty()) << "kCounts must not make L_rp";
    r->downsample_pixels_into(&out);
    const PixelReprojection before = out;
    expect_same(before, downsample(r->read()));
    r->reproject(second);
    r->downsample_pixels_into(&out, skip, DownsampleParts::kCounts);
    const PixelReprojection now = downsample(r->read());
    EXPECT_EQ(out.radiance.data, before.radiance.data) << "kCounts must leave L_rp alone";
    size_t updated = 0;
    for (size_t p = 0; p < skip.size(); ++p) {
      ASSERT_EQ(out.count[p], skip[p] ? before.count[p] : now.count[p]) << p;
      updated += !skip[p] && now.count[p] != before.count[p];
    }
    EXPECT_GT(updated, 100u) << "active pixels must have received samples, or the test shows nothing";
    r->downsample_pixels_into(&out);
    expect_same(out, now);
  }
}

// DownsampleParts::kRadiance (a preview that keeps M' as it was): L_rp of the active pixels is made,
// no count array is allocated, and counts already there are left alone.
TEST_F(DownsamplePixels, RadianceOnlyLeavesTheCountsAlone) {
  const auto points = test::real_like_points(scene, dfb, cam, 100000, 12);
  for (const char* backend : {"cpu", "gl"}) {
    SCOPED_TRACE(backend);
    auto r = make_reprojector(backend, cam, dfb, rs, &gl);
    r->reproject(points);
    const PixelReprojection reference = downsample(r->read());
    PixelReprojection out;
    r->downsample_pixels_into(&out, {}, DownsampleParts::kRadiance);
    EXPECT_TRUE(out.count.empty()) << "kRadiance must not make M'";
    EXPECT_EQ(out.radiance.data, reference.radiance.data);
    out.count.assign(reference.count.size(), 7);
    r->downsample_pixels_into(&out, {}, DownsampleParts::kRadiance);
    EXPECT_EQ(out.count, std::vector<uint32_t>(reference.count.size(), 7)) << "kRadiance must leave M' alone";
    EXPECT_EQ(out.radiance.data, reference.radiance.data);
  }
}

}  // namespace
}  // namespace epr
