// The render flags of `epr render` and `epr submit` parsed as the CLI parses them.
#include "client/render_flags.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <vector>

namespace epr {
namespace {

RenderOptions parse(const std::vector<std::string>& args, RenderFlagSet set) {
  CLI::App app;
  RenderOptions o;
  std::map<std::string, std::string> extra;
  add_render_flags(&app, o, extra, set);
  std::vector<std::string> reversed(args.rbegin(), args.rend());  // CLI11 parses a reversed vector
  app.parse(reversed);
  finish_options(o, extra);
  return o;
}

TEST(RenderFlags, SkipIsTheDefaultModeOfRenderAndSubmit) {
  for (RenderFlagSet set : {RenderFlagSet::kLocal, RenderFlagSet::kRemote}) {
    EXPECT_EQ(parse({"builtin:cornell"}, set).mode, RenderMode::kSkip);
    EXPECT_EQ(parse({"builtin:cornell", "--mode", "pt"}, set).mode, RenderMode::kPathTrace);
    EXPECT_EQ(parse({"builtin:cornell", "--mode", "RP"}, set).mode, RenderMode::kReproject);
  }
}

TEST(RenderFlags, HelpNamesTheDefaultMode) {
  CLI::App app;
  RenderOptions o;
  std::map<std::string, std::string> extra;
  add_render_flags(&app, o, extra);
  const std::string help = app.help();
  const size_t at = help.find("--mode");
  ASSERT_NE(at, std::string::npos);
  const std::string line = help.substr(at, help.find('\n', at) - at);
  EXPECT_NE(line.find("=skip"), std::string::npos) << line;
}

TEST(RenderFlags, AnOutputNameWithTheImageExtensionIsTakenAsItsPrefix) {
  EXPECT_EQ(parse({"builtin:cornell", "--out", "shots/frame.exr"}, RenderFlagSet::kLocal).out, "shots/frame");
  EXPECT_EQ(parse({"builtin:cornell", "--out", "frame.PNG"}, RenderFlagSet::kLocal).out, "frame");
  EXPECT_EQ(parse({"builtin:cornell", "--out", "frame.json"}, RenderFlagSet::kLocal).out, "frame.json");
  EXPECT_EQ(parse({"builtin:cornell", "--out", "v1.2"}, RenderFlagSet::kLocal).out, "v1.2");
  EXPECT_EQ(output_prefix(".exr"), ".exr");  // nothing would be left of the name
}

std::string flag_error(const std::vector<std::string>& args) {
  try {
    parse(args, RenderFlagSet::kRemote);
  } catch (const CLI::Error& e) {
    return e.what();
  }
  return "";
}

TEST(RenderFlags, EnvAndSunReplaceTheScenesLighting) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::temp_directory_path() / ("epr_flags_env_" + std::to_string(::getpid()));
  fs::create_directories(dir / "scene" / "skies");
  std::ofstream(dir / "scene" / "m.obj") << "v 0 0 0\n";
  std::ofstream(dir / "scene" / "skies" / "sky.hdr") << "x";
  std::ofstream(dir / "elsewhere.hdr") << "x";
  const std::string scene = (dir / "scene" / "m.obj").string();

  RenderOptions o = parse({scene, "--env", "1,0.5,0.25", "--sun", "0,1,0,1,3"}, RenderFlagSet::kLocal);
  ASSERT_TRUE(o.lighting.environment && o.lighting.sun);
  EXPECT_EQ(o.lighting.environment->color, Vec3(1, 0.5f, 0.25f));
  EXPECT_TRUE(o.lighting.environment->image.empty());
  EXPECT_EQ(o.lighting.sun->irradiance, Vec3(3.f));
  EXPECT_EQ(o.lighting.sun->angle_deg, 1.f);
  // An image: named relative to the scene's folder, as it travels in the scene's bundle.
  o = parse({scene, "--env", (dir / "scene" / "skies" / "sky.hdr").string()}, RenderFlagSet::kRemote);
  EXPECT_EQ(o.lighting.environment->image, "skies/sky.hdr");
  EXPECT_FALSE(o.lighting.sun);

