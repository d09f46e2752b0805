#include "common/scene_loader.h"

#include <fmt/format.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "common/builtin_scenes.h"
#include "common/image.h"
#include "common/log.h"
#include "tests/common/scene_test_files.h"

namespace epr {
namespace {

namespace fs = std::filesystem;

const std::string kCornellObj = EPR_SOURCE_DIR "/scenes/cornell-box/CornellBox-Original.obj";
const std::string kBadDir = EPR_SOURCE_DIR "/tests/data/scenes/bad";
const std::string kShippedDir = EPR_SOURCE_DIR "/scenes";

using test::load_error;
using test::TempDir;

std::string read_text(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

const Material* find_material(const Scene& s, const std::string& name) {
  for (const Material& m : s.materials)
    if (m.name == name) return &m;
  return nullptr;
}

void expect_vec_near(const Vec3& a, const Vec3& b, float tol = 1e-6f) {
  EXPECT_NEAR(a.x, b.x, tol);
  EXPECT_NEAR(a.y, b.y, tol);
  EXPECT_NEAR(a.z, b.z, tol);
}

using test::kTriangle;

// ---------------------------------------------------------------------------------------------------

TEST(SceneLoader, SharedCornellBoxLoads) {
  const Scene s = load_obj(kCornellObj);
  EXPECT_EQ(s.triangle_count(), 36u);
  EXPECT_EQ(s.name, kCornellObj);
  ASSERT_EQ(s.materials.size(), 8u);  // every face has a material: no default grey
  const Material* light = find_material(s, "light");
  ASSERT_NE(light, nullptr);
  expect_vec_near(light->kd, Vec3(0.78f));
  expect_vec_near(light->ke, Vec3(17, 12, 4));
  expect_vec_near(find_material(s, "leftWall")->kd, Vec3(0.63f, 0.065f, 0.05f));
  expect_vec_near(find_material(s, "rightWall")->kd, Vec3(0.14f, 0.45f, 0.091f));
  expect_vec_near(find_material(s, "tallBox")->kd, Vec3(0.725f, 0.71f, 0.68f));
  size_t emissive = 0;
  for (size_t t = 0; t < s.triangle_count(); ++t) emissive += s.materials[s.material_of[t]].emissive();
  EXPECT_EQ(emissive, 2u);
  for (const Material& m : s.materials) {
    EXPECT_TRUE(m.diffuse()) << m.name << ": illum 2 and Ns must not make a material glossy";
    EXPECT_TRUE(is_black(m.ks)) << m.name;
    EXPECT_EQ(m.kd_texture, -1);
    if (m.name != "light") {
      EXPECT_TRUE(is_black(m.ke)) << m.name;
    }
  }
  EXPECT_TRUE(s.uvs.empty());
  EXPECT_TRUE(s.textures.empty());
  EXPECT_EQ(s.camera.eye, CameraSpec{}.eye);
  EXPECT_FALSE(s.camera.validate().has_value());
  // The bounding box of the published data.
  const Bounds3 b = s.bounds();
  expect_vec_near(b.lo, Vec3(-1.02f, 0.f, -1.04f));
  expect_vec_near(b.hi, Vec3(1.f, 1.99f, 0.99f));
}

// Every file in tests/data/scenes/bad/ starts with a comment "expect: PREFIX | TEXT": loading it must
// raise SceneError whose message contains PREFIX (file name and line) and TEXT.
TEST(SceneLoader, MalformedInputsNameFileAndLine) {
  set_log_level("error");
  size_t cases = 0;
  for (const auto& entry : fs::directory_iterator(kBadDir)) {
    const std::string ext = entry.path().extension().string();
    if (ext != ".obj" && ext != ".json") continue;
    const std::string text = read_text(entry.path().string());
    const std::string first = text.substr(0, text.find_first_of("\r\n"));
    const size_t at = first.find("expect: "), bar = first.find(" | ");
    ASSERT_TRUE(at != std::string::npos && bar != std::string::npos) << entry.path() << " has no expectation";
    const std::string prefix = first.substr(at + 8, bar - at - 8), detail = first.substr(bar + 3);
    SCOPED_TRACE(entry.path().filename().string());
    const std::string msg = load_error(entry.path().string());
    EXPECT_NE(msg.find(prefix), std::string::npos) << "message: " << msg << "\nexpected: " << prefix;
    EXPECT_NE(msg.find(detail), std::string::npos) << "message: " << msg << "\nexpected: " << detail;
    ++cases;
  }
  EXPECT_GE(cases, 50u);
  set_log_level("info");
}

TEST(SceneLoader, ToleratesCommonObjVariants) {
  TempDir dir;
  const std::string obj = dir.write("variants.obj",
                                    "# tabs, CRLF, inline comments, w and colours, 3-component vt\r\n"
                                    "mtllib\tvariants.mtl   # trailing comment\r\n"
                                    "o thing\r\ng part\r\ns off\r\n"
                                    "v 0 0 0 1\r\n"
                                    "v\t+1.0 0 0 1.0 0.5 0.5 0.5\r\n"
                                    "v .5 1. 0  # comment\r\n"
                                    "v 1e0 1 -0\r\n"
                                    "vt 0 0 0\r\nvt 1\r\n"
                                    "vn 0 0 1\r\n"
                                    "l 1 2\r\np 1\r\n"
                                    "usemtl red\r\n"
                                    "f 1/1/1 2/2/1 3//1\r\n"
                                    "f -3 -1 -2\r\n"
                                    "curv 0 1 1 2\r\n");
  dir.write("variants.mtl", "newmtl red # inline\n\tKd 0.5\n  Ks 0 0 0\n illum 2\nmap_Ka whatever.png\n");
  const Scene s = load_obj(obj);
  ASSERT_EQ(s.triangle_count(), 2u);
  ASSERT_EQ(s.materials.size(), 1u);
  EXPECT_EQ(s.materials[0].name, "red");
  expect_vec_near(s.materials[0].kd, Vec3(0.5f));  // one Kd value means grey
  expect_vec_near(s.positions[s.triangles[0][1]], Vec3(1, 0, 0));
  expect_vec_near(s.positions[s.triangles[0][2]], Vec3(0.5f, 1, 0));
}

TEST(SceneLoader, PolygonsAreTriangulatedAndRelativeIndicesResolve) {
  TempDir dir;
  const std::string obj = dir.write("poly.obj",
                                    "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf -4 -3 -2 -1\n"            // quad
                                    "v 0 0 1\nv 2 0 1\nv 3 1 1\nv 1 2 1\nv -1 1 1\nf 5 6 7 8 9\n");  // pentagon
  const Scene s = load_obj(obj);
  ASSERT_EQ(s.triangle_count(), 5u);
  float quad_area = 0, pentagon_area = 0;
  for (size_t t = 0; t < s.triangle_count(); ++t)
    (s.positions[s.triangles[t][0]].z == 0 ? quad_area : pentagon_area) += s.area(t);
  EXPECT_NEAR(quad_area, 1.f, 1e-6f);
  EXPECT_NEAR(pentagon_area, 5.f, 1e-5f);  // shoelace area of the pentagon
}

TEST(SceneLoader, DegenerateTrianglesAreDroppedNotFatal) {
  TempDir dir;
  const std::string obj = dir.write("degenerate.obj", kTriangle + "v 2 0 0\nf 1 2 3\nf 1 2 4\nf 3 3 1\nf 2 3 1\n");
  const Scene s = load_obj(obj);
  EXPECT_EQ(s.triangle_count(), 2u);
  for (size_t t = 0; t < s.triangle_count(); ++t) EXPECT_GT(s.area(t), 0.f);
}

// The bad-scene audit: every kind of broken input a job may carry gives a SceneError that names the
// file and the line (or, for zero-area triangles, which are dropped rather than fatal, a warning that
// does). tests/data/scenes/bad/ holds more variants of each.
TEST(SceneLoader, BadSceneAuditNamesFileAndLine) {
  set_log_level("error");
  TempDir dir;
  const std::string tri = "mtllib m.mtl\n" + kTriangle + "usemtl a\nf 1 2 3\n";  // the MTL is line 1
  dir.write("corrupt.png", std::string("\x89PNG\r\n\x1a\n\0\0\0\rIHDR\0\0\x10\0\0\0\x10\0garbage", 32));
  dir.write("empty.png", "");
  dir.write("notes.png", "just text, not an image\n");
  fs::create_directories(dir.path("scene"));
  dir.write("scene/inner.png", "");
  struct Case {
    const char* what;
    std::string obj, mtl;
    std::string expect;  // "file:line: reason", or a part of it
  };
  const std::vector<Case> cases = {
      {"truncated OBJ: vertex", "v 0 0 0\nv 1 0 0\nv 0 1", "", "case.obj:3: vertex needs 3 coordinates"},
      {"truncated OBJ: face", kTriangle + "f 1 2", "", "case.obj:4: face needs at least 3 vertices, got 2"},
      {"truncated OBJ: number", "v 0 0 0\nv 1 0 0\nv 0 1 1e", "", "case.obj:3: bad number '1e'"},
      {"truncated OBJ: corner", kTriangle + "f 1 2 3/", "", "case.obj:4: face corner '3/' ends in '/'"},
      {"malformed MTL: number", tri, "newmtl a\nKd 0.5 x 0.5\n", "m.mtl:2: bad number 'x'"},
      {"malformed MTL: order", tri, "Kd 1 1 1\nnewmtl a\n", "m.mtl:1: Kd before any newmtl"},
      {"malformed MTL: arity", tri, "newmtl a\nKe 1 2\n", "m.mtl:2: Ke needs 1 or 3 numbers"},
      {"malformed MTL: name", tri, "newmtl\n", "m.mtl:1: newmtl without a material name"},
      {"malformed MTL: emit", tri, "newmtl a\nKe 1 1 1\nemit back\n", "m.mtl:3: emit needs one word: front"},
      {"malformed MTL: NaN", tri, "newmtl a\nKd nan 0 0\n", "m.mtl:2: colour value 'nan' is not finite"},
      {"index out of range", kTriangle + "f 1 2 4\n", "", "case.obj:4: vertex index 4 is out of range"},
      {"negative index out of range", kTriangle + "f -1 -2 -4\n", "", "case.obj:4: vertex index -4 is out of range"},
      {"texcoord out of range", kTriangle + "vt 0 0\nf 1/1 2/2 3/1\n", "", "case.obj:5: texture coordinate index 2"},
      {"index 0", kTriangle + "f 0 1 2\n", "", "case.obj:4: vertex index 0"},
      {"index beyond int64", kTriangle + "f 1 2 99999999999999999999\n", "", "case.obj:4: bad vertex index"},
      {"NaN coordinate", "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n", "", "case.obj:2: coordinate 'nan' is not finite"},
      {"inf coordinate", "v 0 0 0\nv 1 0 0\nv 0 -inf 0\nf 1 2 3\n", "", "case.obj:3: coordinate '-inf' is not finite"},
      {"overflowing coordinate", "v 0 0 1e999\n", "", "case.obj:1: coordinate '1e999' is out of range"},
      {"NaN texture coordinate", kTriangle + "vt 0 nan\n", "", "case.obj:4: texture coordinate 'nan' is not finite"},
      {"all triangles degenerate", kTriangle + "v 2 0 0\nf 1 2 4\nf 3 3 1\n", "",
       "case.obj:5: all 2 triangles are degenerate (zero area)"},
      {"missing texture", tri, "newmtl a\nmap_Kd nope.png\n", "m.mtl:2: texture 'nope.png' does not exist"},
      {"corrupt texture", tri, "newmtl a\nmap_Kd corrupt.png\n", "m.mtl:2: cannot read texture 'corrupt.png'"},
      {"empty texture", tri, "newmtl a\nmap_Kd empty.png\n", "m.mtl:2: cannot read texture 'empty.png'"},
      {"text as texture", tri, "newmtl a\nmap_Kd notes.png\n", "m.mtl:2: cannot read texture 'notes.png'"},
      {"texture is a folder", tri, "newmtl a\nmap_Kd scene\n", "m.mtl:2: texture 'scene' is a directory"},
      {"mtllib escaping", "mtllib ../m.mtl\n" + kTriangle + "f 1 2 3\n", "", "case.obj:1: mtllib '../m.mtl' leaves"},
      {"mtllib absolute", "mtllib /etc/passwd\n" + kTriangle + "f 1 2 3\n", "",
       "case.obj:1: mtllib '/etc/passwd' is an absolute"},
      {"texture escaping", tri, "newmtl a\nmap_Kd ../../x.png\n",
       "m.mtl:2: texture '../../x.png' leaves the scene folder"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.what);
    dir.write("m.mtl", c.mtl);
    const std::string obj = dir.write("case.obj", c.obj);
    const std::string msg = load_error(obj);
    EXPECT_NE(msg.find(c.expect), std::string::npos) << "message: " << msg << "\nexpected: " << c.expect;
    // The file is named by the path the scene was loaded with, joined to the referring file's folder.
    EXPECT_EQ(msg.rfind(dir.path(""), 0), 0u) << msg;
  }

  // Zero-area triangles among good ones are dropped (never fatal), with a warning naming the line of
  // the first one; the scene keeps the rest.
  const std::string obj = dir.write("slivers.obj", kTriangle + "v 2 0 0\nf 1 2 3\nf 1 2 4\nf 2 3 1\nf 4 4 4\n");
  LoadReport report;
  const Scene s = load_obj(obj, {}, &report);
  EXPECT_EQ(s.triangle_count(), 2u);
  ASSERT_EQ(report.warnings.size(), 1u);
  EXPECT_NE(report.warnings[0].find("slivers.obj:6: dropped 2 degenerate (zero-area) triangles"), std::string::npos)
      << report.warnings[0];
}

// A polygon is triangulated in time quadratic in its corners (one face of 20000 took minutes), so
// faces are limited to 1024 corners: a cylinder cap of 1024 segments loads, one more is refused.
TEST(SceneLoader, FacesOfMoreThan1024CornersAreRefused) {
  TempDir dir;
  auto polygon = [](int n) {
    std::string text;
    for (int i = 0; i < n; ++i) {
      const double a = 2 * 3.14159265358979 * i / n;
      text += fmt::format("v {} {} 0\n", std::cos(a), std::sin(a));
    }
    text += "f";
    for (int i = 1; i <= n; ++i) text += fmt::format(" {}", i);
    return text + "\n";
  };
  const Scene s = load_obj(dir.write("cap.obj", polygon(1024)));
  EXPECT_EQ(s.triangle_count(), 1022u);
  float area = 0;
  for (size_t t = 0; t < s.triangle_count(); ++t) area += s.area(t);
  EXPECT_NEAR(area, 3.14159f, 1e-3f);
  EXPECT_NE(
      load_error(dir.write("big.obj", polygon(1025))).find("big.obj:1026: face has 1025 vertices, more than the 1024"),
      std::string::npos);
}

TEST(SceneLoader, FacesWithoutMaterialGetDefaultGrey) {
  set_log_level("error");
  TempDir dir;
  dir.write("m.mtl", "newmtl glow\nKd 0.1 0.2 0.3\nKe 1 2 3\n");
  const std::string obj =
      dir.write("m.obj", "mtllib m.mtl\n" + kTriangle + "f 1 2 3\nusemtl glow\nf 1 2 3\nusemtl missing\nf 1 3 2\n");
  const Scene s = load_obj(obj);
  ASSERT_EQ(s.triangle_count(), 3u);
  const Material& first = s.materials[s.material_of[0]];
  EXPECT_EQ(first.name, "default");
  expect_vec_near(first.kd, Vec3(0.8f));
  EXPECT_TRUE(first.diffuse());
  EXPECT_FALSE(first.emissive());
  EXPECT_EQ(s.materials[s.material_of[1]].name, "glow");
  expect_vec_near(s.materials[s.material_of[1]].ke, Vec3(1, 2, 3));
  EXPECT_EQ(s.materials[s.material_of[2]].name, "default");  // unknown name: default, with a warning
  set_log_level("info");
}

TEST(SceneLoader, TexturedObjReadsTextureAndUvs) {
  TempDir dir;
  // 2 x 2 texture, row 0 at the top (v = 1): red green / blue (over-bright) grey.
  Image img(2, 2, 3);
  img.set_rgb(0, 0, {1, 0, 0});
  img.set_rgb(1, 0, {0, 1, 0});
  img.set_rgb(0, 1, {0, 0, 2.5f});
  img.set_rgb(1, 1, {0.5f, 0.5f, 0.5f});
  fs::create_directories(dir.path("tex"));
  write_exr(dir.path("tex/checker.exr"), img);
  write_png_srgb(dir.path("tex/checker.png"), img);
  dir.write("textured.mtl",
            "newmtl exr\nKd 1 1 1\nmap_Kd -s 1 1 1 tex/checker.exr\n"
            "newmtl png\nmap_Kd tex\\checker.png\n"              // Windows separator
            "newmtl again\nmap_Kd ./tex/../tex/checker.exr\n");  // same file: loaded once
  const std::string obj =
      dir.write("textured.obj",
                "mtllib textured.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
                "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
                "usemtl exr\nf 1/1 2/2 3/3 4/4\nusemtl png\nf 1/1 2/2 3/3\nusemtl again\nf 1 2 3\n");
  const Scene s = load_obj(obj);
  ASSERT_EQ(s.triangle_count(), 4u);
  ASSERT_EQ(s.textures.size(), 2u);
  ASSERT_EQ(s.uvs.size(), s.triangle_count());
  const Material* exr = find_material(s, "exr");
  const Material* png = find_material(s, "png");
  ASSERT_TRUE(exr && png);
  ASSERT_GE(exr->kd_texture, 0);
  EXPECT_EQ(find_material(s, "again")->kd_texture, exr->kd_texture);
  const Texture& t = s.textures[size_t(exr->kd_texture)];
  EXPECT_EQ(t.width, 2);
  EXPECT_EQ(t.height, 2);
  EXPECT_EQ(t.path, "tex/checker.exr");
  expect_vec_near(t.lookup({0.25f, 0.75f}), {1, 0, 0});
  expect_vec_near(t.lookup({0.75f, 0.75f}), {0, 1, 0});
  expect_vec_near(t.lookup({0.25f, 0.25f}), {0, 0, 1});  // 2.5 clamped: kd is an albedo
  expect_vec_near(t.lookup({0.75f, 0.25f}), {0.5f, 0.5f, 0.5f});
  // 8-bit sRGB PNG comes back linear.
  expect_vec_near(s.textures[size_t(png->kd_texture)].lookup({0.75f, 0.25f}), {0.5f, 0.5f, 0.5f}, 0.01f);
  // Per-corner uvs of the first triangle follow the vt indices; untextured corners are (0, 0).
  for (size_t t0 = 0; t0 < 2; ++t0)
    for (int k = 0; k < 3; ++k) {
      const Vec3 p = s.positions[s.triangles[t0][size_t(k)]];
      EXPECT_FLOAT_EQ(s.uvs[t0][size_t(k)].x, p.x);
      EXPECT_FLOAT_EQ(s.uvs[t0][size_t(k)].y, p.y);
    }
}

TEST(SceneLoader, PathsMayNotLeaveTheSceneFolder) {
  TempDir dir;
  dir.write("outside.mtl", "newmtl a\nKd 1 1 1\n");
  dir.write("outside.exr", "");
  dir.write("scene/inside.mtl", "newmtl a\nKd 0.5 0.5 0.5\n");
  fs::create_symlink(dir.path("outside.mtl"), dir.path("scene/link_out.mtl"));
  fs::create_symlink(dir.path("scene/inside.mtl"), dir.path("scene/link_in.mtl"));
  fs::create_directory_symlink(dir.path(""), dir.path("scene/up"));

  auto obj_with = [&](const std::string& name, const std::string& mtllib) {
    return dir.write("scene/" + name + ".obj", "# test\nmtllib " + mtllib + "\n" + kTriangle + "usemtl a\nf 1 2 3\n");
  };
  for (const std::string& bad :
       std::vector<std::string>{"../outside.mtl", "link_out.mtl", "up/outside.mtl", dir.path("outside.mtl")}) {
    SCOPED_TRACE(bad);
    const std::string msg = load_error(obj_with("bad", bad));
    EXPECT_NE(msg.find("bad.obj:2: "), std::string::npos) << msg;
    EXPECT_TRUE(msg.find("leaves the scene folder") != std::string::npos || msg.find("absolute") != std::string::npos)
        << msg;
  }
  // A symlink that stays inside, and '..' that comes back in, are fine.
  EXPECT_EQ(load_error(obj_with("ok1", "link_in.mtl")), "");
  EXPECT_EQ(load_error(obj_with("ok2", "../scene/inside.mtl")), "");
  expect_vec_near(load_obj(dir.path("scene/ok1.obj")).materials[0].kd, Vec3(0.5f));

  // Textures: absolute and escaping map_Kd are rejected naming the MTL line.
  dir.write("scene/tex.mtl", "newmtl a\nmap_Kd " + dir.path("outside.exr") + "\n");
  const std::string msg = load_error(obj_with("tex", "tex.mtl"));
  EXPECT_NE(msg.find("tex.mtl:2: "), std::string::npos) << msg;
  EXPECT_NE(msg.find("absolute"), std::string::npos) << msg;

  // A scene JSON may not name an OBJ outside its folder, not even through a symlink.
  fs::create_directories(dir.path("scene/sub"));
  fs::create_symlink(dir.path("scene/ok1.obj"), dir.path("scene/sub/link.obj"));
  dir.write("scene/sub/a.json", "{\n  \"obj\": \"../ok1.obj\"\n}\n");
  dir.write("scene/sub/b.json", "{\n  \"obj\": \"link.obj\"\n}\n");
  EXPECT_NE(load_error(dir.path("scene/sub/a.json")).find("a.json:2: obj '../ok1.obj' leaves"), std::string::npos);
  EXPECT_NE(load_error(dir.path("scene/sub/b.json")).find("b.json:2: obj 'link.obj' leaves"), std::string::npos);
}

TEST(SceneLoader, LimitsAreEnforced) {
  TempDir dir;
  std::string text = kTriangle;
  for (int i = 0; i < 10; ++i) text += "f 1 2 3\n";
  const std::string obj = dir.write("many.obj", text);
  LoadOptions opts;
  opts.max_triangles = 5;
  EXPECT_NE(load_error(obj, opts).find("many.obj:9: more than 5 triangles"), std::string::npos);
  opts = {};
  opts.max_file_bytes = 16;
  EXPECT_NE(load_error(obj, opts).find("many.obj: has 104 bytes, over the limit of 16"), std::string::npos);
  opts = {};
  opts.max_triangles = 1000;
  EXPECT_NE(load_error("builtin:hall?tess=2", opts).find("exceed the limit of 1000"), std::string::npos);

  Image big(64, 64, 3);
  write_exr(dir.path("big.exr"), big);
  dir.write("big.mtl", "newmtl a\nmap_Kd big.exr\n");
  const std::string tex_obj = dir.write("big.obj", "mtllib big.mtl\n" + kTriangle + "f 1 2 3\n");
  opts = {};
  opts.max_texture_pixels = 1000;
  EXPECT_NE(load_error(tex_obj, opts).find("big.mtl:2: texture 'big.exr' has 64 x 64 pixels"), std::string::npos);
  EXPECT_EQ(load_error(tex_obj), "");

  EXPECT_NE(load_error(dir.path("nope.obj")).find("nope.obj: does not exist"), std::string::npos);
  EXPECT_NE(load_error(dir.path("")).find(": is a directory"), std::string::npos);
}

TEST(SceneLoader, MtlEmitFrontMakesAOneSidedEmitter) {
  TempDir dir;
  dir.write("m.mtl", "newmtl one\nKe 1 1 1\nemit front\nnewmtl two\nKe 1 1 1\nemit both\nnewmtl plain\nKe 1 1 1\n");
  const Scene s = load_scene(dir.write("e.obj", "mtllib m.mtl\n" + kTriangle +
                                                    "usemtl one\nf 1 2 3\nusemtl two\nf 1 3 2\n"
                                                    "usemtl plain\nf 2 1 3\n"));
  ASSERT_EQ(s.materials.size(), 3u);
  EXPECT_TRUE(find_material(s, "one")->emits_front_only);
  EXPECT_FALSE(find_material(s, "two")->emits_front_only);
  EXPECT_FALSE(find_material(s, "plain")->emits_front_only);
}

TEST(SceneLoader, JsonWithBuiltinAppliesCameraAndMaterials) {
  TempDir dir;
  const std::string json = dir.write("glossy.json", R"({
    // comments are allowed
    "builtin": "cornell",
    "tessellation": 2,
    "camera": {"eye": [0, 1, 3.5], "fov": 45},
    "materials": {
      "backWall": {"type": "glossy", "ks": [0.5, 0.5, 0.5], "exponent": 80, "kd": [0.3, 0.3, 0.3]},
      "light": {"ke": [10, 10, 10], "emit": "both"}
    }
  })");
  const Scene s = load_scene(json);
  EXPECT_EQ(s.name, json);
  EXPECT_EQ(s.triangle_count(), 36u * 4);
  EXPECT_EQ(s.camera.eye, Vec3(0, 1, 3.5f));
  EXPECT_EQ(s.camera.look, CameraSpec{}.look);  // fields not given keep the scene's camera
  EXPECT_EQ(s.camera.fov_y_degrees, 45.f);
  const Material* wall = find_material(s, "backWall");
  EXPECT_EQ(wall->type, MaterialType::kGlossy);
  expect_vec_near(wall->ks, Vec3(0.5f));
  expect_vec_near(wall->kd, Vec3(0.3f));
  EXPECT_EQ(wall->exponent, 80.f);
  expect_vec_near(find_material(s, "light")->ke, Vec3(10.f));
  EXPECT_FALSE(find_material(s, "light")->emits_front_only);  // the built-in's one-sided light made two-sided
  EXPECT_TRUE(load_scene("builtin:cornell").materials.back().emits_front_only);
  EXPECT_TRUE(find_material(s, "floor")->diffuse());
  const std::string bad =
      dir.write("bad.json", "{\"builtin\": \"cornell\",\n \"materials\": {\"light\": {\"emit\": \"up\"}}}");
  EXPECT_NE(load_error(bad).find("bad.json:2: emit must be \"front\""), std::string::npos) << load_error(bad);

  const std::string furnace = dir.write("furnace.json", R"({"builtin": "furnace?albedo=0.8&emission=2"})");
  const Scene f = load_scene(furnace);
  expect_vec_near(f.materials.at(0).kd, Vec3(0.8f));
  expect_vec_near(f.materials.at(0).ke, Vec3(2.f));
}

TEST(SceneLoader, JsonWithObjTakesGlossyDefaultsFromMtl) {
  TempDir dir;
  dir.write("models/box.mtl",
            "newmtl shiny\nKd 0.2 0.2 0.2\nKs 0.6 0.5 0.4\nNs 250\nnewmtl matte\nKd 0.5 0.5 0.5\nKs 1 1 1\n");
  dir.write("models/box.obj", "mtllib box.mtl\n" + kTriangle + "usemtl shiny\nf 1 2 3\nusemtl matte\nf 1 3 2\n");
  const std::string json =
      dir.write("box.json", R"({"obj": "models/box.obj", "materials": {"shiny": {"type": "glossy"}}})");
  const Scene s = load_scene(json);
  const Material* shiny = find_material(s, "shiny");
  EXPECT_EQ(shiny->type, MaterialType::kGlossy);
  expect_vec_near(shiny->ks, Vec3(0.6f, 0.5f, 0.4f));
  EXPECT_EQ(shiny->exponent, 250.f);
  const Material* matte = find_material(s, "matte");
  EXPECT_TRUE(matte->diffuse());  // Ks alone does not make a material glossy
  EXPECT_TRUE(is_black(matte->ks));
  EXPECT_EQ(s.camera.eye, CameraSpec{}.eye);

  // Errors inside the OBJ name the OBJ (as reached from the JSON), not the JSON.
  dir.write("models/broken.obj", kTriangle + "f 1 2 4\n");
  const std::string broken = dir.write("broken.json", "{\"obj\": \"models/broken.obj\"}");
  const std::string msg = load_error(broken);
  EXPECT_NE(msg.find("models/broken.obj:4: vertex index 4 is out of range"), std::string::npos) << msg;
}

/// The scene as OBJ + MTL text (triangles, Kd, Ke).
void write_obj(const Scene& s, const TempDir& dir, const std::string& name) {
  std::string obj = "mtllib " + name + ".mtl\n", mtl;
  for (const Vec3& p : s.positions) obj += fmt::format("v {} {} {}\n", p.x, p.y, p.z);
  for (size_t t = 0; t < s.triangle_count(); ++t) {
    if (t == 0 || s.material_of[t] != s.material_of[t - 1])
      obj += "usemtl " + s.materials[s.material_of[t]].name + "\n";
    obj += fmt::format("f {} {} {}\n", s.triangles[t][0] + 1, s.triangles[t][1] + 1, s.triangles[t][2] + 1);
  }
  for (const Material& m : s.materials)
    mtl += fmt::format("newmtl {}\nKd {} {} {}\nKe {} {} {}\n", m.name, m.kd.x, m.kd.y, m.kd.z, m.ke.x, m.ke.y, m.ke.z);
  dir.write(name + ".obj", obj);
  dir.write(name + ".mtl", mtl);
}

TEST(SceneLoader, GeneratedSceneRoundTripsThroughObj) {
  TempDir dir;
  const Scene hall = make_builtin_scene("hall", 3);
  write_obj(hall, dir, "hall");
  const Scene loaded = load_obj(dir.path("hall.obj"));
  ASSERT_EQ(loaded.triangle_count(), hall.triangle_count());
  ASSERT_EQ(loaded.materials.size(), hall.materials.size());
  for (size_t t = 0; t < hall.triangle_count(); ++t) {
    for (int k = 0; k < 3; ++k)
      ASSERT_EQ(loaded.positions[loaded.triangles[t][size_t(k)]], hall.positions[hall.triangles[t][size_t(k)]]);
    const Material &a = loaded.materials[loaded.material_of[t]], &b = hall.materials[hall.material_of[t]];
    ASSERT_EQ(a.name, b.name);
    ASSERT_EQ(a.kd, b.kd);
    ASSERT_EQ(a.ke, b.ke);
  }
}

TEST(SceneLoader, LoadSceneDispatchesOnSpec) {
  EXPECT_EQ(load_scene("builtin:cornell").name, "builtin:cornell");
  EXPECT_EQ(load_scene("builtin:hall?tess=2").triangle_count(), 4 * load_scene("builtin:hall").triangle_count());
  EXPECT_EQ(load_scene(kCornellObj).triangle_count(), 36u);
  EXPECT_NE(load_error("builtin:nope").find("unknown built-in scene 'nope'"), std::string::npos);
  TempDir dir;
  const std::string upper = dir.write("UPPER.JSON", R"({"builtin": "furnace"})");
  EXPECT_EQ(load_scene(upper).triangle_count(), 12u);
}

TEST(SceneLoader, DeeplyNestedJsonIsRejectedCheaply) {
  TempDir dir;
  const size_t depth = 200'000;
  const std::string arrays = dir.write("deep.json", std::string(depth, '[') + std::string(depth, ']'));
  EXPECT_NE(load_error(arrays).find("deep.json:1: a scene file must be a JSON object"), std::string::npos);
  std::string objects = "{\"materials\": ";
  for (size_t i = 0; i < depth; ++i) objects += "{\"a\": ";
  objects += "1" + std::string(depth + 1, '}');
  const std::string nested = dir.write("nested.json", "{\"builtin\": \"cornell\",\n" + objects.substr(1));
  EXPECT_NE(load_error(nested).find("nested.json:2: no material named 'a'"), std::string::npos) << load_error(nested);
}

TEST(SceneLoader, ShippedScenesLoad) {
  size_t count = 0;
  for (const auto& entry : fs::directory_iterator(kShippedDir)) {
    if (entry.path().extension() != ".json") continue;
    SCOPED_TRACE(entry.path().string());
    const Scene s = load_scene(entry.path().string());
    EXPECT_GT(s.triangle_count(), 0u);
    EXPECT_FALSE(s.camera.validate().has_value());
    ++count;
  }
  EXPECT_GE(count, 2u);
}

// Cheap stand-in for the fuzzer: mutated OBJ, MTL and JSON inputs either load or raise SceneError.
TEST(SceneLoader, MutatedInputsLoadOrRaiseSceneError) {
  set_log_level("off");
  TempDir dir;
  const std::string obj = read_text(kCornellObj);
  const std::string mtl = read_text(EPR_SOURCE_DIR "/scenes/cornell-box/CornellBox-Original.mtl");
  const std::string json =
      R"({"builtin": "cornell", "camera": {"eye": [0, 1, 3.9], "fov": 40}, "materials": {"tallBox": {"type": "glossy", "ks": [0.5, 0.5, 0.5]}}})";
  const std::string alphabet = std::string("0123456789.-+/ \t\n\r#eEnaifvtf\0\\[]{}\":,", 39);
  const std::vector<std::string> tokens = {"1e999", "nan",         "-0",         "//",      "/",
                                           "0",     "-99",         "2147483648", "\n",      "f ",
                                           "v ",    "mtllib ../x", "map_Kd ",    "newmtl ", "usemtl "};
  std::mt19937 rng(12345);
  auto mutate = [&](std::string s) {
    const int edits = 1 + int(rng() % 4);
    for (int e = 0; e < edits && !s.empty(); ++e) {
      const size_t pos = rng() % s.size();
      switch (rng() % 5) {
        case 0:
          s[pos] = alphabet[rng() % alphabet.size()];
          break;
        case 1:
          s.erase(pos, 1 + rng() % 16);
          break;
        case 2:
          s.insert(pos, tokens[rng() % tokens.size()]);
          break;
        case 3:
          s.resize(pos);
          break;
        default:
          s.insert(pos, s.substr(rng() % s.size(), rng() % 64));
          break;
      }
    }
    return s;
  };
  size_t loaded = 0, rejected = 0;
  for (int i = 0; i < 400; ++i) {
    const int kind = i % 4;
    dir.write("CornellBox-Original.mtl", kind == 1 ? mutate(mtl) : mtl);
    const std::string o = dir.write("CornellBox-Original.obj", kind == 1 ? obj : mutate(obj));
    const std::string j = dir.write("scene.json", kind == 3 ? mutate(json) : json);
    const std::string msg = load_error(kind == 3 ? j : o);
    (msg.empty() ? loaded : rejected)++;
    if (!msg.empty()) {
      EXPECT_NE(msg.find(':'), std::string::npos) << msg;
    }
  }
  EXPECT_GT(loaded, 0u);
  EXPECT_GT(rejected, 0u);
  set_log_level("info");
}

}  // namespace
}  // namespace epr
