// Cut-out materials as the loaders read them: MTL map_d and glTF alphaMode MASK (BLEND as MASK),
// the alpha read as stored, the cut-off test at barycentrics, and malformed input named by file and
// line or element.
#include <OpenImageIO/imageio.h>
#include <gtest/gtest.h>

#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "common/image.h"
#include "common/log.h"
#include "common/scene_loader.h"
#include "tests/common/gltf_test_files.h"
#include "tests/common/scene_test_files.h"

namespace epr {
namespace {

using test::GltfBuilder;
using test::TempDir;

/// An 8-bit RGBA PNG, alpha not associated (as painting programs write them).
void write_rgba_png(const std::string& path, int w, int h, const std::vector<float>& rgba) {
  auto out = OIIO::ImageOutput::create(path);
  ASSERT_TRUE(out);
  OIIO::ImageSpec spec(w, h, 4, OIIO::TypeDesc::UINT8);
  spec.alpha_channel = 3;
  spec.attribute("oiio:UnassociatedAlpha", 1);
  ASSERT_TRUE(out->open(path, spec));
  ASSERT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, rgba.data()));
  out->close();
}

// A 2 x 1 RGBA texture: left texel red and opaque, right texel green with alpha 0.2.
const std::vector<float> kLeaf = {1, 0, 0, 1, 0, 1, 0, 0.2f};
// uv coordinates of a triangle over the left texel and of one over the right texel.
const std::string kTwoTriangles =
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0.1 0.5\nvt 0.2 0.5\nvt 0.1 0.6\nvt 0.8 0.5\nvt 0.9 0.5\nvt 0.8 0.6\n"
    "usemtl leaf\nf 1/1 2/2 3/3\nf 1/4 2/5 3/6\n";

class SceneCutout : public ::testing::Test {
 protected:
  SceneCutout() { set_log_level("error"); }
  ~SceneCutout() override { set_log_level("info"); }
  TempDir dir;
};

TEST_F(SceneCutout, MapDReadsTheAlphaOfTheMapKdFileAsStored) {
  write_rgba_png(dir.path("leaf.png"), 2, 1, kLeaf);
  dir.write("leaf.mtl", "newmtl leaf\nKd 1 1 1\nmap_Kd leaf.png\nmap_d -clamp on leaf.png\n");
  const Scene s = load_obj(dir.write("leaf.obj", "mtllib leaf.mtl\n" + kTwoTriangles));
  ASSERT_EQ(s.textures.size(), 1u);  // one file, one texture with colour and alpha
  const Material& m = s.materials[s.material_of[0]];
  EXPECT_TRUE(m.cut_out());
  EXPECT_EQ(m.alpha_texture, m.kd_texture);
  EXPECT_EQ(m.alpha_cutoff, 0.5f);
  const Texture& t = s.textures[0];
  ASSERT_EQ(t.alpha.size(), 2u);
  EXPECT_EQ(t.alpha[0], 1.f);
  EXPECT_NEAR(t.alpha[1], 0.2f, 0.5f / 255);  // not linearised as sRGB colour is (that gives 0.033)
  EXPECT_EQ(t.lookup({0.25f, 0.5f}), Vec3(1, 0, 0));
  EXPECT_EQ(t.lookup({0.75f, 0.5f}), Vec3(0, 1, 0));  // colour as stored, not multiplied by alpha
  EXPECT_TRUE(s.has_cut_outs());
  EXPECT_FALSE(s.cut_out_at(0, 0.3f, 0.3f));  // over the opaque texel
  EXPECT_TRUE(s.cut_out_at(1, 0.3f, 0.3f));   // over the transparent one
  EXPECT_NO_THROW(s.validate());
}

TEST_F(SceneCutout, MapDOfAGreyImageUsesItsValueAndKeepsNoColour) {
  Image grey(2, 1, 1);
  grey.data = {1.f, 0.f};
  write_png_srgb(dir.path("mask.png"), grey);
  dir.write("m.mtl", "newmtl leaf\nKd 0.5 0.5 0.5\nmap_d mask.png\n");
  const Scene s = load_obj(dir.write("m.obj", "mtllib m.mtl\n" + kTwoTriangles));
  const Material& m = s.materials[s.material_of[0]];
  ASSERT_EQ(m.alpha_texture, 0);
  EXPECT_EQ(m.kd_texture, -1);
  EXPECT_TRUE(s.textures[0].rgb.empty()) << "a mask alone keeps no colour";
  EXPECT_EQ(s.textures[0].alpha, (std::vector<float>{1.f, 0.f}));
  EXPECT_FALSE(s.cut_out_at(0, 0.2f, 0.2f));
  EXPECT_TRUE(s.cut_out_at(1, 0.2f, 0.2f));
  ASSERT_EQ(s.uvs.size(), 2u) << "a cut-out needs the faces' texture coordinates";
}

