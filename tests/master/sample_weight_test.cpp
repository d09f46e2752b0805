// Reprojector::set_sample_weight (frame windows weigh a neighbour's samples, DESIGN.md "Frame
// windows"): a sample accepted at weight w adds w to its subpixel's count and w times its radiance
// to the sum, in every back-end, as w copies of it at weight 1 would.
#include <gtest/gtest.h>

#include "master/deep_framebuffer.h"
#include "master/gl_context.h"
#include "master/make_reprojector.h"
#include "master/reprojector.h"
#include "test_scenes.h"

namespace epr {
namespace {

TEST(SampleWeight, ASampleOfWeightWCountsAsWCopiesInEveryBackend) {
  const Scene scene = test::scene_named("cornell");
  const Camera cam{scene.camera, 64, 48};
  GlContext gl;
  const DeepFramebuffer dfb = build_deep_framebuffer_gl(gl, scene, cam, 4);
  ReprojectorSettings rs;
  rs.epsilon = default_epsilon(scene.bounds());
  const auto own = test::real_like_points(scene, dfb, cam, 60000, 11);
  const auto other = test::real_like_points(scene, dfb, cam, 60000, 12);
  // The reference: weight 1 throughout, `other` three times.
  auto ref = make_reprojector("cpu", cam, dfb, rs, nullptr);
  ref->reproject(own);
  for (int i = 0; i < 3; ++i) ref->reproject(other);
  ref->reproject(own);
  const SubpixelAccumulation want = ref->read();
  uint64_t want_total = 0;
  for (uint32_t n : want.count) want_total += n;
  auto alone = make_reprojector("cpu", cam, dfb, rs, nullptr);
  alone->reproject(other);
  const uint64_t other_accepted = alone->counts().accepted;
  ASSERT_GT(other_accepted, 1000u);

  ReprojectorSettings banded = rs;
  banded.gl_max_band_cells = 64 * 4 * 4 * 12;  // four bands: the GL back-end's batches wait per band
  const std::pair<const char*, ReprojectorSettings> configs[] = {{"cpu", rs}, {"gl", rs}, {"gl", banded}};
  for (const auto& [backend, settings] : configs) {
    SCOPED_TRACE(std::string(backend) + (settings.gl_max_band_cells ? ", four bands" : ""));
    auto r = make_reprojector(backend, cam, dfb, settings, &gl);
    EXPECT_EQ(r->sample_weight(), 1u);
    r->reproject(own);
    r->set_sample_weight(3);
    r->reproject(other);
    r->set_sample_weight(1);
    r->reproject(own);
    const SubpixelAccumulation got = r->read();
    ASSERT_EQ(got.count.size(), want.count.size());
    size_t wrong = 0;
    for (size_t i = 0; i < want.count.size(); ++i) {
      wrong += got.count[i] != want.count[i];
      for (int c = 0; c < 3; ++c)
        ASSERT_NEAR(got.sum[3 * i + c], want.sum[3 * i + c], 1e-4f * std::max(1.f, std::abs(want.sum[3 * i + c])))
            << "subpixel " << i;
    }
    EXPECT_EQ(wrong, 0u) << "subpixels whose count is not that of the copies";
    // The counters count vertices, not weights: `other`'s accepted ones once.
    EXPECT_EQ(r->counts().accepted, want_total - 2 * other_accepted);
    // Exact samples add 1 whatever the weight.
    r->set_sample_weight(5);
    r->add_exact(std::vector<ExactSample>{{0, Vec3(1.f)}});
    EXPECT_EQ(r->read().count[0], want.count[0] + 1);
  }
}

}  // namespace
}  // namespace epr
