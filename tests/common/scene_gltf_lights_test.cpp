// glTF's KHR_lights_punctual (common/scene_loader/gltf_lights.cpp): lights placed by their nodes,
// photometric units converted (candela and lux / 683, Blender's importer's convention), and bad values
// refused naming the file and the light.
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "common/scene_loader.h"
#include "tests/common/gltf_test_files.h"
#include "tests/common/scene_test_files.h"

namespace epr {
namespace {

using test::GltfBuilder;
using test::TempDir;

// A triangle to render and the lights given, each placed by its own node (`nodes`: the nodes'
// JSON without the extension; the i-th node carries light i).
GltfBuilder lit_triangle(const nlohmann::json& lights, const std::vector<nlohmann::json>& nodes) {
  GltfBuilder g;
  g.node({{"mesh", g.mesh({0, 0, 0, 1, 0, 0, 0, 1, 0})}});
  g.doc["extensionsUsed"] = {"KHR_lights_punctual"};
  g.doc["extensions"]["KHR_lights_punctual"]["lights"] = lights;
  for (size_t i = 0; i < nodes.size(); ++i) {
    nlohmann::json n = nodes[i];
    n["extensions"]["KHR_lights_punctual"]["light"] = i;
    g.node(n);
  }
  return g;
}

std::string load_error(GltfBuilder& g) {
  TempDir dir;
  const std::string path = g.write_gltf(dir, "lamps");
  try {
    load_scene(path);
  } catch (const SceneError& e) {
    return e.what();
  }
  return "(loaded)";
}

TEST(SceneGltfLights, PointSpotAndDirectionalArePlacedAndConverted) {
  TempDir dir;
  const double h = std::sqrt(0.5);
  GltfBuilder g = lit_triangle(
      {{{"type", "point"}, {"name", "bulb"}, {"intensity", 683}, {"color", {1, 0.5, 0.25}}},
       {{"type", "spot"}, {"intensity", 1366}, {"spot", {{"innerConeAngle", 0.2}, {"outerConeAngle", 0.5}}}},
       {{"type", "directional"}, {"intensity", 6830}},
       {{"type", "directional"}, {"intensity", 683}}},
      {{{"translation", {1, 2, 3}}},
       // Rotated -90 degrees about X: local -Z (the way a spot shines) becomes world -Y.
       {{"translation", {0, 4, 0}}, {"rotation", {-h, 0, 0, h}}},
       {{"rotation", {-h, 0, 0, h}}},  // shines down: towards the light is +Y
       {}});                           // shines along -Z: towards the light is +Z
  const Scene s = load_scene(g.write_gltf(dir, "lamps"));
  ASSERT_EQ(s.lights.size(), 4u);
  const PunctualLight& point = s.lights[0];
  EXPECT_EQ(point.type, LightType::kPoint);
  EXPECT_EQ(point.name, "bulb");
  EXPECT_NEAR(point.position.x, 1, 1e-6f);
  EXPECT_NEAR(point.position.y, 2, 1e-6f);
  EXPECT_NEAR(point.position.z, 3, 1e-6f);
  // 683 cd = 1 W/sr, times the colour.
  EXPECT_NEAR(point.intensity.x, 1, 1e-6f);
  EXPECT_NEAR(point.intensity.y, 0.5, 1e-6f);
  EXPECT_NEAR(point.intensity.z, 0.25, 1e-6f);
  const PunctualLight& spot = s.lights[1];
  EXPECT_EQ(spot.type, LightType::kSpot);
  EXPECT_EQ(spot.falloff, SpotFalloff::kGltf);
  EXPECT_NEAR(spot.position.y, 4, 1e-6f);
  EXPECT_NEAR(spot.direction.y, -1, 1e-5f);
  EXPECT_NEAR(spot.intensity.x, 2, 1e-6f);
  EXPECT_NEAR(spot.cos_inner, std::cos(0.2f), 1e-6f);
  EXPECT_NEAR(spot.cos_outer, std::cos(0.5f), 1e-6f);
  EXPECT_EQ(s.lights[2].type, LightType::kDirectional);
  EXPECT_NEAR(s.lights[2].direction.y, 1, 1e-5f);
  EXPECT_NEAR(s.lights[2].intensity.x, 10, 1e-5f);  // 6830 lux = 10 W/m^2
  EXPECT_NEAR(s.lights[3].direction.z, 1, 1e-5f);
  // Lights make a scene without emitters renderable.
  EXPECT_FALSE(unlit_reason(s));
}

TEST(SceneGltfLights, BadValuesAreRefusedNamingTheLight) {
  struct Case {
    nlohmann::json light;
    std::string expected;
  };
  const std::vector<Case> cases = {
      {{{"type", "point"}, {"name", "lamp"}, {"intensity", -1}},
       "KHR_lights_punctual.lights[0] ('lamp'): intensity must be >= 0"},
      {{{"type", "spot"}, {"spot", {{"innerConeAngle", 0.6}, {"outerConeAngle", 0.5}}}},
       "KHR_lights_punctual.lights[0]: spot cone angles must satisfy 0 <= innerConeAngle < outerConeAngle"},
      {{{"type", "spot"}, {"spot", {{"innerConeAngle", 0.1}, {"outerConeAngle", 2.0}}}},
       "outerConeAngle <= pi/2, got innerConeAngle 0.1, outerConeAngle 2"},
      {{{"type", "area"}}, "KHR_lights_punctual.lights[0]: unknown type 'area' (point, spot, directional)"},
      {{{"type", "point"}, {"color", {1, -1, 0}}}, "KHR_lights_punctual.lights[0]: color[1] must be >= 0"},
  };
  for (const Case& c : cases) {
    GltfBuilder g = lit_triangle(nlohmann::json::array({c.light}), {nlohmann::json::object()});
    const std::string error = load_error(g);
    EXPECT_NE(error.find("lamps.gltf: "), std::string::npos) << error;
    EXPECT_NE(error.find(c.expected), std::string::npos) << error;
  }
  // A node naming a light the file does not have.
  GltfBuilder g = lit_triangle({{{"type", "point"}}}, {});
  g.node({{"extensions", {{"KHR_lights_punctual", {{"light", 3}}}}}});
  EXPECT_NE(load_error(g).find("nodes[1]: light 3 does not exist (1 lights in KHR_lights_punctual)"), std::string::npos)
      << load_error(g);
}

TEST(SceneGltfLights, RequiredExtensionIsAccepted) {
  TempDir dir;
  GltfBuilder g = lit_triangle({{{"type", "point"}, {"intensity", 10}}}, {{{"translation", {0, 1, 0}}}});
  g.doc["extensionsRequired"] = {"KHR_lights_punctual"};
  const Scene s = load_scene(g.write_gltf(dir, "lamps"));
  EXPECT_EQ(s.lights.size(), 1u);
}

}  // namespace
}  // namespace epr
