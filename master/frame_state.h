// The per-job image state of a progressive render (DESIGN.md section 1): the M path samples per
// pixel, the reprojected subpixel accumulation, M' and the skip mask, round by round.
//
// Used in the same way by the in-process render and by the master's job manager: tile results are
// applied (add_paths, then reproject / add_exact for their vertices), and when every tile of the
// round is in, finish_round() downsamples, updates M' and the skip mask and opens the next round.
//
// Determinism: path sums are accumulated in float, one tile result per pixel per round, rounds in
// order, so M and the path sums do not depend on the order tiles arrive in. M' (counts) is
// order-independent; reprojected radiance sums agree to float rounding (GL adds atomically).
// Threading: not thread-safe. With the GL back-end every call must come from the thread the
// GlContext is current on (the master's reprojection thread).
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <span>
#include <string_view>
#include <vector>

#include "common/camera.h"
#include "common/image.h"
#include "common/render_options.h"
#include "common/scene.h"
#include "common/vertex_codec.h"
#include "common/vertex_record.h"
#include "master/combine_rule.h"
#include "master/reprojection_image.h"
#include "master/reprojector.h"

namespace epr {

class GlContext;
class SceneBvh;
namespace detail {
class EdgePixels;
}

struct FrameProgress {
  int round = 0;                // rounds finished
  double mean_spp = 0;          // mean over pixels of M + W M' (N_eff with --combine variance: the
                                // samples the skip rule counts)
  double min_spp = 0;           // min over pixels of the same
  double mean_paths = 0;        // mean M
  double mean_reprojected = 0;  // mean M'
  uint64_t pixels_active = 0;   // pixels that trace paths in the next round
  uint64_t pixels_skipped = 0;  // pixels with M + W M' >= P that trace no more (skip mode)
  uint64_t paths_traced = 0;    // sum of M
  uint64_t paths_skipped = 0;   // paths not traced because the pixel was skipped
};

/// A frame's images. FrameState::images() stores the path sums and leaves `combined` and `pathtrace`
/// empty (32 bytes per pixel instead of 44): combined_image() and pathtrace_image() make them, bit for
/// bit as from the frame's arrays while M' < 2^24 (the count images are floats). A set filled the
/// other way (combined and pathtrace given, path_sum empty) serves them as they are.
struct FrameImages {
  Image combined;   // (path_sum + W M' L_rp) / (M + W M'), or empty
  Image pathtrace;  // path_sum / M, or empty
  Image path_sum;   // the RGB sum of each pixel's M path samples, or empty
  // The part of path_sum that is not combined with reprojected samples (PathTracer::trace's `glossy`:
  // glossy lobes at the first vertex), added as glossy_sum / M; empty where nothing is glossy.
  Image glossy_sum;
  Image reprojection;              // L_rp (empty without reprojection)
  Image path_count;                // M, one channel
  Image reprojected;               // M', one channel
  float reprojected_weight = 1.f;  // W (RenderOptions::reprojected_weight), for combined_image()
  // The variance combination's estimate of each pixel's part without glossy_sum (master/combine_rule.h
  // combine_halves), RGB, in place of the fixed rule's; empty for the fixed rule.
  Image cross_combined;
};

/// path_sum / M per pixel (0 where M = 0), or the stored image.
Image pathtrace_image(const FrameImages& images);
/// (path_sum - G + W M' L_rp) / (M + W M') + G / M per pixel (combine_pixel; G the glossy_sum, 0
/// without one), or cross_combined + G / M where that is given; the path-traced
/// image without reprojection, or the stored image.
Image combined_image(const FrameImages& images);

/// Everything a FrameState holds after a finished round, for checkpoints: restoring it into a
/// FrameState made for the same options, camera and scene continues the render exactly (the deep
/// framebuffer is rebuilt from the scene; M' and L_rp continue from the subpixel accumulation).
struct FrameSnapshot {
  int width = 0, height = 0;
  std::vector<float> path_sum;       // 3 per pixel (checkpoint files hold them as doubles)
  std::vector<float> glossy_sum;     // 3 per pixel, the glossy part of path_sum (FrameImages::glossy_sum)
  std::vector<uint32_t> path_count;  // M
  std::vector<uint32_t> mprime;      // M' as of the last downsample (checkpoint files hold 64 bits)
  std::vector<float>
      reprojected;  // empty (L_rp is downsampled when needed); older checkpoints' 3 per pixel are ignored
  std::vector<uint8_t> skip;
  // The variance combination's (empty for the fixed rule): B, the scatter of each pixel's batch
  // means per half (2 per pixel: rounds of even and odd index, combine_rule.h), M'_eff as of the last
  // downsample, and the even rounds' part of path_sum - glossy_sum (3 per pixel).
  std::vector<float> path_m2;
  std::vector<float> reprojected_effective;
  std::vector<float> path_half_sum;
  int paths_done = 0;
  bool done = false;
  FrameProgress progress;
  double seconds_reprojecting = 0, seconds_downsampling = 0;
  bool has_accumulation = false;  // false for path tracing (no reprojector)
  SubpixelAccumulation accumulation;
  ReprojectionCounts counts;
  // Instead of accumulation.sum and .count (then empty; width, height and subpixels still set): the
  // cells read on demand, e.g. from a checkpoint file -- cells(first, out) fills `out` with the cells
  // from subpixel `first` on; throws (CheckpointError) if the source turns out damaged.
  std::function<void(size_t first, std::span<AccumulationCell> out)> cells;
};

/// A FrameState's state as of now, by reference (FrameState::view()), for checkpoints written
/// without copying it: valid until the FrameState changes. The same fields as FrameSnapshot.
struct FrameView {
  int width = 0, height = 0;
  std::span<const float> path_sum;
  std::span<const float> glossy_sum;
  std::span<const uint32_t> path_count;
  std::span<const uint32_t> mprime;
  std::span<const float> reprojected;  // empty (FrameSnapshot::reprojected)
  std::span<const uint8_t> skip;
  std::span<const float> path_m2;
  std::span<const float> reprojected_effective;
  std::span<const float> path_half_sum;
  int paths_done = 0;
  bool done = false;
  FrameProgress progress;
  double seconds_reprojecting = 0, seconds_downsampling = 0;
  bool has_accumulation = false;
  int grid_width = 0, grid_height = 0, subpixels = 0;  // the accumulation's
  ReprojectionCounts counts;
  /// Visits the accumulation's cells in subpixel order, spans of at most max_cells (Reprojector::visit_cells).
  std::function<void(size_t max_cells, const std::function<void(std::span<const AccumulationCell>)>&)> visit_cells;
};

/// A view of a snapshot (its accumulation converted to cells a span at a time, or taken from
/// `cells`); valid while the snapshot lives.
FrameView view_of(const FrameSnapshot& snapshot);

/// M and M' per pixel as one 2-channel image (the counts result).
Image counts_image(const FrameImages& images);

/// Seconds left for a render at `spp` that took `seconds` for the rounds in `p`: the paths still to
/// trace by the pixels that are still active, at the pace per path so far. An upper bound when
/// skipping (pixels keep dropping out), never counting skipped pixels. 0 if nothing is left.
double eta_seconds(const FrameProgress& p, int spp, double seconds);

class FrameState {
 public:
  /// `scene` supplies the triangles of the deep framebuffer (rp / skip modes only). `gl` is the
  /// context for the "gl" reprojector and for rasterising the deep framebuffer of either back-end;
  /// when null, both use a context of their own (the deep framebuffer: the CPU builder without OSMesa).
  /// `bvh`, if given, is `scene`'s BVH shared with its other users (common/scene_bvh.h), which the
  /// edge pixels' rays use (built now unless it was); else they build one of their own.
  FrameState(const RenderOptions& opts, const Camera& camera, const Scene& scene, GlContext* gl = nullptr,
             const SceneBvh* bvh = nullptr);
  ~FrameState();

