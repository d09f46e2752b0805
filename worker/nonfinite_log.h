// The log line a tile with dropped non-finite samples (worker/path_tracer.h: trace) leaves, so that
// the first of them can be replayed: its seed, pixel and sample index are all a path depends on
// (with the job's scene and options), and `epr render --single-process --seed S --trace-path X,Y,N`
// traces that one path again and prints it (client/trace_path.h).
//
// Not a line per sample, nor per tile: of the tiles with dropped samples a process renders, the 1st,
// 2nd, 4th, 8th, ... are logged (warn, logger "worker"), each line saying how many such tiles there
// have been, so a flood of NaNs costs a few dozen lines at most and the first one is always there.
#pragma once

#include <cstdint>
#include <string>

#include "common/tile.h"

namespace epr {

/// What one tile render saw: the first dropped sample and how many were dropped.
class NonFiniteTileLog {
 public:
  void add(int x, int y, uint32_t sample) {
    if (count_++ == 0) first_ = {x, y, sample};
  }
  uint64_t count() const { return count_; }
  /// Logs the tile (rect, the tracer's seed) if it dropped samples and its turn has come.
  void report(const TileRect& rect, uint64_t seed) const;

 private:
  struct Sample {
    int x = 0, y = 0;
    uint32_t sample = 0;
  };
  Sample first_;
  uint64_t count_ = 0;
};

/// The line: "N non-finite path samples dropped in tile [x0,x1)x[y0,y1) (tile K with such samples in
/// this process); the first: seed S, pixel X,Y, sample N; replay: epr render <the job's scene and
/// options> --single-process --seed S --trace-path X,Y,N".
std::string nonfinite_tile_line(const TileRect& rect, uint64_t dropped, uint64_t seed, int x, int y, uint32_t sample,
                                uint64_t tiles_so_far);

}  // namespace epr
