// The CPU reprojector ("cpu"): the reference for the GL back-end and the fallback without OSMesa.
//
// Records are processed in chunks (32768 records per thread, at most 2^19; ReprojectorSettings::
// batch_points is only the GL upload batch), each in two parallel (TBB) passes:
//   1. classify, per block of 2048 records (small enough to stay in L2 between the block's passes):
//      every record's decision and target subpixel (reprojection_kernel.h) and the block's counts --
//      projection and facing first, prefetching the deep-framebuffer entries, then the plane tests,
//      so that the random lookups overlap instead of stalling; then the block's accepted records are
//      binned by owner (a counting sort of the block, each owner's records in their input order,
//      with their radiance);
//   2. accumulate, one task per owner: the subpixel grid is cut into stripes of 2^k consecutive
//      subpixels (16-32 stripes per owner), stripe j belonging to owner j mod T, T a power
//      of two >= 4x the threads (interleaved screen bands: every owner gets a share of every part of
//      the image, so a culled sky or a dense floor does not unbalance them). An owner reads its bin
//      of every block, in block order, and adds the radiance to its own cells -- no atomics, no two
//      tasks write the same memory, and every subpixel receives its samples in input order, so the
//      sums are those of the serial loop bit for bit, whatever the thread count. Cells are
//      prefetched a few records ahead.
// Calls of fewer than 32768 records (the master's one call per tile) and calls allowed one thread (the
// arena's concurrency capped by tbb::global_control) take the serial path: classify, then one
// in-order loop over the targets.
// Memory: the grid (16 bytes per subpixel), the compact deep framebuffer (2 bytes per texel when the
// plane table has fewer than 65535 entries, else 4, plus the table) and ~20 bytes of scratch per chunk record (44 with
// reproject_packed): 1.3-2.9 MiB at 2 threads, at most 10-22 MiB.
#pragma once

#include <array>
#include <vector>

#include "master/reprojection_kernel.h"
#include "master/reprojector.h"

namespace epr {

class CpuReprojector final : public Reprojector {
 public:
  CpuReprojector(const Camera& camera, const DeepFramebuffer& dfb, const ReprojectorSettings& settings);
  /// From the compact deep framebuffer (built for `settings`, see detail::validate_reprojector_inputs).
  CpuReprojector(const Camera& camera, detail::PlaneGrid grid, const ReprojectorSettings& settings);

  void reproject(std::span<const VertexRecord> records) override;
  using Reprojector::reproject_packed;
  void reproject_packed(std::span<const std::string_view> parts, const VertexCodec& codec) override;
  void add_exact(std::span<const ExactSample> samples) override;
  ReprojectionCounts counts() const override { return counts_; }
  SubpixelAccumulation read() override;
  void downsample_pixels_into(PixelReprojection* out, std::span<const uint8_t> skip = {},
                              DownsampleParts parts = DownsampleParts::kBoth) override;
  void reset() override;
  void restore(const SubpixelAccumulation& acc, const ReprojectionCounts& counts) override;
  void visit_cells(size_t max_cells, const std::function<void(std::span<const AccumulationCell>)>& visit) override;
  void restore_cells(const std::function<void(std::span<AccumulationCell>)>& fill,
                     const ReprojectionCounts& counts) override;
  size_t cell_count() const override { return cells_.size(); }
  std::string_view backend() const override { return "cpu"; }

 private:
  struct Cell {
    float r = 0, g = 0, b = 0;
    uint32_t n = 0;
  };
  struct Entry {  // an accepted record, binned by owner
    uint32_t target;
    float r, g, b;
  };
  struct Owners {        // the partition of the grid among accumulation tasks; tasks == 1: serial
    uint32_t shift = 0;  // stripe j = subpixels [j << shift, (j + 1) << shift)
    uint32_t mask = 0;   // owner of stripe j: j & mask
    size_t tasks = 1;
  };
  static constexpr uint16_t kNarrowUncovered = 0xffff;
  // The texel's plane-table entry (PlaneGrid::kUncovered if none), from whichever index is held.
  uint32_t plane_of(uint32_t texel) const {
    if (narrow_plane_.empty()) return grid_.texel_plane[texel];
    const uint16_t p = narrow_plane_[texel];
    return p == kNarrowUncovered ? detail::PlaneGrid::kUncovered : p;
  }
  void prefetch_plane(uint32_t texel) const {
    if (narrow_plane_.empty())
      __builtin_prefetch(&grid_.texel_plane[texel]);
    else
      __builtin_prefetch(&narrow_plane_[texel]);
  }
  Owners owners_for(size_t n) const;
  size_t chunk_for(const Owners& o);                    // records per chunk; sizes the scratch
  uint32_t* bin_counts(size_t block, const Owners& o);  // the block's zeroed per-owner counts, or null
  template <class Radiance>
  void bin_block(size_t block, size_t begin, size_t end, const Owners& o, const Radiance& radiance_of, bool counted);
  void accumulate_owned(size_t blocks, const Owners& o, uint32_t weight);
  template <class Radiance>
  void accumulate_serial(size_t n, const Radiance& radiance_of, uint32_t weight);
  void add_block_counts(const std::vector<std::array<uint32_t, 6>>& block_counts);

  ReprojectorSettings settings_;
  detail::KernelParams params_;
  detail::PlaneGrid grid_;              // its texel_plane is emptied when narrow_plane_ holds the index
  std::vector<uint16_t> narrow_plane_;  // per texel: the plane entry in 16 bits (0xffff: uncovered), or empty
  int subpixels_;
  std::vector<Cell> cells_;
  std::vector<uint32_t> target_;         // per batch point: subpixel index or kNone
  std::vector<Vec3> position_;           // reproject_packed: per batch point, the decoded position of a candidate
  std::vector<Vec3> normal_;             // reproject_packed: ... and its decoded normal
  std::vector<unsigned char> gathered_;  // reproject_packed: a chunk that spans several parts, copied together
  std::vector<Entry> binned_;            // per chunk record: its block's accepted records, grouped by owner
  std::vector<uint32_t> bin_start_;      // per block: tasks + 1 offsets of its owners' bins (from the block's start)
  ReprojectionCounts counts_;
};

}  // namespace epr
