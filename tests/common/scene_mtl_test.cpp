// MTL material libraries (common/scene_loader/mtl.cpp): which materials an OBJ's mtllib statements
// add to the scene, in which order, with which values. The material tables are those tinyobjloader
// 2.0.0rc10 builds from the same files. Malformed MTL lines are in scene_loader_test.cpp's audit.
#include <gtest/gtest.h>

#include <string>

#include "common/image.h"
#include "common/log.h"
#include "common/scene_loader.h"
#include "tests/common/scene_test_files.h"

namespace epr {
namespace {

using test::kTriangle;

/// Names of the scene's materials, in order.
std::vector<std::string> names(const Scene& s) {
  std::vector<std::string> out;
  for (const Material& m : s.materials) out.push_back(m.name);
  return out;
}

class SceneMtl : public ::testing::Test {
 protected:
  SceneMtl() {
    set_log_level("error");
    write_png_srgb(dir.path("tex.png"), Image(2, 2, 3));
  }
  ~SceneMtl() override { set_log_level("info"); }

  test::TempDir dir;
};

TEST_F(SceneMtl, ARepeatedNameIsKeptAndUsemtlTakesTheFirst) {
  dir.write("dup.mtl", "newmtl a\nKd 0.1 0.1 0.1\nnewmtl a\nKd 0.9 0.9 0.9\nnewmtl b\nKe 1 1 1\n");
  const Scene s = load_obj(dir.write("dup.obj", "mtllib dup.mtl\n" + kTriangle + "usemtl a\nf 1 2 3\n"));
  EXPECT_EQ(names(s), (std::vector<std::string>{"a", "a", "b"}));
  EXPECT_EQ(s.material_of, (std::vector<uint32_t>{0}));
  EXPECT_EQ(s.materials[0].kd, Vec3(0.1f));
  EXPECT_EQ(s.materials[1].kd, Vec3(0.9f));
  EXPECT_EQ(s.materials[2].kd, Vec3(0.f));  // Kd not given: black
  EXPECT_EQ(s.materials[2].ke, Vec3(1.f));
}

TEST_F(SceneMtl, ALibraryWithoutMaterialsAddsAnUnnamedBlackOne) {
  dir.write("empty.mtl", "# nothing here\n");
  const Scene s = load_obj(dir.write("empty.obj", "mtllib empty.mtl\n" + kTriangle + "f 1 2 3\n"));
  EXPECT_EQ(names(s), (std::vector<std::string>{"", "default"}));
  EXPECT_EQ(s.materials[0].kd, Vec3(0.f));
  EXPECT_EQ(s.material_of, (std::vector<uint32_t>{1}));  // the face has no material: the default grey
}

TEST_F(SceneMtl, MapKdSetsKdToGreyUnlessAKdCameEarlierInTheLibrary) {
  dir.write("grey.mtl",
            "newmtl t\nmap_Kd tex.png\n"                    // no Kd yet in the library: 0.6
            "newmtl u\nKd 0.2 0.2 0.2\n"                    //
            "newmtl v\nmap_Kd tex.png\n"                    // u had a Kd: v keeps black
            "newmtl w\nmap_Kd tex.png\nKd 0.5 0.5 0.5\n");  // a Kd after the map wins
  const Scene s = load_obj(dir.write("grey.obj", "mtllib grey.mtl\n" + kTriangle + "usemtl t\nf 1 2 3\n"));
  ASSERT_EQ(names(s), (std::vector<std::string>{"t", "u", "v", "w"}));
  EXPECT_EQ(s.materials[0].kd, Vec3(0.6f));
  EXPECT_EQ(s.materials[1].kd, Vec3(0.2f));
  EXPECT_EQ(s.materials[2].kd, Vec3(0.f));
  EXPECT_EQ(s.materials[3].kd, Vec3(0.5f));
  for (size_t i : {0, 2, 3}) EXPECT_EQ(s.materials[i].kd_texture, 0) << i;
  EXPECT_EQ(s.materials[1].kd_texture, -1);
}

TEST_F(SceneMtl, TheFilesOfOneMtllibAreOneLibrary) {
  dir.write("x.mtl", "newmtl x\nKd 0.3 0.3 0.3\nnewmtl y\n");
  dir.write("y.mtl", "newmtl t\nmap_Kd tex.png\n");
  const Scene s = load_obj(dir.write("two.obj", "mtllib x.mtl y.mtl\n" + kTriangle + "usemtl t\nf 1 2 3\n"));
  EXPECT_EQ(names(s), (std::vector<std::string>{"x", "y", "t"}));
  EXPECT_EQ(s.materials[2].kd, Vec3(0.f));  // x.mtl's Kd counts for y.mtl's map_Kd
  EXPECT_EQ(s.material_of, (std::vector<uint32_t>{2}));
}

TEST_F(SceneMtl, AListOfFilesIsAddedOnceAndAnotherListAddsItsFilesAgain) {
  dir.write("x.mtl", "newmtl x\nKd 0.3 0.3 0.3\n");
  dir.write("y.mtl", "newmtl t\nmap_Kd tex.png\n");
  const Scene s = load_obj(dir.write(
      "lists.obj", "mtllib y.mtl\nmtllib y.mtl\n" + kTriangle + "f 1 2 3\nmtllib x.mtl y.mtl\nusemtl t\nf 1 2 3\n"));
  EXPECT_EQ(names(s), (std::vector<std::string>{"t", "x", "t", "default"}));
  EXPECT_EQ(s.materials[0].kd, Vec3(0.6f));                 // y.mtl alone: no Kd before its map_Kd
  EXPECT_EQ(s.materials[2].kd, Vec3(0.f));                  // after x.mtl's Kd
  EXPECT_EQ(s.material_of, (std::vector<uint32_t>{3, 0}));  // usemtl t: the first t
  EXPECT_EQ(s.textures.size(), 1u);                         // one file, read once
}

TEST_F(SceneMtl, GlossyOverridesStartFromKsAndNsWithNsOneByDefault) {
  dir.write("g.mtl", "newmtl g\nKd 0.2 0.2 0.2\nKs 0.5 0.4 0.3\nnewmtl h\nKs 0.1 0.1 0.1\nNs 30\n");
  dir.write("g.obj", "mtllib g.mtl\n" + kTriangle + "usemtl g\nf 1 2 3\nusemtl h\nf 1 3 2\n");
  const Scene s = load_scene(
      dir.write("g.json", R"({"obj": "g.obj", "materials": {"g": {"type": "glossy"}, "h": {"type": "glossy"}}})"));
  ASSERT_EQ(names(s), (std::vector<std::string>{"g", "h"}));
  EXPECT_EQ(s.materials[0].ks, Vec3(0.5f, 0.4f, 0.3f));
  EXPECT_EQ(s.materials[0].exponent, 1.f);
  EXPECT_EQ(s.materials[1].exponent, 30.f);
}

TEST_F(SceneMtl, ColoursOutsideTheirRangeAreClamped) {
  dir.write("c.mtl", "newmtl c\nKd 1.5 -0.5 0.5\nKe -1 0 3\n");
  const Scene s = load_obj(dir.write("c.obj", "mtllib c.mtl\n" + kTriangle + "usemtl c\nf 1 2 3\n"));
  EXPECT_EQ(s.materials[0].kd, Vec3(1.f, 0.f, 0.5f));
  EXPECT_EQ(s.materials[0].ke, Vec3(0.f, 0.f, 3.f));
}

// Every new list of files adds its files' materials again: the bytes of all lists together are held
// to the file size limit, and the message names the mtllib line that goes over it.
TEST_F(SceneMtl, ListsOfFilesTogetherStayWithinTheFileSizeLimit) {
  dir.write("m.mtl", "newmtl m\nKd 0.5 0.5 0.5\n");  // 24 bytes
  const std::string obj =
      dir.write("lists.obj", "mtllib m.mtl\nmtllib m.mtl m.mtl\nmtllib m.mtl m.mtl m.mtl\n" + kTriangle + "f 1 2 3\n");
  LoadOptions opts;
  opts.max_file_bytes = 100;  // the OBJ has 89 bytes; the lists 24, 48 and 72
  EXPECT_NE(test::load_error(obj, opts).find("lists.obj:3: material libraries exceed 100 bytes in total"),
            std::string::npos)
      << test::load_error(obj, opts);
  opts.max_file_bytes = 150;
  EXPECT_EQ(test::load_error(obj, opts), "");
}

}  // namespace
}  // namespace epr
