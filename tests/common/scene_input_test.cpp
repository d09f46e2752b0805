// Scene input that is not what it claims to be (issue 16): every scene file must be a regular file,
// its size checked before it is read, its path free of NUL bytes; warnings are collected naming the
// user's files; a scene without light is refused with a reason that says how to light it.
#include <fmt/format.h>
#include <fmt/ranges.h>
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "common/builtin_scenes.h"
#include "common/image.h"
#include "common/scene_loader.h"
#include "tests/common/scene_test_files.h"

namespace epr {
namespace {

namespace fs = std::filesystem;
using test::load_error;
using test::TempDir;

using test::kTriangle;
// A lit triangle: its material emits.
const std::string kLitMtl = "newmtl glow\nKd 0.5 0.5 0.5\nKe 4 4 4\n";
const std::string kLitObj = "mtllib lit.mtl\n" + kTriangle + "usemtl glow\nf 1 2 3\n";

void make_fifo(const std::string& path) { ASSERT_EQ(::mkfifo(path.c_str(), 0600), 0) << path; }

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

// A FIFO named as any of a scene's files is refused naming it; the load never waits for a writer.
TEST(SceneInput, FifosAreRefusedWithoutBlocking) {
  TempDir dir;
  dir.write("lit.mtl", kLitMtl);
  make_fifo(dir.path("pipe.obj"));
  make_fifo(dir.path("pipe.json"));
  make_fifo(dir.path("pipe.mtl"));
  make_fifo(dir.path("pipe.png"));
  EXPECT_TRUE(contains(load_error(dir.path("pipe.obj")), "pipe.obj: is a FIFO (named pipe), not a regular file"))
      << load_error(dir.path("pipe.obj"));
  EXPECT_TRUE(contains(load_error(dir.path("pipe.json")), "pipe.json: is a FIFO"));

  const std::string mtl_msg = load_error(dir.write("m.obj", "mtllib pipe.mtl\n" + kTriangle + "f 1 2 3\n"));
  EXPECT_TRUE(contains(mtl_msg, "m.obj:1: mtllib 'pipe.mtl' is a FIFO")) << mtl_msg;

  dir.write("tex.mtl", "newmtl t\nmap_Kd pipe.png\n");
  const std::string tex_msg = load_error(dir.write("t.obj", "mtllib tex.mtl\n" + kTriangle + "usemtl t\nf 1 2 3\n"));
  EXPECT_TRUE(contains(tex_msg, "tex.mtl:2: texture 'pipe.png' is a FIFO")) << tex_msg;

  const std::string json_msg = load_error(dir.write("s.json", "{\n  \"obj\": \"pipe.obj\"\n}\n"));
  EXPECT_TRUE(contains(json_msg, "s.json:2: obj file 'pipe.obj' is a FIFO")) << json_msg;
}

// Devices are refused by type, before they are opened (reading /dev/zero would never end).
TEST(SceneInput, DevicesAreRefusedBeforeTheyAreRead) {
  EXPECT_EQ(load_error("/dev/zero"), "/dev/zero: is a character device, not a regular file");
  EXPECT_EQ(load_error("/dev/null"), "/dev/null: is a character device, not a regular file");
}

// A folder named like a scene file is "a directory", not an OBJ without faces.
TEST(SceneInput, DirectoriesAreRefusedAsDirectories) {
  TempDir dir;
  fs::create_directories(dir.path("x.obj"));
  fs::create_directories(dir.path("d.mtl"));
  fs::create_directories(dir.path("y.json"));
  EXPECT_EQ(load_error(dir.path("x.obj")), dir.path("x.obj") + ": is a directory");
  EXPECT_EQ(load_error(dir.path("y.json")), dir.path("y.json") + ": is a directory");
  const std::string msg = load_error(dir.write("m.obj", "mtllib d.mtl\n" + kTriangle + "f 1 2 3\n"));
  EXPECT_TRUE(contains(msg, "m.obj:1: mtllib 'd.mtl' is a directory")) << msg;
}

// The size is checked before anything is read: a sparse file of 2 GiB is refused at once.
TEST(SceneInput, SizeIsCheckedBeforeReading) {
  TempDir dir;
  const std::string big = dir.path("big.obj");
  std::ofstream(big).put('v');
  fs::resize_file(big, (size_t(1) << 31));
  const std::string msg = load_error(big);
  EXPECT_EQ(msg, big + ": has 2147483648 bytes, over the limit of 1073741824");
}

TEST(SceneInput, PathsWithANulByteAreRefused) {
  TempDir dir;
  dir.write("lit.mtl", kLitMtl);
  const std::string obj = dir.write("a.obj", kLitObj);
  EXPECT_EQ(load_error(obj), "");
  const std::string msg = load_error(obj + std::string("\0.png", 5));
  EXPECT_TRUE(contains(msg, "contains a NUL byte")) << msg;
  EXPECT_TRUE(contains(load_error(std::string("builtin:cornell\0x", 17)), "contains a NUL byte"));
  // The JSON's "obj" (JSON strings may hold U+0000).
  const std::string json = dir.write("n.json", "{\n  \"obj\": \"a.obj\\u0000.png\"\n}\n");
  EXPECT_TRUE(contains(load_error(json), "n.json:2: obj path contains a NUL byte")) << load_error(json);
}

// Warnings go to the report (not to the log above debug level), naming the files as the user named
// them, each once.
TEST(SceneInput, WarningsAreReportedOnceNamingTheUsersFiles) {
  TempDir dir;
  dir.write("sub/lit.mtl", kLitMtl + "newmtl glow\nKd 0.1 0.1 0.1\n");
  const std::string obj = dir.write("sub/w.obj", kLitObj + "curv 0 1 2\n");
  LoadReport report;
  load_job_scene(obj, {}, &report);
  ASSERT_EQ(report.warnings.size(), 2u) << fmt::format("{}", fmt::join(report.warnings, "\n"));
  EXPECT_EQ(report.warnings[0],
            dir.path("sub/lit.mtl") + ":4: material 'glow' is defined again; the first definition is used");
  EXPECT_EQ(report.warnings[1], obj + ":7: unsupported statement 'curv' ignored");
  ASSERT_EQ(report.files.size(), 2u);
  EXPECT_EQ(report.files[0].display, obj);
  EXPECT_EQ(report.files[1].display, dir.path("sub/lit.mtl"));
}

// An OBJ whose materials do not emit would render black: refused, saying how to light it.
TEST(SceneInput, SceneWithoutLightIsRefusedSayingHowToLightIt) {
  TempDir dir;
  dir.write("dark.mtl", "newmtl grey\nKd 0.5 0.5 0.5\nnewmtl off\nKd 0.5 0.5 0.5\nKe 0 0 0\n");
  const std::string dark = dir.write("dark.obj", "mtllib dark.mtl\n" + kTriangle + "usemtl grey\nf 1 2 3\n");
  EXPECT_NO_THROW(load_scene(dark));  // loading is fine; rendering it is not
  const std::string reason = unlit_reason(load_scene(dark)).value_or("");
  EXPECT_EQ(reason.rfind(dark + " has no light: no material has an emission (Ke)", 0), 0u) << reason;
  EXPECT_TRUE(contains(reason, "Ke 10 10 10")) << reason;
  try {
    load_job_scene(dark);
    ADD_FAILURE() << "an unlit scene was accepted";
  } catch (const SceneError& e) {
    EXPECT_EQ(std::string(e.what()), reason);
  }
  // Ke 0 0 0 is no emission.
  const std::string off = dir.write("off.obj", "mtllib dark.mtl\n" + kTriangle + "usemtl off\nf 1 2 3\n");
  EXPECT_TRUE(contains(unlit_reason(load_scene(off)).value_or(""), "no material has an emission"));
  // An emitter no face uses lights nothing either.
  dir.write("lit.mtl", kLitMtl + "newmtl grey\nKd 0.5 0.5 0.5\n");
  const std::string unused = dir.write("unused.obj", "mtllib lit.mtl\n" + kTriangle + "usemtl grey\nf 1 2 3\n");
  EXPECT_TRUE(contains(unlit_reason(load_scene(unused)).value_or(""), "no face uses the emitting material 'glow'"));
  EXPECT_EQ(unlit_reason(load_scene(dir.write("lit.obj", kLitObj))), std::nullopt);

  // A scene JSON may light a dark OBJ, or switch off a built-in's light.
  const std::string lit_json =
      dir.write("lit.json", R"({"obj": "dark.obj", "materials": {"grey": {"ke": [5, 5, 5]}}})");
  EXPECT_EQ(unlit_reason(load_job_scene(lit_json)), std::nullopt);
  const std::string off_json =
      dir.write("off.json", R"({"builtin": "cornell", "materials": {"light": {"ke": [0, 0, 0]}}})");
  EXPECT_EQ(load_error(off_json), "");  // it loads; a job of it is refused
  EXPECT_EQ(unlit_reason(load_scene(off_json)).value_or("").rfind(off_json + " has no light", 0), 0u);
}

// Every built-in scene and every scene file shipped under scenes/ has a light. An OBJ lit only from
// outside, by the sky and sun of a scene JSON beside it, is checked through that JSON.
TEST(SceneInput, BuiltinAndShippedScenesAreLit) {
  std::vector<std::string> specs;
  for (const std::string& name : builtin_scene_names()) specs.push_back("builtin:" + name);
  for (const std::string& name : study_scene_names()) specs.push_back("builtin:" + name);
  specs.push_back("builtin:furnace?albedo=0.5&emission=1");
  const auto lit_by_a_json = [](const fs::path& obj) {
    for (const auto& j : fs::directory_iterator(obj.parent_path())) {
      if (j.path().extension() != ".json") continue;
      const Scene s = load_scene(j.path().string());
      std::ifstream in(j.path());
      const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
      if (s.lighting.lights() && text.find("\"" + obj.filename().string() + "\"") != std::string::npos) return true;
    }
    return false;
  };
  for (const auto& e : fs::recursive_directory_iterator(EPR_SOURCE_DIR "/scenes"))
    if ((e.path().extension() == ".obj" && !lit_by_a_json(e.path())) || e.path().extension() == ".json")
      specs.push_back(e.path().string());
  EXPECT_GE(specs.size(), 10u);
  for (const std::string& spec : specs) {
    SCOPED_TRACE(spec);
    EXPECT_EQ(unlit_reason(load_scene(spec)), std::nullopt);
  }
}

}  // namespace
}  // namespace epr
