// The preview images of a job (the monitoring endpoint's /jobs/ID/preview/LAYER): PNGs of its
// layers, encoded from a running job's image copy or read from a finished job's result files.
#pragma once

#include <array>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "master/frame_state.h"

namespace epr {

/// combined (the image), pathtrace (path samples only), reprojection (L_rp), samples (M' heat map).
inline constexpr std::array<std::string_view, 4> kPreviewLayers = {"combined", "pathtrace", "reprojection", "samples"};
bool is_preview_layer(std::string_view layer);

/// The PNG of `layer`, or nullopt if the job has no such layer (reprojection layers without reprojection).
std::optional<std::vector<unsigned char>> encode_preview(const FrameImages& images, bool reprojects,
                                                         std::string_view layer);
/// The PNG of `layer` from the result files in a finished job's folder.
std::optional<std::vector<unsigned char>> result_preview(const std::string& dir, std::string_view layer);

}  // namespace epr
