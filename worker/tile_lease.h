// A TileLease (proto/epr/v1/worker_service.proto) as the tile renderer wants it: checked, skip mask
// unpacked, first sample indices expanded, vertex filter chosen from the render settings. Pure code
// (no gRPC, no Embree), so every rule of the lease is testable on its own.
//
// The worker trusts the master but not blindly: a lease that would make the renderer read out of
// bounds (tile outside the image, arrays of the wrong length), overflow a sample index or divide by
// zero is refused with a reason and given back, never traced.
#pragma once

#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "epr/v1/worker_service.pb.h"
#include "worker/tile_renderer.h"

namespace epr {

/// Skip mask bytes (per tile pixel, non-zero = skipped) from TileLease.skip_bits: pixel i is skipped
/// when bit (i % 8) of byte i / 8 is set, least significant bit first. Empty `bits`: none skipped.
/// Returns nullopt unless bits is empty or exactly ceil(n / 8) bytes. Unused high bits of the last
/// byte are ignored.
std::optional<std::vector<uint8_t>> unpack_skip_bits(std::string_view bits, size_t n);
/// The inverse: ceil(skip.size() / 8) bytes, unused high bits zero.
std::string pack_skip_bits(std::span<const uint8_t> skip);

/// What a render mode asks the tile renderer to record: nothing for PT, culled vertices for RP/SKIP
/// with the GL or CPU method (or unset), visibility-tested samples for EXACT.
VertexFilter vertex_filter_for(const v1::RenderSettings& settings);

/// Empty if the settings can be traced (image size, camera, roulette, subpixels, codec bounds);
/// otherwise the reason.
std::optional<std::string> check_render_settings(const v1::RenderSettings& settings);

/// One leased tile, unpacked.
struct LeasedTile {
  TileRect rect;
  std::vector<uint8_t> skip;           // per tile pixel, row-major; empty: none skipped
  std::vector<uint32_t> first_sample;  // per tile pixel, row-major (always n entries)
  int paths_per_pixel = 1;
  std::vector<uint32_t> paths;  // per tile pixel, row-major, each <= paths_per_pixel; empty: that many each
  VertexFilter filter;

  /// A request viewing this tile's arrays (valid while the LeasedTile lives).
  TileRequest request() const;
  /// The request for rows [y0, y1) of the tile (full width), for rendering in strips.
  TileRequest strip(int y0, int y1) const;
};

/// Checks `lease` (rect inside the image, array lengths, paths_per_pixel, sample index overflow,
/// settings) and unpacks it into `out`. Returns the reason if the lease is unusable.
std::optional<std::string> unpack_tile_lease(const v1::TileLease& lease, LeasedTile* out);

/// Renders the tile in strips of whole rows of about `strip_paths` paths, asking `cancelled` between
/// strips; nullopt if it said yes. Bit-identical to rendering the tile in one call (the renderer is deterministic per
/// pixel and sample, and strips are concatenated in row-major order); stats.seconds is the sum over strips.
std::optional<TileResult> render_leased_tile(const TileRenderer& renderer, const LeasedTile& tile,
                                             const std::function<bool()>& cancelled, int strip_paths = 4096);

}  // namespace epr
