// RoundDriver::first_plan -- the round-0 plan the master leases while a fresh job's frame is still
// being built -- is exactly what open() of a newly built RoundDriver gives: the same paths per pixel,
// skip masks, first samples and tile order, for any frame size, tiling and round schedule.
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "common/camera.h"
#include "common/tile.h"
#include "master/round_driver.h"
#include "test_scenes.h"

namespace epr {
namespace {

struct Case {
  int width, height, tile_size;
  bool taper;
  int spp, paths_per_round;
  float round_growth;
  RenderMode mode;
};

std::string describe(const Case& c) {
  return std::to_string(c.width) + "x" + std::to_string(c.height) + " tile " + std::to_string(c.tile_size) +
         (c.taper ? " tapered" : "") + " spp " + std::to_string(c.spp) + " k " + std::to_string(c.paths_per_round) +
         " growth " + std::to_string(c.round_growth) + " " + std::string(to_string(c.mode));
}

TEST(RoundDriverFirstPlan, EqualsOpenOfANewFrame) {
  const Scene scene = test::scene_named("cornell");
  const Case cases[] = {
      {32, 32, 8, false, 4, 1, 0.25f, RenderMode::kSkip},
      {37, 23, 8, false, 16, 2, 0.25f, RenderMode::kSkip},  // edge tiles of other sizes: order by area
      {50, 41, 16, true, 8, 3, 0.f, RenderMode::kReproject},
      {64, 48, 16, true, 1, 4, 0.5f, RenderMode::kPathTrace},  // the first round caps at spp
      {5, 3, 16, false, 2, 1, 0.25f, RenderMode::kSkip},       // one tile larger than the frame
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(describe(c));
    RenderOptions o;
    o.width = c.width;
    o.height = c.height;
    o.tile_size = c.tile_size;
    o.taper_tiles = c.taper;
    o.spp = c.spp;
    o.paths_per_round = c.paths_per_round;
    o.round_growth = c.round_growth;
    o.min_paths = 1;
    o.mode = c.mode;
    o.reproject = ReprojectMethod::kCpu;
    o.subpixels = 2;
    const std::vector<TileRect> tiles = make_tiles(o);
    const Camera camera(scene.camera, o.width, o.height);
    const RoundDriver driver(o, camera, scene, nullptr);
    const RoundPlan want = driver.open(tiles);
    const RoundPlan got = RoundDriver::first_plan(o, tiles);
    EXPECT_EQ(got.round, want.round);
    EXPECT_EQ(got.paths_per_pixel, want.paths_per_pixel);
    EXPECT_EQ(got.skip, want.skip);
    EXPECT_EQ(got.first_sample, want.first_sample);
    EXPECT_EQ(got.order, want.order);
    // Not vacuous: every tile traces, and tiles of different sizes were ordered.
    EXPECT_EQ(got.order.size(), tiles.size());
    EXPECT_GT(got.paths_per_pixel, 0);
  }
}

}  // namespace
}  // namespace epr
