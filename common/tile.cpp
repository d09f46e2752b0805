#include "common/tile.h"

#include <fmt/format.h>

#include <algorithm>

namespace epr {

std::vector<TileRect> make_tiles(int width, int height, int tile_size, bool taper) {
  std::vector<TileRect> tiles;
  const int rows = (height + tile_size - 1) / tile_size;
  const int small_rows = taper && tile_size >= 2 ? std::max(1, rows / 4) : 0;
  for (int row = 0, y = 0; y < height; ++row, y += tile_size) {
    const int y1 = std::min(height, y + tile_size);
    const int t = row >= rows - small_rows ? tile_size / 2 : tile_size;
    for (int ty = y; ty < y1; ty += t)
      for (int x = 0; x < width; x += t) tiles.push_back({x, ty, std::min(width, x + t), std::min(y1, ty + t)});
  }
  return tiles;
}

PathStats& PathStats::operator+=(const PathStats& o) {
  paths += o.paths;
  vertices += o.vertices;
  rays += o.rays;
  nonfinite_dropped += o.nonfinite_dropped;
  return *this;
}

std::optional<std::string> nonfinite_warning(uint64_t dropped, uint64_t paths) {
  if (!(double(dropped) > kNonFiniteWarnFraction * double(paths))) return std::nullopt;
  return fmt::format(
      "{} samples came out NaN or infinite and were dropped ({:.3g} per million of the {} paths traced): the image "
      "lacks their light; look for extreme values in the scene's lights (emission, sky image, sun)",
      dropped, 1e6 * double(dropped) / double(std::max<uint64_t>(paths, 1)), paths);
}

TileStats& TileStats::operator+=(const TileStats& o) {
  paths += o.paths;
  vertices_recorded += o.vertices_recorded;
  culled_frustum += o.culled_frustum;
  culled_facing += o.culled_facing;
  culled_glossy += o.culled_glossy;
  exact_occluded += o.exact_occluded;
  seconds += o.seconds;
  return *this;
}

}  // namespace epr