  /// The path samples of one tile: sums and counts row-major over [x0, x1) x [y0, y1); `glossy` the
  /// sums' glossy parts (PathTracer::trace), the same size, or empty (0).
  void add_paths(int x0, int y0, int x1, int y1, std::span<const Vec3> sums, std::span<const uint32_t> counts,
                 std::span<const Vec3> glossy = {});
  void reproject(std::span<const VertexRecord> vertices);
  /// Vertices in their 16-byte wire form, quantised with the scene's bounds (VertexCodec): the same
  /// as reproject() of their decoded records.
  void reproject_packed(std::string_view packed);
  /// The same for the concatenation of `parts`, without copying them together.
  void reproject_packed(std::span<const std::string_view> parts);
  void add_exact(std::span<const ExactSample> samples);
  /// Frame windows weigh reprojected samples by the frame they were traced for (DESIGN.md "Frame
  /// windows"): a sample of this frame's own adds `units` to its subpixel's count, and M' counts in
  /// these units (the skip rule and the combination take W / units per unit; the counts image is in
  /// samples). 1 unless set, before any sample arrives; set_sample_weight() sets what the following
  /// reproject calls' samples add (a neighbour's: fewer units), until set back to count_unit().
  void set_count_unit(uint32_t units);
  uint32_t count_unit() const { return count_unit_; }
  void set_sample_weight(uint32_t units);
  /// Ends the round: M', skip mask and progress. Returns true if another round is needed.
  bool finish_round();

