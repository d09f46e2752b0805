// common/check.h without NDEBUG (a debug build): EPR_DCHECK... run and abort like EPR_CHECK...,
// with both operands in the message. Compiled alone (EPR_UNITY_ALONE): no other file of the unity
// batch may include check.h with NDEBUG first.
#undef NDEBUG
#include <gtest/gtest.h>

#include "common/check.h"

namespace epr {
namespace {

TEST(DebugCheckDeathTest, DebugChecksRunWithoutNdebugAndNameBothOperands) {
  GTEST_FLAG_SET(death_test_style, "threadsafe");
  int evaluated = 0;
  EPR_DCHECK_EQ(++evaluated, 1);
  EPR_DCHECK(++evaluated == 2);
  EXPECT_EQ(evaluated, 2);
  const float pdf = -0.5f;
  EXPECT_DEATH(EPR_DCHECK_GT(pdf, 0.f),
               "check_debug_test.cpp:[0-9]+: invariant broken: pdf > 0.f \\(pdf = -0.5, 0.f = 0\\)");
  EXPECT_DEATH(EPR_DCHECK(pdf > 0), "invariant broken: pdf > 0\n");
}

}  // namespace
}  // namespace epr
