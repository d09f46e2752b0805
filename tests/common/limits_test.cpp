// The ranges the validation enforces (common/limits.h) are the ones the proto documents.
#include "common/limits.h"

#include <gtest/gtest.h>

#include <fstream>
#include <sstream>

#include "common/render_options.h"

namespace epr {
namespace {

std::string read(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// The comment lines just above `field` in a proto file.
std::string comment_of(const std::string& proto, const std::string& field) {
  const size_t at = proto.find(field);
  EXPECT_NE(at, std::string::npos) << field;
  if (at == std::string::npos) return "";
  size_t line = proto.rfind('\n', at);
  // The field's own line (trailing comments) and the comment block above it.
  std::string out = proto.substr(line + 1, proto.find('\n', at) - line - 1);
  while (line != std::string::npos && line > 0) {
    const size_t prev = proto.rfind('\n', line - 1);
    const std::string text = proto.substr(prev + 1, line - prev - 1);
    if (text.find("//") == std::string::npos) break;
    out += text;
    line = prev;
  }
  return out;
}

template <class T>
std::string range_text(const Range<T>& r) {
  return fmt::format("[{}, {}]", r.lo, r.hi);
}

TEST(Limits, TheProtoDocumentsTheValidatedRanges) {
  const std::string job = read(EPR_SOURCE_DIR "/proto/epr/v1/job_service.proto");
  const std::string settings = read(EPR_SOURCE_DIR "/proto/epr/v1/render_settings.proto");
  ASSERT_FALSE(job.empty());
  ASSERT_FALSE(settings.empty());
  const struct {
    const std::string& proto;
    std::string field, range;
  } cases[] = {
      {job, "uint32 width = 4;", range_text(limits::kImageSide)},
      {job, "uint32 height = 5;", range_text(limits::kImageSide)},
      {job, "uint32 target_spp = 6;", range_text(limits::kSpp)},
      {job, "optional uint32 tile_size = 14;", range_text(limits::kTileSize)},
      {job, "optional float round_growth = 16;", range_text(limits::kRoundGrowth)},
      {settings, "optional uint32 subpixels = 2;", range_text(limits::kSubpixels)},
      {settings, "optional float epsilon_fraction = 3;", range_text(limits::kEpsilon)},
      {settings, "optional uint32 max_depth = 4;", range_text(limits::kMaxDepth)},
  };
  for (const auto& c : cases)
    EXPECT_NE(comment_of(c.proto, c.field).find(c.range), std::string::npos)
        << c.field << " should document " << c.range << "; its comment: " << comment_of(c.proto, c.field);
}

TEST(Limits, ValidationAcceptsTheEndsOfEachRangeAndRefusesJustOutside) {
  auto with = [](auto set) {
    RenderOptions o;
    o.width = o.height = 64;
    o.spp = 64;
    set(o);
    return o.validate();
  };
  EXPECT_FALSE(with([](RenderOptions& o) { o.tile_size = limits::kTileSize.lo; }));
  EXPECT_FALSE(with([](RenderOptions& o) { o.tile_size = limits::kTileSize.hi; }));
  EXPECT_TRUE(with([](RenderOptions& o) { o.tile_size = limits::kTileSize.hi + 1; }));
  EXPECT_FALSE(with([](RenderOptions& o) { o.subpixels = limits::kSubpixels.hi; }));
  EXPECT_TRUE(with([](RenderOptions& o) { o.subpixels = limits::kSubpixels.hi + 1; }));
  EXPECT_FALSE(with([](RenderOptions& o) { o.rr.max_depth = limits::kMaxDepth.hi; }));
  EXPECT_TRUE(with([](RenderOptions& o) { o.rr.max_depth = limits::kMaxDepth.hi + 1; }));
  EXPECT_TRUE(with([](RenderOptions& o) { o.spp = limits::kSpp.hi + 1; }));
  const auto err = with([](RenderOptions& o) { o.tile_size = 2; });
  ASSERT_TRUE(err);
  EXPECT_NE(err->find("--tile 2 must be between 4 and 1024"), std::string::npos) << *err;
}

TEST(Limits, AGridTheMasterCannotBuildIsRefusedAtValidationNamingTheSubpixelsThatFit) {
  RenderOptions o;
  o.mode = RenderMode::kSkip;
  o.subpixels = 4;
  o.width = 3840, o.height = 2160;  // 15360 x 8640: fits both limits
  EXPECT_FALSE(o.validate());
  o.width = 5000, o.height = 100;  // 20000 texels wide: few texels, too wide
  auto err = o.validate();
  ASSERT_TRUE(err);
  EXPECT_NE(err->find("20000x400 deep framebuffer"), std::string::npos) << *err;
  EXPECT_NE(err->find("--subpixels 3 fits"), std::string::npos) << *err;
  o.width = 7680, o.height = 4320;  // 8K: 2^28 texels are reached at S = 2
  err = o.validate();
  ASSERT_TRUE(err);
  EXPECT_NE(err->find("--subpixels 2 fits"), std::string::npos) << *err;
  o.width = o.height = limits::kImageSide.hi;  // S = 1 is 2^28 texels exactly
  o.subpixels = 2;
  err = o.validate();
  ASSERT_TRUE(err);
  EXPECT_NE(err->find("--subpixels 1 fits"), std::string::npos) << *err;
  o.mode = RenderMode::kPathTrace;  // no deep framebuffer
  EXPECT_FALSE(o.validate());
}

}  // namespace
}  // namespace epr