  bool done() const { return done_; }
  int round() const { return progress_.round; }
  /// Paths each active pixel traces in the next round (the schedule of round_paths(), landing
  /// exactly on P).
  int next_paths_per_pixel() const;
  /// Inputs of a tile for the next round: skip (1 = trace nothing) and the first sample index per pixel.
  void tile_inputs(int x0, int y0, int x1, int y1, std::vector<uint8_t>* skip,
                   std::vector<uint32_t>* first_sample) const;
  /// Paths of pixel (x, y) in the next round if it traces: k = next_paths_per_pixel(), or, with
  /// --path-budget in skip mode with the fixed rule, fewer where its counts say fewer reach the skip rule's target: the
  /// least n with M + n + d W M' >= P (and M + n >= min_paths), as M' only grows (DESIGN.md "Progressive rounds").
  int path_budget(int x, int y) const;
  /// path_budget() of every pixel of a tile, row-major; empty when each traces k (skipped ones aside).
  void tile_paths(int x0, int y0, int x1, int y1, std::vector<uint32_t>* paths) const;
  /// True if path_budget() can give a pixel fewer than k paths (--path-budget, skip, the fixed rule).
  bool budgets_paths() const;
  /// True if no pixel of the tile traces in the next round.
  bool tile_idle(int x0, int y0, int x1, int y1) const;

  const FrameProgress& progress() const { return progress_; }
  ReprojectionCounts counts() const;
  double seconds_reprojecting() const { return seconds_reprojecting_; }
  /// Part of seconds_reprojecting(): reading the accumulation back and downsampling it.
  double seconds_downsampling() const { return seconds_downsampling_; }
  bool reprojects() const { return reprojects_; }
  /// Where the constructor's time went (wall seconds): the deep framebuffer into the plane grid, the
  /// edge pixels, and the reprojector (its GL buffers and the grid's upload).
  struct BuildSeconds {
    double grid = 0, edge_pixels = 0, reprojector = 0;
  };
  const BuildSeconds& build_seconds() const { return build_seconds_; }
  /// Counts, percentages and timings as JSON (the statistics file of a render). `worker_culled`: the
  /// vertices the workers culled before sending; the percentages count them (ReprojectionOutcomes).
  nlohmann::json statistics(const RenderOptions& opts, uint64_t worker_culled) const;
  /// The state as of now (call between rounds); reads the accumulation back when reprojecting.
  FrameSnapshot save();
  /// The state as of now by reference (call between rounds), for a checkpoint written straight from
  /// it: nothing is copied; the accumulation is visited in place (GL: one band mapped at a time).
  FrameView view();
  /// Continues from `snapshot`. Throws std::invalid_argument (naming the mismatch) if it was not
  /// taken from a FrameState of the same size and reprojection set-up; the state is then unchanged.
  void restore(const FrameSnapshot& snapshot);
  /// The images as of the last finished round (L_rp and M' read back from the accumulation: L_rp of
  /// every pixel is downsampled here, it is not kept between calls). A skip round refreshes only the
  /// active pixels' M'; with `preview` the skipped pixels' M' stays as of the last round they were
  /// active in, without it every pixel's is brought up to date.
  FrameImages images(bool preview = false);
  /// images() for the end of a render, holding less at once: L_rp is downsampled, then the reprojector
  /// (accumulation and plane index) is released before the per-pixel images are made, and the path
  /// sums are moved out. Afterwards only progress(), counts(), reprojects() and statistics() answer.
  FrameImages release_images();

