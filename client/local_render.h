// The embedded render: progressive rounds of eye paths traced in this process, reprojected into the
// deep framebuffer, combined and skipped (DESIGN.md section 1), with the outputs written at the end.
#pragma once

#include <functional>
#include <nlohmann/json.hpp>
#include <string>

#include "common/image.h"
#include "common/render_options.h"
#include "master/frame_state.h"

namespace epr {

struct RoundProgress {
  int round = 0;        // 1-based
  double seconds = 0;   // since the render started
  double mean_spp = 0;  // mean over pixels of M + M'
  double min_spp = 0;
  double mean_mprime = 0;       // mean reprojected samples per pixel
  double pixels_active = 0;     // fraction of pixels that traced paths this round
  double eta_seconds = -1;      // -1 when unknown
  FrameState* frame = nullptr;  // render_local only: the frame after this round (e.g. to read images())
};

struct RenderOutputs {
  Image combined;      // the image: path samples and reprojected samples combined
  Image pathtrace;     // path samples only (sum / M)
  Image reprojection;  // L_rp per pixel (0 where M' = 0)
  Image path_count;    // M per pixel (1 channel)
  Image mprime;        // M' per pixel (1 channel)
  Image counts;        // M and M' per pixel (2 channels)
  nlohmann::json stats;
};

using ProgressCallback = std::function<void(const RoundProgress&)>;

/// Renders `opts` to completion in this process. Throws std::runtime_error (bad scene, no OSMesa, ...).
RenderOutputs render_local(const RenderOptions& opts, const ProgressCallback& progress = {});

/// Writes every result kind (common/result_kinds.h) as PREFIX + its suffix: PREFIX.exr, .png, .json,
/// .pathtrace.exr, .counts.exr (M, M') and, when reprojection ran, .reprojection.exr, .samples.exr (M')
/// and .samples.png (M' heat map).
void write_outputs(const std::string& prefix, const RenderOutputs& out);

}  // namespace epr
