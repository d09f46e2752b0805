// Reprojection of eye-path vertices into the subpixel grid (DESIGN.md section 1, paper 4.1-4.3).
//
// A Reprojector owns a per-subpixel accumulation (RGB radiance sum, sample count) over the grid of
// the deep framebuffer it was made with: S*W x S*H subpixels, subpixel index = sy * (S*W) + sx with
// integer subpixel coordinates sx, sy, y pointing DOWN (row 0 = top). Accumulation persists across
// calls (progressive rounds) until reset(). Memory is the grid plus one fixed-size upload batch
// (ReprojectorSettings::batch_points), independent of the number of points or rounds.
//
// Semantics of reproject(), identical in every back-end (see reprojection_kernel.h, mirrored by the
// GLSL in gl_reprojector_shaders.cpp), evaluated in this order per VertexRecord:
//   1. not diffuse (and reproject_glossy off)  -> counts.not_diffuse, skipped
//   2. non-finite position, normal or radiance  -> counts.invalid, skipped
//   3. Camera::project fails (not strictly in front of the eye) or the subpixel position
//      (rx * S, ry * S) lies outside [0, S*W) x [0, S*H)  -> counts.culled
//   4. dot(normal, eye - position) <= 0 (the point faces away from the camera on the side it was lit
//      from; records' normals point towards the previous path vertex)  -> counts.occluded (and
//      counts.backfacing): no light leaks through thin two-sided walls
//   5. texel uncovered, or |dot(position, N_t) - d_t| > epsilon, or (joint test on) the point is not
//      on a surface parallel to the texel's: |dot(normal, N_t)| < 0.5 (more than 60 degrees apart),
//      or it lies more than epsilon / 1024 beyond one of the texel's creases -- a plane seen by a
//      neighbouring texel, oriented towards the texel's own visible point (reprojection_kernel.h):
//      past the line where that surface meets the texel's plane, e.g. a floor running on under a thin
//      partition  -> counts.occluded
//   6. otherwise accepted: subpixel (sum += radiance, count += 1)  -> counts.accepted
// Exact mode (paper 4.3): add_exact() adds samples whose visibility a worker already decided with a
// ray; a sample with subpixel index outside the grid or non-finite radiance counts as invalid.
//
// Epsilon is absolute, in metres (default_epsilon = 3e-4 x scene bounding-box diagonal, the paper's
// 0.03 %). The plane test uses `<=`, so epsilon = 0 accepts a point only if its plane distance
// computes to exactly 0: guaranteed for points on axis-aligned planes (whose stored normal is exactly
// a unit axis and d exactly the coordinate, see deep_framebuffer.h); for tilted planes float rounding
// of dot(P, N) usually makes it non-zero, so epsilon = 0 rejects most of their points.
//
// Decisions and per-subpixel counts are bit-identical between the "gl" and "cpu" back-ends (same
// float operations, no FMA contraction: C++ is compiled with -ffp-contract=off, llvmpipe lowers
// ffma and the GLSL marks the arithmetic `precise`). Radiance sums agree to float rounding: the GL
// back-end adds with float atomics in an unspecified order; the CPU back-end adds in input order
// (deterministic for a given call sequence).
//
// Threading: a Reprojector is not thread-safe; call it from one thread. The GL back-end must be used
// on the thread its GlContext is current on (it checks and throws std::logic_error otherwise).
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string_view>
#include <vector>

#include "common/camera.h"
#include "common/math.h"
#include "common/vertex_codec.h"
#include "common/vertex_record.h"
#include "master/deep_framebuffer.h"
#include "master/reprojection_image.h"

