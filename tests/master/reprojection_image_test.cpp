// Downsampling (mean of non-empty subpixel means, M' = total count), the combination formula and
// the skip mask, on hand-made inputs with known answers.
#include "master/reprojection_image.h"

#include <gtest/gtest.h>

#include "master/frame_state.h"

namespace epr {
namespace {

// 2x1 pixels, S = 2: subpixel grid 4x2.
SubpixelAccumulation two_pixels() {
  SubpixelAccumulation a;
  a.subpixels = 2;
  a.width = 4;
  a.height = 2;
  a.sum.assign(3 * 8, 0.f);
  a.count.assign(8, 0);
  auto set = [&](int x, int y, Vec3 sum, uint32_t n) {
    const size_t i = size_t(y) * 4 + size_t(x);
    a.sum[3 * i] = sum.x, a.sum[3 * i + 1] = sum.y, a.sum[3 * i + 2] = sum.z;
    a.count[i] = n;
  };
  // Pixel 0: subpixel (0,0) has 3 samples summing to 3 (mean 1), (1,1) has 1 sample of 5 (mean 5).
  set(0, 0, {3, 6, 9}, 3);
  set(1, 1, {5, 0, 1}, 1);
  // Pixel 1: empty.
  return a;
}

TEST(Downsample, AveragesNonEmptySubpixelMeansAndSumsCounts) {
  const PixelReprojection p = downsample(two_pixels());
  ASSERT_EQ(p.radiance.width, 2);
  ASSERT_EQ(p.radiance.height, 1);
  // Mean of subpixel means (1,2,3) and (5,0,1) = (3,1,2): NOT the pooled mean (8/4, 6/4, 10/4).
  EXPECT_FLOAT_EQ(p.radiance.rgb(0, 0).x, 3.f);
  EXPECT_FLOAT_EQ(p.radiance.rgb(0, 0).y, 1.f);
  EXPECT_FLOAT_EQ(p.radiance.rgb(0, 0).z, 2.f);
  EXPECT_EQ(p.count[0], 4u);
  EXPECT_EQ(p.radiance.rgb(1, 0), Vec3(0.f));
  EXPECT_EQ(p.count[1], 0u);
}

TEST(Downsample, RejectsMalformedAccumulation) {
  SubpixelAccumulation a = two_pixels();
  a.width = 3;  // not a multiple of S
  EXPECT_THROW(downsample(a), std::invalid_argument);
  a = two_pixels();
  a.count.pop_back();
  EXPECT_THROW(downsample(a), std::invalid_argument);
}

TEST(Combine, WeightsPathSamplesAndReprojectedSamplesByTheirCounts) {
  const PixelReprojection rp = downsample(two_pixels());
  Image path_sum(2, 1, 3);
  path_sum.set_rgb(0, 0, {2, 2, 2});  // M = 2 samples summing to 2 (mean 1)
  path_sum.set_rgb(1, 0, {6, 3, 0});  // M = 3, no reprojection: plain mean
  const Image L = combine(path_sum, {2, 3}, rp);
  // (2 + 4 * 3) / 6, (2 + 4 * 1) / 6, (2 + 4 * 2) / 6
  EXPECT_FLOAT_EQ(L.rgb(0, 0).x, 14.f / 6.f);
  EXPECT_FLOAT_EQ(L.rgb(0, 0).y, 1.f);
  EXPECT_FLOAT_EQ(L.rgb(0, 0).z, 10.f / 6.f);
  EXPECT_FLOAT_EQ(L.rgb(1, 0).x, 2.f);
  EXPECT_FLOAT_EQ(L.rgb(1, 0).y, 1.f);
  // No samples at all: 0, not NaN.
  PixelReprojection none;
  none.radiance = Image(2, 1, 3);
  none.count = {0, 0};
  const Image Z = combine(Image(2, 1, 3), {0, 0}, none);
  EXPECT_EQ(Z.rgb(0, 0), Vec3(0.f));
  // Only reprojected samples: L = L_rp.
  const Image R = combine(Image(2, 1, 3), {0, 0}, rp);
  EXPECT_FLOAT_EQ(R.rgb(0, 0).x, 3.f);
  EXPECT_THROW(combine(path_sum, {1}, rp), std::invalid_argument);
}

TEST(Combine, AReprojectedSampleCountsForWOfAPath) {
  const PixelReprojection rp = downsample(two_pixels());  // pixel 0: M' = 4, L_rp = (3, 1, 2)
  Image path_sum(2, 1, 3);
  path_sum.set_rgb(0, 0, {2, 2, 2});  // M = 2, mean 1
  path_sum.set_rgb(1, 0, {6, 3, 0});
  // W = 0.25: M' = 4 counts as one path. (2 + 1 * 3) / 3, (2 + 1 * 1) / 3, (2 + 1 * 2) / 3.
  const Image L = combine(path_sum, {2, 3}, rp, 0.25f);
  EXPECT_FLOAT_EQ(L.rgb(0, 0).x, 5.f / 3.f);
  EXPECT_FLOAT_EQ(L.rgb(0, 0).y, 1.f);
  EXPECT_FLOAT_EQ(L.rgb(0, 0).z, 4.f / 3.f);
  EXPECT_FLOAT_EQ(L.rgb(1, 0).x, 2.f);  // no reprojected samples: W does not matter
  // Only reprojected samples: L = L_rp whatever W.
  EXPECT_FLOAT_EQ(combine(Image(2, 1, 3), {0, 0}, rp, 0.25f).rgb(0, 0).x, 3.f);
  // W = 1 is the unweighted formula bit for bit.
  const Image one = combine(path_sum, {2, 3}, rp, 1.f), plain = combine(path_sum, {2, 3}, rp);
  EXPECT_EQ(one.data, plain.data);
  EXPECT_FLOAT_EQ(one.rgb(0, 0).x, 14.f / 6.f);
}

// combined_image() takes W from the images, so every consumer of a frame's images (result files,
// previews, the benchmarks) combines with the job's W.
TEST(Combine, CombinedImageUsesTheFramesWeight) {
  const PixelReprojection rp = downsample(two_pixels());
  FrameImages f;
  f.path_sum = Image(2, 1, 3);
  f.path_sum.set_rgb(0, 0, {2, 2, 2});
  f.path_count = Image(2, 1, 1);
  f.path_count.at(0, 0)[0] = 2;
  f.reprojected = Image(2, 1, 1);
  f.reprojected.at(0, 0)[0] = float(rp.count[0]);
  f.reprojection = rp.radiance;
  EXPECT_FLOAT_EQ(combined_image(f).rgb(0, 0).x, 14.f / 6.f);
  f.reprojected_weight = 0.25f;
  EXPECT_FLOAT_EQ(combined_image(f).rgb(0, 0).x, 5.f / 3.f);
}

TEST(SkipMask, SkipsWhenTargetReachedAndEnoughPathsTraced) {
  // P = 8, min_paths = 1 (default).
  const std::vector<uint32_t> m = {0, 1, 4, 8, 7, 2};
  const std::vector<uint32_t> mr = {100, 7, 3, 0, 0, 6};
  EXPECT_EQ(skip_mask(m, mr, 8), (std::vector<uint8_t>{0, 1, 0, 1, 0, 1}));
  // min_paths = 3: pixels with fewer traced paths keep tracing.
  EXPECT_EQ(skip_mask(m, mr, 8, 3), (std::vector<uint8_t>{0, 0, 0, 1, 0, 0}));
  // min_paths = 0: reprojection alone may satisfy a pixel.
  EXPECT_EQ(skip_mask(m, mr, 8, 0), (std::vector<uint8_t>{1, 1, 0, 1, 0, 1}));
  EXPECT_THROW(skip_mask(m, {1, 2}, 8), std::invalid_argument);
}

TEST(SkipMask, ReprojectedSamplesCountForWEach) {
  // P = 8, W = 0.5: M + M' / 2 >= 8.
  const std::vector<uint32_t> m = {1, 1, 4, 4, 7, 8, 0};
  const std::vector<uint32_t> mr = {7, 14, 7, 8, 2, 0, 16};
  EXPECT_EQ(skip_mask(m, mr, 8, 1, 0.5f), (std::vector<uint8_t>{0, 1, 0, 1, 1, 1, 0}));
  // The same counts at W = 1 skip every pixel with a path of its own.
  EXPECT_EQ(skip_mask(m, mr, 8, 1, 1.f), (std::vector<uint8_t>{1, 1, 1, 1, 1, 1, 0}));
  // min_paths still applies.
  EXPECT_EQ(skip_mask(m, mr, 8, 4, 0.5f), (std::vector<uint8_t>{0, 0, 0, 1, 1, 1, 0}));
  EXPECT_TRUE(skip_pixel(2, 6, 5, 1, 0.5f));
  EXPECT_FALSE(skip_pixel(2, 5, 5, 1, 0.5f));
  EXPECT_DOUBLE_EQ(weighted_samples(2, 5, 0.5f), 4.5);
}

}  // namespace
}  // namespace epr

// The ETA counts only the paths the still-active pixels have left, at the pace per path so far.
TEST(EtaSeconds, CountsOnlyActivePixelsAtThePaceSoFar) {
  epr::FrameProgress p;
  p.round = 4;
  p.pixels_active = 100;
  p.pixels_skipped = 900;
  p.mean_paths = 4;
  p.paths_traced = 4000;  // 1000 pixels x 4 paths in 8 s: 2 ms per path
  EXPECT_DOUBLE_EQ(epr::eta_seconds(p, 16, 8.0), 8.0 / 4000 * 100 * 12);
  p.pixels_active = 1000;  // nothing skipped: all pixels' 12 paths left
  EXPECT_DOUBLE_EQ(epr::eta_seconds(p, 16, 8.0), 8.0 / 4000 * 1000 * 12);
  p.pixels_active = 0;  // all skipped: done
  EXPECT_EQ(epr::eta_seconds(p, 16, 8.0), 0.0);
  p.pixels_active = 10;
  p.mean_paths = 20;  // past P
  EXPECT_EQ(epr::eta_seconds(p, 16, 8.0), 0.0);
}
