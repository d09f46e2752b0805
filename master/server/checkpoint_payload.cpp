// See checkpoint_payload.h.
#include "master/server/checkpoint_payload.h"

#include <algorithm>
#include <limits>
#include <stdexcept>
#include <type_traits>
#include <vector>

namespace epr::checkpoint_io {

namespace {
// Cells of the accumulation per span handed to the writer (4 MiB).
constexpr size_t kCellsPerSpan = size_t(1) << 18;
// The path sums are kept in float and written as doubles (the format's array of 8-byte values), a
// chunk at a time.
constexpr size_t kValuesPerChunk = size_t(1) << 16;

// Arrays held narrower in memory than in the file (path sums: float / double; M': uint32 / uint64),
// widened a chunk at a time on the way out and narrowed on the way in (counts saturate).
template <class Wide, class Narrow>
void put_widened(ByteWriter& w, std::span<const Narrow> v) {
  w.put<uint64_t>(v.size());
  std::vector<Wide> chunk(std::min(v.size(), kValuesPerChunk));
  for (size_t off = 0; off < v.size(); off += kValuesPerChunk) {
    const size_t m = std::min(kValuesPerChunk, v.size() - off);
    for (size_t k = 0; k < m; ++k) chunk[k] = Wide(v[off + k]);
    w.put_bytes(chunk.data(), m * sizeof(Wide));
  }
}

template <class Wide, class Narrow>
std::vector<Narrow> get_narrowed(ByteReader& r) {
  const uint64_t n = r.get<uint64_t>();
  if (n > r.remaining() / sizeof(Wide)) throw CheckpointError("malformed payload: an array runs past its end");
  std::vector<Narrow> v(n);
  std::vector<Wide> chunk(std::min<uint64_t>(n, kValuesPerChunk));
  for (uint64_t off = 0; off < n; off += kValuesPerChunk) {
    const size_t m = size_t(std::min<uint64_t>(kValuesPerChunk, n - off));
    r.get_bytes(chunk.data(), m * sizeof(Wide));
    for (size_t k = 0; k < m; ++k) {
      if constexpr (std::is_integral_v<Narrow>)
        v[size_t(off) + k] = Narrow(std::min<Wide>(chunk[k], Wide(std::numeric_limits<Narrow>::max())));
      else
        v[size_t(off) + k] = Narrow(chunk[k]);
    }
  }
  return v;
}
}  // namespace

void put(ByteWriter& w, const FrameProgress& p) {
  w.put<int32_t>(p.round);
  w.put(p.mean_spp);
  w.put(p.min_spp);
  w.put(p.mean_paths);
  w.put(p.mean_reprojected);
  w.put(p.pixels_active);
  w.put(p.pixels_skipped);
  w.put(p.paths_traced);
  w.put(p.paths_skipped);
}

FrameProgress get_progress(ByteReader& r) {
  FrameProgress p;
  p.round = r.get<int32_t>();
  p.mean_spp = r.get<double>();
  p.min_spp = r.get<double>();
  p.mean_paths = r.get<double>();
  p.mean_reprojected = r.get<double>();
  p.pixels_active = r.get<uint64_t>();
  p.pixels_skipped = r.get<uint64_t>();
  p.paths_traced = r.get<uint64_t>();
  p.paths_skipped = r.get<uint64_t>();
  return p;
}

void put(ByteWriter& w, const ReprojectionCounts& c) {
  for (uint64_t v : {c.accepted, c.occluded, c.backfacing, c.culled, c.not_diffuse, c.invalid, c.exact}) w.put(v);
}

ReprojectionCounts get_counts(ByteReader& r) {
  ReprojectionCounts c;
  for (uint64_t* v : {&c.accepted, &c.occluded, &c.backfacing, &c.culled, &c.not_diffuse, &c.invalid, &c.exact})
    *v = r.get<uint64_t>();
  return c;
}

void put(ByteWriter& w, const FrameView& f) {
  w.put<int32_t>(f.width);
  w.put<int32_t>(f.height);
  put_widened<double>(w, f.path_sum);
  w.put_vector(f.path_count);
  put_widened<uint64_t>(w, f.mprime);
  w.put_vector(f.reprojected);
  w.put_vector(f.skip);
  w.put_vector(f.path_m2);  // version 4
  w.put_vector(f.reprojected_effective);
  put_widened<double>(w, f.glossy_sum);  // version 5
  w.put_vector(f.path_half_sum);         // version 6
  w.put<int32_t>(f.paths_done);
  w.put<uint8_t>(f.done);
  put(w, f.progress);
  w.put(f.seconds_reprojecting);
  w.put(f.seconds_downsampling);
  w.put<uint8_t>(f.has_accumulation);
  if (f.has_accumulation) {
    w.put<int32_t>(f.grid_width);
    w.put<int32_t>(f.grid_height);
    w.put<int32_t>(f.subpixels);
    put(w, f.counts);
    // Version 3: the cells as the back-ends hold them, {float r, g, b; uint32 n} per subpixel in
    // subpixel order, written a span at a time straight from the accumulation.
    const uint64_t cells = uint64_t(f.grid_width) * uint64_t(f.grid_height);
    w.put<uint64_t>(cells);
    uint64_t written = 0;
    f.visit_cells(kCellsPerSpan, [&](std::span<const AccumulationCell> span) {
      w.put_bytes(span.data(), span.size_bytes());
      written += span.size();
    });
    if (written != cells) throw std::logic_error("the accumulation visited is not of the frame's grid");
  }
}

uint64_t get_frame_head(ByteReader& r, FrameSnapshot* f, uint32_t version) {
  f->width = r.get<int32_t>();
  f->height = r.get<int32_t>();
  f->path_sum = get_narrowed<double, float>(r);
  f->path_count = r.get_vector<uint32_t>();
  f->mprime = get_narrowed<uint64_t, uint32_t>(r);
  f->reprojected = r.get_vector<float>();
  f->skip = r.get_vector<uint8_t>();
  if (version >= 4) {
    f->path_m2 = r.get_vector<float>();
    f->reprojected_effective = r.get_vector<float>();
  }
  if (version >= 5) f->glossy_sum = get_narrowed<double, float>(r);
  if (version >= 6) f->path_half_sum = r.get_vector<float>();
  f->paths_done = r.get<int32_t>();
  f->done = r.get_bool();
  f->progress = get_progress(r);
  f->seconds_reprojecting = r.get<double>();
  f->seconds_downsampling = r.get<double>();
  f->has_accumulation = r.get_bool();
  if (!f->has_accumulation) return 0;
  SubpixelAccumulation& a = f->accumulation;
  a.width = r.get<int32_t>();
  a.height = r.get<int32_t>();
  a.subpixels = r.get<int32_t>();
  f->counts = get_counts(r);
  const uint64_t cells = r.get<uint64_t>();
  if (a.width < 0 || a.height < 0 || cells != uint64_t(a.width) * uint64_t(a.height))
    throw CheckpointError("malformed payload: the accumulation's size does not match its grid");
  if (cells > r.remaining() / sizeof(AccumulationCell))
    throw CheckpointError("malformed payload: the accumulation runs past its end");
  return cells;
}

FrameSnapshot get_frame(ByteReader& r, uint32_t version) {
  FrameSnapshot f;
  const uint64_t cells = get_frame_head(r, &f, version);
  if (f.has_accumulation) {
    SubpixelAccumulation& a = f.accumulation;
    a.sum.resize(3 * cells);
    a.count.resize(cells);
    std::vector<AccumulationCell> chunk(std::min<uint64_t>(cells, kCellsPerSpan));
    for (uint64_t off = 0; off < cells; off += chunk.size()) {
      const size_t m = size_t(std::min<uint64_t>(chunk.size(), cells - off));
      r.get_bytes(chunk.data(), m * sizeof(AccumulationCell));
      for (size_t k = 0; k < m; ++k) {
        const size_t i = size_t(off) + k;
        a.sum[3 * i] = chunk[k].r;
        a.sum[3 * i + 1] = chunk[k].g;
        a.sum[3 * i + 2] = chunk[k].b;
        a.count[i] = chunk[k].n;
      }
    }
  }
  return f;
}

}  // namespace epr::checkpoint_io
