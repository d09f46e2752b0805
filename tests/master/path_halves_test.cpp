// The variance combination's halves of a pixel's path samples (FrameState::path_half, combine_rule.h):
// the rounds of even index make half 0, the odd ones half 1; their sums (without the glossy part),
// counts and batch scatters are those of the batches given, and add up to the frame's totals.
#include <gtest/gtest.h>

#include <stdexcept>
#include <string>
#include <vector>

#include "master/combine_rule.h"
#include "master/frame_state.h"
#include "master/memory_estimate.h"
#include "tests/master/test_scenes.h"

namespace epr {
namespace {

// A 4 x 2 frame of the Cornell box, reprojected on the CPU, with the variance combination.
RenderOptions variance_options(int spp) {
  RenderOptions o;
  o.width = 4;
  o.height = 2;
  o.spp = spp;
  o.mode = RenderMode::kReproject;
  o.reproject = ReprojectMethod::kCpu;
  o.combine = CombineRule::kVariance;
  return o;
}

TEST(PathHalves, EvenAndOddRoundsAddUpToTheTotals) {
  const Scene scene = test::scene_named("cornell");
  const RenderOptions o = variance_options(32);
  const Camera camera(scene.camera, o.width, o.height);
  FrameState frame(o, camera, scene);
  const size_t pixels = size_t(o.width) * size_t(o.height);
  // Expected per pixel and half: diffuse sum (luminance of a grey value is the value), paths, B, rounds.
  std::vector<double> sum(2 * pixels, 0), m2(2 * pixels, 0);
  std::vector<uint32_t> paths(2 * pixels, 0), rounds(2 * pixels, 0);
  int round = 0;
  do {
    const uint32_t k = uint32_t(frame.next_paths_per_pixel());
    std::vector<Vec3> sums, glossy;
    std::vector<uint32_t> counts(pixels, k);
    for (size_t p = 0; p < pixels; ++p) {
      // A batch of k paths of diffuse value (p + 1) * (1 + round % 3), plus a glossy part of 0.25 per path.
      const float diffuse = float(k) * float(p + 1) * float(1 + round % 3);
      sums.push_back(Vec3(diffuse + 0.25f * float(k)));
      glossy.push_back(Vec3(0.25f * float(k)));
      const size_t i = 2 * p + size_t(round & 1);
      m2[i] = add_batch(m2[i], sum[i], paths[i], diffuse, k);
      sum[i] += diffuse;
      paths[i] += k;
      ++rounds[i];
    }
    frame.add_paths(0, 0, o.width, o.height, sums, counts, glossy);
    ++round;
  } while (frame.finish_round());
  ASSERT_GE(round, 8);
  for (size_t p = 0; p < pixels; ++p) {
    const CombineHalf even = frame.path_half(p, 0), odd = frame.path_half(p, 1);
    EXPECT_EQ(even.paths + odd.paths, double(frame.path_counts()[p])) << p;
    EXPECT_EQ(even.paths, paths[2 * p]) << p;
    EXPECT_EQ(odd.paths, paths[2 * p + 1]) << p;
    const double total = frame.path_sums()[3 * p] - 0.25 * frame.path_counts()[p];
    EXPECT_NEAR(even.path_sum.x + odd.path_sum.x, total, 1e-5 * total) << p;
    EXPECT_NEAR(even.path_sum.x, sum[2 * p], 1e-5 * sum[2 * p]) << p;
    EXPECT_NEAR(odd.path_sum.y, sum[2 * p + 1], 1e-4 * sum[2 * p + 1]) << p;
    for (int h = 0; h < 2; ++h) {
      const size_t i = 2 * p + size_t(h);
      const double want = path_sample_variance(m2[i], rounds[i]);
      EXPECT_GT(want, 0) << p;
      EXPECT_NEAR((h == 0 ? even : odd).path_variance, want, 1e-3 * want) << p << " half " << h;
    }
  }
}

// A snapshot of the variance combination without the halves (a checkpoint older than version 6) does
// not restore, naming why; the memory estimate counts what the halves add.
TEST(PathHalves, AnOlderSnapshotWithoutHalvesIsRefusedAndTheEstimateCountsThem) {
  const Scene scene = test::scene_named("cornell");
  RenderOptions o = variance_options(8);
  const Camera camera(scene.camera, o.width, o.height);
  FrameState frame(o, camera, scene);
  FrameSnapshot old = frame.save();
  ASSERT_EQ(old.path_half_sum.size(), 3u * 8u);
  old.path_half_sum.clear();
  old.path_m2.resize(8);  // one B per pixel, as version 5 held
  try {
    frame.restore(old);
    ADD_FAILURE() << "a snapshot without halves restored";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("predates"), std::string::npos) << e.what();
  }
  RenderOptions fixed = o;
  fixed.combine = CombineRule::kFixed;
  o.width = fixed.width = 100;
  o.height = fixed.height = 10;
  // FrameState's B per half, M'_eff and the even rounds' sums (24); a downsampling's M'_eff (4) and
  // halves (42); the combined image (12).
  EXPECT_EQ(estimate_job_memory(o, false).pixel_bytes - estimate_job_memory(fixed, false).pixel_bytes, 1000u * 82u);
}

}  // namespace
}  // namespace epr
