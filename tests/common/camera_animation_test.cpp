// Camera keyframes in scene JSON files (common/camera_animation.h): parsing, interpolation, and the
// errors of malformed keys, which name the file and the line like every scene error.
#include "common/camera_animation.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <string>

#include "tests/common/scene_test_files.h"

namespace epr {
namespace {

using test::TempDir;

void expect_near(const Vec3& a, const Vec3& b, float tol = 1e-5f) {
  EXPECT_NEAR(a.x, b.x, tol);
  EXPECT_NEAR(a.y, b.y, tol);
  EXPECT_NEAR(a.z, b.z, tol);
}

// The SceneError of loading `path` both ways (load_scene and load_camera_animation), which agree.
std::string animation_error(const std::string& path) {
  const std::string err = test::load_error(path);
  try {
    load_camera_animation(path);
    ADD_FAILURE() << "load_camera_animation accepted what load_scene refused: " << err;
  } catch (const SceneError& e) {
    EXPECT_EQ(std::string(e.what()), err);
  }
  return err;
}

const char* kTwoKeys = R"({
  "builtin": "cornell",
  "camera": {"fov": 40},
  "animation": {
    "camera": [
      {"frame": 1, "eye": [0, 1, 3.9], "look": [0, 1, 0]},
      {"frame": 5, "eye": [0.8, 1.4, 3.1], "look": [0.4, 1, 0], "fov": 60}
    ]
  }
})";

TEST(CameraAnimation, KeysAreInterpolatedLinearlyAndHeldOutsideTheirRange) {
  TempDir dir;
  const std::string path = dir.write("anim.json", kTwoKeys);
  CameraSpec still;
  const CameraAnimation a = load_camera_animation(path, {}, &still);
  ASSERT_TRUE(a.animated());
  ASSERT_EQ(a.keys.size(), 2u);
  EXPECT_EQ(a.keys[0].frame, 1u);
  EXPECT_EQ(a.keys[0].line, 6u);
  EXPECT_EQ(a.keys[1].line, 7u);
  EXPECT_EQ(still.fov_y_degrees, 40.f);  // the scene's camera, as load_scene gives it
  EXPECT_EQ(load_scene(path).camera.fov_y_degrees, 40.f);

  // The first key's missing fields come from the scene's camera.
  EXPECT_EQ(a.at(1, still).fov_y_degrees, 40.f);
  expect_near(a.at(1, still).up, {0, 1, 0});
  // Frame 3 is half-way: eye, look and fov midway.
  const CameraSpec mid = a.at(3, still);
  expect_near(mid.eye, {0.4f, 1.2f, 3.5f});
  expect_near(mid.look, {0.2f, 1.f, 0.f});
  EXPECT_NEAR(mid.fov_y_degrees, 50.f, 1e-4f);
  const CameraSpec quarter = a.at(2, still);
  expect_near(quarter.eye, {0.2f, 1.1f, 3.7f});
  EXPECT_NEAR(quarter.fov_y_degrees, 45.f, 1e-4f);
  // Before the first key and after the last: held.
  EXPECT_EQ(a.at(0, still).eye, a.keys[0].camera.eye);
  EXPECT_EQ(a.at(5, still).eye, a.keys[1].camera.eye);
  EXPECT_EQ(a.at(900, still).fov_y_degrees, 60.f);
  for (uint32_t f = 0; f < 10; ++f) EXPECT_FALSE(a.frame_problem(f, still)) << f;
}

TEST(CameraAnimation, AKeyKeepsWhatItDoesNotGiveFromTheKeyBefore) {
  TempDir dir;
  const std::string path = dir.write("anim.json", R"({"builtin": "cornell", "animation": {"camera": [
    {"frame": 0, "eye": [0, 1, 4], "fov": 30},
    {"frame": 10, "look": [0, 0.5, 0]},
    {"frame": 20, "eye": [1, 1, 4]}
  ]}})");
  const CameraAnimation a = load_camera_animation(path);
  ASSERT_EQ(a.keys.size(), 3u);
  EXPECT_EQ(a.keys[1].camera.eye, Vec3(0, 1, 4));
  EXPECT_EQ(a.keys[1].camera.fov_y_degrees, 30.f);
  EXPECT_EQ(a.keys[2].camera.look, Vec3(0, 0.5f, 0));
  EXPECT_EQ(a.keys[2].camera.fov_y_degrees, 30.f);
}

