// common/check.h: EPR_CHECK_EQ... abort with both operands' values in the message, and EPR_DCHECK...
// are compiled out of this (NDEBUG) build: their arguments are never evaluated.
#include "common/check.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <limits>

namespace epr {
namespace {

enum class Colour : uint8_t { kRed = 3, kBlue = 7 };

TEST(CheckDeathTest, ComparisonsThatHoldDoNotAbortAndEvaluateEachOperandOnce) {
  int evaluated = 0;
  auto once = [&](int v) {
    ++evaluated;
    return v;
  };
  EPR_CHECK_EQ(once(2), once(2));
  EPR_CHECK_NE(once(1), 2);
  EPR_CHECK_LT(once(1), 2);
  EPR_CHECK_LE(once(2), 2);
  EPR_CHECK_GT(once(3), 2);
  EPR_CHECK_GE(once(2), 2);
  EXPECT_EQ(evaluated, 7);
}

TEST(CheckDeathTest, AFailedComparisonNamesBothExpressionsTheirValuesAndThePlace) {
  GTEST_FLAG_SET(death_test_style, "threadsafe");
  const int tiles = 3;
  const size_t slots = 2;
  EXPECT_DEATH(EPR_CHECK_EQ(tiles, 4), "check_test.cpp:[0-9]+: invariant broken: tiles == 4 \\(tiles = 3, 4 = 4\\)");
  EXPECT_DEATH(EPR_CHECK_LT(slots, size_t(tiles) - 1),
               "invariant broken: slots < size_t\\(tiles\\) - 1 \\(slots = 2, size_t\\(tiles\\) - 1 = 2\\)");
  EXPECT_DEATH(EPR_CHECK_NE(tiles, 3), "tiles != 3 \\(tiles = 3, 3 = 3\\)");
  EXPECT_DEATH(EPR_CHECK_LE(tiles, 2), "tiles <= 2 \\(tiles = 3, 2 = 2\\)");
  EXPECT_DEATH(EPR_CHECK_GT(tiles, 5), "tiles > 5 \\(tiles = 3, 5 = 5\\)");
  EXPECT_DEATH(EPR_CHECK_GE(tiles, 4), "tiles >= 4 \\(tiles = 3, 4 = 4\\)");
}

TEST(CheckDeathTest, OperandsPrintAsNumbersWithEveryDigitThatTellsThemApart) {
  GTEST_FLAG_SET(death_test_style, "threadsafe");
  const float pdf = 0.1f;
  const double sum = 0.1;
  EXPECT_DEATH(EPR_CHECK_EQ(double(pdf), sum),
               "double\\(pdf\\) = 0.100000001[0-9]*, sum = 0.1000000000000000[0-9]*\\)");
  const uint8_t flags = 65;  // 'A' as a character
  EXPECT_DEATH(EPR_CHECK_EQ(flags, 0), "\\(flags = 65, 0 = 0\\)");
  EXPECT_DEATH(EPR_CHECK_EQ(Colour::kRed, Colour::kBlue), "Colour::kRed = 3, Colour::kBlue = 7\\)");
  const float nan = std::numeric_limits<float>::quiet_NaN();
  EXPECT_DEATH(EPR_CHECK_GT(nan, 0.f), "\\(nan = nan, 0.f = 0\\)");
}

TEST(CheckDeathTest, PlainCheckNamesItsCondition) {
  GTEST_FLAG_SET(death_test_style, "threadsafe");
  const bool leased = false;
  EXPECT_DEATH(EPR_CHECK(leased), "check_test.cpp:[0-9]+: invariant broken: leased\n");
}

#ifdef NDEBUG
TEST(CheckDeathTest, DebugChecksAreCompiledOutOfReleaseBuildsAndNeverEvaluated) {
  int evaluated = 0;
  auto broken = [&] {
    ++evaluated;
    return false;
  };
  EPR_DCHECK(broken());
  EPR_DCHECK_EQ(broken(), true);
  EPR_DCHECK_NE(broken(), false);
  EPR_DCHECK_LT(evaluated++, -1);
  EPR_DCHECK_LE(evaluated++, -1);
  EPR_DCHECK_GT(evaluated++, 1 << 30);
  EPR_DCHECK_GE(evaluated++, 1 << 30);
  EXPECT_EQ(evaluated, 0);
}
#endif

}  // namespace
}  // namespace epr
