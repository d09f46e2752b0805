// Our path tracer against an independent renderer: Blender Cycles' 16384-spp render of the shared
// Cornell box OBJ (tests/data/cornell_cycles_128.exr) and its 8192-spp render of builtin:cornell,
// whose light is one-sided (tests/data/cornell_onesided_cycles_128.exr); both made by
// scripts/cycles_reference.py, see tests/data/README.md.
//
// Compared: means over 8x8-pixel blocks (16 x 16 blocks), per channel, with a tolerance taken from
// the noise measured in the two images rather than guessed. The standard error of a block mean is
// estimated two ways and the larger is used:
//   - from our per-sample variance (sums of squares kept per block), and
//   - from the spread of the 64 pixel values inside the block, in each image (for Cycles, the only
//     noise estimate its file allows; structure inside a block makes this conservative).
// The second matters because the OBJ's box has a heavy-tailed component: the light hangs 1 cm below
// the ceiling and emits from both sides, so rare paths that slip into the gap pick up very bright
// light. A block's sample variance underestimates the truth when those paths are
// missing; realised fireflies show up in the pixel spread. Measured on 128x128 renders (seed 7, at
// 43399bd, when next event estimation sampled the light by area only):
// with this sigma, the largest |diff|/sigma was 7.1 at 512 spp (9 of 768 comparisons over 5 sigma)
// and 3.7 at 4096 spp (none); with seed 2024 at 1024 spp one comparison reached 5.8 sigma (a block
// that drew none of the rare bright paths: 0.135 against Cycles' 0.156, where our 4096-spp render
// gives 0.161). Those figures are next event estimation only; with MIS (the tracer's default, used
// here) the heavy tail is gone and the largest |diff|/sigma at seed 2024, 1024 spp is 2.5. The rules,
// kept for either estimator, at 1024 spp (512 for the built-in, which has no such tail):
//   - at most 1 % of the 768 block/channel comparisons may exceed 5 sigma + 1 % of the block mean;
//   - the mean signed relative deviation of block luminance (a bias) is within 1.5 %;
//   - the mean over the whole image agrees within 1 % per channel.
// A wrong albedo, emission, fov or a biased estimator shifts whole regions by several percent and
// fails all three.
#include <gtest/gtest.h>
#include <tbb/parallel_for.h>

#include <cmath>
#include <iostream>

#include "common/image.h"
#include "common/rng.h"
#include "common/scene_loader.h"
#include "worker/path_tracer.h"
#include "worker/sky_light.h"

