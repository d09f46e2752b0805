// Scene bundles made from user files (issue 16): the bundler bundles exactly the files the loader
// reads (texture names with blanks and options included), refuses what is not a regular file
// without blocking, refuses NUL bytes in paths and unlit scenes, and shows the scene's warnings once,
// on the client's side, naming the user's files.
#include "wire/scene_bundle.h"

#include <gtest/gtest.h>
#include <spdlog/sinks/ostream_sink.h>
#include <sys/stat.h>

#include <algorithm>
#include <filesystem>
#include <functional>
#include <sstream>
#include <string>

#include "common/image.h"
#include "common/log.h"
#include "common/scene_loader.h"
#include "tests/common/scene_test_files.h"

namespace epr {
namespace {

namespace fs = std::filesystem;
using test::TempDir;

const std::string kTriangles = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvt 1 1\n";
const std::string kLitMtl = "newmtl glow\nKd 0.5 0.5 0.5\nKe 4 4 4\n";

/// The SceneError message of bundling `spec`, or "" if it bundled.
std::string bundle_error(const std::string& spec) {
  try {
    bundle_scene(spec);
  } catch (const SceneError& e) {
    return e.what();
  }
  return "";
}

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

/// What the "common" logger writes at warn level and above while it lives.
class WarnCapture {
 public:
  WarnCapture() : sink_(std::make_shared<spdlog::sinks::ostream_sink_mt>(text_)) {
    set_log_level("warn");
    logger("common")->sinks().push_back(sink_);
  }
  ~WarnCapture() {
    auto& sinks = logger("common")->sinks();
    sinks.erase(std::remove(sinks.begin(), sinks.end(), sink_), sinks.end());
    set_log_level("info");
  }
  std::string text() const { return text_.str(); }

