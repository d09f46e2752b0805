// glTF metallic-roughness materials onto the microfacet material (common/scene_loader/gltf_materials.cpp):
// metals, the metallicRoughnessTexture read as linear data, KHR_materials_transmission and _ior,
// emission textures kept per texel.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <string>

#include "common/image.h"
#include "common/scene_loader.h"
#include "tests/common/gltf_test_files.h"
#include "tests/common/scene_test_files.h"

namespace epr {
namespace {

const std::vector<float> kPbrTriangle = {0, 0, 0, 1, 0, 0, 0, 1, 0};
const std::vector<float> kPbrUv = {0.25f, 0.5f, 0.75f, 0.5f, 0.25f, 0.f};  // corners 0, 2: left texel; 1: right

TEST(GltfMaterials, MetallicMaterialLoadsAsAConductor) {
  test::TempDir dir;
  test::GltfBuilder g;
  const int metal =
      g.material({{"name", "gold"},
                  {"pbrMetallicRoughness",
                   {{"baseColorFactor", {1.0, 0.77, 0.34, 1}}, {"metallicFactor", 1}, {"roughnessFactor", 0.3}}}});
  g.node({{"mesh", g.mesh(kPbrTriangle, {}, metal)}});
  const Scene s = load_scene(g.write_gltf(dir, "scene"));
  const Material& m = s.materials[s.material_of[0]];
  EXPECT_EQ(m.type, MaterialType::kMicrofacet);
  EXPECT_FLOAT_EQ(m.metallic, 1.f);
  EXPECT_FLOAT_EQ(m.roughness, 0.3f);
  EXPECT_FLOAT_EQ(m.kd.y, 0.77f);  // F0 = base colour
  EXPECT_FALSE(m.diffuse());       // not reprojected
  EXPECT_EQ(m.metallic_roughness_texture, -1);
}

// The texture's G (roughness) and B (metallic) channels are data, not sRGB colour: a stored 127 is
// 127 / 255 (0.50), not the 0.21 that decoding it as sRGB gives. The scene keeps the image as decoded
// (no copy); re-encoding a lookup gives the stored value, which the factors multiply.
TEST(GltfMaterials, MetallicRoughnessTextureSetsRoughnessPerTexel) {
  test::TempDir dir;
  Image img(2, 1);
  const float mid = 0.214f;  // written as sRGB byte 127
  img.set_rgb(0, 0, {0, mid, 1});
  img.set_rgb(1, 0, {0, 1, 0});
  std::filesystem::create_directories(dir.path("tex"));
  write_png_srgb(dir.path("tex/mr.png"), img);
  const float stored = float(std::lround(linear_to_srgb(mid) * 255)) / 255.f;
  ASSERT_NEAR(stored, 0.5f, 0.01f);  // byte 127
  test::GltfBuilder g;
  const int mat =
      g.material({{"name", "worn"},
                  {"pbrMetallicRoughness",
                   {{"metallicFactor", 0.5}, {"roughnessFactor", 0.8}, {"metallicRoughnessTexture", {{"index", 0}}}}}});
  g.doc["images"] = {{{"uri", "tex/mr.png"}}};
  g.doc["textures"] = {{{"source", 0}}};
  g.node({{"mesh", g.mesh(kPbrTriangle, {}, mat, kPbrUv)}});
  const Scene s = load_scene(g.write_gltf(dir, "scene"));
  const Material& m = s.materials[s.material_of[0]];
  ASSERT_EQ(m.type, MaterialType::kMicrofacet);
  ASSERT_GE(m.metallic_roughness_texture, 0);
  ASSERT_EQ(s.uvs.size(), 1u);
  const Texture& t = s.textures[size_t(m.metallic_roughness_texture)];
  const Vec3 left = t.lookup(s.uvs[0][0]), right = t.lookup(s.uvs[0][1]);
  EXPECT_FLOAT_EQ(m.roughness, 0.8f);
  EXPECT_FLOAT_EQ(m.metallic, 0.5f);
  EXPECT_NEAR(linear_to_srgb(left.y), stored, 1e-5f);  // roughness
  EXPECT_NEAR(linear_to_srgb(left.z), 1.f, 1e-5f);     // metallic
  EXPECT_NEAR(linear_to_srgb(right.y), 1.f, 1e-5f);
  EXPECT_NEAR(linear_to_srgb(right.z), 0.f, 1e-5f);
  EXPECT_EQ(s.textures.size(), 1u);  // the image itself, not a copy
}

TEST(GltfMaterials, TransmissionAndIorMakeGlass) {
  test::TempDir dir;
  test::GltfBuilder g;
  const int glass = g.material(
      {{"name", "glass"},
       {"pbrMetallicRoughness", {{"metallicFactor", 0}, {"roughnessFactor", 0}}},
       {"extensions",
        {{"KHR_materials_transmission", {{"transmissionFactor", 1}}}, {"KHR_materials_ior", {{"ior", 1.45}}}}}});
  g.doc["extensionsUsed"] = {"KHR_materials_transmission", "KHR_materials_ior"};
  g.doc["extensionsRequired"] = {"KHR_materials_transmission"};
  g.node({{"mesh", g.mesh(kPbrTriangle, {}, glass)}});
  const Scene s = load_scene(g.write_gltf(dir, "scene"));
  const Material& m = s.materials[s.material_of[0]];
  EXPECT_EQ(m.type, MaterialType::kMicrofacet);
  EXPECT_FLOAT_EQ(m.transmission, 1.f);
  EXPECT_FLOAT_EQ(m.ior, 1.45f);
  EXPECT_FLOAT_EQ(m.roughness, 0.f);
}

TEST(GltfMaterials, IorBelowOneIsAnErrorNamingTheMaterial) {
  test::TempDir dir;
  test::GltfBuilder g;
  const int bad = g.material({{"name", "odd"}, {"extensions", {{"KHR_materials_ior", {{"ior", 0.5}}}}}});
  g.node({{"mesh", g.mesh(kPbrTriangle, {}, bad)}});
  const std::string e = test::load_error(g.write_gltf(dir, "scene"));
  EXPECT_NE(e.find("scene.gltf"), std::string::npos) << e;
  EXPECT_NE(e.find("materials[0]: KHR_materials_ior.ior 0.5 is below 1"), std::string::npos) << e;
}

// An emission texture stays a texture: Ke is its mean (what light selection weighs), and Ke x the
// stored variation gives emissiveFactor x texel at each texel.
TEST(GltfMaterials, EmissionTextureVariesPerTexel) {
  test::TempDir dir;
  Image img(2, 1);
  img.set_rgb(0, 0, {1, 0, 0});
  img.set_rgb(1, 0, {0, 0, 1});
  std::filesystem::create_directories(dir.path("tex"));
  write_png_srgb(dir.path("tex/glow.png"), img);
  test::GltfBuilder g;
  const int lamp = g.material({{"name", "sign"}, {"emissiveFactor", {2, 2, 2}}, {"emissiveTexture", {{"index", 0}}}});
  g.doc["images"] = {{{"uri", "tex/glow.png"}}};
  g.doc["textures"] = {{{"source", 0}}};
  g.node({{"mesh", g.mesh(kPbrTriangle, {}, lamp, kPbrUv)}});
  const Scene s = load_scene(g.write_gltf(dir, "scene"));
  const Material& m = s.materials[s.material_of[0]];
  ASSERT_GE(m.ke_texture, 0);
  EXPECT_NEAR(m.ke.x, 1.f, 1e-5f);  // 2 x mean(1, 0)
  EXPECT_NEAR(m.ke.y, 0.f, 1e-5f);
  EXPECT_NEAR(m.ke.z, 1.f, 1e-5f);
  const Texture& t = s.textures[size_t(m.ke_texture)];
  const Vec3 left = m.ke * t.lookup(s.uvs[0][0]), right = m.ke * t.lookup(s.uvs[0][1]);
  EXPECT_NEAR(left.x, 2.f, 1e-5f);
  EXPECT_NEAR(left.z, 0.f, 1e-5f);
  EXPECT_NEAR(right.x, 0.f, 1e-5f);
  EXPECT_NEAR(right.z, 2.f, 1e-5f);
}

// scenes/crytek-sponza/sponza-lambertian.json (the like-for-like scene of the Cycles comparison): the
// same model, sky and sun as sponza.json, every material Lambertian with its colour and normal maps.
TEST(GltfMaterials, TheLambertianSponzaKeepsTheMapsAndMakesEveryMaterialDiffuse) {
  const std::filesystem::path dir = std::filesystem::path(EPR_SOURCE_DIR) / "scenes" / "crytek-sponza";
  const Scene pbr = load_scene((dir / "sponza.json").string());
  const Scene lambertian = load_scene((dir / "sponza-lambertian.json").string());
  EXPECT_EQ(lambertian.triangle_count(), pbr.triangle_count());
  EXPECT_TRUE(lambertian.lighting.environment && lambertian.lighting.sun);
  ASSERT_EQ(lambertian.materials.size(), pbr.materials.size());
  size_t not_diffuse = 0;
  for (size_t i = 0; i < pbr.materials.size(); ++i) {
    const Material &a = pbr.materials[i], &b = lambertian.materials[i];
    SCOPED_TRACE(a.name);
    not_diffuse += a.diffuse() ? 0 : 1;
    EXPECT_TRUE(b.diffuse());
    EXPECT_EQ(b.kd_texture, a.kd_texture);
    EXPECT_EQ(b.normal_texture, a.normal_texture);
    EXPECT_EQ(b.kd, a.kd);
  }
  EXPECT_GT(not_diffuse, 0u);  // the PBR scene has lobes the Lambertian one drops
}

}  // namespace
}  // namespace epr