TEST(CameraAnimation, ScenesWithoutKeysDoNotMove) {
  TempDir dir;
  const std::string path = dir.write("still.json", R"({"builtin": "cornell", "camera": {"fov": 50}})");
  CameraSpec still;
  const CameraAnimation a = load_camera_animation(path, {}, &still);
  EXPECT_FALSE(a.animated());
  EXPECT_EQ(a.at(7, still).fov_y_degrees, 50.f);
  EXPECT_FALSE(load_camera_animation("builtin:cornell").animated());
  EXPECT_FALSE(load_camera_animation(dir.write("empty.json", R"({"builtin": "cornell", "animation": {}})")).animated());
}

TEST(CameraAnimation, TheShippedExampleLoadsAndMoves) {
  const std::string path = std::string(EPR_SOURCE_DIR) + "/scenes/cornell-flythrough.json";
  CameraSpec still;
  const CameraAnimation a = load_camera_animation(path, {}, &still);
  ASSERT_TRUE(a.animated());
  EXPECT_NE(a.at(1, still).eye, a.at(48, still).eye);
  for (uint32_t f = 1; f <= 48; ++f) EXPECT_FALSE(a.frame_problem(f, still)) << f;
}

TEST(CameraAnimation, MalformedKeysNameTheFileAndLine) {
  TempDir dir;
  struct Case {
    const char* keys;  // the "camera" array's contents, from line 3 on
    int line;
    const char* reason;
  };
  const Case cases[] = {
      {"{\"frame\": 1},\n  {\"eye\": [0, 1, 3]}", 4, "camera key has no \"frame\""},
      {"{\"frame\": 1.5}", 3, "camera key frame must be an integer from 0 to 9999999"},
      {"{\"frame\": -1}", 3, "camera key frame must be an integer"},
      {"{\"frame\": 10000000}", 3, "camera key frame must be an integer"},
      {"{\"frame\": 5},\n  {\"frame\": 5}", 4, "camera key frame 5 does not come after frame 5 (line 3)"},
      {"{\"frame\": 9},\n  {\"frame\": 2}", 4, "does not come after frame 9"},
      {"{\"frame\": 1,\n \"eye\": [0, 1]}", 4, "camera key eye must be an array of 3 numbers"},
      {"{\"frame\": 1, \"fov\": \"wide\"}", 3, "camera key fov must be a number"},
      {"{\"frame\": 1, \"fov\": 200}", 3, "camera key at frame 1: camera fov 200 degrees is outside"},
      {"{\"frame\": 1, \"eye\": [0, 1, 0], \"look\": [0, 1, 0]}", 3,
       "camera key at frame 1: camera eye and look-at point coincide"},
      {"{\"frame\": 1, \"zoom\": 2}", 3, "unknown key 'zoom' (known: frame, eye, look, up, fov)"},
      {"3", 3, "a camera key must be an object"},
  };
  for (const Case& c : cases) {
    const std::string path = dir.write(
        "bad.json", std::string("{\"builtin\": \"cornell\",\n \"animation\": {\"camera\": [\n  ") + c.keys + "\n]}}\n");
    const std::string err = animation_error(path);
    const std::string where = path + ":" + std::to_string(c.line) + ": ";
    EXPECT_EQ(err.rfind(where, 0), 0u) << c.keys << "\n  gave: " << err;
    EXPECT_NE(err.find(c.reason), std::string::npos) << c.keys << "\n  gave: " << err;
  }
  // The animation itself.
  EXPECT_NE(animation_error(dir.write("a.json", "{\"builtin\": \"cornell\",\n \"animation\": []}"))
                .find("a.json:2: \"animation\" must be an object"),
            std::string::npos);
  EXPECT_NE(animation_error(dir.write("b.json", "{\"builtin\": \"cornell\",\n \"animation\": {\"camera\": []}}"))
                .find("b.json:2: animation camera must be an array of keys"),
            std::string::npos);
  EXPECT_NE(animation_error(dir.write("c.json", "{\"builtin\": \"cornell\",\n \"animation\": {\"light\": []}}"))
                .find("c.json:2: unknown key 'light' (known: camera)"),
            std::string::npos);
}

TEST(CameraAnimation, ADegenerateCameraBetweenKeysIsFoundAtItsFrame) {
  TempDir dir;
  // The eye passes through the look-at point half-way.
  const std::string path = dir.write("through.json", R"({"builtin": "cornell",
  "animation": {"camera": [
    {"frame": 0, "eye": [0, 1, 1], "look": [0, 1, 0]},
    {"frame": 4, "eye": [0, 1, -1], "look": [0, 1, 0]}
  ]}})");
  CameraSpec still;
  const CameraAnimation a = load_camera_animation(path, {}, &still);
  EXPECT_FALSE(a.frame_problem(1, still));
  const auto problem = a.frame_problem(2, still);
  ASSERT_TRUE(problem);
  EXPECT_EQ(*problem, path + ":3: frame 2: camera eye and look-at point coincide");
}

}  // namespace
}  // namespace epr