 private:
  std::ostringstream text_;
  std::shared_ptr<spdlog::sinks::ostream_sink_mt> sink_;
};

size_t count(const std::string& text, const std::string& part) {
  size_t n = 0;
  for (size_t p = text.find(part); p != std::string::npos; p = text.find(part, p + 1)) ++n;
  return n;
}

// `map_Kd -s 1 1 1 tex/my texture.png`: the loader reads "tex/my texture.png", and so the bundle
// carries that file (the bundler once kept the last blank-separated word, "texture.png"); the
// bundled scene, loaded from a cache as master and workers do, equals the one loaded locally.
TEST(SceneBundle, TextureNamesWithBlanksAndOptionsAreBundled) {
  TempDir dir;
  Image tex(4, 2, 3);
  for (size_t i = 0; i < tex.data.size(); ++i) tex.data[i] = float(i % 7) / 7.f;
  fs::create_directories(dir.path("scene/tex"));
  write_png_srgb(dir.path("scene/tex/my texture.png"), tex);
  write_png_srgb(dir.path("scene/tex/texture.png"), Image(1, 1, 3));  // the wrong file, were the name cut
  dir.write("scene/m.mtl", kLitMtl + "newmtl wall\nKd 0.5 0.5 0.5\nmap_Kd -s 1 1 1 -o 0 0 0 tex/my texture.png\n");
  const std::string obj =
      dir.write("scene/s.obj", "mtllib m.mtl\n" + kTriangles + "usemtl glow\nf 1 2 3\nusemtl wall\nf 2/2 4/4 3/3\n");

  const SceneBundleData b = bundle_scene(obj);
  EXPECT_EQ(b.entry_path, "s.obj");
  std::vector<std::string> paths;
  for (const auto& f : b.files) paths.push_back(f.first);
  EXPECT_EQ(paths, (std::vector<std::string>{"m.mtl", "s.obj", "tex/my texture.png"}));

  const Scene local = load_scene(obj);
  const Scene bundled = load_bundle(b, dir.path("cache"));
  ASSERT_EQ(bundled.textures.size(), 1u);
  ASSERT_EQ(local.textures.size(), 1u);
  EXPECT_EQ(bundled.textures[0].width, 4);
  EXPECT_EQ(bundled.textures[0].rgb, local.textures[0].rgb);
  ASSERT_EQ(bundled.materials.size(), local.materials.size());
  for (size_t m = 0; m < local.materials.size(); ++m) {
    EXPECT_EQ(bundled.materials[m].kd_texture, local.materials[m].kd_texture);
    EXPECT_EQ(bundled.materials[m].ke, local.materials[m].ke);
  }
  EXPECT_EQ(bundled.positions, local.positions);
  EXPECT_EQ(bundled.triangles, local.triangles);
  ASSERT_EQ(bundled.uvs.size(), local.uvs.size());
  for (size_t t = 0; t < local.uvs.size(); ++t)
    for (size_t k = 0; k < 3; ++k) {
      EXPECT_EQ(bundled.uvs[t][k].x, local.uvs[t][k].x);
      EXPECT_EQ(bundled.uvs[t][k].y, local.uvs[t][k].y);
    }
}

// The shipped scenes and a scene JSON naming an OBJ in a subfolder bundle the files they read and
// load from the bundle as they load locally.
TEST(SceneBundle, FileScenesLoadFromTheirBundlesAsTheyLoadLocally) {
  TempDir dir;
  dir.write("scene/models/lit.mtl", kLitMtl);
  dir.write("scene/models/room.obj", "mtllib lit.mtl\n" + kTriangles + "usemtl glow\nf 1 2 3\n");
  const std::string json = dir.write("scene/room.json", R"({"obj": "models/room.obj", "camera": {"fov": 50}})");
  std::vector<std::string> specs = {json};
  for (const auto& e : fs::recursive_directory_iterator(EPR_SOURCE_DIR "/scenes"))
    if (e.path().extension() == ".obj" || e.path().extension() == ".json") specs.push_back(e.path().string());
  for (const std::string& spec : specs) {
    SCOPED_TRACE(spec);
    // A shipped OBJ lit only by the sky of a scene JSON beside it is bundled with a job's sky.
    Lighting job;
    if (unlit_reason(load_scene(spec))) job.environment = EnvironmentLight{};
    const SceneBundleData b = bundle_scene(spec, job);
    const Scene local = load_scene(spec), bundled = load_bundle(b, dir.path("cache"), job);
    EXPECT_EQ(bundled.positions, local.positions);
    EXPECT_EQ(bundled.material_of, local.material_of);
    EXPECT_EQ(bundled.camera.fov_y_degrees, local.camera.fov_y_degrees);
  }
  std::vector<std::string> paths;
  for (const auto& f : bundle_scene(json).files) paths.push_back(f.first);
  EXPECT_EQ(paths, (std::vector<std::string>{"models/lit.mtl", "models/room.obj", "room.json"}));
}

// An environment image, named by a scene JSON or by the job (`--env`, relative to the scene's folder),
// travels in the bundle and is read from it inside the scene's folder.
TEST(SceneBundle, EnvironmentImagesTravelInTheBundle) {
  TempDir dir;
  dir.write("scene/models/room.obj", kTriangles + "f 1 2 3\n");
  std::filesystem::create_directories(dir.path("scene/skies"));
  Image sky(4, 2, 3);
  for (float& v : sky.data) v = 0.25f;
  write_exr(dir.path("scene/skies/a.exr"), sky);
  for (float& v : sky.data) v = 0.5f;
  write_exr(dir.path("scene/skies/b.exr"), sky);
  const std::string json =
      dir.write("scene/room.json", R"({"obj": "models/room.obj", "environment": {"image": "skies/a.exr"}})");
  SceneBundleData b = bundle_scene(json);
  std::vector<std::string> paths;
  for (const auto& f : b.files) paths.push_back(f.first);
  EXPECT_EQ(paths, (std::vector<std::string>{"models/room.obj", "room.json", "skies/a.exr"}));
  Scene s = load_bundle(b, dir.path("cache"));
  ASSERT_TRUE(s.lighting.environment && s.lighting.environment->pixels);
  EXPECT_EQ(s.lighting.environment->pixels->rgb(0, 0), Vec3(0.25f));
  // The job's image replaces the scene's, and is bundled with it.
  Lighting job;
  job.environment = EnvironmentLight{};
  job.environment->image = "skies/b.exr";
  b = bundle_scene(json, job);
  paths.clear();
  for (const auto& f : b.files) paths.push_back(f.first);
  EXPECT_EQ(paths, (std::vector<std::string>{"models/room.obj", "room.json", "skies/a.exr", "skies/b.exr"}));
  s = load_bundle(b, dir.path("cache"), job);
  ASSERT_TRUE(s.lighting.environment && s.lighting.environment->pixels);
  EXPECT_EQ(s.lighting.environment->pixels->rgb(0, 0), Vec3(0.5f));
  // A bundle that lacks the job's image is refused naming the flag.
  job.environment->image = "skies/c.exr";
  try {
    load_bundle(b, dir.path("cache"), job);
    ADD_FAILURE() << "a missing environment image was accepted";
  } catch (const SceneError& e) {
    EXPECT_NE(std::string(e.what()).find("--env: environment image 'skies/c.exr' does not exist"), std::string::npos)
        << e.what();
  }
}

// A built-in scene with a job's image (`--env FILE`, read from the image's folder on the client's
// side) is bundled as a scene JSON naming the built-in beside the image; master and workers load it
// as the client does. Without the folder (a raw submission) the image is refused.
TEST(SceneBundle, ABuiltInSceneTakesAJobsImageAlong) {
  TempDir dir;
  std::filesystem::create_directories(dir.path("skies"));
  Image sky(4, 2, 3);
  for (float& v : sky.data) v = 0.75f;
  write_exr(dir.path("skies/sky.exr"), sky);
  Lighting job;
  job.environment = EnvironmentLight{};
  job.environment->image = "sky.exr";
  const SceneBundleData b = bundle_scene("builtin:cornell?tess=2", job, dir.path("skies"));
  EXPECT_TRUE(b.builtin.empty());
  EXPECT_EQ(b.entry_path, "builtin.json");
  ASSERT_EQ(b.files.size(), 2u);
  EXPECT_EQ(b.files[0].first, "builtin.json");
  EXPECT_EQ(b.files[0].second, "{\"builtin\":\"cornell?tess=2\"}\n");
  EXPECT_EQ(b.files[1].first, "sky.exr");
  const Scene local = load_job_scene("builtin:cornell?tess=2", {}, nullptr, job, dir.path("skies"));
  const Scene bundled = load_bundle(b, dir.path("cache"), job);
  EXPECT_EQ(bundled.positions, local.positions);
  EXPECT_EQ(bundled.material_of, local.material_of);
  EXPECT_EQ(bundled.camera.eye, local.camera.eye);
  ASSERT_TRUE(bundled.lighting.environment && bundled.lighting.environment->pixels);
  EXPECT_EQ(bundled.lighting.environment->pixels->rgb(1, 1), Vec3(0.75f));
  // Without the folder: refused with the reason, on the client's side and the master's.
  for (auto attempt : {std::function<void()>([&] { bundle_scene("builtin:cornell", job); }), std::function<void()>([&] {
                         load_bundle(SceneBundleData{"builtin:cornell", "", {}, {}, {}, {}}, dir.path("cache"), job);
                       })}) {
    try {
      attempt();
      ADD_FAILURE() << "a built-in scene read an image without a folder";
    } catch (const SceneError& e) {
      EXPECT_NE(std::string(e.what()).find("a built-in scene has no folder"), std::string::npos) << e.what();
    }
  }
  // A missing image names the flag and the file.
  job.environment->image = "missing.exr";
  try {
    bundle_scene("builtin:cornell", job, dir.path("skies"));
    ADD_FAILURE() << "a missing image was bundled";
  } catch (const SceneError& e) {
    EXPECT_NE(std::string(e.what()).find("--env: environment image 'missing.exr' does not exist"), std::string::npos)
        << e.what();
  }
}

// A FIFO, a device or a directory named as a scene file is refused naming it; nothing blocks or
// reads without end.
TEST(SceneBundle, OnlyRegularFilesAreBundled) {
  TempDir dir;
  dir.write("lit.mtl", kLitMtl);
  ASSERT_EQ(::mkfifo(dir.path("pipe.obj").c_str(), 0600), 0);
  ASSERT_EQ(::mkfifo(dir.path("pipe.mtl").c_str(), 0600), 0);
  ASSERT_EQ(::mkfifo(dir.path("pipe.png").c_str(), 0600), 0);
  fs::create_directories(dir.path("x.obj"));
  EXPECT_EQ(bundle_error(dir.path("pipe.obj")), dir.path("pipe.obj") + ": is a FIFO (named pipe), not a regular file");
  EXPECT_EQ(bundle_error("/dev/zero"), "/dev/zero: is a character device, not a regular file");
  EXPECT_EQ(bundle_error(dir.path("x.obj")), dir.path("x.obj") + ": is a directory");
  const std::string m = dir.write("m.obj", "mtllib pipe.mtl\n" + kTriangles + "f 1 2 3\n");
  EXPECT_TRUE(contains(bundle_error(m), "m.obj:1: mtllib 'pipe.mtl' is a FIFO")) << bundle_error(m);
  dir.write("t.mtl", kLitMtl + "map_Kd pipe.png\n");
  const std::string t = dir.write("t.obj", "mtllib t.mtl\n" + kTriangles + "usemtl glow\nf 1 2 3\n");
  EXPECT_TRUE(contains(bundle_error(t), "t.mtl:4: texture 'pipe.png' is a FIFO")) << bundle_error(t);
}

TEST(SceneBundle, PathsWithANulByteAreRefused) {
  EXPECT_FALSE(is_safe_relative_path(std::string("scene.obj\0.png", 14)));
  EXPECT_TRUE(is_safe_relative_path("scene.obj"));
  EXPECT_TRUE(contains(bundle_error(std::string("scene.obj\0x", 11)), "contains a NUL byte"));

  // A raw submission naming its entry or a file with a NUL (which a file name would end at).
  TempDir dir;
  SceneBundleData b;
  b.entry_path = std::string("s.obj\0x", 7);
  b.files = {{"lit.mtl", kLitMtl}, {"s.obj", "mtllib lit.mtl\n" + kTriangles + "usemtl glow\nf 1 2 3\n"}};
  EXPECT_THROW(load_bundle(b, dir.path("cache")), SceneError);
  b.entry_path = "s.obj";
  b.files[0].first = std::string("lit.mtl\0.txt", 12);
  EXPECT_THROW(load_bundle(b, dir.path("cache")), SceneError);
  b.files[0].first = "lit.mtl";
  EXPECT_EQ(load_bundle(b, dir.path("cache")).triangle_count(), 1u);
}

// An OBJ without emitters renders black: the bundler (client side) and load_bundle (the master's
// check of a raw submission) refuse it with the reason.
TEST(SceneBundle, UnlitScenesAreRefused) {
  TempDir dir;
  dir.write("grey.mtl", "newmtl grey\nKd 0.5 0.5 0.5\n");
  const std::string obj = dir.write("dark.obj", "mtllib grey.mtl\n" + kTriangles + "usemtl grey\nf 1 2 3\n");
  const std::string msg = bundle_error(obj);
  EXPECT_EQ(msg.rfind(obj + " has no light: no material has an emission (Ke)", 0), 0u) << msg;

  SceneBundleData raw;
  raw.entry_path = "dark.obj";
  raw.files = {{"dark.obj", "mtllib grey.mtl\n" + kTriangles + "usemtl grey\nf 1 2 3\n"},
               {"grey.mtl", "newmtl grey\nKd 0.5 0.5 0.5\n"}};
  try {
    load_bundle(raw, dir.path("cache"));
    ADD_FAILURE() << "an unlit bundle loaded";
  } catch (const SceneError& e) {
    EXPECT_TRUE(contains(e.what(), "/dark.obj has no light")) << e.what();
  }
}

// The bundler (the client) logs each warning once, naming the user's path; loading the bundle from
// a cache (master, workers) logs none above debug level.
TEST(SceneBundle, WarningsAreLoggedOnceByTheBundlerOnly) {
  TempDir dir;
  dir.write("scene/lit.mtl", kLitMtl);
  const std::string obj =
      dir.write("scene/w.obj", "mtllib lit.mtl\n" + kTriangles + "usemtl glow\nf 1 2 3\ncurv 0 1 2\n");
  WarnCapture log;
  const SceneBundleData b = bundle_scene(obj);
  const std::string after_bundle = log.text();
  EXPECT_EQ(count(after_bundle, "unsupported statement 'curv' ignored"), 1u) << after_bundle;
  EXPECT_TRUE(contains(after_bundle, obj + ":12: unsupported statement 'curv' ignored")) << after_bundle;
  load_bundle(b, dir.path("cache"));
  EXPECT_EQ(log.text(), after_bundle);
}

}  // namespace
}  // namespace epr
