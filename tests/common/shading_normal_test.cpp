// Shading normals (common/shading_normal.h), tangents and normal maps (common/tangents.h), bilinear
// texture lookups, and the loaders' smooth normals: glTF NORMAL placed by the node's inverse
// transpose, TANGENT, normalTexture read as data, OBJ vn, and bad normals refused naming the element.
#include "common/shading_normal.h"

#include <OpenImageIO/imageio.h>
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "common/image.h"
#include "common/scene_loader.h"
#include "common/tangents.h"
#include "tests/common/gltf_test_files.h"
#include "tests/common/scene_test_files.h"

namespace epr {
namespace {

using test::GltfBuilder;
using test::TempDir;
using test::write_rgb8_png;

void expect_vec_near(Vec3 a, Vec3 b, float tol = 1e-5f) {
  EXPECT_NEAR(a.x, b.x, tol) << "(" << a.x << ", " << a.y << ", " << a.z << ")";
  EXPECT_NEAR(a.y, b.y, tol) << "(" << a.x << ", " << a.y << ", " << a.z << ")";
  EXPECT_NEAR(a.z, b.z, tol) << "(" << a.x << ", " << a.y << ", " << a.z << ")";
}

// One triangle in the z = 0 plane (geometric normal +z) with the given corner normals.
Scene triangle_with_normals(Vec3 n0, Vec3 n1, Vec3 n2) {
  Scene s;
  s.name = "smooth-triangle";
  const uint32_t m = add_material(s, Material{});
  add_triangle(s, {0, 0, 0}, {1, 0, 0}, {0, 1, 0}, m);
  s.normals = {{normalize(n0), normalize(n1), normalize(n2)}};
  return s;
}

TEST(ShadingNormal, InterpolatedAtAKnownBarycentric) {
  const Vec3 n0 = normalize({0, 0, 1}), n1 = normalize({1, 0, 1}), n2 = normalize({0, 1, 2});
  const Scene s = triangle_with_normals(n0, n1, n2);
  s.validate();
  const float u = 0.2f, v = 0.3f;  // corners 1 and 2; corner 0 weighs 0.5
  expect_vec_near(interpolated_normal(s, 0, u, v), normalize(n0 * 0.5f + n1 * u + n2 * v));
  expect_vec_near(interpolated_normal(s, 0, 1, 0), n1);
  expect_vec_near(shading_normal(s, 0, u, v), normalize(n0 * 0.5f + n1 * u + n2 * v));  // no normal map
  Scene flat = s;
  flat.normals.clear();
  expect_vec_near(interpolated_normal(flat, 0, u, v), {0, 0, 1});
}

TEST(ShadingNormal, ValidateRefusesZeroAndNonFiniteNormals) {
  Scene s = triangle_with_normals({0, 0, 1}, {0, 0, 1}, {0, 0, 1});
  s.normals[0][2] = Vec3(0.f);
  try {
    s.validate();
    FAIL() << "a zero normal was accepted";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("triangle 0 corner 2"), std::string::npos) << e.what();
  }
  s.normals[0][2] = Vec3(std::nanf(""), 0, 1);
  EXPECT_THROW(s.validate(), std::runtime_error);
  s.normals.push_back(s.normals[0]);  // one entry per triangle
  s.normals[0][2] = Vec3(0, 0, 1);
  EXPECT_THROW(s.validate(), std::runtime_error);
}

// The normal turned to the viewer's side and bent as Cycles does: wo's mirror image stays above the
// geometric surface.
TEST(ShadingNormal, OrientedNormalKeepsTheReflectionAboveTheSurface) {
  const Vec3 ng{0, 0, 1};
  // Already valid: unchanged, but turned to ng's side.
  expect_vec_near(oriented_shading_normal(normalize({0.1f, 0, 1}), ng, normalize({0, 0.3f, 1})),
                  normalize({0.1f, 0, 1}));
  expect_vec_near(oriented_shading_normal(normalize({-0.1f, 0, -1}), ng, normalize({0, 0.3f, 1})),
                  normalize({0.1f, 0, 1}));
  // A grazing view from -x with the shading normal tilted 40 degrees to +x: wo lies below the
  // shading hemisphere, and its reflection would go under the surface.
  const Vec3 n = normalize({std::sin(0.7f), 0, std::cos(0.7f)});
  const Vec3 wo = normalize({-1, 0, 0.15f});
  ASSERT_LT(dot(n * (2 * dot(n, wo)) - wo, ng), 0.f);
  const Vec3 bent = oriented_shading_normal(n, ng, wo);
  EXPECT_NEAR(length(bent), 1.f, 1e-5f);
  const Vec3 r = bent * (2 * dot(bent, wo)) - wo;
  EXPECT_NEAR(dot(r, ng), std::min(0.9f * dot(wo, ng), 0.01f), 1e-4f);
  EXPECT_GT(dot(bent, wo), 0.f);
  EXPECT_GT(bent.x, 0.f);  // bent towards ng, not past it
  EXPECT_LT(bent.x, n.x);
}

// A 2 x 1 m quad in z = 0 (two triangles sharing corners by value) with uv over [0, 1]^2.
Scene uv_quad(std::array<Vec2, 4> uv) {
  Scene s;
  s.name = "uv-quad";
  const uint32_t m = add_material(s, Material{});
  const Vec3 p[4] = {{0, 0, 0}, {2, 0, 0}, {2, 1, 0}, {0, 1, 0}};
  s.positions = {p[0], p[1], p[2], p[0], p[2], p[3]};
  s.triangles = {{0, 1, 2}, {3, 4, 5}};
  s.material_of = {m, m};
  s.uvs = {{uv[0], uv[1], uv[2]}, {uv[0], uv[2], uv[3]}};
  return s;
}

TEST(Tangents, QuadWithKnownUvGetsItsUDirection) {
  Scene s = uv_quad({Vec2{0, 0}, Vec2{1, 0}, Vec2{1, 1}, Vec2{0, 1}});
  generate_tangents(s, {true, true});
  ASSERT_EQ(s.tangents.size(), 2u);
  for (const auto& tri : s.tangents)
    for (const Tangent& t : tri) {
      expect_vec_near(t.t, {1, 0, 0});
      EXPECT_EQ(t.w, 1.f);  // cross(n, t) = +y = +v
    }
  // u mirrored: the tangent turns round and the handedness flips (the bitangent stays +v = +y).
  s = uv_quad({Vec2{1, 0}, Vec2{0, 0}, Vec2{0, 1}, Vec2{1, 1}});
  generate_tangents(s, {true, true});
  for (const auto& tri : s.tangents)
    for (const Tangent& t : tri) {
      expect_vec_near(t.t, {-1, 0, 0});
      EXPECT_EQ(t.w, -1.f);
    }
  // uv turned a quarter: +u runs along +y.
  s = uv_quad({Vec2{0, 1}, Vec2{0, 0}, Vec2{1, 0}, Vec2{1, 1}});
  generate_tangents(s, {true, false});
  for (const Tangent& t : s.tangents[0]) {
    expect_vec_near(t.t, {0, 1, 0});
    EXPECT_EQ(t.w, 1.f);  // +v runs along -x = cross(n, t)
  }
  for (const Tangent& t : s.tangents[1]) expect_vec_near(t.t, {0, 0, 0});  // not asked for
  // uv_derivatives scales with the uv map: the quad is 2 m wide for one unit of u.
  const UvDerivatives d =
      uv_derivatives({Vec3{0, 0, 0}, Vec3{2, 0, 0}, Vec3{2, 1, 0}}, {Vec2{0, 0}, Vec2{1, 0}, Vec2{1, 1}});
  expect_vec_near(d.dp_du, {2, 0, 0});
  expect_vec_near(d.dp_dv, {0, 1, 0});
}

// A welded vertex averages its triangles' tangents, orthogonalised against its normal.
TEST(Tangents, SharedVertexAveragesAndIsOrthogonalToItsNormal) {
  Scene s = uv_quad({Vec2{0, 0}, Vec2{1, 0}, Vec2{1, 1}, Vec2{0, 1}});
  // Second triangle's uv sheared so that its own +u leans towards +y.
  s.uvs[1] = {Vec2{0, 0}, Vec2{1, 0.5f}, Vec2{0, 1}};
  const Vec3 tilted = normalize({0.3f, 0, 1});
  s.normals = {{tilted, tilted, tilted}, {tilted, tilted, tilted}};
  generate_tangents(s, {true, true});
  // Corner 0 of both triangles is one vertex (same position, normal and uv): one tangent.
  expect_vec_near(s.tangents[0][0].t, s.tangents[1][0].t);
  for (const auto& tri : s.tangents)
    for (const Tangent& t : tri) {
      EXPECT_NEAR(dot(t.t, tilted), 0.f, 1e-5f);
      EXPECT_NEAR(length(t.t), 1.f, 1e-5f);
    }
  // Corner 1 of triangle 0 (uv (1, 0)) is its own vertex: its tangent is triangle 0's +u, +x
  // orthogonalised against the tilted normal.
  expect_vec_near(s.tangents[0][1].t, normalize(Vec3{1, 0, 0} - tilted * tilted.x));
  EXPECT_GT(s.tangents[0][0].t.y, 0.f);  // the shared vertex leans towards the sheared triangle's +u
}

TEST(Tangents, NormalMapTexelTiltsTheNormal) {
  const Vec3 n{0, 0, 1};
  const Tangent t{{1, 0, 0}, 1};
  expect_vec_near(apply_normal_map(n, t, {0.5f, 0.5f, 1}, 1), n);  // the flat texel
  const float a = 0.3f;                                            // tilt of the stored normal, radians
  const Vec3 texel{0.5f + 0.5f * std::sin(a), 0.5f, 0.5f + 0.5f * std::cos(a)};
  expect_vec_near(apply_normal_map(n, t, texel, 1), {std::sin(a), 0, std::cos(a)});
  // Green is +v, the bitangent w cross(n, t): +y, or -y for the other handedness.
  expect_vec_near(apply_normal_map(n, t, {0.5f, 1, 0.5f}, 1), {0, 1, 0});
  expect_vec_near(apply_normal_map(n, {{1, 0, 0}, -1}, {0.5f, 1, 0.5f}, 1), {0, -1, 0});
  // scale multiplies x and y: 0 flattens the map, 2 doubles the tangent part.
  expect_vec_near(apply_normal_map(n, t, texel, 0), n);
  expect_vec_near(apply_normal_map(n, t, texel, 2), normalize({2 * std::sin(a), 0, std::cos(a)}));
  expect_vec_near(apply_normal_map(n, Tangent{}, texel, 1), n);  // no tangent: unchanged
}

TEST(TextureLookup, BilinearBetweenTexelCentresAndNearestOnRequest) {
  Texture t;
  t.width = 2;
  t.height = 1;
  t.rgb = {0, 0, 0, 1, 1, 1};
  EXPECT_FLOAT_EQ(t.lookup({0.25f, 0.5f}).x, 0.f);  // texel centres
  EXPECT_FLOAT_EQ(t.lookup({0.75f, 0.5f}).x, 1.f);
  EXPECT_FLOAT_EQ(t.lookup({0.5f, 0.5f}).x, 0.5f);  // halfway
  EXPECT_FLOAT_EQ(t.lookup({0.375f, 0.5f}).x, 0.25f);
  EXPECT_FLOAT_EQ(t.lookup({0.f, 0.5f}).x, 0.5f);      // wraps: between the last and the first texel
  EXPECT_FLOAT_EQ(t.lookup({1.125f, 0.2f}).x, 0.25f);  // repeats
  t.nearest = true;
  EXPECT_FLOAT_EQ(t.lookup({0.375f, 0.5f}).x, 0.f);
  EXPECT_FLOAT_EQ(t.lookup({0.5f, 0.5f}).x, 1.f);
}

const std::vector<float> kSnQuad = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0};
const std::vector<uint16_t> kSnQuadIndices = {0, 1, 2, 0, 2, 3};

