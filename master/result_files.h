// A finished render's files (common/result_kinds.h), written the same way by the single-process
// render and the master: each to a temp file beside its place, renamed into place when complete.
#pragma once

#include <functional>
#include <nlohmann/json.hpp>
#include <string>

#include "common/image.h"
#include "common/result_kinds.h"
#include "master/frame_state.h"

namespace epr {

/// The heat map of M' (the samples PNG), scaled to the image's largest M'.
Image samples_heat_map(const Image& mprime);

/// Writes every kind that applies (the reprojection kinds only when `reprojects`) to
/// `path_of(kind)` (an empty path: not this kind), side by side. Throws what a write threw.
void write_results(const FrameImages& images, bool reprojects, const nlohmann::json& stats,
                   const std::function<std::string(const ResultKindInfo&)>& path_of);

/// The bytes of one kind's file, as write_results() would write it. EXR kinds are written to
/// `scratch_path` (a file name ending in the kind's extension) and read back; the file is removed.
std::string encode_result(const ResultKindInfo& kind, const FrameImages& images, const nlohmann::json& stats,
                          const std::string& scratch_path);

}  // namespace epr
