#include "worker/nonfinite_log.h"

#include <fmt/format.h>

#include <atomic>

#include "common/log.h"

namespace epr {

std::string nonfinite_tile_line(const TileRect& r, uint64_t dropped, uint64_t seed, int x, int y, uint32_t sample,
                                uint64_t tiles_so_far) {
  return fmt::format(
      "{} non-finite path samples dropped in tile [{},{})x[{},{}) (tile {} with such samples in this process); the "
      "first: seed {}, pixel {},{}, sample {}; replay: epr render <the job's scene and options> --single-process "
      "--seed {} --trace-path {},{},{}",
      dropped, r.x0, r.x1, r.y0, r.y1, tiles_so_far, seed, x, y, sample, seed, x, y, sample);
}

void NonFiniteTileLog::report(const TileRect& rect, uint64_t seed) const {
  if (count_ == 0) return;
  static std::atomic<uint64_t> tiles{0};
  const uint64_t n = tiles.fetch_add(1, std::memory_order_relaxed) + 1;
  if ((n & (n - 1)) != 0) return;  // the 1st, 2nd, 4th, 8th, ... tile
  logger("worker")->warn(nonfinite_tile_line(rect, count_, seed, first_.x, first_.y, first_.sample, n));
}

}  // namespace epr
