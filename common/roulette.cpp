#include "common/roulette.h"

#include <algorithm>
#include <array>
#include <cctype>

namespace epr {
namespace {

const std::array<NamedRoulette, 6> kNamed = {{
    {"paper", RussianRoulette::paper()},
    {"albedo", RussianRoulette::albedo()},
    {"off", RussianRoulette::off(8)},
    {"throughput", RussianRoulette::throughput()},
    {"reuse", RussianRoulette::reuse()},
    {"auto", RussianRoulette::automatic()},
}};

}  // namespace

std::span<const NamedRoulette> named_roulettes() { return kNamed; }

RussianRoulette RussianRoulette::resolved(bool light_from_outside) const {
  if (mode != Mode::kAuto) return *this;
  RussianRoulette r = light_from_outside ? reuse() : albedo();
  if (start_depth >= 0) r.start_depth = start_depth;
  r.max_depth = max_depth;
  return r;
}

std::optional<RussianRoulette> roulette_named(std::string_view name) {
  for (const NamedRoulette& n : kNamed)
    if (std::equal(n.name.begin(), n.name.end(), name.begin(), name.end(),
                   [](char a, char b) { return a == std::tolower(static_cast<unsigned char>(b)); }))
      return n.rr;
  return std::nullopt;
}

std::string_view roulette_name(RussianRoulette::Mode mode) {
  for (const NamedRoulette& n : kNamed)
    if (n.rr.mode == mode) return n.name;
  return "unknown";
}

std::string roulette_names() {
  std::string s;
  for (const NamedRoulette& n : kNamed) s += (s.empty() ? "" : ", ") + std::string(n.name);
  return s;
}

}  // namespace epr
