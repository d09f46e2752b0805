// What a job costs the master in memory, estimated from its size and settings before anything is
// allocated, and the budget it is compared with: a frame that cannot fit is refused at submission
// (JobService.SubmitJob, `epr render`) with the memory it would need, not after seconds of setup.
//
// The estimate is the peak of a running job's own arrays (frame_state.h, reprojector.h, the round's
// plan and queued tiles, the image copies), not the process's baseline, the scene or its BVH. The
// job's peak is the larger of two phases:
//   the frame's build (rp and skip modes): the plane grid's 4-byte index of every texel, its 2-byte
//     copy (reprojectors narrow it when the frame shows fewer than 65535 planes), and the band
//     buffers of the builder (about kPlaneGridBandBytes, master/plane_grid_builder.h);
//   the rounds: per subpixel 16 B of accumulation (RGB float sums + a uint32 count) and the 2-byte
//     plane index (4 B on frames with 65535 planes or more, which the estimate does not foresee);
// plus, in both, per pixel: FrameState's arrays (21 B: path sums in float, M, M' in 32 bits, skip), a
// round's plan (1 B of skip flags; a tile's first sample index is one number when its pixels share
// it, as they do) and its tile results queued for the reprojection thread (sums and counts, 16 B),
// and one set of images (FrameImages, 32 B: path sums, L_rp, M and M'; combined and path-traced
// images are made from them when a file or preview is encoded. The preview copy a running job keeps
// is dropped before the next one, or the final images, are made);
// the result files are written after the frame is dropped (no peak of their own); the commit queue's
// vertices (kCommitQueueBytes: full while round 0 is traced during the build); with checkpoints: two
// 4 MiB chunks (a checkpoint streams from the live frame).
#pragma once

#include <algorithm>
#include <cstdint>
#include <optional>
#include <string>

#include "common/render_options.h"

namespace epr {

struct MemoryEstimate {
  uint64_t subpixel_bytes = 0;    // accumulation and plane index during the rounds, for the whole job
  uint64_t build_bytes = 0;       // the frame's build: the plane index in 4 and 2 bytes and the band buffers
  uint64_t pixel_bytes = 0;       // FrameState, the round's plan and tiles, the image copies
  uint64_t checkpoint_bytes = 0;  // with checkpoints
  uint64_t queue_bytes = 0;       // the commit queue's vertices
  /// The peak: the larger phase (build or rounds) plus what both hold.
  uint64_t total() const {
    return std::max(subpixel_bytes, build_bytes) + pixel_bytes + checkpoint_bytes + queue_bytes;
  }
};

/// Per texel while the frame is built: the plane index (4 B) and its narrowed copy (2 B).
inline constexpr uint64_t kBuildIndexBytesPerTexel = 4 + 2;
/// The builder's band buffers: about this many bytes (plane_grid_builder.h's kPlaneGridBandBytes), or
/// kBuildBandBytesPerTexel per texel of a grid smaller than one band.
inline constexpr uint64_t kBuildBandBytes = uint64_t(64) << 20;
inline constexpr uint64_t kBuildBandBytesPerTexel = 49;
/// The commit queue's vertices at its bound (JobManager's default max_queued_vertices, 8 Mi vertices
/// of 16 bytes on the wire).
inline constexpr uint64_t kCommitQueueBytes = (uint64_t(8) << 20) * 16;
/// A checkpoint's buffers: it writes the live frame a chunk at a time.
inline constexpr uint64_t kCheckpointBytes = uint64_t(8) << 20;

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
/// "1.93 GiB", "256.00 MiB", "12.50 KiB", "100 bytes": the largest binary unit the size reaches.
std::string format_byte_size(uint64_t bytes);

/// Why a job with these options does not fit `budget` bytes ("a 7680x4320 frame at S=4 needs 9.12 GiB
/// of master memory; the budget is 6.20 GiB"), or nullopt when it fits (or budget is 0: no limit).
/// `frames` > 1: a window run of that many such frames held at once, one commit queue between them.
std::optional<std::string> memory_budget_error(const RenderOptions& opts, bool checkpoints, uint64_t budget,
                                               uint32_t frames = 1);
/// What `frames` jobs with these options held at once need, one commit queue between them.
uint64_t frames_memory(const RenderOptions& opts, bool checkpoints, uint32_t frames);

}  // namespace epr