TEST_F(SceneCutout, MalformedMapDNamesTheFileTheLineAndTheMaterial) {
  const std::string obj = "mtllib bad.mtl\n" + kTwoTriangles;
  const std::string mtl = dir.write("bad.mtl", "map_d mask.png\n");
  dir.write("bad.obj", obj);
  EXPECT_EQ(test::load_error(dir.path("bad.obj")), mtl + ":1: map_d before any newmtl");
  dir.write("bad.mtl", "newmtl leaf\nmap_d -clamp on\n");
  EXPECT_EQ(test::load_error(dir.path("bad.obj")), mtl + ":2: map_d of material 'leaf' without a texture file name");
  dir.write("bad.mtl", "newmtl leaf\n\nmap_d missing.png\n");
  const std::string e = test::load_error(dir.path("bad.obj"));
  EXPECT_EQ(e.rfind(mtl + ":3: ", 0), 0u) << e;
  EXPECT_NE(e.find("missing.png"), std::string::npos) << e;
  dir.write("junk.png", "not an image");
  dir.write("bad.mtl", "newmtl leaf\nmap_d junk.png\n");
  const std::string j = test::load_error(dir.path("bad.obj"));
  EXPECT_EQ(j.rfind(mtl + ":2: cannot read texture 'junk.png'", 0), 0u) << j;
}

TEST_F(SceneCutout, AnEmitterIsNotCutOutAndTheWarningNamesIt) {
  write_rgba_png(dir.path("leaf.png"), 2, 1, kLeaf);
  dir.write("e.mtl", "newmtl lamp\nKe 5 5 5\nmap_d leaf.png\n");
  LoadReport report;
  const std::string obj =
      dir.write("e.obj", "mtllib e.mtl\n" + std::string(kTwoTriangles).replace(kTwoTriangles.find("leaf"), 4, "lamp"));
  const Scene s = load_obj(obj, {}, &report);
  EXPECT_FALSE(s.has_cut_outs());
  ASSERT_EQ(report.warnings.size(), 1u);
  EXPECT_EQ(report.warnings[0], obj + ": material 'lamp': map_d ignored: an emitter is not cut out");
}

const std::vector<float> kTriangle = {0, 0, 0, 1, 0, 0, 0, 1, 0};
const std::vector<float> kLeftUv = {0.1f, 0.5f, 0.2f, 0.5f, 0.1f, 0.4f};   // over the left texel
const std::vector<float> kRightUv = {0.8f, 0.5f, 0.9f, 0.5f, 0.8f, 0.4f};  // over the right texel

TEST_F(SceneCutout, GltfMaskTimesTheBaseColourAlphaAgainstTheCutoff) {
  write_rgba_png(dir.path("leaf.png"), 2, 1, kLeaf);
  GltfBuilder g;
  g.doc["images"] = {{{"uri", "leaf.png"}}};
  g.doc["textures"] = {{{"source", 0}}};
  const nlohmann::json pbr = {{"baseColorTexture", {{"index", 0}}}, {"metallicFactor", 0}};
  // Default cut-off 0.5: alpha 1 stays, 0.2 goes.
  const int plain = g.material({{"name", "plain"}, {"alphaMode", "MASK"}, {"pbrMetallicRoughness", pbr}});
  // alpha = 0.5 x texture alpha against 0.15: 0.5 stays, 0.1 goes.
  nlohmann::json faded = pbr;
  faded["baseColorFactor"] = {1, 1, 1, 0.5};
  const int low =
      g.material({{"name", "faded"}, {"alphaMode", "MASK"}, {"alphaCutoff", 0.15}, {"pbrMetallicRoughness", faded}});
  // Cut-off 0.1: 0.2 stays as well.
  const int keep =
      g.material({{"name", "keep"}, {"alphaMode", "MASK"}, {"alphaCutoff", 0.1}, {"pbrMetallicRoughness", pbr}});
  for (int m : {plain, low, keep}) {
    g.node({{"mesh", g.mesh(kTriangle, {}, m, kLeftUv)}});
    g.node({{"mesh", g.mesh(kTriangle, {}, m, kRightUv)}});
  }
  LoadReport report;
  const Scene s = load_scene(g.write_gltf(dir, "mask"), {}, &report);
  ASSERT_EQ(s.triangle_count(), 6u);
  EXPECT_TRUE(report.warnings.empty()) << report.warnings[0];
  const std::vector<bool> expected = {false, true, false, true, false, false};
  for (size_t t = 0; t < 6; ++t) EXPECT_EQ(s.cut_out_at(t, 0.2f, 0.2f), expected[t]) << "triangle " << t;
  EXPECT_FLOAT_EQ(s.materials[s.material_of[2]].alpha_cutoff, 0.3f);
  EXPECT_NO_THROW(s.validate());
}

