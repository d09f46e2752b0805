// Scene input beyond what a render can hold (issues "Step 14" and "Step 16"): glTF positions and node
// transforms against the coordinate limit, and the built scene's vertices whatever the loader; glTF
// files whose structure tinygltf would pass over (required extensions, primitives); a camera far
// away; environment images with huge, infinite, negative or NaN texels; a sun too small to be a disc;
// when dropped non-finite samples make a render's end warn.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "common/camera.h"
#include "common/image.h"
#include "common/lighting.h"
#include "common/limits.h"
#include "common/render_options.h"
#include "common/scene_loader.h"
#include "common/tile.h"
#include "tests/common/gltf_test_files.h"
#include "tests/common/scene_test_files.h"

namespace epr {
namespace {

using test::GltfBuilder;
using test::TempDir;

const std::vector<float> kUnitTriangle = {0, 0, 0, 1, 0, 0, 0, 1, 0};

bool holds(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

TEST(SceneLimits, GltfPositionBeyondTheLimitIsRefusedNamingTheElement) {
  TempDir dir;
  for (const float big : {1e25f, 3e38f, -2e8f}) {
    GltfBuilder g;
    std::vector<float> xyz = kUnitTriangle;
    xyz[0] = big;
    g.node({{"mesh", g.mesh(xyz)}});
    const std::string path = g.write_gltf(dir, "scene");
    EXPECT_EQ(test::load_error(path), fmt::format("{}: meshes[0].primitives[0]: POSITION accessors[0] element 0 ({:g}, "
                                                  "0, 0) exceeds the magnitude limit 1e+08 (metres)",
                                                  path, double(big)));
  }
  // At the limit it loads.
  GltfBuilder g;
  std::vector<float> xyz = kUnitTriangle;
  xyz[3] = 1e8f;
  g.node({{"mesh", g.mesh(xyz)}});
  EXPECT_EQ(test::load_error(g.write_gltf(dir, "edge")), "");
}

TEST(SceneLimits, GltfNodeTransformBeyondTheLimitNamesTheNode) {
  TempDir dir;
  GltfBuilder g;
  const int mesh = g.mesh(kUnitTriangle);
  g.node({{"mesh", mesh}});
  g.node({{"mesh", mesh}, {"scale", {1e25, 1, 1}}});
  const std::string path = g.write_gltf(dir, "scene");
  EXPECT_EQ(test::load_error(path),
            path +
                ": meshes[0].primitives[0]: POSITION accessors[0] element 1 (1, 0, 0), placed by nodes[1] and its "
                "parents at (1e+25, 0, 0), exceeds the magnitude limit 1e+08 (metres)");
  // Each transform within reason, their product not: the child is named.
  GltfBuilder n;
  const int child = n.node({{"mesh", n.mesh(kUnitTriangle)}, {"translation", {0, 5e4, 0}}}, false);
  n.node({{"children", {child}}, {"scale", {1e4, 1e4, 1e4}}});
  const std::string nested = n.write_gltf(dir, "nested");
  const std::string e = test::load_error(nested);
  EXPECT_TRUE(holds(e, nested + ": meshes[0].primitives[0]: POSITION accessors[0] element 0 (0, 0, 0), placed by "
                                "nodes[0] and its parents at (0, 5e+08, 0)"))
      << e;
}

TEST(SceneLimits, NonFiniteGltfPositionsNameTheAccessor) {
  TempDir dir;
  const float inf = std::numeric_limits<float>::infinity();
  for (const float bad : {inf, std::numeric_limits<float>::quiet_NaN()}) {
    GltfBuilder g;
    std::vector<float> xyz = kUnitTriangle;
    xyz[4] = bad;
    g.node({{"mesh", g.mesh(xyz)}});
    const std::string path = g.write_gltf(dir, "scene");
    EXPECT_EQ(test::load_error(path),
              fmt::format("{}: meshes[0].primitives[0]: POSITION accessors[0] element 1 (1, {}, 0) is not finite", path,
                          std::isnan(bad) ? "nan" : "inf"));
  }
  GltfBuilder all;
  all.node({{"mesh", all.mesh(std::vector<float>(9, inf))}});
  const std::string path = all.write_gltf(dir, "all");
  EXPECT_EQ(test::load_error(path),
            path + ": meshes[0].primitives[0]: POSITION accessors[0] element 0 (inf, inf, inf) is not finite");
}

TEST(SceneLimits, BuiltSceneVerticesAreCheckedWhateverTheLoader) {
  Scene s;
  s.name = "made";
  const uint32_t m = add_material(s, Material{});
  add_triangle(s, {0, 0, 0}, {1, 0, 0}, {0, 1, 0}, m);
  EXPECT_NO_THROW(s.validate());
  add_triangle(s, {0, 0, 0}, {0, 2e8f, 0}, {0, 0, 1}, m);
  try {
    s.validate();
    ADD_FAILURE() << "a vertex beyond the limit passed";
  } catch (const std::runtime_error& e) {
    EXPECT_EQ(std::string(e.what()),
              "scene 'made': vertex 4 at (0, 2e+08, 0) exceeds the magnitude limit 1e+08 (metres)");
  }
}

TEST(SceneLimits, RequiredExtensionsAreCheckedBeforeAnythingElse) {
  TempDir dir;
  // As a Draco file is: the accessors have no bufferView, the primitive's extension points at the data.
  GltfBuilder g;
  const int view = g.view(std::string(64, '\x01'));
  g.doc["accessors"] = {{{"componentType", 5126}, {"count", 3}, {"type", "VEC3"}},
                        {{"componentType", 5123}, {"count", 3}, {"type", "SCALAR"}}};
  g.doc["meshes"] = {
      {{"primitives",
        {{{"attributes", {{"POSITION", 0}}},
          {"indices", 1},
          {"extensions",
           {{"KHR_draco_mesh_compression", {{"bufferView", view}, {"attributes", {{"POSITION", 0}}}}}}}}}}}};
  g.node({{"mesh", 0}});
  g.doc["extensionsUsed"] = {"KHR_draco_mesh_compression"};
  g.doc["extensionsRequired"] = {"KHR_draco_mesh_compression"};
  const std::string path = g.write_gltf(dir, "draco");
  EXPECT_EQ(test::load_error(path), path +
                                        ": requires the extension 'KHR_draco_mesh_compression', which is not "
                                        "supported (export the meshes without Draco compression)");
  g.doc["extensionsRequired"] = {"KHR_materials_emissive_strength", "EXT_meshopt_compression"};
  EXPECT_EQ(test::load_error(g.write_gltf(dir, "draco")),
            path + ": requires the extension 'EXT_meshopt_compression', which is not supported");
}

TEST(SceneLimits, PrimitivesMustBeAnArrayOfObjectsWithAttributes) {
  TempDir dir;
  GltfBuilder g;
  g.node({{"mesh", g.mesh(kUnitTriangle)}});
  g.doc["meshes"][0]["primitives"] = g.doc["meshes"][0]["primitives"][0];  // an object, not an array
  const std::string path = g.write_gltf(dir, "scene");
  EXPECT_EQ(test::load_error(path), path + ": meshes[0]: primitives must be a non-empty array");
  g.doc["meshes"][0]["primitives"] = nlohmann::json::array({{{"mode", 4}}});
  EXPECT_EQ(test::load_error(g.write_gltf(dir, "scene")),
            path + ": meshes[0].primitives[0] must be an object with attributes");
}

TEST(SceneLimits, NoTrianglesSaysWhichPrimitivesGaveNone) {
  TempDir dir;
  GltfBuilder g;
  g.node({{"mesh", g.mesh(std::vector<float>(9, 0.f))}});
  const std::string path = g.write_gltf(dir, "flat");
  EXPECT_EQ(test::load_error(path),
            path +
                ": no triangles: the 1 primitive(s) scenes[0] places, the first meshes[0].primitives[0], hold 1 "
                "triangle(s): 1 of zero area, 0 cut out entirely by their material");
  GltfBuilder empty;
  empty.mesh(kUnitTriangle);
  empty.node({{"name", "lamp"}});
  const std::string none = empty.write_gltf(dir, "none");
  EXPECT_EQ(test::load_error(none), none +
                                        ": no triangles: no node of scenes[0] holds a mesh (1 nodes, 1 meshes in "
                                        "the file)");
}

TEST(SceneLimits, CameraBeyondTheLimitSaysSo) {
  CameraSpec c;
  c.eye = {1e20f, 0, 0};
  EXPECT_EQ(c.validate().value_or(""), "camera eye (1e+20, 0, 0) exceeds the magnitude limit 1e+08 (metres)");
  c.eye = {0, 1, 4};
  c.look = {0, 0, -3e9f};
  EXPECT_EQ(c.validate().value_or(""),
            "camera look-at point (0, 0, -3e+09) exceeds the magnitude limit 1e+08 (metres)");
  RenderOptions o;
  o.eye = Vec3(1e20f, 0, 0);
  EXPECT_EQ(o.validate().value_or(""), "--eye 1e+20,0,0 exceeds the magnitude limit 1e+08 (metres)");
  o.eye = Vec3(0, 1, 3);
  o.look = Vec3(0, 5e8f, 0);
  EXPECT_EQ(o.validate().value_or(""), "--look 0,5e+08,0 exceeds the magnitude limit 1e+08 (metres)");
  // A scene JSON's camera is named by its file and line.
  TempDir dir;
  dir.write("t.obj", test::kTriangle + "f 1 2 3\n");
  const std::string json = dir.write("s.json", "{\"obj\": \"t.obj\",\n\"camera\": {\"eye\": [0, 0, 1e20]}}");
  const std::string e = test::load_error(json);
  EXPECT_TRUE(holds(e, json + ":2: camera eye (0, 0, 1e+20) exceeds the magnitude limit")) << e;
}

TEST(SceneLimits, EnvironmentTexelsAreCappedAndNegativesReadAsZero) {
  TempDir dir;
  dir.write("t.obj", test::kTriangle + "f 1 2 3\n");
  const float inf = std::numeric_limits<float>::infinity();
  Image sky(4, 2, 3);
  for (int y = 0; y < 2; ++y)
    for (int x = 0; x < 4; ++x) sky.set_rgb(x, y, {0.5f, 0.5f, 0.5f});
  sky.set_rgb(0, 0, {3e38f, 2e6f, 1.f});
  sky.set_rgb(1, 0, {-0.003f, 0.25f, -1e-5f});
  sky.set_rgb(2, 1, {inf, 1.f, 1.f});
  dir.write("sky.exr", "");
  write_exr(dir.path("sky.exr"), sky);
  const std::string json = dir.write("s.json", "{\"obj\": \"t.obj\",\n\"environment\": {\"image\": \"sky.exr\"}}");
  LoadReport report;
  const Scene s = load_scene(json, {}, &report);
  ASSERT_TRUE(s.lighting.environment && s.lighting.environment->pixels);
  const Image& px = *s.lighting.environment->pixels;
  EXPECT_EQ(px.rgb(0, 0), Vec3(1e6f, 1e6f, 1.f));
  EXPECT_EQ(px.rgb(1, 0), Vec3(0.f, 0.25f, 0.f));
  EXPECT_EQ(px.rgb(2, 1), Vec3(1e6f, 1.f, 1.f));
  EXPECT_EQ(px.rgb(3, 1), Vec3(0.5f));
  ASSERT_EQ(report.warnings.size(), 2u);
  EXPECT_EQ(report.warnings[0], json + ":2: environment image 'sky.exr': 2 negative texel values read as 0");
  EXPECT_EQ(report.warnings[1],
            json + ":2: environment image 'sky.exr': 3 texel values above 1e+06 (or infinite) capped to 1e+06");
  // NaN has no meaning: refused, naming the texel.
  sky.set_rgb(3, 1, {0.5f, std::numeric_limits<float>::quiet_NaN(), 0.5f});
  write_exr(dir.path("sky.exr"), sky);
  EXPECT_EQ(test::load_error(json), json + ":2: environment image 'sky.exr' has a NaN texel at (3, 1)");
}

TEST(SceneLimits, SunTooSmallForADiscIsRefused) {
  SunLight s;
  s.angle_deg = 1e-18f;
  EXPECT_EQ(check_sun(s).value_or(""), "sun angle (angular diameter, degrees) must be in [0.001, 90], got 1e-18");
  EXPECT_THROW(parse_sun_flag("0,1,0,1e-18"), std::invalid_argument);
  // At the smallest angle the strongest sun's radiance is finite and gives back its irradiance.
  s = parse_sun_flag("0,1,0,0.001,1e9");
  EXPECT_EQ(s.angle_deg, limits::kMinSunAngleDeg);
  const double h = std::sin(0.5 * double(s.angle_deg) * kPi / 180);
  ASSERT_TRUE(is_finite(s.radiance()));
  EXPECT_NEAR(double(s.radiance().x) * kPi * h * h, 1e9, 1e9 * 1e-4);
}

TEST(SceneLimits, NonFiniteDropsWarnAboveOnePerMillionPaths) {
  EXPECT_FALSE(nonfinite_warning(0, 1000));
  EXPECT_FALSE(nonfinite_warning(1, 1000000));
  EXPECT_FALSE(nonfinite_warning(0, 0));
  const auto w = nonfinite_warning(962, 65536);
  ASSERT_TRUE(w);
  EXPECT_EQ(w->rfind("962 samples came out NaN or infinite and were dropped (1.47e+04 per million of the 65536 "
                     "paths traced)",
                     0),
            0u)
      << *w;
  EXPECT_TRUE(nonfinite_warning(2, 1000000));
  EXPECT_TRUE(nonfinite_warning(1, 0));
}

}  // namespace
}  // namespace epr