namespace epr {

class GlContext;

/// One exact-mode sample: its visibility to the camera was decided by a ray on the worker.
/// `subpixel` = sy * (S*W) + sx (integer subpixel coordinates, y down) -- see subpixel_index().
struct ExactSample {
  uint32_t subpixel = 0;
  Vec3 radiance;  // linear RGB, W / (m^2 sr)
};
static_assert(sizeof(ExactSample) == 16);

/// The subpixel index of raster position (rx, ry) (pixels, y down) in a grid of S subpixels per
/// axis over a width x height image, or UINT32_MAX if outside [0, S*W) x [0, S*H). Same arithmetic
/// as the reprojectors: sx = rx * S, sy = ry * S, truncated.
uint32_t subpixel_index(float rx, float ry, int subpixels, int width, int height);

/// The paper's default: 0.03 % of the scene's bounding-box diagonal, in metres.
inline float default_epsilon(const Bounds3& scene_bounds) { return 3e-4f * scene_bounds.diagonal_length(); }

struct ReprojectorSettings {
  float epsilon = 0;              // plane-distance tolerance, metres (>= 0); see default_epsilon()
  bool reproject_glossy = false;  // also reproject records without the diffuse flag (biased: their
                                  // radiance depends on the view direction)
  bool joint_test = true;         // step 5's normal and crease tests (off: the plane test alone, as
                                  // in the paper; thin walls then leak at their joints)
  // GL upload batch: points per dispatch. Bounded memory: 2 batches of 36 bytes per point in
  // flight, and with several bands a staging batch (4.5 + 2.3 MiB at the default; larger batches
  // are no faster on llvmpipe, docs/BENCHMARKS.md section 8). The CPU back-end uses chunks of
  // 32768 points per thread instead.
  size_t batch_points = size_t(1) << 16;
  // GL compute tuning (ignored by "cpu"): invocations per workgroup and workgroups per dispatch
  // (a grid-stride loop covers the batch), and whether to prefetch the accumulation cache line with a
  // vector gather before the per-lane atomics (llvmpipe executes SSBO atomics lane by lane).
  int workgroup_size = 32;
  int workgroups = 16;
  bool prefetch = true;
  // GL: downsample at a round's end by mapping the accumulation and running the CPU downsample on it
  // (cheaper on llvmpipe, whose buffers are host memory) instead of a compute pass and a read-back.
  bool gl_map_downsample = true;
  // GL: at most this many subpixels per band of the accumulation (0: as many as GL's buffer limits
  // allow; see gl_reprojector.h, Limits). Tests lower it to get several bands on small frames.
  size_t gl_max_band_cells = 0;
  // GL: the shader's 32-bit per-invocation counters are folded into 64-bit host totals after this
  // many points (2^31 keeps every counter far from overflow; tests lower it).
  uint64_t counter_fold_points = uint64_t(1) << 31;
};

struct ReprojectionCounts {
  uint64_t accepted = 0;
  uint64_t occluded = 0;     // includes backfacing
  uint64_t backfacing = 0;   // occluded because the point faces away from the camera
  uint64_t culled = 0;       // behind the camera or outside the image
  uint64_t not_diffuse = 0;  // skipped: glossy vertex (reproject_glossy off)
  uint64_t invalid = 0;      // skipped: non-finite values; exact samples outside the grid
  uint64_t exact = 0;        // exact samples added
  uint64_t total() const { return accepted + occluded + culled + not_diffuse + invalid + exact; }
  ReprojectionCounts& operator+=(const ReprojectionCounts& o) {
    accepted += o.accepted;
    occluded += o.occluded;
    backfacing += o.backfacing;
    culled += o.culled;
    not_diffuse += o.not_diffuse;
    invalid += o.invalid;
    exact += o.exact;
    return *this;
  }
  bool operator==(const ReprojectionCounts&) const = default;
};

class Reprojector {
 public:
  virtual ~Reprojector() = default;
  /// Reprojects eye-path vertices (DESIGN.md: x_n, n >= 2) and accumulates the accepted ones.
  virtual void reproject(std::span<const VertexRecord> records) = 0;
  /// The same for vertices in their 16-byte wire form (VERTEX_ENCODING_PACKED16, a multiple of 16
  /// bytes; a trailing partial record is ignored): exactly reproject() of codec.decode() of each, in
  /// order -- same decisions, counts and sums. The default decodes in batches; the CPU back-end
  /// decodes in place, each field only when the vertex gets that far.
  void reproject_packed(std::string_view packed, const VertexCodec& codec) {
    reproject_packed(std::span<const std::string_view>(&packed, 1), codec);
  }
  /// The same for the concatenation of `parts` (several tiles' vertices in one call, without
  /// copying them together first), each a multiple of 16 bytes.
  virtual void reproject_packed(std::span<const std::string_view> parts, const VertexCodec& codec);
  /// Adds exact-mode samples directly to their subpixels.
  virtual void add_exact(std::span<const ExactSample> samples) = 0;
  virtual ReprojectionCounts counts() const = 0;
  /// A copy of the accumulation (GL: read back, synchronising with outstanding work).
  virtual SubpixelAccumulation read() = 0;
  /// L_rp and M' per pixel (reprojection_image.h's downsample of read()), computed where the
  /// accumulation lives so that a round's end does not copy the whole subpixel grid: GL maps its
  /// accumulation (or runs a compute pass and reads back only W x H pixels); the CPU back-end reads
  /// its cells in place.
  PixelReprojection downsample_pixels();
  /// The same into *out, for the pixels p with skip[p] == 0 only (all if `skip` is empty or *out is
  /// not W x H): the others keep their values. A skip-mode round needs M' only where pixels are still
  /// active, which late in a job is a small part of the image. `parts`: M' only (the skip decision
  /// needs no radiance) or L_rp only, the other as it was. The default computes both for every pixel.
  virtual void downsample_pixels_into(PixelReprojection* out, std::span<const uint8_t> skip = {},
                                      DownsampleParts parts = DownsampleParts::kBoth);
  /// Zeroes the accumulation and the counts.
  virtual void reset() = 0;
  /// Replaces the accumulation and the counts with `acc` (as read() returned it) and `counts` (as
  /// counts() returned them), e.g. from a checkpoint: reprojection then continues exactly as if
  /// the samples had been added to this reprojector. Throws std::invalid_argument if `acc` is not of
  /// this reprojector's grid (the state is then unchanged).
  virtual void restore(const SubpixelAccumulation& acc, const ReprojectionCounts& counts) = 0;
  /// Visits the accumulation in subpixel order (row-major, as read() lays it out) as consecutive spans
  /// of cells, none longer than `max_cells` (> 0), without copying the grid: the CPU back-end passes
  /// its cells in place, GL maps one band at a time (synchronising with outstanding work). For
  /// checkpoints written straight from the live accumulation. The spans are valid during the call
  /// only; `visit` must not call this reprojector. The default copies read() a span at a time.
  virtual void visit_cells(size_t max_cells, const std::function<void(std::span<const AccumulationCell>)>& visit);
  /// The counterpart of restore() in bounded memory: `fill` is called with consecutive spans of cells
  /// in subpixel order (at most ~1M cells each; together the whole grid) and writes the checkpoint's
  /// values into them; the counts become `counts`. If `fill` throws, the accumulation and the counts
  /// are reset (zero) and the exception propagates. The default fills a SubpixelAccumulation and calls
  /// restore().
  virtual void restore_cells(const std::function<void(std::span<AccumulationCell>)>& fill,
                             const ReprojectionCounts& counts);
  /// Subpixels of the grid (S*W x S*H).
  virtual size_t cell_count() const = 0;
  virtual std::string_view backend() const = 0;
  /// What each sample accepted by the following reproject() / reproject_packed() calls adds to its
  /// subpixel: `units` (>= 1) to the count and its radiance times `units` to the sum, so that a
  /// subpixel's mean weighs it by that (frame windows: a neighbouring frame's vertices count for less
  /// than the frame's own, DESIGN.md "Frame windows"). 1 by default; exact samples always add 1.
  virtual void set_sample_weight(uint32_t units) { sample_weight_ = units; }
  uint32_t sample_weight() const { return sample_weight_; }

 protected:
  uint32_t sample_weight_ = 1;
};

}  // namespace epr