// Adds NORMAL (and TANGENT) accessors to the builder's last mesh.
void add_attribute(GltfBuilder& g, const char* name, const std::vector<float>& v, const char* type, size_t n) {
  g.doc["meshes"].back()["primitives"][0]["attributes"][name] = g.accessor(test::bytes_of(v), 5126, v.size() / n, type);
}

TEST(SceneGltfNormals, NormalsFollowTheInverseTransposeOfTheNodeTransform) {
  TempDir dir;
  GltfBuilder g;
  const int mesh = g.mesh(kSnQuad, kSnQuadIndices);
  const float h = std::sqrt(0.5f);
  add_attribute(g, "NORMAL", {h, 0, h, h, 0, h, h, 0, h, h, 0, h}, "VEC3", 3);
  g.node({{"mesh", mesh}, {"scale", {2, 1, 1}}});
  g.node({{"mesh", mesh}, {"scale", {-1, 1, 1}}, {"translation", {0, 0, 3}}});
  const Scene s = load_scene(g.write_gltf(dir, "normals"));
  ASSERT_EQ(s.triangle_count(), 4u);
  ASSERT_EQ(s.normals.size(), 4u);
  // Stretched 2x along x, the surface x + z = c becomes x / 2 + z = c: normal (1, 0, 2) / sqrt 5.
  for (size_t k = 0; k < 3; ++k) expect_vec_near(s.normals[0][k], normalize({1, 0, 2}));
  // Mirrored in x: (-1, 0, 1) / sqrt 2, still on the side the geometric normal (+z) is.
  for (size_t k = 0; k < 3; ++k) expect_vec_near(s.normals[2][k], normalize({-1, 0, 1}));
  EXPECT_GT(dot(s.geometric_normal(2), s.normals[2][0]), 0.f);
}

