#include "common/sampler.h"

namespace epr {

const char* to_string(SamplerKind k) { return k == SamplerKind::kIndependent ? "independent" : "sobol-burley"; }

std::optional<SamplerKind> parse_sampler(std::string_view name) {
  if (name == "sobol-burley") return SamplerKind::kSobolBurley;
  if (name == "independent") return SamplerKind::kIndependent;
  return std::nullopt;
}

}  // namespace epr
