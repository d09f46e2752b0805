// `epr render --single-process --trace-path X,Y,N`: the replay of one eye path. A path depends only on
// the scene, the render options, the seed and (pixel, sample index) (worker/path_tracer.h), so with the
// job's scene and options and the seed, pixel and sample a worker logged for a dropped non-finite
// sample (worker/nonfinite_log.h), this traces the same path again and prints it, NaN included.
#pragma once

#include <cstdint>
#include <cstdio>
#include <optional>
#include <string>

#include "common/render_options.h"

namespace epr {

struct PathRef {
  int x = 0, y = 0;
  uint32_t sample = 0;
};

/// "X,Y,N" (pixel column and row, sample index) into a PathRef; nullopt and `why` when it is not one.
std::optional<PathRef> parse_path_ref(const std::string& text, std::string* why);

/// Traces path `ref.sample` of pixel (ref.x, ref.y) as the single-process render of `opts` would and
/// writes it to `out`: a first line "seed S pixel X,Y sample N: radiance R G B" (with ", non-finite:
/// a render drops this sample" when it is NaN or infinite), a line with its vertex and ray counts, and
/// one line per recorded vertex x_n, n >= 2 (position, normal, radiance Le + R_n). Writes no file.
/// Throws std::invalid_argument for a pixel outside the image, and what loading the scene throws.
/// Returns whether the sample is finite.
bool trace_path(const RenderOptions& opts, const PathRef& ref, std::FILE* out);

}  // namespace epr
