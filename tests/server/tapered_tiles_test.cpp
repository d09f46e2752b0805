// A job with tapered tiles (the last quarter of the tile rows in half-size tiles, as `epr render`
// uses by default) on a real master and worker node over loopback: the same counts and path sums
// as the single-process render, which tiles the image square.
#include "tests/server/farm_fixture.h"

namespace epr::test {
namespace {

TEST_F(FarmFixture, TaperedTilesGiveTheSingleProcessImage) {
  start();
  RenderOptions o = cornell(RenderMode::kSkip, 64, 8, 1);
  o.tile_size = 32;
  o.taper_tiles = true;
  const std::string id = submit(o, bundle_scene(o.scene));
  RunningNode node(node_options("tapered", 2));
  const v1::JobStatus st = wait_done(id, 120s);
  node.stop();
  ASSERT_EQ(st.state(), v1::JOB_STATE_DONE) << st.error_message();
  EXPECT_TRUE(server_->jobs().get(id)->options.taper_tiles);
  // 64 x 64 in 32-pixel tiles: one row of 2, then the last row as 2 rows of 4 tiles of 16.
  EXPECT_EQ(st.tiles_committed() % 10, 0u) << "10 tiles per round";
  RenderOptions square = o;
  square.taper_tiles = false;
  expect_same_as_local(id, square);
}

}  // namespace
}  // namespace epr::test