TEST_F(SceneCutout, GltfEmbeddedImageAndBlendAndConstantAlpha) {
  // An RGBA PNG inside a .glb, used by a BLEND material (a MASK at 0.5, with a warning); a MASK
  // material without texture whose constant alpha is below its cut-off (its triangles are dropped).
  const std::string png_path = dir.path("embedded.png");
  write_rgba_png(png_path, 2, 1, kLeaf);
  const std::string png = [&] {
    std::ifstream in(png_path, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), {});
  }();
  GltfBuilder g;
  const int v = g.view(png);
  g.doc["images"] = {{{"bufferView", v}, {"mimeType", "image/png"}}};
  g.doc["textures"] = {{{"source", 0}}};
  const int glass =
      g.material({{"name", "glass"},
                  {"alphaMode", "BLEND"},
                  {"pbrMetallicRoughness", {{"baseColorTexture", {{"index", 0}}}, {"metallicFactor", 0}}}});
  const int ghost =
      g.material({{"name", "ghost"},
                  {"alphaMode", "MASK"},
                  {"pbrMetallicRoughness", {{"baseColorFactor", {1, 1, 1, 0.2}}, {"metallicFactor", 0}}}});
  g.node({{"mesh", g.mesh(kTriangle, {}, glass, kLeftUv)}});
  g.node({{"mesh", g.mesh(kTriangle, {}, glass, kRightUv)}});
  g.node({{"mesh", g.mesh(kTriangle, {}, ghost)}});
  LoadReport report;
  const std::string path = g.write_glb(dir, "blend");
  const Scene s = load_scene(path, {}, &report);
  ASSERT_EQ(s.triangle_count(), 2u) << "the ghost's triangle is dropped";
  EXPECT_FALSE(s.cut_out_at(0, 0.2f, 0.2f));
  EXPECT_TRUE(s.cut_out_at(1, 0.2f, 0.2f));
  ASSERT_EQ(report.warnings.size(), 2u);
  EXPECT_EQ(report.warnings[0], path +
                                    ": material 'glass' (materials[0]): alphaMode BLEND rendered as MASK with "
                                    "alphaCutoff 0.5 (no partial transparency)");
  EXPECT_EQ(report.warnings[1], path +
                                    ": material 'ghost' (materials[1]): baseColorFactor alpha 0.2 is below "
                                    "alphaCutoff 0.5: the surface is not rendered");
}

TEST_F(SceneCutout, MalformedGltfAlphaNamesTheFileAndTheMaterial) {
  GltfBuilder g;
  const int m = g.material({{"alphaMode", "CUTOUT"}, {"pbrMetallicRoughness", {{"metallicFactor", 0}}}});
  g.node({{"mesh", g.mesh(kTriangle, {}, m)}});
  const std::string path = g.write_gltf(dir, "bad");
  EXPECT_EQ(test::load_error(path), path + ": materials[0]: alphaMode 'CUTOUT' is not OPAQUE, MASK or BLEND");
  g.doc["materials"][0]["alphaMode"] = "MASK";
  g.doc["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"] = {{"index", 3}};
  EXPECT_EQ(test::load_error(g.write_gltf(dir, "bad")),
            path + ": materials[0].pbrMetallicRoughness.baseColorTexture: texture 3 does not exist (0 textures)");
}

}  // namespace
}  // namespace epr
