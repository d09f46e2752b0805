// auto_tile_size: the tile size `epr render` picks unless told.
#include "common/render_options.h"

#include <gtest/gtest.h>

namespace epr {
namespace {

int tiles(int width, int height, int t) { return ((width + t - 1) / t) * ((height + t - 1) / t); }

TEST(AutoTileSize, LargestTileGivingEveryThreadEightTiles) {
  EXPECT_EQ(auto_tile_size(512, 512, 2), 128);  // 16 tiles for 2 threads
  EXPECT_EQ(auto_tile_size(512, 512, 4), 64);   // 128 would give 16 < 32
  EXPECT_EQ(auto_tile_size(512, 512, 8), 64);   // 64 tiles for 8 threads
  EXPECT_EQ(auto_tile_size(512, 512, 16), 32);
  EXPECT_EQ(auto_tile_size(256, 256, 2), 64);
  EXPECT_EQ(auto_tile_size(1920, 1080, 2), 128);  // partial tiles at the edges count
  EXPECT_EQ(auto_tile_size(64, 64, 1), 16);       // nothing larger gives 8 tiles
  EXPECT_EQ(auto_tile_size(64, 48, 1000), 16);    // the smallest when none does
  EXPECT_EQ(auto_tile_size(512, 512, 0), 128);    // threads < 1 count as 1
  for (int threads : {1, 2, 3, 6, 12, 24})
    for (int side : {96, 200, 512, 777}) {
      const int t = auto_tile_size(side, side, threads);
      SCOPED_TRACE(testing::Message() << side << " px, " << threads << " threads -> " << t);
      if (t > 16) {
        EXPECT_GE(tiles(side, side, t), kTilesPerThread * threads);
      }
      if (t < 128) {
        EXPECT_LT(tiles(side, side, 2 * t), kTilesPerThread * threads) << "a larger tile would do";
      }
      RenderOptions o;
      o.tile_size = t;
      EXPECT_FALSE(o.validate()) << "the chosen size is a valid --tile";
    }
}

}  // namespace
}  // namespace epr
