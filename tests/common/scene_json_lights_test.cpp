// A scene JSON's "lights" (common/scene_loader/scene_json.cpp; scenes/README.md, "Lamps"): Blender's
// power in W converted as Cycles reads it (point and spot: P / (4 pi) W/sr; point lamps with a radius:
// emitting spheres of radiance P / (pi A); area lamps: emitting polygons of radiance P / (4 A), front
// side only), suns as directional lights, and bad values refused naming the file and line.
#include <gtest/gtest.h>

#include <cmath>

#include "common/scene_loader.h"
#include "tests/common/scene_test_files.h"

namespace epr {
namespace {

const std::string kLampObj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";

// Sum over the triangles of `material`: area x radiance (x) and the area-weighted normal.
double emitted_flux(const Scene& s, uint32_t material, Vec3* normal = nullptr) {
  double flux = 0;
  Vec3 n(0.f);
  for (size_t t = 0; t < s.triangle_count(); ++t) {
    if (s.material_of[t] != material) continue;
    flux += double(s.area(t)) * s.materials[material].ke.x;
    n += s.geometric_normal(t) * s.area(t);
  }
  if (normal) *normal = n;
  return flux * kPi;  // a one-sided Lambertian emitter: power = pi L A
}

TEST(SceneJsonLights, BlenderLampsInWatts) {
  test::TempDir dir;
  dir.write("m.obj", kLampObj);
  const Scene s = load_scene(dir.write("s.json", R"({"obj": "m.obj", "lights": [
    {"type": "point", "name": "bulb", "position": [0, 2, 0], "power": [100, 50, 0]},
    {"type": "spot", "position": [0, 3, 0], "direction": [0, -2, 0], "power": 40, "spot_size_deg": 60, "spot_blend": 0.5},
    {"type": "spot", "position": [0, 3, 0], "direction": [0, -1, 0], "intensity": 2, "inner_cone_deg": 10, "outer_cone_deg": 30},
    {"type": "sun", "name": "fill", "direction": [0, 1, 0], "angle_deg": 2, "irradiance": 5},
    {"type": "point", "name": "ball", "position": [0, 5, 0], "power": 60, "radius": 0.2},
    {"type": "area", "name": "panel", "corners": [[0, 4, 0], [2, 4, 0], [2, 4, 1], [0, 4, 1]], "power": 30}
  ]})"));
  ASSERT_EQ(s.lights.size(), 4u);  // the sphere and the panel are triangles
  EXPECT_EQ(s.lights[0].name, "bulb");
  EXPECT_NEAR(s.lights[0].intensity.x, 100 / (4 * kPi), 1e-5f);
  EXPECT_NEAR(s.lights[0].intensity.y, 50 / (4 * kPi), 1e-5f);
  const PunctualLight& spot = s.lights[1];
  EXPECT_EQ(spot.falloff, SpotFalloff::kBlender);
  EXPECT_NEAR(spot.intensity.x, 40 / (4 * kPi), 1e-5f);
  EXPECT_NEAR(spot.direction.y, -1, 1e-6f);
  EXPECT_NEAR(spot.cos_outer, std::cos(30 * kPi / 180), 1e-6f);
  EXPECT_NEAR(spot.cos_inner, spot.cos_outer + (1 - spot.cos_outer) * 0.5f, 1e-6f);
  EXPECT_EQ(s.lights[2].falloff, SpotFalloff::kGltf);
  EXPECT_NEAR(s.lights[2].cos_inner, std::cos(10 * kPi / 180), 1e-6f);
  EXPECT_EQ(s.lights[3].type, LightType::kDirectional);
  EXPECT_EQ(s.lights[3].angle_deg, 2.f);
  // The sphere emits its power (pi L A over its triangles), the panel pi / 4 of it (Cycles' area
  // lamp), front side only.
  ASSERT_EQ(s.materials.size(), 3u);
  const Material& ball = s.materials[1];
  EXPECT_TRUE(ball.emits_front_only);
  EXPECT_NEAR(emitted_flux(s, 1), 60, 1e-3);
  Vec3 n;
  EXPECT_NEAR(emitted_flux(s, 2, &n), 30 * kPi / 4, 1e-4);
  EXPECT_LT(n.y, 0);  // counter-clockwise seen from below: it lights the floor
  EXPECT_EQ(s.triangle_count(), 1u + 320u + 2u);
}

TEST(SceneJsonLights, BadLightsNameFileAndLine) {
  test::TempDir dir;
  dir.write("m.obj", kLampObj);
  const auto err = [&](const std::string& body) {
    return test::load_error(dir.write("e.json", "{\"obj\": \"m.obj\",\n\"lights\": [\n" + body + "]}"));
  };
  const auto has = [](const std::string& e, const std::string& part) {
    EXPECT_NE(e.find(part), std::string::npos) << e;
  };
  has(err(R"({"type": "laser"})"), "e.json:3: unknown light type 'laser' (point, spot, sun, area)");
  has(err(R"({"type": "point", "position": [0, 1, 0], "power": -5})"), "e.json:3: light power must be >= 0");
  has(err(R"({"type": "point", "position": [0, 1, 0]})"), "give exactly one of \"power\" and \"intensity\"");
  has(err(R"({"type": "spot", "position": [0, 1, 0], "direction": [0, -1, 0], "power": 1,
      "inner_cone_deg": 40, "outer_cone_deg": 30})"),
      "e.json:3: spot cone angles must satisfy 0 <= inner_cone_deg < outer_cone_deg <= 90");
  has(err(R"({"type": "area", "corners": [[0, 0, 0], [1, 0, 0], [2, 0, 0]], "power": 1})"),
      "area light 'light 0' has no area");
  has(err(R"({"type": "point", "position": [0, 1, 0], "power": 1, "colour": 1})"), "unknown key 'colour'");
}

}  // namespace
}  // namespace epr
