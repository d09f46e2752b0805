// make_tiles: the tiles cover the image once; tapered, the last quarter of the tile rows is in tiles
// of half the edge.
#include <gtest/gtest.h>

#include <tuple>
#include <vector>

#include "worker/tile_renderer.h"

namespace epr {
namespace {

void expect_cover_once(const std::vector<TileRect>& tiles, int width, int height) {
  std::vector<int> hits(size_t(width) * size_t(height), 0);
  for (const TileRect& t : tiles) {
    ASSERT_LT(t.x0, t.x1);
    ASSERT_LT(t.y0, t.y1);
    ASSERT_GE(t.x0, 0);
    ASSERT_GE(t.y0, 0);
    ASSERT_LE(t.x1, width);
    ASSERT_LE(t.y1, height);
    for (int y = t.y0; y < t.y1; ++y)
      for (int x = t.x0; x < t.x1; ++x) ++hits[size_t(y) * size_t(width) + size_t(x)];
  }
  for (size_t i = 0; i < hits.size(); ++i) ASSERT_EQ(hits[i], 1) << "pixel " << i;
}

TEST(MakeTiles, SquareTilesCoverTheImageOnce) {
  const auto tiles = make_tiles(512, 512, 128);
  EXPECT_EQ(tiles.size(), 16u);
  expect_cover_once(tiles, 512, 512);
  expect_cover_once(make_tiles(100, 70, 32), 100, 70);
}

TEST(MakeTiles, TaperedTilesEndOnHalfSizeTiles) {
  const auto tiles = make_tiles(512, 512, 128, /*taper=*/true);
  expect_cover_once(tiles, 512, 512);
  ASSERT_EQ(tiles.size(), 12u + 16u);  // three rows of 4, then the last row as 2 x 8 tiles of 64
  for (const TileRect& t : tiles) {
    const int edge = t.x1 - t.x0;
    EXPECT_EQ(edge, t.y1 - t.y0);
    EXPECT_EQ(edge, t.y0 >= 384 ? 64 : 128) << t.x0 << "," << t.y0;
  }
  // Uneven sizes: still a cover, and at least one row tapered.
  for (auto [w, h, t] : {std::tuple{100, 70, 32}, std::tuple{1920, 1080, 128}, std::tuple{17, 9, 8}}) {
    SCOPED_TRACE(testing::Message() << w << "x" << h << " / " << t);
    const auto tapered = make_tiles(w, h, t, true);
    expect_cover_once(tapered, w, h);
    EXPECT_GT(tapered.size(), make_tiles(w, h, t).size());
  }
}

}  // namespace
}  // namespace epr
