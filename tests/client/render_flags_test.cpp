// The render flags of `epr render` and `epr submit` parsed as the CLI parses them.
#include "client/render_flags.h"

#include <gtest/gtest.h>

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

}  // namespace
}  // namespace epr