  int width() const { return width_; }
  int height() const { return height_; }
  const std::vector<uint32_t>& path_counts() const { return path_count_; }
  const std::vector<float>& path_sums() const { return path_sum_; }
  const std::vector<uint32_t>& reprojected_counts() const { return mprime_; }  // M', in count_unit()s
  /// The variance combination's half h of pixel p's path samples (combine_rule.h; h = 0: the rounds
  /// of even index, 1: odd): their sum without the glossy part, count and variance; the reprojected
  /// members are left empty. Only with --combine variance when reprojecting.
  CombineHalf path_half(size_t p, int h) const;

 private:
  // M' from the reprojector: every pixel, or (active_only) the pixels not skipped.
  void refresh_counts(bool active_only);
  // L_rp of every pixel (and v_rp with the variance combination), downsampled from the accumulation
  // (reprojecting frames only); with `counts_too` M' of every pixel is brought up to date on the way.
  PixelReprojection reprojected_radiance(bool counts_too);
  // The variance combination's estimate per pixel (FrameImages::cross_combined) from the state and
  // `rp`'s halves.
  Image cross_image(const PixelReprojection& rp) const;
  // The samples the skip rule counts for pixel p: M + d W M' (fixed) or N_eff with d M'_eff
  // (variance), d = diffuse_share(p).
  double pixel_samples(size_t p) const;
  // The share of pixel p's own estimate that reprojected samples improve: luminance of (path_sum -
  // glossy_sum) / path_sum in [0, 1]; 1 without a glossy part (DESIGN.md "Diffuse-share reprojection").
  double diffuse_share(size_t p) const;
  // W per count unit.
  float unit_weight() const { return opts_.reprojected_weight / float(count_unit_); }
  // References to the per-pixel arrays and scalars a snapshot holds, under the snapshot's names
  // (frame_state.cpp: frame_fields copies them between state, snapshot and view).
  struct Fields;
  Fields fields();
  bool variance_rule() const { return opts_.combine == CombineRule::kVariance; }
  // M and M' of every pixel as float images.
  void count_images(FrameImages* out) const;
  // The glossy sums as an image, when there are any.
  void glossy_images(FrameImages* out) const;
  // progress_'s path and sample counts (paths traced, mean M, M', M + M', min M + M') from the arrays.
  void update_sample_progress();
  size_t pixel(int x, int y) const { return size_t(y) * size_t(width_) + size_t(x); }

  RenderOptions opts_;
  int width_, height_;
  std::unique_ptr<Reprojector> reprojector_;
  // The pixels that take no reprojected samples (edge_pixels.h); null for exact mode and pt.
  std::unique_ptr<detail::EdgePixels> edge_pixels_;
  bool reprojects_ = false;
  ReprojectionCounts released_counts_;  // the reprojector's counts when release_images() let it go
  std::unique_ptr<VertexCodec> codec_;  // the wire's quantisation (scene bounds), when reprojecting
  std::vector<float> path_sum_;         // 3 per pixel
  std::vector<float> glossy_sum_;       // 3 per pixel, or empty while every pixel's is 0
  std::vector<uint32_t> path_count_;    // M
  std::vector<uint32_t> mprime_;        // M' as of the last downsample (L_rp is made when asked for)
  uint32_t count_unit_ = 1;             // what one of the frame's own reprojected samples counts
  bool reprojection_partial_ = false;   // the last downsample left skipped pixels' M' as they were
  std::vector<uint8_t> skip_;           // 1 = no more paths for this pixel
  bool lit_from_outside_ = false;       // the scene's lights, for the roulette `auto` resolves to (statistics)
  // The variance combination only (else empty): B per pixel and half, M'_eff as of the last
  // downsample, the even rounds' diffuse path sums (FrameSnapshot), the rounds a pixel with M paths
  // has traced in (rounds_at_[M], from the schedule), and the paths of the first r rounds that were
  // even rounds (even_paths_[r]).
  std::vector<float> path_m2_;
  std::vector<float> reprojected_effective_;
  std::vector<float> path_half_sum_;
  std::vector<uint16_t> rounds_at_;
  std::vector<uint32_t> even_paths_;
  int paths_done_ = 0;  // paths every active pixel has traced
  bool done_ = false;
  FrameProgress progress_;
  double seconds_reprojecting_ = 0;
  double seconds_downsampling_ = 0;
  BuildSeconds build_seconds_;
};

}  // namespace epr
