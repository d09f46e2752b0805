// The wire's Russian roulette modes and common/roulette.h's table are one: every
// RussianRouletteMode (but UNSPECIFIED) is the policy of the same name, with that policy's start
// depth, termination and depth cap when the job sends the mode alone (as the Python client does), and
// back; UNSPECIFIED is the default. A mode added on one side only fails here.
#include <gtest/gtest.h>

#include <cctype>
#include <string>

#include "wire/convert.h"

namespace epr {
namespace {

std::string lower_name(v1::RussianRouletteMode mode) {
  std::string name = v1::RussianRouletteMode_Name(mode).substr(sizeof "RUSSIAN_ROULETTE_MODE_" - 1);
  for (char& c : name) c = char(std::tolower(static_cast<unsigned char>(c)));
  return name;
}

TEST(RouletteProto, EveryModeIsTheNamedPolicyAndBack) {
  const auto* modes = v1::RussianRouletteMode_descriptor();
  size_t named = 0;
  for (int i = 0; i < modes->value_count(); ++i) {
    const auto mode = v1::RussianRouletteMode(modes->value(i)->number());
    if (mode == v1::RUSSIAN_ROULETTE_MODE_UNSPECIFIED) continue;
    const std::string name = lower_name(mode);
    SCOPED_TRACE(name);
    const std::optional<RussianRoulette> ours = roulette_named(name);
    ASSERT_TRUE(ours) << "no policy called " << name << " in common/roulette.cpp";
    ++named;
    v1::RussianRouletteSettings sent;
    sent.set_mode(mode);
    EXPECT_EQ(from_proto(sent), *ours);
    v1::RussianRouletteSettings back;
    to_proto(*ours, &back);
    EXPECT_EQ(back.mode(), mode);
    EXPECT_EQ(from_proto(back), *ours);
  }
  EXPECT_EQ(named, named_roulettes().size()) << "a policy of common/roulette.cpp has no RussianRouletteMode";
  EXPECT_EQ(from_proto(v1::RussianRouletteSettings{}), RussianRoulette::standard());
  EXPECT_EQ(RenderOptions{}.rr, RussianRoulette::standard());
}

TEST(RouletteProto, SentFieldsOverrideThePolicysOwn) {
  v1::RussianRouletteSettings sent;
  sent.set_mode(v1::RUSSIAN_ROULETTE_MODE_PAPER);
  sent.set_start_depth(3);
  sent.set_termination_probability(0.25f);
  sent.set_max_depth(40);
  const RussianRoulette r = from_proto(sent);
  EXPECT_EQ(r.mode, RussianRoulette::Mode::kPaper);
  EXPECT_EQ(r.start_depth, 3);
  EXPECT_FLOAT_EQ(r.termination, 0.25f);
  EXPECT_EQ(r.max_depth, 40);
}

}  // namespace
}  // namespace epr
