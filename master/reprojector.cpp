// What every reprojector shares: downsampling through a read-back, and packed vertices decoded in
// batches. See reprojector.h.
#include "master/reprojector.h"

#include <algorithm>
#include <cstdint>

namespace epr {

uint32_t subpixel_index(float rx, float ry, int subpixels, int width, int height) {
  const float gx = rx * float(subpixels), gy = ry * float(subpixels);
  if (!(gx >= 0 && gx < float(subpixels * width) && gy >= 0 && gy < float(subpixels * height))) return UINT32_MAX;
  return uint32_t(gy) * uint32_t(subpixels * width) + uint32_t(gx);
}

PixelReprojection Reprojector::downsample_pixels() {
  PixelReprojection out;
  downsample_pixels_into(&out);
  return out;
}

void Reprojector::downsample_pixels_into(PixelReprojection* out, std::span<const uint8_t>, DownsampleParts parts) {
  PixelReprojection all = downsample(read());
  if (parts != DownsampleParts::kRadiance) out->count = std::move(all.count);
  if (parts != DownsampleParts::kCounts) out->radiance = std::move(all.radiance);
}

void Reprojector::visit_cells(size_t max_cells, const std::function<void(std::span<const AccumulationCell>)>& visit) {
  const SubpixelAccumulation a = read();
  std::vector<AccumulationCell> chunk(std::min(max_cells, a.size()));
  for (size_t off = 0; off < a.size(); off += max_cells) {
    const size_t m = std::min(max_cells, a.size() - off);
    for (size_t k = 0; k < m; ++k) {
      const size_t i = off + k;
      chunk[k] = {a.sum[3 * i], a.sum[3 * i + 1], a.sum[3 * i + 2], a.count[i]};
    }
    visit({chunk.data(), m});
  }
}

void Reprojector::restore_cells(const std::function<void(std::span<AccumulationCell>)>& fill,
                                const ReprojectionCounts& counts) {
  SubpixelAccumulation a = read();  // the grid's size
  constexpr size_t kChunk = size_t(1) << 20;
  std::vector<AccumulationCell> chunk(std::min(kChunk, a.size()));
  try {
    for (size_t off = 0; off < a.size(); off += kChunk) {
      const size_t m = std::min(kChunk, a.size() - off);
      fill({chunk.data(), m});
      for (size_t k = 0; k < m; ++k) {
        const size_t i = off + k;
        a.sum[3 * i] = chunk[k].r;
        a.sum[3 * i + 1] = chunk[k].g;
        a.sum[3 * i + 2] = chunk[k].b;
        a.count[i] = chunk[k].n;
      }
    }
  } catch (...) {
    reset();
    throw;
  }
  restore(a, counts);
}

void Reprojector::reproject_packed(std::span<const std::string_view> parts, const VertexCodec& codec) {
  constexpr size_t kBatch = 32768;  // records decoded at a time: bounded scratch memory
  std::vector<VertexRecord> records;
  for (const std::string_view packed : parts) {
    const size_t n = packed.size() / VertexCodec::kPackedBytes;
    for (size_t off = 0; off < n; off += kBatch) {
      const size_t m = std::min(kBatch, n - off);
      records.clear();
      codec.decode_batch(packed.substr(off * VertexCodec::kPackedBytes, m * VertexCodec::kPackedBytes), &records);
      reproject(records);
    }
  }
}

}  // namespace epr
