#include "common/result_kinds.h"

#include <array>

namespace epr {
namespace {

constexpr std::array<ResultKindInfo, 8> kKinds = {{
    {ResultKind::kExr, "exr", ".exr", "combined.exr", "image/x-exr", false},
    {ResultKind::kPng, "png", ".png", "combined.png", "image/png", false},
    {ResultKind::kJson, "json", ".json", "stats.json", "application/json", false},
    {ResultKind::kPathtrace, "pathtrace.exr", ".pathtrace.exr", "pathtrace.exr", "image/x-exr", false},
    {ResultKind::kCounts, "counts.exr", ".counts.exr", "counts.exr", "image/x-exr", false},
    {ResultKind::kReprojection, "reprojection.exr", ".reprojection.exr", "reprojection.exr", "image/x-exr", true},
    {ResultKind::kSamplesExr, "samples.exr", ".samples.exr", "samples.exr", "image/x-exr", true},
    {ResultKind::kSamplesPng, "samples.png", ".samples.png", "samples.png", "image/png", true},
}};

}  // namespace

std::span<const ResultKindInfo> result_kinds() { return kKinds; }

const ResultKindInfo& result_kind(ResultKind kind) {
  for (const auto& k : kKinds)
    if (k.kind == kind) return k;
  return kKinds[0];  // unreachable: every enumerator has a row
}

}  // namespace epr
