#include "worker/tile_lease.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "common/limits.h"
#include "common/vertex_codec.h"
#include "wire/convert.h"

namespace epr {
namespace {

constexpr uint32_t kMaxSide = 16384;                            // JobSpec width / height range
constexpr uint32_t kMaxPathsPerPixel = 1u << 20;                // JobSpec target_spp range
constexpr int kMaxWindowCameras = 2 * limits::kFrameWindow.hi;  // K frames on each side
constexpr int kMaxDepth = 100000;                               // RenderOptions::validate's --max-depth range
constexpr uint32_t kMaxSubpixels = 16;                          // ReprojectionSettings.subpixels range

}  // namespace

std::optional<std::vector<uint8_t>> unpack_skip_bits(std::string_view bits, size_t n) {
  std::vector<uint8_t> skip;
  if (bits.empty()) return skip;
  if (bits.size() != (n + 7) / 8) return std::nullopt;
  skip.resize(n);
  for (size_t i = 0; i < n; ++i) skip[i] = (uint8_t(bits[i / 8]) >> (i % 8)) & 1u;
  return skip;
}

std::string pack_skip_bits(std::span<const uint8_t> skip) {
  std::string bits((skip.size() + 7) / 8, '\0');
  for (size_t i = 0; i < skip.size(); ++i)
    if (skip[i]) bits[i / 8] = char(uint8_t(bits[i / 8]) | uint8_t(1u << (i % 8)));
  return bits;
}

VertexFilter vertex_filter_for(const v1::RenderSettings& s) {
  VertexFilter f;
  const auto& r = s.reprojection();
  f.subpixels = r.has_subpixels() ? int(r.subpixels()) : 4;
  f.reproject_glossy = r.has_reproject_glossy() && r.reproject_glossy();
  if (s.mode() == v1::RENDER_MODE_PT)
    f.mode = VertexFilter::Mode::kNone;
  else if (r.method() == v1::REPROJECTION_METHOD_EXACT)
    f.mode = VertexFilter::Mode::kExact;
  else
    f.mode = VertexFilter::Mode::kCull;
  return f;
}

std::optional<std::string> check_render_settings(const v1::RenderSettings& s) {
  if (s.width() < 1 || s.height() < 1 || s.width() > kMaxSide || s.height() > kMaxSide)
    return fmt::format("image size {}x{} outside 1x1 .. {}x{}", s.width(), s.height(), kMaxSide, kMaxSide);
  if (s.mode() != v1::RENDER_MODE_PT && s.mode() != v1::RENDER_MODE_RP && s.mode() != v1::RENDER_MODE_SKIP)
    return fmt::format("unknown render mode {}", int(s.mode()));
  const auto& r = s.reprojection();
  if (s.mode() != v1::RENDER_MODE_PT) {
    if (r.method() < v1::REPROJECTION_METHOD_UNSPECIFIED || r.method() > v1::REPROJECTION_METHOD_EXACT)
      return fmt::format("unknown reprojection method {}", int(r.method()));
    const uint32_t S = r.has_subpixels() ? r.subpixels() : 4;
    if (S < 1 || S > kMaxSubpixels) return fmt::format("subpixels {} outside [1, {}]", S, kMaxSubpixels);
    // Exact-mode subpixel indices are uint32 over the whole S x S-per-pixel grid.
    if (uint64_t(S) * s.width() * S * s.height() > (uint64_t(1) << 32))
      return "the subpixel grid (S * width x S * height) exceeds 2^32 entries";
    try {
      VertexCodec codec(from_proto(s.codec_bounds()));
    } catch (const std::invalid_argument& e) {
      return fmt::format("codec_bounds: {}", e.what());
    }
  }
  if (auto err = from_proto(s.camera()).validate()) return fmt::format("camera: {}", *err);
  const auto& rr = s.russian_roulette();
  if (!v1::RussianRouletteMode_IsValid(rr.mode()))
    return fmt::format("unknown Russian roulette mode {}", int(rr.mode()));
  const RussianRoulette rrs = from_proto(rr);
  if (!std::isfinite(rrs.termination) || rrs.termination < 0 || rrs.termination >= 1)
    return "Russian roulette termination probability must be in [0, 1)";
  if (rrs.max_depth < 1 || rrs.max_depth > kMaxDepth)
    return fmt::format("max_depth {} outside [1, {}]", rrs.max_depth, kMaxDepth);
  if (!from_proto(s.sampler())) return fmt::format("unknown sampler {}", int(s.sampler()));
  return std::nullopt;
}

TileRequest LeasedTile::request() const { return strip(rect.y0, rect.y1); }

TileRequest LeasedTile::strip(int y0, int y1) const {
  const size_t w = size_t(rect.width());
  const size_t first = size_t(y0 - rect.y0) * w, n = size_t(y1 - y0) * w;
  TileRequest req;
  req.rect = {rect.x0, y0, rect.x1, y1};
  if (!skip.empty()) req.skip = std::span<const uint8_t>(skip).subspan(first, n);
  req.first_sample = std::span<const uint32_t>(first_sample).subspan(first, n);
  req.paths_per_pixel = paths_per_pixel;
  if (!paths.empty()) req.paths = std::span<const uint32_t>(paths).subspan(first, n);
  return req;
}

std::optional<std::string> unpack_tile_lease(const v1::TileLease& lease, LeasedTile* out) {
  const v1::RenderSettings& s = lease.settings();
  if (auto err = check_render_settings(s)) return err;
  const auto& r = lease.rect();
  if (!(r.x0() < r.x1() && r.y0() < r.y1() && r.x1() <= s.width() && r.y1() <= s.height()))
    return fmt::format("tile [{}, {}) x [{}, {}) is empty or outside the {}x{} image", r.x0(), r.x1(), r.y0(), r.y1(),
                       s.width(), s.height());
  const size_t n = size_t(r.x1() - r.x0()) * (r.y1() - r.y0());
  if (lease.paths_per_pixel() < 1 || lease.paths_per_pixel() > kMaxPathsPerPixel)
    return fmt::format("paths_per_pixel {} outside [1, {}]", lease.paths_per_pixel(), kMaxPathsPerPixel);
  auto skip = unpack_skip_bits(lease.skip_bits(), n);
  if (!skip)
    return fmt::format("skip_bits has {} bytes for {} pixels (want 0 or {})", lease.skip_bits().size(), n, (n + 7) / 8);
  std::vector<uint32_t> first;
  if (lease.first_sample_index_size() == 0) {
    first.assign(n, lease.uniform_first_sample_index());
  } else if (size_t(lease.first_sample_index_size()) == n) {
    first.assign(lease.first_sample_index().begin(), lease.first_sample_index().end());
  } else {
    return fmt::format("first_sample_index has {} entries for {} pixels", lease.first_sample_index_size(), n);
  }
  std::vector<uint32_t> paths(lease.pixel_paths().begin(), lease.pixel_paths().end());
  if (!paths.empty() && paths.size() != n)
    return fmt::format("pixel_paths has {} entries for {} pixels", paths.size(), n);
  for (size_t i = 0; i < paths.size(); ++i)
    if ((skip->empty() || !(*skip)[i]) && (paths[i] < 1 || paths[i] > lease.paths_per_pixel()))
      return fmt::format("pixel {}: pixel_paths {} outside [1, paths_per_pixel {}]", i, paths[i],
                         lease.paths_per_pixel());
  // The last sample index a pixel traces must fit the RNG key's 32 bits.
  const uint64_t last_paths = lease.paths_per_pixel() - 1;
  for (size_t i = 0; i < n; ++i)
    if (uint64_t(first[i]) + last_paths > UINT32_MAX)
      return fmt::format("pixel {}: sample index {} + {} paths overflows", i, first[i], lease.paths_per_pixel());

  out->rect = {int(r.x0()), int(r.y0()), int(r.x1()), int(r.y1())};
  out->skip = std::move(*skip);
  out->first_sample = std::move(first);
  out->paths_per_pixel = int(lease.paths_per_pixel());
  out->paths = std::move(paths);
  out->filter = vertex_filter_for(s);
  if (lease.window_cameras_size() > kMaxWindowCameras)
    return fmt::format("{} window cameras, at most {}", lease.window_cameras_size(), kMaxWindowCameras);
  for (int i = 0; i < lease.window_cameras_size(); ++i) {
    const CameraSpec c = from_proto(lease.window_cameras(i));
    if (auto err = c.validate()) return fmt::format("window camera {}: {}", i, *err);
    out->filter.window_cameras.emplace_back(c, int(s.width()), int(s.height()));
  }
  return std::nullopt;
}

std::optional<TileResult> render_leased_tile(const TileRenderer& renderer, const LeasedTile& tile,
                                             const std::function<bool()>& cancelled, int strip_paths) {
  const int w = tile.rect.width();
  const int64_t paths_per_row = std::max<int64_t>(1, int64_t(w) * tile.paths_per_pixel);
  const int rows = int(std::max<int64_t>(1, strip_paths / paths_per_row));
  TileResult out;
  out.rect = tile.rect;
  out.path_sum.reserve(size_t(tile.rect.pixel_count()));
  out.glossy_sum.reserve(size_t(tile.rect.pixel_count()));
  out.path_count.reserve(size_t(tile.rect.pixel_count()));
  for (int y = tile.rect.y0; y < tile.rect.y1; y += rows) {
    if (cancelled && cancelled()) return std::nullopt;
    renderer.render_into(tile.strip(y, std::min(tile.rect.y1, y + rows)), out);
  }
  return out;
}

}  // namespace epr
