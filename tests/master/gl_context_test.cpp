// OSMesa context: creation, profile, the extensions the reprojector needs, thread ownership.
#include "master/gl_context.h"

#include <gtest/gtest.h>

#include <thread>

namespace epr {
namespace {

TEST(GlContext, CreatesCoreProfile45WithComputeAndFloatAtomics) {
  ASSERT_TRUE(gl_available()) << "OSMesa unavailable: run scripts/setup.sh (libosmesa6)";
  GlContext ctx;
  EXPECT_NE(ctx.version().find("4.5"), std::string::npos) << ctx.version();
  EXPECT_NE(ctx.version().find("Core"), std::string::npos) << ctx.version();
  EXPECT_TRUE(ctx.has_extension("GL_NV_shader_atomic_float"));
  EXPECT_FALSE(ctx.has_extension("GL_EPR_no_such_extension"));
  EXPECT_NO_THROW(ctx.check_error("fresh context"));
}

TEST(GlContext, RefusesUseFromAnotherThreadUntilMadeCurrentThere) {
  ASSERT_TRUE(gl_available()) << "OSMesa unavailable: run scripts/setup.sh (libosmesa6)";
  GlContext ctx;
  EXPECT_NO_THROW(ctx.check_thread());
  bool threw = false;
  std::thread([&] {
    try {
      ctx.check_thread();
    } catch (const std::logic_error&) {
      threw = true;
    }
  }).join();
  EXPECT_TRUE(threw);
  // Hand the context over and back.
  ctx.release();
  std::thread([&] {
    ctx.make_current();
    EXPECT_NO_THROW(ctx.renderer());
    ctx.release();
  }).join();
  EXPECT_THROW(ctx.check_thread(), std::logic_error);
  ctx.make_current();
  EXPECT_FALSE(ctx.renderer().empty());
}

TEST(GlContext, TwoContextsCoexist) {
  ASSERT_TRUE(gl_available()) << "OSMesa unavailable: run scripts/setup.sh (libosmesa6)";
  GlContext a;
  GlContext b;  // now current
  EXPECT_FALSE(b.renderer().empty());
  a.make_current();
  EXPECT_FALSE(a.renderer().empty());
}

}  // namespace
}  // namespace epr
