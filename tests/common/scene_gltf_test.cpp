// The glTF 2.0 loader (common/scene_loader/gltf.cpp): node transforms, meshes, materials, camera,
// .glb, the files a bundle carries, the path sandbox and errors naming the file and the element.
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "common/image.h"
#include "common/scene_loader.h"
#include "tests/common/gltf_test_files.h"
#include "tests/common/scene_test_files.h"

namespace epr {
namespace {

using test::GltfBuilder;
using test::TempDir;

const std::vector<float> kTriangle = {0, 0, 0, 1, 0, 0, 0, 1, 0};
const std::vector<float> kQuad = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0};

void expect_near(Vec3 a, Vec3 b) {
  EXPECT_NEAR(a.x, b.x, 1e-5f);
  EXPECT_NEAR(a.y, b.y, 1e-5f);
  EXPECT_NEAR(a.z, b.z, 1e-5f);
}

TEST(SceneGltf, ChildNodeGetsItsParentsTransform) {
  TempDir dir;
  GltfBuilder g;
  const int mesh = g.mesh(kTriangle);
  // Child: rotated 90 degrees about y, then moved up 1; parent: scaled 2, then moved +x 1.
  const double h = std::sqrt(0.5);
  const int child = g.node({{"mesh", mesh}, {"rotation", {0, h, 0, h}}, {"translation", {0, 1, 0}}}, false);
  g.node({{"children", {child}}, {"scale", {2, 2, 2}}, {"translation", {1, 0, 0}}});
  const Scene s = load_scene(g.write_gltf(dir, "scene"));
  ASSERT_EQ(s.triangle_count(), 1u);
  const auto& t = s.triangles[0];
  expect_near(s.positions[t[0]], {1, 2, 0});
  expect_near(s.positions[t[1]], {1, 2, -2});
  expect_near(s.positions[t[2]], {1, 4, 0});
}

TEST(SceneGltf, MatrixNodeAndMirroringKeepTheNormal) {
  TempDir dir;
  GltfBuilder g;
  // Mirrored in x: the triangle keeps facing +z.
  g.node({{"mesh", g.mesh(kTriangle)}, {"matrix", {-1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 5, 0, 0, 1}}});
  const Scene s = load_scene(g.write_gltf(dir, "scene"));
  ASSERT_EQ(s.triangle_count(), 1u);
  expect_near(s.geometric_normal(0), {0, 0, 1});
  Bounds3 b = s.bounds();
  expect_near(b.lo, {4, 0, 0});
  expect_near(b.hi, {5, 1, 0});
}

TEST(SceneGltf, IndexedAndNonIndexedMeshes) {
  TempDir dir;
  GltfBuilder g;
  g.node({{"mesh", g.mesh(kQuad, {0, 1, 2, 0, 2, 3})}});
  std::vector<float> soup = {0, 0, 1, 1, 0, 1, 1, 1, 1, 0, 0, 1, 1, 1, 1, 0, 1, 1};
  g.node({{"mesh", g.mesh(soup)}});
  const Scene s = load_scene(g.write_gltf(dir, "scene"));
  ASSERT_EQ(s.triangle_count(), 4u);
  EXPECT_FLOAT_EQ(s.area(0) + s.area(1), 1.f);
  EXPECT_FLOAT_EQ(s.area(2) + s.area(3), 1.f);
  expect_near(s.positions[s.triangles[1][2]], {0, 1, 0});
  expect_near(s.positions[s.triangles[3][1]], {1, 1, 1});
}

TEST(SceneGltf, OtherPrimitiveModesAreRefusedNamingTheElement) {
  TempDir dir;
  GltfBuilder g;
  g.node({{"mesh", g.mesh(kTriangle)}});
  g.node({{"mesh", g.mesh(kQuad, {}, -1, {}, 1)}});
  const std::string path = g.write_gltf(dir, "scene");
  EXPECT_EQ(test::load_error(path),
            path + ": meshes[1].primitives[0]: mode 1 (lines) is not supported: only triangle lists (mode 4) are read");
  g.doc["meshes"][1]["primitives"][0]["mode"] = 0;
  EXPECT_NE(test::load_error(g.write_gltf(dir, "scene")).find("meshes[1].primitives[0]: mode 0 (points)"),
            std::string::npos);
}

TEST(SceneGltf, BaseColourFactorAndTexture) {
  TempDir dir;
  Image img(2, 1, 3);
  img.set_rgb(0, 0, {1, 0, 0});
  img.set_rgb(1, 0, {0, 1, 0});
  dir.write("tex/rg.png", "");
  write_png_srgb(dir.path("tex/rg.png"), img);
  GltfBuilder g;
  const int plain = g.material(
      {{"name", "paint"}, {"pbrMetallicRoughness", {{"baseColorFactor", {0.5, 0.25, 1, 1}}, {"metallicFactor", 0}}}});
  const nlohmann::json tex = {{"baseColorTexture", {{"index", 0}}}, {"metallicFactor", 0}};
  const int textured = g.material({{"name", "tiles"}, {"pbrMetallicRoughness", tex}});
  nlohmann::json half = tex;
  half["baseColorFactor"] = {0.5, 0.5, 0.5, 1};
  const int tinted = g.material({{"name", "tinted"}, {"pbrMetallicRoughness", half}});
  g.doc["images"] = {{{"uri", "tex/rg.png"}}};
  g.doc["textures"] = {{{"source", 0}}};
  g.node({{"mesh", g.mesh(kTriangle, {}, plain)}});
  const std::vector<float> uv = {0.25f, 0.5f, 0.75f, 0.5f, 0.25f, 0.f};
  g.node({{"mesh", g.mesh(kTriangle, {}, textured, uv)}});
  g.node({{"mesh", g.mesh(kTriangle, {}, tinted, uv)}});
  const Scene s = load_scene(g.write_gltf(dir, "scene"));
  ASSERT_EQ(s.triangle_count(), 3u);
  const Material& p = s.materials[s.material_of[0]];
  EXPECT_EQ(p.name, "paint");
  expect_near(p.kd, {0.5f, 0.25f, 1.f});
  EXPECT_EQ(p.type, MaterialType::kMicrofacet);  // a dielectric: specular layer over the base colour
  EXPECT_EQ(p.kd_texture, -1);
  const Material& t = s.materials[s.material_of[1]];
  ASSERT_GE(t.kd_texture, 0);
  ASSERT_EQ(s.uvs.size(), 3u);
  // glTF's v runs down the image: (0.25, 0.5) is the left texel, (0.75, 0.5) the right one.
  expect_near(s.textures[size_t(t.kd_texture)].lookup(s.uvs[1][0]), {1, 0, 0});
  expect_near(s.textures[size_t(t.kd_texture)].lookup(s.uvs[1][1]), {0, 1, 0});
  const Material& h = s.materials[s.material_of[2]];
  ASSERT_GE(h.kd_texture, 0);
  EXPECT_NE(h.kd_texture, t.kd_texture);
  expect_near(s.textures[size_t(h.kd_texture)].lookup(s.uvs[2][1]), {0, 0.5f, 0});
}

TEST(SceneGltf, EmissiveStrengthMakesAnAreaLight) {
  TempDir dir;
  GltfBuilder g;
  const int lamp = g.material({{"name", "lamp"},
                               {"emissiveFactor", {1, 0.5, 0.25}},
                               {"extensions", {{"KHR_materials_emissive_strength", {{"emissiveStrength", 10}}}}}});
  g.doc["extensionsUsed"] = {"KHR_materials_emissive_strength"};
  g.node({{"mesh", g.mesh(kTriangle, {}, lamp)}});
  const std::string path = g.write_gltf(dir, "scene");
  const Scene s = load_scene(path);
  expect_near(s.materials[s.material_of[0]].ke, {10, 5, 2.5f});
  EXPECT_FALSE(unlit_reason(s).has_value());
  g.doc["materials"][0].erase("extensions");
  g.doc["materials"][0]["emissiveFactor"] = {0, 0, 0};
  EXPECT_TRUE(unlit_reason(load_scene(g.write_gltf(dir, "scene"))).has_value());
}

TEST(SceneGltf, FirstCameraNodeIsTheScenesCamera) {
  TempDir dir;
  GltfBuilder g;
  g.doc["cameras"] = {{{"type", "perspective"}, {"perspective", {{"yfov", 0.5}, {"aspectRatio", 1.5}, {"znear", 0.1}}}},
                      {{"type", "perspective"}, {"perspective", {{"yfov", 1.0}, {"znear", 0.1}}}}};
  g.node({{"mesh", g.mesh(kTriangle)}});
  const int cam = g.node({{"camera", 0}, {"translation", {0, 1, 5}}}, false);
  g.node({{"children", {cam}}, {"translation", {1, 0, 0}}});
  g.node({{"camera", 1}, {"translation", {9, 9, 9}}});
  const Scene s = load_scene(g.write_gltf(dir, "scene"));
  expect_near(s.camera.eye, {1, 1, 5});
  expect_near(s.camera.look, {1, 1, 4});
  expect_near(s.camera.up, {0, 1, 0});
  EXPECT_NEAR(s.camera.fov_y_degrees, 0.5 * 180 / 3.14159265358979, 1e-4);

  GltfBuilder none;
  none.node({{"mesh", none.mesh(kTriangle)}});
  const CameraSpec def;
  expect_near(load_scene(none.write_gltf(dir, "plain")).camera.eye, def.eye);
}

TEST(SceneGltf, GlbWithEmbeddedImage) {
  TempDir dir;
  Image img(1, 1, 3);
  img.set_rgb(0, 0, {0, 0, 1});
  const std::vector<unsigned char> png = encode_png_srgb(img);
  GltfBuilder g;
  const int v = g.view(std::string(png.begin(), png.end()));
  g.doc["images"] = {{{"bufferView", v}, {"mimeType", "image/png"}}};
  g.doc["textures"] = {{{"source", 0}}};
  const int m = g.material({{"pbrMetallicRoughness", {{"baseColorTexture", {{"index", 0}}}, {"metallicFactor", 0}}}});
  g.node({{"mesh", g.mesh(kTriangle, {0, 1, 2}, m, {0, 0, 1, 0, 0, 1})}});
  LoadReport report;
  const std::string path = g.write_glb(dir, "scene");
  const Scene s = load_scene(path, {}, &report);
  ASSERT_EQ(s.triangle_count(), 1u);
  const Material& mat = s.materials[s.material_of[0]];
  ASSERT_GE(mat.kd_texture, 0);
  expect_near(s.textures[size_t(mat.kd_texture)].lookup({0.5f, 0.5f}), {0, 0, 1});
  ASSERT_EQ(report.files.size(), 1u);
  EXPECT_EQ(report.files[0].display, path);
}

TEST(SceneGltf, TheLoadReadsTheGltfItsBufferAndItsImage) {
  TempDir dir;
  dir.write("maps/wood.png", "");
  write_png_srgb(dir.path("maps/wood.png"), Image(2, 2, 3));
  dir.write("unused.png", "not read");
  GltfBuilder g;
  g.doc["images"] = {{{"uri", "maps/wood.png"}}};
  g.doc["textures"] = {{{"source", 0}}};
  const int m = g.material({{"pbrMetallicRoughness", {{"baseColorTexture", {{"index", 0}}}, {"metallicFactor", 0}}}});
  g.node({{"mesh", g.mesh(kTriangle, {}, m, {0, 0, 1, 0, 0, 1})}});
  LoadReport report;
  load_scene(g.write_gltf(dir, "scene"), {}, &report);
  // The bundle a job carries is made of exactly these files (wire/scene_bundle.cpp).
  ASSERT_EQ(report.files.size(), 3u);
  EXPECT_EQ(report.files[0].real.filename(), "scene.gltf");
  EXPECT_EQ(report.files[1].real.filename(), "scene.bin");
  EXPECT_EQ(report.files[2].display, dir.path("maps/wood.png"));
}

TEST(SceneGltf, UrisMustStayInsideTheSceneFolder) {
  TempDir dir;
  GltfBuilder g;
  g.node({{"mesh", g.mesh(kTriangle)}});
  const std::string path = g.write_gltf(dir, "in/scene");
  dir.write("outside.bin", g.bin);
  g.doc["buffers"] = {{{"uri", "../outside.bin"}, {"byteLength", g.bin.size()}}};
  dir.write("in/scene.gltf", g.doc.dump());
  EXPECT_EQ(test::load_error(path), path + ": buffers[0]: uri '../outside.bin' leaves the scene folder");
  g.doc["buffers"][0]["uri"] = dir.path("outside.bin");
  dir.write("in/scene.gltf", g.doc.dump());
  EXPECT_NE(test::load_error(path).find(path + ": buffers[0]: uri '/"), std::string::npos);
  EXPECT_NE(test::load_error(path).find("is an absolute path"), std::string::npos);
  g.doc["buffers"][0]["uri"] = "scene.bin";
  g.doc["images"] = {{{"uri", "../x.png"}}};
  dir.write("in/scene.gltf", g.doc.dump());
  EXPECT_EQ(test::load_error(path), path + ": images[0]: uri '../x.png' leaves the scene folder");
  g.doc.erase("images");
  g.doc["buffers"][0]["uri"] = "missing.bin";
  dir.write("in/scene.gltf", g.doc.dump());
  EXPECT_EQ(test::load_error(path), path + ": buffers[0]: uri 'missing.bin' does not exist");
}

TEST(SceneGltf, OversizedDataUriIsRefused) {
  TempDir dir;
  GltfBuilder g;
  g.node({{"mesh", g.mesh(kTriangle)}});
  g.write_gltf(dir, "scene");
  // A little over 16 MiB once decoded.
  const size_t decoded = (size_t(16) << 20) + 3000;
  g.doc["buffers"] = {
      {{"uri", "data:application/octet-stream;base64," + std::string(decoded / 3 * 4, 'A')}, {"byteLength", decoded}}};
  const std::string path = dir.write("big.gltf", g.doc.dump());
  const std::string err = test::load_error(path);
  EXPECT_EQ(err.rfind(path + ": buffers[0]: data URI of about", 0), 0u) << err;
  // A small one is read.
  g.doc["buffers"] = {{{"uri", "data:application/octet-stream;base64," +
                                   [&] {
                                     static const char* k =
                                         "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
                                     std::string out;
                                     const std::string& b = g.bin;
                                     for (size_t i = 0; i < b.size(); i += 3) {
                                       uint32_t v = uint32_t(uint8_t(b[i])) << 16;
                                       if (i + 1 < b.size()) v |= uint32_t(uint8_t(b[i + 1])) << 8;
                                       if (i + 2 < b.size()) v |= uint8_t(b[i + 2]);
                                       out += k[(v >> 18) & 63];
                                       out += k[(v >> 12) & 63];
                                       out += i + 1 < b.size() ? k[(v >> 6) & 63] : '=';
                                       out += i + 2 < b.size() ? k[v & 63] : '=';
                                     }
                                     return out;
                                   }()},
                       {"byteLength", g.bin.size()}}};
  EXPECT_EQ(load_scene(dir.write("small.gltf", g.doc.dump())).triangle_count(), 1u);
}

TEST(SceneGltf, MalformedFilesNameTheFileAndTheElement) {
  TempDir dir;
  const std::string bad = dir.write("bad.gltf", "{\n \"asset\": {\"version\": \"2.0\"},\n \"nodes\": [,]\n}\n");
  EXPECT_EQ(test::load_error(bad).rfind(bad + ":3: invalid JSON", 0), 0u) << test::load_error(bad);
  GltfBuilder g;
  g.node({{"mesh", g.mesh(kTriangle)}});
  g.doc["accessors"][0]["count"] = 4;  // 48 bytes from a 36-byte bufferView
  const std::string path = g.write_gltf(dir, "scene");
  EXPECT_EQ(test::load_error(path).rfind(path + ": meshes[0].primitives[0]: POSITION accessors[0] is out of range", 0),
            0u)
      << test::load_error(path);
  GltfBuilder i;
  i.node({{"mesh", i.mesh(kTriangle, {0, 1, 3})}});
  const std::string ipath = i.write_gltf(dir, "index");
  EXPECT_EQ(test::load_error(ipath),
            ipath + ": meshes[0].primitives[0]: index 3 (entry 2) is out of range: POSITION has 3 vertices");
  i.doc["nodes"][0]["mesh"] = 7;
  EXPECT_EQ(test::load_error(i.write_gltf(dir, "index")), ipath + ": nodes[0]: mesh 7 does not exist (1 meshes)");
  const std::string glb = dir.write("short.glb", "glTF\x02");
  EXPECT_EQ(test::load_error(glb), glb + ": not a valid .glb file: shorter than its header");
}

TEST(SceneGltf, ApproximationsAreReportedOncePerMaterial) {
  TempDir dir;
  GltfBuilder g;
  const int chrome = g.material({{"name", "chrome"},
                                 {"pbrMetallicRoughness", {{"metallicFactor", 1}, {"roughnessFactor", 0.2}}},
                                 {"extensions", {{"KHR_materials_clearcoat", nlohmann::json::object()}}}});
  const int leaf =
      g.material({{"name", "leaf"}, {"alphaMode", "BLEND"}, {"pbrMetallicRoughness", {{"metallicFactor", 0}}}});
  g.node({{"mesh", g.mesh(kTriangle, {}, chrome)}});
  g.node({{"mesh", g.mesh(kTriangle, {}, chrome)}});
  g.node({{"mesh", g.mesh(kTriangle, {}, leaf)}});
  LoadReport report;
  const std::string path = g.write_gltf(dir, "scene");
  const Scene s = load_scene(path, {}, &report);
  const Material& c = s.materials[s.material_of[0]];
  EXPECT_EQ(c.type, MaterialType::kMicrofacet);
  EXPECT_FLOAT_EQ(c.metallic, 1.f);
  EXPECT_FLOAT_EQ(c.roughness, 0.2f);
  ASSERT_EQ(report.warnings.size(), 2u);
  EXPECT_EQ(report.warnings[0].rfind(
                path + ": material 'chrome' (materials[0]): extension 'KHR_materials_clearcoat' ignored", 0),
            0u)
      << report.warnings[0];
  EXPECT_NE(report.warnings[1].find("material 'leaf' (materials[1]): alphaMode BLEND rendered as MASK with "
                                    "alphaCutoff 0.5"),
            std::string::npos)
      << report.warnings[1];
}

TEST(SceneGltf, SceneJsonNamesAGltfAndOverridesItsCamera) {
  TempDir dir;
  GltfBuilder g;
  g.doc["cameras"] = {{{"type", "perspective"}, {"perspective", {{"yfov", 0.5}, {"znear", 0.1}}}}};
  const int lamp = g.material({{"name", "lamp"}, {"emissiveFactor", {1, 1, 1}}});
  g.node({{"mesh", g.mesh(kTriangle, {}, lamp)}});
  g.node({{"camera", 0}, {"translation", {0, 0, 4}}});
  g.write_gltf(dir, "models/room");
  const std::string json = dir.write(
      "scene.json", R"({"obj": "models/room.gltf", "camera": {"fov": 60}, "materials": {"lamp": {"ke": [3, 3, 3]}}})");
  const Scene s = load_scene(json);
  expect_near(s.camera.eye, {0, 0, 4});
  EXPECT_FLOAT_EQ(s.camera.fov_y_degrees, 60.f);
  expect_near(s.materials[s.material_of[0]].ke, {3, 3, 3});
}

TEST(SceneGltf, ShippedCornellBoxGltfIsLit) {
  const Scene s = load_job_scene(std::string(EPR_SOURCE_DIR) + "/scenes/cornell-box.gltf");
  EXPECT_GE(s.triangle_count(), 30u);
  EXPECT_FALSE(unlit_reason(s).has_value());
  EXPECT_NEAR(s.camera.fov_y_degrees, 39.3077f, 1e-3f);
}

}  // namespace
}  // namespace epr
