// detail::EdgePixels (master/edge_pixels.h): which pixels take no reprojected samples, on hand-made
// plane grids, and what dropping them does to a downsample's result.
#include "master/edge_pixels.h"

#include <gtest/gtest.h>

namespace epr {
namespace {

// A 4 x 3 pixel grid at S = 2 (8 x 6 texels) seen by the default camera (eye (0, 1, 3.9) looking
// down -z): entry 0 everywhere. Planes: 0 (z = 0), 1 (z = -0.01, 1 cm behind), 2 (the opposite
// winding of plane 0), 3 (z = 1e-6: another plane 1 um off plane 0, as the facets of one flat mesh
// come out), 4 (a creased entry that copies plane 0).
detail::PlaneGrid edge_test_grid() {
  detail::PlaneGrid g;
  g.width = 8;
  g.height = 6;
  g.subpixels = 2;
  g.texel_plane.assign(48, 0);
  g.planes = {0, 0, 1, 0, 0, 0, 1, -0.01f, -0.f, -0.f, -1, -0.f, 0, 0, 1, 1e-6f, 0, 0, 1, 0};
  g.first_creased = 4;
  g.crease_range = {0, 0};
  return g;
}

const Camera kEdgeCamera(CameraSpec{}, 4, 3);
constexpr float kEdgeEpsilon = 1e-3f;  // metres

std::vector<int> edge_list(const detail::EdgePixels& e, size_t pixels) {
  std::vector<int> out;
  for (size_t p = 0; p < pixels; ++p)
    if (e[p]) out.push_back(int(p));
  return out;
}

TEST(EdgePixels, OnePlaneEverywhereHasNone) {
  detail::PlaneGrid g = edge_test_grid();
  // The same plane under other entries (opposite winding, a creased copy), and a plane within
  // epsilon of it along the texels' rays, are one surface.
  g.texel_plane[9] = 2;
  g.texel_plane[20] = 4;
  g.texel_plane[30] = 3;
  const detail::EdgePixels e(g, kEdgeCamera, kEdgeEpsilon);
  EXPECT_TRUE(e.empty());
  EXPECT_EQ(edge_list(e, 12), std::vector<int>{});
}

TEST(EdgePixels, AnotherPlaneMarksItsPixelAndThePixelsWhoseRingSeesIt) {
  detail::PlaneGrid g = edge_test_grid();
  // Texel (2, 2): pixel (1, 1) = 5. Its ring reaches pixels (0..1, 0..1) (texel x 2 is the first
  // of pixel column 1, so pixel column 0's ring sees it; row 2 likewise for pixel row 0).
  g.texel_plane[2 * 8 + 2] = 1;
  const detail::EdgePixels e(g, kEdgeCamera, kEdgeEpsilon);
  EXPECT_EQ(edge_list(e, 12), (std::vector<int>{0, 1, 4, 5}));
  // With an epsilon of 2 cm the plane 1 cm behind is taken for the same surface.
  EXPECT_TRUE(detail::EdgePixels(g, kEdgeCamera, 0.02f).empty());
  EXPECT_EQ(e.count(), 4u);
  // An uncovered texel among covered ones: texel (7, 5), the last one, is in pixel (3, 2) = 11; the
  // rings of pixels (2, 2) and (3, 1) end at texel column 6 and row 4: only pixel 11.
  g.texel_plane.assign(48, 0);
  g.texel_plane[47] = detail::PlaneGrid::kUncovered;
  EXPECT_EQ(edge_list(detail::EdgePixels(g, kEdgeCamera, kEdgeEpsilon), 12), std::vector<int>{11});
  // A pixel that sees nothing at all is not an edge pixel (it gets no samples anyway).
  g.texel_plane.assign(48, detail::PlaneGrid::kUncovered);
  EXPECT_TRUE(detail::EdgePixels(g, kEdgeCamera, kEdgeEpsilon).empty());
}

TEST(EdgePixels, DropZeroesTheEdgePixelsOfEveryPartPresent) {
  detail::PlaneGrid g = edge_test_grid();
  g.texel_plane[2 * 8 + 2] = 1;
  const detail::EdgePixels e(g, kEdgeCamera, kEdgeEpsilon);
  PixelReprojection pr;
  pr.radiance = Image(4, 3, 3);
  for (float& v : pr.radiance.data) v = 2.f;
  pr.count.assign(12, 7);
  pr.effective.assign(12, 5.f);
  pr.half_radiance.assign(72, 1.f);
  pr.half_effective.assign(24, 5.f);
  pr.half_variance.assign(24, 0.5f);
  pr.half_subpixels.assign(24, 3);
  e.drop(&pr);
  for (size_t p = 0; p < 12; ++p) {
    const bool edge = p == 0 || p == 1 || p == 4 || p == 5;
    EXPECT_EQ(pr.count[p], edge ? 0u : 7u) << p;
    EXPECT_EQ(pr.effective[p], edge ? 0.f : 5.f) << p;
    for (size_t h = 0; h < 2; ++h) {
      EXPECT_EQ(pr.half_variance[2 * p + h], edge ? -1.f : 0.5f) << p;
      EXPECT_EQ(pr.half_subpixels[2 * p + h], edge ? 0 : 3) << p;
      EXPECT_EQ(pr.half_effective[2 * p + h], edge ? 0.f : 5.f) << p;
      EXPECT_EQ(pr.half_radiance[6 * p + 3 * h], edge ? 0.f : 1.f) << p;
    }
    EXPECT_EQ(pr.radiance.data[3 * p + 1], edge ? 0.f : 2.f) << p;
  }
  // A counts-only result (no radiance image) keeps working.
  PixelReprojection counts;
  counts.count.assign(12, 3);
  e.drop(&counts);
  EXPECT_EQ(counts.count[5], 0u);
  EXPECT_EQ(counts.count[6], 3u);
}

}  // namespace
}  // namespace epr
