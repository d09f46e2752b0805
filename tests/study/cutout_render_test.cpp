// Reprojection on a scene with cut-outs (scenes/cutout-lattice: a lattice screen and leaf cards
// whose holes are alpha masks, the floor seen through the holes): the GL and CPU back-ends take the
// same decisions (the same M' in every pixel), and the skip-mode image stays close to a converged
// path-traced reference: its mean within 2 % (no bias from the holes) and its error at most 1.5 x
// that of plain path tracing with the same P (skip traces fewer paths; measured 1.24 at seed 1).
//
// 64 x 64 pixels, P = 16, single-process renders (render_local). Errors are the trimmed relative MSE
// of tests/study/image_error.h (the largest 1 % of pixel terms dropped) against a 128-path reference
// with its own seed. The decisions themselves are tested point by point in
// tests/master/cutout_visibility_test.cpp.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "client/local_render.h"
#include "tests/study/image_error.h"

namespace epr {
namespace {

constexpr int kSize = 64;

const std::string kScene = std::string(EPR_SOURCE_DIR) + "/scenes/cutout-lattice/cutout-lattice.gltf";

RenderOptions options(RenderMode mode, int spp, uint64_t seed, ReprojectMethod method = ReprojectMethod::kCpu) {
  RenderOptions o;
  o.scene = kScene;
  o.width = o.height = kSize;
  o.spp = spp;
  o.mode = mode;
  o.reproject = method;
  o.seed = seed;
  if (spp > 16) o.paths_per_round = 32;
  return o;
}

TEST(CutoutRender, SkipModeIsWithinNoiseOfPathTracingAndGlAgreesWithCpu) {
  const Image ref = render_local(options(RenderMode::kPathTrace, 128, 9001)).combined;
  const RenderOutputs pt = render_local(options(RenderMode::kPathTrace, 16, 1));
  const RenderOutputs skip = render_local(options(RenderMode::kSkip, 16, 1));
  const RenderOutputs skip_gl = render_local(options(RenderMode::kSkip, 16, 1, ReprojectMethod::kGl));
  // The same decisions: the same M' in every pixel and so the same skip masks and images.
  ASSERT_EQ(skip.mprime.data.size(), skip_gl.mprime.data.size());
  size_t differ = 0;
  for (size_t i = 0; i < skip.mprime.data.size(); ++i) differ += skip.mprime.data[i] != skip_gl.mprime.data[i];
  EXPECT_EQ(differ, 0u) << "pixels whose reprojected sample counts differ between GL and CPU";
  double mprime = 0;
  for (float v : skip.mprime.data) mprime += v;
  EXPECT_GT(mprime / double(skip.mprime.data.size()), 2.0) << "reprojection must do a good part of the work";

  const double e_pt = rmse(pt.combined, ref), e_skip = rmse(skip.combined, ref);
  std::printf("cutout-lattice 64x64 P=16: rMSE pt %.5f, skip %.5f (ratio %.2f); mean ref %.5f pt %.5f skip %.5f\n",
              e_pt, e_skip, e_skip / e_pt, mean(ref), mean(pt.combined), mean(skip.combined));
  EXPECT_LT(e_skip, 1.5 * e_pt);
  EXPECT_NEAR(mean(skip.combined), mean(ref), 0.02 * mean(ref)) << "no bias in the image mean";
}

}  // namespace
}  // namespace epr
