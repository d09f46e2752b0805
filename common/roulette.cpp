#include "common/roulette.h"

#include <algorithm>
#include <array>
#include <cctype>

namespace epr {
namespace {

const std::array<NamedRoulette, 5> kNamed = {{
    {"paper", RussianRoulette::paper()},
    {"albedo", RussianRoulette::albedo()},
    {"off", RussianRoulette::off(8)},
    {"throughput", RussianRoulette::throughput()},
    {"reuse", RussianRoulette::reuse()},
}};

}  // namespace

std::span<const NamedRoulette> named_roulettes() { return kNamed; }

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
