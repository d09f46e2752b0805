// The CPU reprojector ("cpu"): the reference for the GL back-end and the fallback without OSMesa.
//
// Records are processed in chunks of 32768 (small enough for the chunk's records to stay in L2
// between the passes; ReprojectorSettings::batch_points is only the GL upload batch), each in two
// parallel (TBB) passes:
//   1. classify: every record's decision and target subpixel (reprojection_kernel.h), counts per
//      block; projection and facing first for a block of 2048, prefetching the deep-framebuffer
//      entries, then the plane tests, so that the random lookups overlap instead of stalling;
//   2. accumulate: the subpixel grid is split into row ranges, one task per range scans the batch's
//      targets and adds the radiance of those in its range -- no atomics, and every subpixel receives
//      its samples in input order, so sums are deterministic whatever the thread count. Cells are
//      prefetched a few targets ahead.
// Memory: the grid (16 bytes per subpixel), the compact deep framebuffer (4 bytes per texel plus the
// plane table) and 128 KiB of scratch.
#pragma once

#include <array>
#include <vector>

#include "master/reprojection_kernel.h"
#include "master/reprojector.h"

namespace epr {

class CpuReprojector final : public Reprojector {
 public:
  CpuReprojector(const Camera& camera, const DeepFramebuffer& dfb, const ReprojectorSettings& settings);

  void reproject(std::span<const VertexRecord> records) override;
  void reproject_packed(std::string_view packed, const VertexCodec& codec) override;
  void add_exact(std::span<const ExactSample> samples) override;
  ReprojectionCounts counts() const override { return counts_; }
  SubpixelAccumulation read() override;
  void downsample_pixels_into(PixelReprojection* out, std::span<const uint8_t> skip = {},
                              bool counts_only = false) override;
  void reset() override;
  void restore(const SubpixelAccumulation& acc, const ReprojectionCounts& counts) override;
  std::string_view backend() const override { return "cpu"; }

 private:
  struct Cell {
    float r = 0, g = 0, b = 0;
    uint32_t n = 0;
  };
  template <class Radiance>
  void accumulate(size_t n, const Radiance& radiance_of);
  void add_block_counts(const std::vector<std::array<uint32_t, 6>>& block_counts);

  ReprojectorSettings settings_;
  detail::KernelParams params_;
  detail::PlaneGrid grid_;
  int subpixels_;
  std::vector<Cell> cells_;
  std::vector<uint32_t> target_;  // per batch point: subpixel index or kNone
  std::vector<Vec3> position_;    // reproject_packed: per batch point, the decoded position of a candidate
  std::vector<Vec3> normal_;      // reproject_packed: ... and its decoded normal
  ReprojectionCounts counts_;
};

}  // namespace epr