  std::string e = flag_error({scene, "--env", (dir / "elsewhere.hdr").string()});
  EXPECT_NE(e.find("--env: '"), std::string::npos) << e;
  EXPECT_NE(e.find("lies outside the scene's folder"), std::string::npos) << e;
  e = flag_error({scene, "--env", (dir / "missing.hdr").string()});
  EXPECT_NE(e.find("is not a readable file"), std::string::npos) << e;
  // A built-in scene has no folder: the image's own stands in for it, the image named by its file name.
  o = parse({"builtin:cornell", "--env", (dir / "elsewhere.hdr").string()}, RenderFlagSet::kRemote);
  EXPECT_EQ(o.lighting.environment->image, "elsewhere.hdr");
  EXPECT_EQ(o.env_folder, fs::canonical(dir).string());
  e = flag_error({"builtin:cornell", "--env", (dir / "missing.hdr").string()});
  EXPECT_NE(e.find("'" + (dir / "missing.hdr").string() + "' is not a readable file"), std::string::npos) << e;
  o = parse({scene, "--env", "0.5"}, RenderFlagSet::kLocal);
  EXPECT_TRUE(o.env_folder.empty());
  e = flag_error({scene, "--sun", "1,2"});
  EXPECT_NE(e.find("--sun '1,2': expects DX,DY,DZ"), std::string::npos) << e;
  e = flag_error({scene, "--env", "1,2"});
  EXPECT_NE(e.find("--env '1,2': a colour is one number"), std::string::npos) << e;
  fs::remove_all(dir);
}

TEST(RenderFlags, AnOutputPrefixMayNotReplaceAFileTheSceneReads) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::temp_directory_path() / ("epr-out-input-" + std::to_string(::getpid()));
  fs::create_directories(dir / "scn");
  for (const char* f : {"scene.json", "scene.obj", "sky.exr", "shot.v2.obj"}) std::ofstream(dir / "scn" / f) << "x";
  std::vector<fs::path> inputs;
  for (const char* f : {"scene.json", "scene.obj", "sky.exr", "shot.v2.obj"})
    inputs.push_back(fs::canonical(dir / "scn" / f));
  const std::string scn = (dir / "scn").string();
  EXPECT_TRUE(output_replaces_input(scn + "/scene", inputs));                 // scene.json
  EXPECT_TRUE(output_replaces_input(scn + "/../scn/sky", inputs));            // sky.exr, another spelling
  EXPECT_TRUE(output_replaces_input(scn + "/sky", {dir / "scn/./sky.exr"}));  // compared by identity
  EXPECT_FALSE(output_replaces_input(scn + "/shot", inputs));                 // shot.exr, ... : no clash
  EXPECT_FALSE(output_replaces_input(scn + "/render", inputs));
  EXPECT_FALSE(output_replaces_input((dir / "other" / "scene").string(), inputs));  // another folder
  std::ofstream(dir / "scn" / "frames.0007.png") << "x";
  EXPECT_TRUE(output_replaces_input(scn + "/frames", {fs::canonical(dir / "scn/frames.0007.png")}));  // a frame
  // A scene JSON is never replaced, even when this scene does not read it (garden.json beside garden.gltf).
  std::ofstream(dir / "scn" / "garden.json") << "{\n  // comment\n  \"obj\": \"garden.gltf\"\n}\n";
  std::ofstream(dir / "scn" / "old.json") << R"({"seconds": 1.5})";
  EXPECT_TRUE(output_replaces_input(scn + "/garden", {}));
  EXPECT_FALSE(output_replaces_input(scn + "/old", {}));  // earlier statistics: replaced as always
  fs::remove_all(dir);
}

}  // namespace
}  // namespace epr
