// The preview images of a job (the monitoring endpoint's /api/v1/jobs/ID/image.png): PNGs of its
// layers, encoded from a running job's image copy or read from a finished job's result files.
//
// A preview is at most `max` pixels on its longest side (kPreviewMaxSide by default, ?max= on the
// route): a frame larger than that is box-filtered by the whole factor k = ceil(longest / max), each
// preview pixel the mean of the linear radiance of its k x k block of image pixels (the last row and
// column of blocks average the pixels they hold), so the aspect ratio is kept to within a pixel and
// a 3840 x 2160 frame previews at 960 x 540. Frames within the bound keep their full resolution.
// The full-resolution image stays available as the job's (partial) results (`epr get [--partial]`).
#pragma once

#include <array>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "common/image.h"
#include "master/frame_state.h"

namespace epr {

/// combined (the image), pathtrace (path samples only), reprojection (L_rp), samples (M' heat map).
inline constexpr std::array<std::string_view, 4> kPreviewLayers = {"combined", "pathtrace", "reprojection", "samples"};
bool is_preview_layer(std::string_view layer);

/// The default bound of a preview's longest side, and the range ?max= may ask for (it is rounded
/// down to a power of two so that a job's cached previews stay few).
inline constexpr int kPreviewMaxSide = 1024;
inline constexpr int kPreviewMinBound = 64;
inline constexpr int kPreviewMaxBound = 8192;

/// The bound ?max=`text` asks for: a decimal integer, clamped to [kPreviewMinBound, kPreviewMaxBound]
/// and rounded down to a power of two; nullopt if `text` is not a positive decimal integer.
std::optional<int> parse_preview_bound(std::string_view text);

/// What JobManager::preview_png caches a preview under: the layer at the default bound ("combined"),
/// "LAYER@MAX" at another ("combined@2048").
std::string preview_key(std::string_view layer, int max_side = kPreviewMaxSide);

/// The box filter's factor for a width x height frame under `max_side`: ceil(longest / max_side), >= 1.
int preview_factor(int width, int height, int max_side);
/// Each output pixel the mean of a k x k block of `img` (ceil(w / k) x ceil(h / k) pixels; the last
/// row and column average the pixels their blocks hold). k <= 1 returns a copy.
Image box_downscale(const Image& img, int k);

/// The PNG of the preview `key` (preview_key), or nullopt if the job has no such layer (reprojection
/// layers without reprojection) or the key is not one.
std::optional<std::vector<unsigned char>> encode_preview(const FrameImages& images, bool reprojects,
                                                         std::string_view key);
/// The PNG of the preview `key` from the result files in a finished job's folder.
std::optional<std::vector<unsigned char>> result_preview(const std::string& dir, std::string_view key);

}  // namespace epr