TEST(SceneGltfNormals, PrimitivesWithoutNormalAreFlat) {
  TempDir dir;
  GltfBuilder g;
  const int smooth = g.mesh(kSnQuad, kSnQuadIndices);
  add_attribute(g, "NORMAL", {0, 0.6f, 0.8f, 0, 0.6f, 0.8f, 0, 0.6f, 0.8f, 0, 0.6f, 0.8f}, "VEC3", 3);
  const int flat = g.mesh(kSnQuad, kSnQuadIndices);
  g.node({{"mesh", smooth}});
  g.node({{"mesh", flat}, {"translation", {0, 0, 1}}});
  const Scene s = load_scene(g.write_gltf(dir, "mixed"));
  ASSERT_EQ(s.normals.size(), 4u);
  expect_vec_near(s.normals[0][1], {0, 0.6f, 0.8f});
  expect_vec_near(s.normals[3][1], {0, 0, 1});
  // Without any NORMAL the scene keeps no normals.
  GltfBuilder plain;
  plain.node({{"mesh", plain.mesh(kSnQuad, kSnQuadIndices)}});
  EXPECT_TRUE(load_scene(plain.write_gltf(dir, "plain")).normals.empty());
}

TEST(SceneGltfNormals, BadNormalsAreRefusedNamingTheAccessorAndElement) {
  TempDir dir;
  for (const bool nan : {true, false}) {
    GltfBuilder g;
    const int mesh = g.mesh(kSnQuad, kSnQuadIndices);
    const float bad = nan ? std::nanf("") : 0.f;
    add_attribute(g, "NORMAL", {0, 0, 1, 0, 0, 1, bad, 0, nan ? 1.f : 0.f, 0, 0, 1}, "VEC3", 3);
    g.node({{"mesh", mesh}});
    const std::string err = test::load_error(g.write_gltf(dir, nan ? "nan" : "zero"));
    EXPECT_NE(err.find(nan ? "nan.gltf" : "zero.gltf"), std::string::npos) << err;
    EXPECT_NE(err.find("meshes[0].primitives[0]: NORMAL accessors[2] element 2"), std::string::npos) << err;
    EXPECT_NE(err.find(nan ? "is not finite" : "has zero length"), std::string::npos) << err;
  }
  GltfBuilder g;
  const int mesh = g.mesh(kSnQuad, kSnQuadIndices);
  add_attribute(g, "NORMAL", {0, 0, 1, 0, 0, 1, 0, 0, 1}, "VEC3", 3);  // 3 normals for 4 vertices
  g.node({{"mesh", mesh}});
  const std::string err = test::load_error(g.write_gltf(dir, "short"));
  EXPECT_NE(err.find("NORMAL accessors[2] must be float VEC3 with one entry per POSITION"), std::string::npos) << err;
}

