// The skip rule's path budget (--path-budget, FrameState::path_budget, DESIGN.md "Progressive
// rounds"): in skip mode with the fixed rule, a pixel whose counts say that n < k_r more paths reach the target
// (M + n + W M' >= P) is planned n paths in round r, traces exactly n and is skipped after it; the
// others trace k_r. The variance rule, rp and the default (no budget) keep k_r for every pixel.
#include <gtest/gtest.h>

#include <random>
#include <vector>

#include "common/camera.h"
#include "common/tile.h"
#include "common/vertex_codec.h"
#include "master/deep_framebuffer.h"
#include "master/round_driver.h"
#include "test_scenes.h"
#include "wire/tile_result_stream.h"

namespace epr {
namespace {

struct BudgetFrame {
  Scene scene = test::scene_named("cornell");
  RenderOptions opts;
  std::unique_ptr<Camera> camera;
  std::vector<TileRect> rects;

  explicit BudgetFrame(RenderMode mode, CombineRule combine = CombineRule::kFixed) {
    opts.width = 16;
    opts.height = 16;
    opts.spp = 64;
    opts.mode = mode;
    opts.combine = combine;
    opts.reproject = ReprojectMethod::kCpu;
    opts.tile_size = 8;
    opts.min_paths = 1;
    opts.path_budget = true;
    camera = std::make_unique<Camera>(scene.camera, opts.width, opts.height);
    rects = make_tiles(opts);
  }
};

// The least n in [max(1, min_paths - M), k] with M + n + W M' >= P (k if none), by counting up.
int least_paths(const FrameState& f, const RenderOptions& o, size_t p, int k) {
  const double m = f.path_counts()[p];
  const double w_mprime = double(o.reprojected_weight) * f.reprojected_counts()[p] / f.count_unit();
  int n = std::max(1, o.min_paths - int(f.path_counts()[p]));
  while (n < k && m + n + w_mprime < double(o.spp)) ++n;
  return std::min(n, k);
}

struct BudgetRun {
  int rounds = 0;
  uint64_t fewer = 0;             // pixel-rounds planned fewer than k_r paths
  uint64_t fewer_last_round = 0;  // ... in the final round
  uint64_t paths = 0;             // paths traced in all
};

// Renders the frame to the end with synthetic tile results: every pixel traces what the plan says
// (a path of radiance 0.5 each), and every tile sends vertices of the scene's visible points, so
// that M' grows. Checks every round's plan against least_paths() and the counts after it.
BudgetRun run_budget(BudgetFrame& b, bool expect_budget) {
  RoundDriver driver(b.opts, *b.camera, b.scene, nullptr);
  const DeepFramebuffer dfb = build_deep_framebuffer_cpu(b.scene, *b.camera, b.opts.subpixels);
  const VertexCodec codec(b.scene.bounds());
  BudgetRun run;
  while (!driver.done()) {
    const RoundPlan plan = driver.open(b.rects);
    const int k = plan.paths_per_pixel;
    const FrameState& f = driver.frame();
    const std::vector<uint32_t> before = f.path_counts();
    std::vector<int> planned(before.size(), 0);
    for (uint32_t t : plan.order) {
      const TileRect& r = b.rects[t];
      AssembledTile a;
      a.x0 = uint32_t(r.x0), a.y0 = uint32_t(r.y0), a.x1 = uint32_t(r.x1), a.y1 = uint32_t(r.y1);
      size_t i = 0;
      for (int y = r.y0; y < r.y1; ++y)
        for (int x = r.x0; x < r.x1; ++x, ++i) {
          const size_t p = size_t(y) * size_t(b.opts.width) + size_t(x);
          const bool skipped = plan.skip[t][i] != 0;
          const int n = skipped ? 0 : plan.paths[t].empty() ? k : int(plan.paths[t][i]);
          if (!skipped) {
            const int want = expect_budget ? least_paths(f, b.opts, p, k) : k;
            EXPECT_EQ(n, want) << "pixel " << x << "," << y << " round " << run.rounds << " k " << k;
            run.fewer += n < k;
          }
          planned[p] = n;
          a.path_sum.push_back(Vec3(0.5f * float(n)));
          a.path_count.push_back(uint32_t(n));
        }
      const auto v = test::real_like_points(b.scene, dfb, *b.camera, 400, 7 + t + 100 * uint32_t(run.rounds));
      codec.encode_batch(v, &a.packed_vertices);
      driver.apply(a);
    }
    const bool more = driver.close();
    for (size_t p = 0; p < before.size(); ++p) {
      EXPECT_EQ(f.path_counts()[p], before[p] + uint32_t(planned[p])) << "pixel " << p;
      EXPECT_LE(f.path_counts()[p], uint32_t(b.opts.spp));
      // A pixel that traced its budget n < k reached the target with it: it is skipped now.
      if (expect_budget && planned[p] > 0 && planned[p] < k) {
        std::vector<uint8_t> skip;
        std::vector<uint32_t> first;
        const int x = int(p % size_t(b.opts.width)), y = int(p / size_t(b.opts.width));
        if (more) {
          f.tile_inputs(x, y, x + 1, y + 1, &skip, &first);
          EXPECT_EQ(skip.at(0), 1) << "pixel " << p << " traced its budget and is still active";
        }
      }
      run.paths += planned[p];
    }
    if (!more) {
      for (uint32_t t : plan.order)
        for (size_t i = 0; i < plan.paths[t].size(); ++i)
          run.fewer_last_round += !plan.skip[t][i] && plan.paths[t][i] < uint32_t(k);
    }
    ++run.rounds;
    EXPECT_LT(run.rounds, 100) << "the frame does not end";
    if (run.rounds >= 100) break;
  }
  return run;
}

TEST(PathBudget, APixelNeedingFewerThanTheRoundsPathsTracesExactlyThoseAndSkips) {
  BudgetFrame b(RenderMode::kSkip);
  const BudgetRun run = run_budget(b, true);
  // Not vacuous: pixels were planned fewer paths, in the final round too, and fewer paths were traced
  // than P per pixel.
  EXPECT_GT(run.fewer, 0u);
  EXPECT_GT(run.fewer_last_round, 0u);
  EXPECT_LT(run.paths, uint64_t(b.opts.spp) * uint64_t(b.opts.width * b.opts.height));
}

TEST(PathBudget, RpAndTheVarianceRuleTraceEveryRoundsPaths) {
  BudgetFrame rp(RenderMode::kReproject);
  const BudgetRun a = run_budget(rp, false);
  EXPECT_EQ(a.fewer, 0u);
  EXPECT_EQ(a.paths, uint64_t(rp.opts.spp) * uint64_t(rp.opts.width * rp.opts.height));
  BudgetFrame variance(RenderMode::kSkip, CombineRule::kVariance);
  EXPECT_EQ(run_budget(variance, false).fewer, 0u);
  BudgetFrame off(RenderMode::kSkip);  // the default: whole rounds
  off.opts.path_budget = false;
  EXPECT_EQ(run_budget(off, false).fewer, 0u);
}

}  // namespace
}  // namespace epr
