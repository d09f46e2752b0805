// Triangulation of OBJ faces (common/scene_loader/polygon.h). The expected triangles are those
// tinyobjloader 2.0.0rc10 gives for the same faces.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <vector>

#include "common/scene_loader.h"
#include "common/scene_loader/polygon.h"
#include "tests/common/scene_test_files.h"

namespace epr {
namespace {

using Triangles = std::vector<std::array<uint32_t, 3>>;

Triangles triangulate(const std::vector<Vec3>& corners) {
  std::vector<uint32_t> vertex(corners.size());
  for (size_t k = 0; k < vertex.size(); ++k) vertex[k] = uint32_t(k);
  Triangles out;
  loader::triangulate_face(corners, vertex.data(), vertex.size(), &out);
  return out;
}

float area(const std::vector<Vec3>& p, const std::array<uint32_t, 3>& t) {
  return 0.5f * length(cross(p[t[1]] - p[t[0]], p[t[2]] - p[t[0]]));
}

TEST(ScenePolygon, TrianglesStayAsTheyAre) {
  EXPECT_EQ(triangulate({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}}), (Triangles{{0, 1, 2}}));
}

TEST(ScenePolygon, QuadsSplitAlongTheShorterDiagonal) {
  // |p2 - p0| < |p3 - p1|: along 0-2.
  EXPECT_EQ(triangulate({{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 2, 0}}), (Triangles{{0, 1, 2}, {0, 2, 3}}));
  // |p2 - p0| > |p3 - p1|: along 1-3.
  EXPECT_EQ(triangulate({{0, 0, 0}, {1, 0, 0}, {2, 1, 0}, {0, 1, 0}}), (Triangles{{0, 1, 3}, {1, 2, 3}}));
  // A tie (a square) goes along 1-3.
  EXPECT_EQ(triangulate({{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}}), (Triangles{{0, 1, 3}, {1, 2, 3}}));
}

TEST(ScenePolygon, ConcavePolygonsAreEarClipped) {
  // A U in the xy plane: a fan from any corner would cross the notch.
  const std::vector<Vec3> u = {{0, 0, 0}, {3, 0, 0}, {3, 2, 0}, {2, 2, 0}, {2, 1, 0}, {1, 1, 0}, {1, 2, 0}, {0, 2, 0}};
  const Triangles tu = triangulate(u);
  EXPECT_EQ(tu, (Triangles{{1, 2, 3}, {1, 3, 4}, {1, 4, 5}, {5, 6, 7}, {5, 7, 0}, {0, 1, 5}}));
  float total = 0;
  for (const auto& t : tu) total += area(u, t);
  EXPECT_FLOAT_EQ(total, 5.f);

  // A four-pointed star in the yz plane, clockwise seen from +x: clipped in the y-z axes.
  const std::vector<Vec3> star = {{0, 0, 1},  {0, 0.3f, 0.3f},   {0, 1, 0},  {0, 0.3f, -0.3f},
                                  {0, 0, -1}, {0, -0.3f, -0.3f}, {0, -1, 0}, {0, -0.3f, 0.3f}};
  const Triangles ts = triangulate(star);
  EXPECT_EQ(ts, (Triangles{{1, 2, 3}, {1, 3, 4}, {1, 4, 5}, {1, 5, 6}, {7, 0, 1}, {1, 6, 7}}));
  float star_area = 0;
  for (const auto& t : ts) star_area += area(star, t);
  EXPECT_NEAR(star_area, 8 * 0.15f, 1e-6f);  // eight triangles centre, tip, inner corner
}

TEST(ScenePolygon, CollinearCornersGiveZeroAreaTriangles) {
  // Corners 0, 1, 2 lie on a line: the first triangle has no area (the loader drops it).
  const std::vector<Vec3> p = {{0, 0, 0}, {1, 0, 0}, {2, 0, 0}, {2, 1, 0}, {1, 2, 0}, {0, 1, 0}};
  const Triangles t = triangulate(p);
  EXPECT_EQ(t, (Triangles{{0, 1, 2}, {0, 2, 3}, {0, 3, 4}, {0, 4, 5}}));
  EXPECT_EQ(area(p, t[0]), 0.f);
}

TEST(ScenePolygon, SelfIntersectingPolygonsKeepTheTrianglesFound) {
  // Edges 0-1 and 2-3 cross: after one ear no corner is an ear any more.
  EXPECT_EQ(triangulate({{3, 3, 0}, {1, 0, 0}, {0, 2, 0}, {2, 1, 0}, {2, 2, 0}}), (Triangles{{4, 0, 1}}));
}

TEST(ScenePolygon, ObjFacesUseTheTriangulationWithTheirOwnIndices) {
  test::TempDir dir;
  // The U again, its corners listed from the fourth vertex of the file and with relative indices.
  const std::string obj = dir.write("u.obj",
                                    "v 9 9 9\nv 8 8 8\nv 7 7 7\n"
                                    "v 0 0 0\nv 3 0 0\nv 3 2 0\nv 2 2 0\nv 2 1 0\nv 1 1 0\nv 1 2 0\nv 0 2 0\n"
                                    "f -8 -7 -6 -5 -4 -3 -2 -1\n");
  const Scene s = load_obj(obj);
  const std::vector<std::array<uint32_t, 3>> expected = {{4, 5, 6},  {4, 6, 7},  {4, 7, 8},
                                                         {8, 9, 10}, {8, 10, 3}, {3, 4, 8}};
  EXPECT_EQ(s.triangles, expected);
}

}  // namespace
}  // namespace epr