namespace epr {
namespace {

constexpr int kSize = 128, kBlock = 8, kBlocks = kSize / kBlock;

struct BlockStats {
  double sum[3] = {0, 0, 0}, sum2[3] = {0, 0, 0};
  double pixel_sum[3] = {0, 0, 0}, pixel_sum2[3] = {0, 0, 0};  // over the block's pixel means
};

/// Standard error of a block mean from the spread of its pixel values.
double spread_se(double sum, double sum2, double n) {
  const double mean = sum / n;
  return std::sqrt(std::max(0.0, sum2 / n - mean * mean) / n);
}

/// Renders `spec` at 128 x 128 with `spp` paths per pixel and checks it against the Cycles render
/// tests/data/`exr` by the rules above.
void expect_block_means_match_cycles(const std::string& spec, const std::string& exr, int spp) {
  const std::string dir = std::string(EPR_SOURCE_DIR);
  const Image reference = read_image(dir + "/tests/data/" + exr);
  ASSERT_EQ(reference.width, kSize);
  ASSERT_EQ(reference.height, kSize);

  const Scene scene = load_scene(spec);
  EmbreeScene es(scene);
  const Camera cam(scene.camera, kSize, kSize);
  const SkyLight lights(scene.lighting, es);  // the scene's lamps, if any
  PathTracer tracer(es, cam, 2024, RussianRoulette::paper(), true, SamplerKind::kSobolBurley, &lights);

  std::vector<BlockStats> blocks(kBlocks * kBlocks);
  tbb::parallel_for(0, kBlocks * kBlocks, [&](int b) {
    const int bx = b % kBlocks, by = b / kBlocks;
    BlockStats& st = blocks[size_t(b)];
    for (int y = by * kBlock; y < (by + 1) * kBlock; ++y)
      for (int x = bx * kBlock; x < (bx + 1) * kBlock; ++x) {
        double pixel[3] = {0, 0, 0};
        for (int s = 0; s < spp; ++s) {
          const Vec3 c = tracer.trace(x, y, uint32_t(s), nullptr, nullptr);
          for (int k = 0; k < 3; ++k) {
            st.sum[k] += c[k];
            st.sum2[k] += double(c[k]) * c[k];
            pixel[k] += c[k];
          }
        }
        for (int k = 0; k < 3; ++k) {
          st.pixel_sum[k] += pixel[k] / spp;
          st.pixel_sum2[k] += (pixel[k] / spp) * (pixel[k] / spp);
        }
      }
  });

  const double n = double(kBlock * kBlock * spp);
  double ours_total[3] = {0, 0, 0}, ref_total[3] = {0, 0, 0};
  int failures = 0;
  double signed_rel = 0;
  const double kLum[3] = {0.2126, 0.7152, 0.0722};
  double worst_z = 0;
  for (int b = 0; b < kBlocks * kBlocks; ++b) {
    const int bx = b % kBlocks, by = b / kBlocks;
    double lum_ours = 0, lum_ref = 0;
    for (int k = 0; k < 3; ++k) {
      double ref_sum = 0, ref_sum2 = 0;
      for (int y = by * kBlock; y < (by + 1) * kBlock; ++y)
        for (int x = bx * kBlock; x < (bx + 1) * kBlock; ++x) {
          ref_sum += reference.at(x, y)[k];
          ref_sum2 += double(reference.at(x, y)[k]) * reference.at(x, y)[k];
        }
      const double pixels = kBlock * kBlock;
      const double ref = ref_sum / pixels;
      const BlockStats& st = blocks[size_t(b)];
      const double mean = st.sum[k] / n;
      const double var = std::max(0.0, st.sum2[k] / n - mean * mean);
      const double se_ours = std::max(std::sqrt(var / n), spread_se(st.pixel_sum[k], st.pixel_sum2[k], pixels));
      const double se_ref = spread_se(ref_sum, ref_sum2, pixels);
      const double sigma = std::sqrt(se_ours * se_ours + se_ref * se_ref);
      const double tolerance = 5 * sigma + 0.01 * std::max(mean, ref);
      const double diff = std::abs(mean - ref);
      if (sigma > 0) worst_z = std::max(worst_z, diff / sigma);
      if (diff > tolerance) {
        ++failures;
        std::cout << "over 5 sigma: block (" << bx << "," << by << ") channel " << k << ": ours " << mean << " cycles "
                  << ref << " tolerance " << tolerance << " (se " << se_ours << ")" << std::endl;
      }
      ours_total[k] += mean;
      ref_total[k] += ref;
      lum_ours += mean * kLum[k];
      lum_ref += ref * kLum[k];
    }
    if (lum_ref > 0) signed_rel += (lum_ours - lum_ref) / lum_ref;
  }
  for (int k = 0; k < 3; ++k)
    EXPECT_NEAR(ours_total[k], ref_total[k], 0.01 * ref_total[k]) << "image mean, channel " << k;
  EXPECT_LE(failures, kBlocks * kBlocks * 3 / 100) << "block/channel comparisons beyond 5 sigma";
  EXPECT_NEAR(signed_rel / (kBlocks * kBlocks), 0.0, 0.015) << "mean signed relative deviation of block luminance";
  ::testing::Test::RecordProperty("worst_z", std::to_string(worst_z));
  std::printf("worst block |diff| / sigma = %.2f\n", worst_z);
}

TEST(CyclesReference, CornellBoxBlockMeansAgreeWithinNoise) {
  expect_block_means_match_cycles(std::string(EPR_SOURCE_DIR) + "/scenes/cornell-box/CornellBox-Original.obj",
                                  "cornell_cycles_128.exr", 1024);
}

// The built-in box, whose light emits downwards only: Cycles renders its exported OBJ (MTL `emit
// front`) with an Emission strength of 1 - Backfacing. Rendered two-sided, ours is ~15 % brighter.
TEST(CyclesReference, OneSidedLightBuiltinCornellBoxAgrees) {
  expect_block_means_match_cycles("builtin:cornell", "cornell_onesided_cycles_128.exr", 512);
}

// A room lit only by a point lamp, a spot lamp and a rectangular area lamp in Blender's units
// (tests/data/scenes/lamps/lamps.json: power in W, the spot's size and blend), against Cycles
// rendering the same lamps (scripts/cycles_reference.py --lamps; 2048 spp, tests/data/README.md):
// the conversions P / (4 pi) W/sr and P / (4 A), Cycles' spot falloff, direct and bounced light.
TEST(CyclesReference, PointSpotAndAreaLampsAgree) {
  expect_block_means_match_cycles(std::string(EPR_SOURCE_DIR) + "/tests/data/scenes/lamps/lamps.json",
                                  "lamps_cycles_128.exr", 512);
}

}  // namespace
}  // namespace epr
