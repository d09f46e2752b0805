// What a job costs the master in memory, estimated from its size and settings before anything is
// allocated, and the budget it is compared with: a frame that cannot fit is refused at submission
// (JobService.SubmitJob, `epr render`) with the memory it would need, not after seconds of setup.
//
// The estimate is the peak of a running job's own arrays (frame_state.h, reprojector.h,
// result_files.h), not the process's baseline, the scene or its BVH:
//   per subpixel (S x S per pixel, rp and skip modes only):
//     16 B the reprojection accumulation (RGB float sums + a uint32 count),
//      4 B the compact deep framebuffer's plane index,
//     and while the deep framebuffer is built, its transient full records (position, normal,
//     plane offset, coverage, triangle: 33 B per texel) for the rows being built;
//   per pixel: FrameState's arrays (49 B: path sums in double, M, M', L_rp, skip), the result images
//     made at the end (FrameImages and the temporaries of encoding them, ~100 B) and the preview copy
//     a running job keeps (FrameImages, 44 B);
//   with checkpoints: a copy of the frame (accumulation and per-pixel arrays) and its encoding.
#pragma once

#include <cstdint>
#include <optional>
#include <string>

#include "common/render_options.h"

namespace epr {

struct MemoryEstimate {
  uint64_t subpixel_bytes = 0;    // accumulation and plane index, for the whole job
  uint64_t build_bytes = 0;       // the deep framebuffer build's transient records
  uint64_t pixel_bytes = 0;       // FrameState, result images, the preview copy
  uint64_t checkpoint_bytes = 0;  // with checkpoints
  uint64_t total() const { return subpixel_bytes + build_bytes + pixel_bytes + checkpoint_bytes; }
};

/// Bytes per deep framebuffer texel while it is built, and the most grid rows built at once (the
/// build goes band by band; a grid lower than this is built whole).
inline constexpr uint64_t kDeepFramebufferBuildBytesPerTexel = 33;
inline constexpr uint64_t kDeepFramebufferBuildRows = 1024;

/// The master memory of a job with these options (width, height, S, mode, reprojector).
MemoryEstimate estimate_job_memory(const RenderOptions& opts, bool checkpoints);

/// The machine's physical memory in bytes, or its cgroup's limit (memory.max) if lower; 0 if unknown.
uint64_t physical_memory_bytes();
/// The default budget: kDefaultBudgetFraction of physical_memory_bytes() (0 if unknown: no limit).
inline constexpr double kDefaultBudgetFraction = 0.8;
uint64_t default_memory_budget();

/// "8G", "512M", "1.5GiB", "100000" (bytes), suffixes K M G T (powers of 1024, optional "i", "B").
/// nullopt if malformed or zero.
std::optional<uint64_t> parse_byte_size(const std::string& text);
/// "1.93 GiB"-style text.
std::string format_gib(uint64_t bytes);

/// Why a job with these options does not fit `budget` bytes ("a 7680x4320 frame at S=4 needs 9.12 GiB
/// of master memory; the budget is 6.20 GiB"), or nullopt when it fits (or budget is 0: no limit).
std::optional<std::string> memory_budget_error(const RenderOptions& opts, bool checkpoints, uint64_t budget);

}  // namespace epr
