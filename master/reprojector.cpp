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

void Reprojector::downsample_pixels_into(PixelReprojection* out, std::span<const uint8_t>, bool) {
  *out = downsample(read());
}

void Reprojector::reproject_packed(std::string_view packed, const VertexCodec& codec) {
  constexpr size_t kBatch = 32768;  // records decoded at a time: bounded scratch memory
  std::vector<VertexRecord> records;
  const size_t n = packed.size() / VertexCodec::kPackedBytes;
  for (size_t off = 0; off < n; off += kBatch) {
    const size_t m = std::min(kBatch, n - off);
    records.clear();
    codec.decode_batch(packed.substr(off * VertexCodec::kPackedBytes, m * VertexCodec::kPackedBytes), &records);
    reproject(records);
  }
}

}  // namespace epr
