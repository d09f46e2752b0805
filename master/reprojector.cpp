// Shared pieces of the reprojectors and the back-end factory. See reprojector.h.
#include "master/reprojector.h"

#include "master/reprojection_image.h"

#include <cmath>
#include <stdexcept>
#include <string>
#include <unordered_map>

#include <fmt/format.h>

#include "master/cpu_reprojector.h"
#include "master/gl_reprojector.h"
#include "master/reprojection_kernel.h"

namespace epr {

uint32_t subpixel_index(float rx, float ry, int subpixels, int width, int height) {
  const float gx = rx * float(subpixels), gy = ry * float(subpixels);
  if (!(gx >= 0 && gx < float(subpixels * width) && gy >= 0 && gy < float(subpixels * height))) return UINT32_MAX;
  return uint32_t(gy) * uint32_t(subpixels * width) + uint32_t(gx);
}

namespace detail {

PlaneGrid make_plane_grid(const DeepFramebuffer& dfb) {
  PlaneGrid g;
  g.width = dfb.width;
  g.height = dfb.height;
  g.texel_plane.assign(dfb.texel_count(), PlaneGrid::kUncovered);
  struct Key {
    uint32_t b[4];
    bool operator==(const Key& o) const { return std::memcmp(b, o.b, 16) == 0; }
  };
  struct Hash {
    size_t operator()(const Key& k) const {
      uint64_t h = 0x9e3779b97f4a7c15ull;
      for (uint32_t v : k.b) h = (h ^ v) * 0xbf58476d1ce4e5b9ull;
      return size_t(h ^ (h >> 31));
    }
  };
  std::unordered_map<Key, uint32_t, Hash> index;
  Key last{};
  uint32_t last_plane = PlaneGrid::kUncovered;
  for (size_t t = 0; t < dfb.texel_count(); ++t) {
    if (!dfb.covered[t]) continue;
    const float v[4] = {dfb.normal[3 * t], dfb.normal[3 * t + 1], dfb.normal[3 * t + 2], dfb.plane_offset[t]};
    Key key;
    std::memcpy(key.b, v, 16);
    if (last_plane == PlaneGrid::kUncovered || !(key == last)) {
      auto [it, inserted] = index.try_emplace(key, uint32_t(index.size()));
      if (inserted) g.planes.insert(g.planes.end(), v, v + 4);
      last = key;
      last_plane = it->second;
    }
    g.texel_plane[t] = last_plane;
  }
  return g;
}

KernelParams make_kernel_params(const Camera& camera, int subpixels, float epsilon) {
  KernelParams k;
  k.eye = camera.eye();
  k.forward = camera.forward();
  k.right = camera.right();
  k.up = camera.up();
  k.tan_half_x = camera.tan_half_x();
  k.tan_half_y = camera.tan_half_y();
  k.width = float(camera.width());
  k.height = float(camera.height());
  k.s = float(subpixels);
  k.grid_w = float(subpixels * camera.width());
  k.grid_h = float(subpixels * camera.height());
  k.grid_wi = uint32_t(subpixels * camera.width());
  k.epsilon = epsilon;
  return k;
}

void validate_reprojector_inputs(const Camera& camera, const DeepFramebuffer& dfb, const ReprojectorSettings& s) {
  if (!(std::isfinite(s.epsilon) && s.epsilon >= 0))
    throw std::invalid_argument(fmt::format("reprojection epsilon {} must be finite and >= 0 (metres)", s.epsilon));
  if (dfb.subpixels < 1 || dfb.width != camera.width() * dfb.subpixels || dfb.height != camera.height() * dfb.subpixels)
    throw std::invalid_argument(fmt::format("deep framebuffer {}x{} (S={}) does not match the {}x{} camera", dfb.width,
                                            dfb.height, dfb.subpixels, camera.width(), camera.height()));
  const size_t n = dfb.texel_count();
  if (dfb.covered.size() != n || dfb.normal.size() != 3 * n || dfb.plane_offset.size() != n)
    throw std::invalid_argument("deep framebuffer arrays do not match its size");
  if (s.batch_points < 1024 || s.batch_points > (size_t(1) << 24))
    throw std::invalid_argument(fmt::format("batch_points {} outside [1024, 2^24]", s.batch_points));
  if (s.workgroup_size < 1 || s.workgroup_size > 1024 || s.workgroups < 1 || s.workgroups > 65535)
    throw std::invalid_argument("workgroup_size must be in [1, 1024] and workgroups in [1, 65535]");
}

}  // namespace detail

std::unique_ptr<Reprojector> make_reprojector(std::string_view backend, const Camera& camera, const DeepFramebuffer& dfb,
                                              const ReprojectorSettings& settings, GlContext* gl) {
  if (backend == "cpu") return std::make_unique<CpuReprojector>(camera, dfb, settings);
  if (backend == "gl") {
    if (gl) return std::make_unique<GlReprojector>(*gl, camera, dfb, settings);
    return std::make_unique<GlReprojector>(camera, dfb, settings);
  }
  throw std::invalid_argument(fmt::format("unknown reprojector back-end '{}' (expected 'gl' or 'cpu')", backend));
}

PixelReprojection Reprojector::downsample_pixels() { return downsample(read()); }

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