TEST(SceneGltfNormals, NormalTextureIsReadAsDataWithItsScaleAndTangents) {
  TempDir dir;
  write_rgb8_png(dir.path("n.png"), 1, 1, {0.75f, 0.5f, 1.f});  // stored 191, 128, 255
  for (const bool given : {false, true}) {
    GltfBuilder g;
    g.doc["images"] = {{{"uri", "n.png"}}};
    g.doc["samplers"] = {{{"magFilter", 9728}}};
    g.doc["textures"] = {{{"source", 0}, {"sampler", 0}}};
    const int mat = g.material({{"normalTexture", {{"index", 0}, {"scale", 0.5}}}});
    const int mesh = g.mesh(kSnQuad, kSnQuadIndices, mat, {0, 1, 1, 1, 1, 0, 0, 0});  // glTF v points down
    if (given) add_attribute(g, "TANGENT", {0, 1, 0, -1, 0, 1, 0, -1, 0, 1, 0, -1, 0, 1, 0, -1}, "VEC4", 4);
    g.node({{"mesh", mesh}});
    LoadReport report;
    const Scene s = load_scene(g.write_gltf(dir, "mapped"), {}, &report);
    for (const std::string& w : report.warnings) EXPECT_EQ(w.find("normalTexture"), std::string::npos) << w;
    ASSERT_EQ(s.materials.size(), 1u);
    const Material& m = s.materials[0];
    ASSERT_GE(m.normal_texture, 0);
    EXPECT_FLOAT_EQ(m.normal_scale, 0.5f);
    const Texture& t = s.textures[size_t(m.normal_texture)];
    EXPECT_TRUE(t.nearest);
    EXPECT_NEAR(t.lookup({0.5f, 0.5f}).x, 191.f / 255.f, 1e-6f);  // as stored, not sRGB-decoded
    ASSERT_EQ(s.tangents.size(), 2u);
    ASSERT_EQ(s.normals.size(), 2u);  // flat, from the faces
    if (given) {
      expect_vec_near(s.tangents[0][0].t, {0, 1, 0});
      EXPECT_EQ(s.tangents[0][0].w, -1.f);
    } else {
      expect_vec_near(s.tangents[0][0].t, {1, 0, 0});  // u runs along +x
      EXPECT_EQ(s.tangents[0][0].w, 1.f);
    }
    // The shading normal: the stored texel (x = 2 * 191/255 - 1, scaled by 0.5) along the tangent.
    const float x = (2 * 191.f / 255.f - 1) * 0.5f, y = (2 * 128.f / 255.f - 1) * 0.5f;
    const Vec3 tan = given ? Vec3{0, 1, 0} : Vec3{1, 0, 0};
    const Vec3 bit = cross(Vec3{0, 0, 1}, tan) * (given ? -1.f : 1.f);
    expect_vec_near(shading_normal(s, 0, 0.2f, 0.3f), normalize(tan * x + bit * y + Vec3{0, 0, 1}));
  }
}

TEST(SceneObjNormals, VnSmoothShadesAndZeroVnIsRefused) {
  TempDir dir;
  const std::string obj = dir.write("smooth.obj", test::kTriangle + "vn 0 0 2\nvn 0.6 0 0.8\nf 1//1 2//2 3\n");
  const Scene s = load_scene(obj);
  ASSERT_EQ(s.normals.size(), 1u);
  expect_vec_near(s.normals[0][0], {0, 0, 1});  // normalised
  expect_vec_near(s.normals[0][1], {0.6f, 0, 0.8f});
  expect_vec_near(s.normals[0][2], {0, 0, 1});  // no vn: the face's normal
  EXPECT_TRUE(load_scene(dir.write("flat.obj", test::kTriangle + "f 1 2 3\n")).normals.empty());
  const std::string err =
      test::load_error(dir.write("zero.obj", test::kTriangle + "vn 0 0 1\nvn 0 0 0\nf 1//1 2//2 3//1\n"));
  EXPECT_NE(err.find("zero.obj:5"), std::string::npos) << err;
  EXPECT_NE(err.find("normal has zero length"), std::string::npos) << err;
}

}  // namespace
}  // namespace epr
