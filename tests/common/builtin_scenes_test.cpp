#include "common/builtin_scenes.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cstring>
#include <map>
#include <string>
#include <tuple>
#include <vector>

#include "common/scene_loader.h"

namespace epr {
namespace {

const std::string kCornellObj = EPR_SOURCE_DIR "/scenes/cornell-box/CornellBox-Original.obj";

size_t emissive_triangles(const Scene& s) {
  size_t n = 0;
  for (size_t t = 0; t < s.triangle_count(); ++t) n += s.materials[s.material_of[t]].emissive();
  return n;
}

Vec3 centroid(const Scene& s, size_t t) {
  const auto& tri = s.triangles[t];
  return (s.positions[tri[0]] + s.positions[tri[1]] + s.positions[tri[2]]) / 3.f;
}

TEST(BuiltinScenes, NamesAreTheSixOfTheDesign) {
  auto names = builtin_scene_names();
  std::sort(names.begin(), names.end());
  EXPECT_EQ(names, (std::vector<std::string>{"conference", "cornell", "furnace", "glossy", "hall", "wall"}));
}

TEST(BuiltinScenes, EveryBuiltinValidatesHasAnEmitterAndAUsableCamera) {
  for (const std::string& name : builtin_scene_names()) {
    SCOPED_TRACE(name);
    const Scene s = make_builtin_scene(name);
    EXPECT_NO_THROW(s.validate());
    EXPECT_EQ(s.name, "builtin:" + name);
    EXPECT_GT(emissive_triangles(s), 0u);
    EXPECT_FALSE(s.camera.validate().has_value()) << *s.camera.validate();
    EXPECT_TRUE(s.uvs.empty());
    for (size_t t = 0; t < s.triangle_count(); ++t) ASSERT_GT(s.area(t), 0.f) << "triangle " << t;
    // The camera stands inside the closed scenes (the Cornell box is open at the front).
    if (name == "cornell" || name == "glossy") continue;
    const Bounds3 b = s.bounds();
    for (int k = 0; k < 3; ++k) {
      EXPECT_GT(s.camera.eye[k], b.lo[k]);
      EXPECT_LT(s.camera.eye[k], b.hi[k]);
    }
  }
}

// Every quad becomes N x N cells, so the count is exactly N^2 times the count at N = 1.
// For the benchmarks: hall has 924 triangles at tess 1, 92,400 (~100k) at tess=10,
// 111,804 at tess=11 and 299,376 (~300k) at tess=18.
TEST(BuiltinScenes, TriangleCountGrowsWithTheSquareOfTessellation) {
  for (const std::string& name : builtin_scene_names()) {
    SCOPED_TRACE(name);
    const size_t base = make_builtin_scene(name, 1).triangle_count();
    for (int n : {2, 3, 5}) {
      const Scene s = make_builtin_scene(name, n);
      EXPECT_EQ(s.triangle_count(), base * size_t(n) * size_t(n));
      EXPECT_EQ(builtin_triangle_count(parse_builtin_spec(name + "?tess=" + std::to_string(n))), s.triangle_count());
      EXPECT_NO_THROW(s.validate());
    }
  }
  EXPECT_EQ(make_builtin_scene("cornell").triangle_count(), 36u);
  EXPECT_EQ(make_builtin_scene("furnace").triangle_count(), 12u);
  EXPECT_EQ(make_builtin_scene("hall", 1).triangle_count(), 924u);
  EXPECT_EQ(make_builtin_scene("hall", 10).triangle_count(), 92'400u);
  const Scene big = make_builtin_scene("hall", 18);
  EXPECT_EQ(big.triangle_count(), 299'376u);
  EXPECT_NO_THROW(big.validate());
}

TEST(BuiltinScenes, AreDeterministic) {
  for (const std::string& name : builtin_scene_names()) {
    SCOPED_TRACE(name);
    const Scene a = make_builtin_scene(name, 3), b = make_builtin_scene(name, 3);
    ASSERT_EQ(a.positions.size(), b.positions.size());
    EXPECT_EQ(std::memcmp(a.positions.data(), b.positions.data(), a.positions.size() * sizeof(Vec3)), 0);
    EXPECT_EQ(a.triangles, b.triangles);
    EXPECT_EQ(a.material_of, b.material_of);
    ASSERT_EQ(a.materials.size(), b.materials.size());
    for (size_t i = 0; i < a.materials.size(); ++i) {
      EXPECT_EQ(a.materials[i].name, b.materials[i].name);
      EXPECT_EQ(a.materials[i].kd, b.materials[i].kd);
      EXPECT_EQ(a.materials[i].ke, b.materials[i].ke);
      EXPECT_EQ(a.materials[i].ks, b.materials[i].ks);
    }
    EXPECT_EQ(a.camera.eye, b.camera.eye);
  }
}

// (centroid, area, kd, ke) of every triangle, sorted: a scene's triangles as a set.
using TriangleKey = std::array<float, 10>;
std::vector<TriangleKey> triangle_set(const Scene& s) {
  std::vector<TriangleKey> out;
  for (size_t t = 0; t < s.triangle_count(); ++t) {
    const Vec3 c = centroid(s, t);
    const Material& m = s.materials[s.material_of[t]];
    out.push_back({c.x, c.y, c.z, s.area(t), m.kd.x, m.kd.y, m.kd.z, m.ke.x, m.ke.y, m.ke.z});
  }
  std::sort(out.begin(), out.end());
  return out;
}

TEST(BuiltinScenes, CornellEqualsTheSharedObj) {
  const Scene obj = load_obj(kCornellObj);
  const Scene builtin = make_builtin_scene("cornell");
  const auto a = triangle_set(obj), b = triangle_set(builtin);
  ASSERT_EQ(a.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i)
    for (size_t k = 0; k < a[i].size(); ++k) EXPECT_NEAR(a[i][k], b[i][k], 1e-5f) << "triangle " << i << " field " << k;
  // Same orientation (the OBJ's corner order) for every triangle, matched by centroid.
  for (size_t t = 0; t < builtin.triangle_count(); ++t) {
    bool matched = false;
    for (size_t u = 0; u < obj.triangle_count() && !matched; ++u)
      if (length(centroid(obj, u) - centroid(builtin, t)) < 1e-5f) {
        EXPECT_GT(dot(obj.geometric_normal(u), builtin.geometric_normal(t)), 0.999f);
        matched = true;
      }
    EXPECT_TRUE(matched);
  }
  // Same materials in the same (MTL) order, same camera; only the built-in's light is one-sided,
  // and its front (the quad's normal) faces down into the box.
  ASSERT_EQ(obj.materials.size(), builtin.materials.size());
  for (size_t i = 0; i < obj.materials.size(); ++i) {
    EXPECT_EQ(obj.materials[i].name, builtin.materials[i].name);
    EXPECT_TRUE(builtin.materials[i].diffuse());
    EXPECT_FALSE(obj.materials[i].emits_front_only);
    EXPECT_EQ(builtin.materials[i].emits_front_only, builtin.materials[i].name == "light");
  }
  for (size_t t = 0; t < builtin.triangle_count(); ++t) {
    if (builtin.materials[builtin.material_of[t]].emissive()) {
      EXPECT_LT(builtin.geometric_normal(t).y, -0.999f);
    }
  }
  EXPECT_EQ(obj.camera.eye, builtin.camera.eye);
  EXPECT_EQ(obj.camera.look, builtin.camera.look);
  EXPECT_EQ(obj.camera.up, builtin.camera.up);
  EXPECT_EQ(obj.camera.fov_y_degrees, builtin.camera.fov_y_degrees);
  EXPECT_EQ(builtin.camera.eye, Vec3(0, 1, 3.9f));
  EXPECT_FLOAT_EQ(builtin.camera.fov_y_degrees, 39.3077f);
}

TEST(BuiltinScenes, GlossyIsCornellWithAGlossyTallBox) {
  const Scene cornell = make_builtin_scene("cornell"), glossy = make_builtin_scene("glossy");
  ASSERT_EQ(cornell.positions.size(), glossy.positions.size());
  EXPECT_EQ(std::memcmp(cornell.positions.data(), glossy.positions.data(), cornell.positions.size() * sizeof(Vec3)), 0);
  size_t glossy_materials = 0;
  for (const Material& m : glossy.materials) {
    if (m.diffuse()) continue;
    ++glossy_materials;
    EXPECT_EQ(m.name, "tallBox");
    EXPECT_NEAR(m.ks.x, 0.6f, 1e-6f);
    EXPECT_NEAR(m.exponent, 200.f, 1e-3f);
    EXPECT_LE(max_component(m.kd + m.ks), 1.f);  // conserves energy
  }
  EXPECT_EQ(glossy_materials, 1u);
}

// Watertight: every edge (by exact endpoint positions) is used once in each direction, so the
// surface is closed and consistently oriented; all normals face the centre.
void expect_closed_and_inward(const Scene& s) {
  using P = std::tuple<float, float, float>;
  auto key = [&](uint32_t i) { return P{s.positions[i].x, s.positions[i].y, s.positions[i].z}; };
  std::map<std::pair<P, P>, int> directed;
  for (const auto& t : s.triangles)
    for (int k = 0; k < 3; ++k) ++directed[{key(t[size_t(k)]), key(t[size_t((k + 1) % 3)])}];
  for (const auto& [edge, count] : directed) {
    ASSERT_EQ(count, 1) << "edge used twice in the same direction";
    const auto reverse = directed.find({edge.second, edge.first});
    ASSERT_TRUE(reverse != directed.end()) << "open edge";
  }
  const Vec3 centre = s.bounds().centre();
  for (size_t t = 0; t < s.triangle_count(); ++t) EXPECT_GT(dot(s.geometric_normal(t), centre - centroid(s, t)), 0.f);
}

TEST(BuiltinScenes, FurnaceIsAClosedInwardBoxWithParameters) {
  for (int n : {1, 2, 3, 7}) {
    SCOPED_TRACE(n);
    expect_closed_and_inward(make_builtin_scene("furnace", n));
  }
  const Scene def = make_builtin_scene("furnace");
  ASSERT_EQ(def.materials.size(), 1u);
  EXPECT_EQ(def.materials[0].kd, Vec3(0.5f));
  EXPECT_EQ(def.materials[0].ke, Vec3(1.f));

  const Scene s = load_scene("builtin:furnace?albedo=0.8&emission=2&tess=3");
  EXPECT_EQ(s.triangle_count(), 12u * 9);
  EXPECT_EQ(s.materials[0].kd, Vec3(0.8f));
  EXPECT_EQ(s.materials[0].ke, Vec3(2.f));
  EXPECT_EQ(s.name, "builtin:furnace?tess=3&albedo=0.8&emission=2");
  // The canonical name round-trips.
  const BuiltinSpec spec = parse_builtin_spec(s.name);
  EXPECT_EQ(spec.tessellation, 3);
  EXPECT_EQ(spec.albedo, 0.8f);
  EXPECT_EQ(spec.emission, 2.f);
}

// Surfaces of the rooms face the inside; columns face outwards from their axes; lights face down.
TEST(BuiltinScenes, SurfacesFaceTheViewerSide) {
  for (const char* name : {"hall", "conference"}) {
    SCOPED_TRACE(name);
    const Scene s = make_builtin_scene(name, 2);
    const Vec3 centre = s.bounds().centre();
    for (size_t t = 0; t < s.triangle_count(); ++t) {
      const std::string& m = s.materials[s.material_of[t]].name;
      const Vec3 n = s.geometric_normal(t), c = centroid(s, t);
      if (m == "wall" || m == "floor" || m == "carpet" || m == "ceiling" || m == "whiteboard" || m == "picture" ||
          m == "light" || m == "skylight") {
        EXPECT_GT(dot(n, centre - c), 0.f) << m;
      }
      if (m == "light" || m == "skylight") {
        EXPECT_LT(n.y, -0.99f);
      }
      if (m == "column") {
        // Nearest colonnade axis: x on the 3 m grid, z = +-3.5.
        const Vec3 axis(std::round(c.x / 3.f) * 3.f, c.y, c.z > 0 ? 3.5f : -3.5f);
        EXPECT_GT(dot(n, c - axis), 0.f);
      }
    }
  }
}

TEST(BuiltinScenes, BadNamesAndParametersRaiseSceneError) {
  EXPECT_THROW(make_builtin_scene("nope"), SceneError);
  EXPECT_THROW(make_builtin_scene(""), SceneError);
  EXPECT_THROW(load_scene("builtin:Cornell"), SceneError);
  for (const char* bad :
       {"hall?tess=0", "hall?tess=-2", "hall?tess=abc", "hall?tess=4097", "hall?tess=", "hall?foo=1",
        "hall?tess=2&tess=3", "hall?albedo=0.5", "furnace?albedo=1", "furnace?albedo=-0.1", "furnace?emission=0",
        "furnace?emission=inf", "furnace?albedo=nan", "furnace?tess", "hall?tess=2&"}) {
    SCOPED_TRACE(bad);
    try {
      parse_builtin_spec(bad);
      ADD_FAILURE() << "accepted";
    } catch (const SceneError& e) {
      EXPECT_NE(std::string(e.what()).find("builtin:"), std::string::npos) << e.what();
    }
  }
  EXPECT_THROW(make_builtin_scene("hall", 0), SceneError);
  // Too many triangles fails before anything is allocated.
  EXPECT_THROW(make_builtin_scene(parse_builtin_spec("hall?tess=4096")), SceneError);
  EXPECT_EQ(make_builtin_scene("hall?tess=2", 5).triangle_count(), 4 * 924u);  // the name's tess wins
}

}  // namespace
}  // namespace epr
