#include "master/frame_state.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <stdexcept>
#include <string>

#include "common/check.h"
#include "common/log.h"
#include "common/scene_bvh.h"
#include "master/combine_rule.h"
#include "master/deep_framebuffer.h"
#include "master/edge_pixels.h"
#include "master/gl_context.h"
#include "master/make_reprojector.h"
#include "master/plane_grid_builder.h"
#include "master/reprojection_outcomes.h"

namespace epr {
namespace {

using Clock = std::chrono::steady_clock;

// Luminance of an RGB sum, in double (the variance combination's moments).
double luminance_of(double r, double g, double b) { return 0.2126 * r + 0.7152 * g + 0.0722 * b; }

// Adds the time spent in a scope to a counter.
class ScopedTimer {
 public:
  explicit ScopedTimer(double* total) : total_(total), start_(Clock::now()) {}
  ~ScopedTimer() { *total_ += std::chrono::duration<double>(Clock::now() - start_).count(); }

 private:
  double* total_;
  Clock::time_point start_;
};

// Copies one field: a vector or a span into a span (a view of it) or into a vector (a copy), or a value.
template <class To, class From>
void copy_field(To& to, const From& from) {
  if constexpr (requires { to = std::span(from); }) {
    to = std::span(from);
  } else if constexpr (requires { to.assign(from.begin(), from.end()); }) {
    to.assign(from.begin(), from.end());
  } else {
    to = from;
  }
}

}  // namespace

// The per-pixel arrays and scalars of a frame, one list for save(), view(), view_of() and restore():
// to.f = from.f for each (FrameSnapshot, FrameView or FrameState::Fields on either side).
template <class To, class From>
void frame_fields(To& to, const From& from) {
  copy_field(to.path_sum, from.path_sum);
  copy_field(to.glossy_sum, from.glossy_sum);
  copy_field(to.path_count, from.path_count);
  copy_field(to.mprime, from.mprime);
  copy_field(to.skip, from.skip);
  copy_field(to.path_m2, from.path_m2);
  copy_field(to.reprojected_effective, from.reprojected_effective);
  copy_field(to.path_half_sum, from.path_half_sum);
  copy_field(to.paths_done, from.paths_done);
  copy_field(to.done, from.done);
  copy_field(to.progress, from.progress);
  copy_field(to.seconds_reprojecting, from.seconds_reprojecting);
  copy_field(to.seconds_downsampling, from.seconds_downsampling);
}

struct FrameState::Fields {
  std::vector<float>& path_sum;
  std::vector<float>& glossy_sum;
  std::vector<uint32_t>& path_count;
  std::vector<uint32_t>& mprime;
  std::vector<uint8_t>& skip;
  std::vector<float>& path_m2;
  std::vector<float>& reprojected_effective;
  std::vector<float>& path_half_sum;
  int& paths_done;
  bool& done;
  FrameProgress& progress;
  double& seconds_reprojecting;
  double& seconds_downsampling;
};

FrameState::Fields FrameState::fields() {
  return {path_sum_,
          glossy_sum_,
          path_count_,
          mprime_,
          skip_,
          path_m2_,
          reprojected_effective_,
          path_half_sum_,
          paths_done_,
          done_,
          progress_,
          seconds_reprojecting_,
          seconds_downsampling_};
}

double eta_seconds(const FrameProgress& p, int spp, double seconds) {
  if (p.paths_traced == 0 || p.pixels_active == 0) return 0;
  // Active pixels have all traced the same number of paths, at least the mean over all pixels.
  const double paths_left = double(p.pixels_active) * std::max(0.0, double(spp) - p.mean_paths);
  return seconds / double(p.paths_traced) * paths_left;
}

FrameState::FrameState(const RenderOptions& opts, const Camera& camera, const Scene& scene, GlContext* gl,
                       const SceneBvh* bvh)
    : opts_(opts),
      width_(opts.width),
      height_(opts.height),
      path_sum_(size_t(opts.width) * size_t(opts.height) * 3, 0.f),
      path_count_(size_t(opts.width) * size_t(opts.height), 0),
      mprime_(size_t(opts.width) * size_t(opts.height), 0),
      skip_(size_t(opts.width) * size_t(opts.height), 0),
      lit_from_outside_(lit_from_outside(scene.lighting, scene.lights)) {
  if (camera.width() != width_ || camera.height() != height_)
    throw std::invalid_argument("camera and frame sizes differ");
  if (opts.mode != RenderMode::kPathTrace) {
    ScopedTimer t(&seconds_reprojecting_);
    ReprojectorSettings rs;
    rs.epsilon = opts.epsilon * scene.bounds().diagonal_length();
    rs.reproject_glossy = opts.reproject_glossy;
    rs.joint_test = opts.joint_test;
    // Exact mode decides visibility with rays on the workers; the accumulation is the same, so the
    // CPU back-end (no GL needed) holds it.
    // The deep framebuffer is built band by band straight into the compact plane grid, by the same
    // builder whatever the back-end: the GL rasteriser where OSMesa is there (on `gl`, else on a
    // private context), the CPU builder only without it. The two builders pick different triangles
    // where an edge passes through a texel centre (deep_framebuffer.h); with one builder the GL and
    // CPU back-ends, whose kernels agree bit for bit, decide every vertex alike.
    const bool use_gl = opts.reproject == ReprojectMethod::kGl;
    const float tolerance = rs.epsilon * detail::kCreaseToleranceFraction;
    detail::PlaneGrid grid;
    const auto grid_start = Clock::now();
    try {
      grid = gl ? detail::build_plane_grid(scene, camera, opts.subpixels, tolerance, rs.joint_test, gl)
                : detail::build_plane_grid_any(scene, camera, opts.subpixels, tolerance, rs.joint_test);
    } catch (const std::runtime_error& e) {
      // What this GL cannot rasterise (more triangles than its buffer textures hold) the CPU builder
      // can; only the GL back-end needs GL.
      if (use_gl) throw;
      logger("master")->info("deep framebuffer built on the CPU: {}", e.what());
      grid = detail::build_plane_grid(scene, camera, opts.subpixels, tolerance, rs.joint_test, nullptr);
    }
    build_seconds_.grid = std::chrono::duration<double>(Clock::now() - grid_start).count();
    // Exact mode's visibility rays have no discretisation: its edge pixels keep their samples.
    if (opts.reproject != ReprojectMethod::kExact && opts.edge_pixels) {
      detail::CoherentRays rays;
      if (bvh)
        rays = [b = &bvh->bvh()](std::span<const Ray> r, std::span<const float> tnear, std::span<Hit> hits) {
          b->intersect_coherent(r, tnear, hits);
        };
      ScopedTimer edge_timer(&build_seconds_.edge_pixels);
      edge_pixels_ = std::make_unique<detail::EdgePixels>(grid, camera, rs.epsilon, &scene, rays);
    }
    ScopedTimer reprojector_timer(&build_seconds_.reprojector);
    reprojector_ = make_reprojector(use_gl ? "gl" : "cpu", camera, std::move(grid), rs, gl);
    reprojects_ = true;
    codec_ = std::make_unique<VertexCodec>(scene.bounds());
  }
  if (variance_rule() && reprojector_) {
    path_m2_.assign(2 * path_count_.size(), 0.f);
    reprojected_effective_.assign(path_count_.size(), 0.f);
    path_half_sum_.assign(path_sum_.size(), 0.f);
    // rounds_at_[M]: the rounds of the schedule whose paths add up to at most M.
    rounds_at_.assign(size_t(opts.spp) + 1, 0);
    even_paths_.assign(1, 0);
    int done = 0, rounds = 0;
    while (done < opts.spp) {
      const int k = round_paths(opts, done);
      if (k <= 0) break;
      for (int m = done + 1; m < done + k; ++m) rounds_at_[size_t(m)] = uint16_t(rounds);
      even_paths_.push_back(even_paths_.back() + (rounds % 2 == 0 ? uint32_t(k) : 0u));
      done += k;
      rounds_at_[size_t(done)] = uint16_t(++rounds);
    }
  }
  progress_.pixels_active = uint64_t(width_) * uint64_t(height_);
}

FrameState::~FrameState() = default;

void FrameState::add_paths(int x0, int y0, int x1, int y1, std::span<const Vec3> sums, std::span<const uint32_t> counts,
                           std::span<const Vec3> glossy) {
  const size_t n = size_t(x1 - x0) * size_t(y1 - y0);
  if (x0 < 0 || y0 < 0 || x1 > width_ || y1 > height_ || x0 >= x1 || y0 >= y1 || sums.size() != n ||
      counts.size() != n || (!glossy.empty() && glossy.size() != n))
    throw std::invalid_argument("tile outside the frame or with the wrong number of pixels");
  if (glossy_sum_.empty() && std::any_of(glossy.begin(), glossy.end(), [](const Vec3& g) { return !is_black(g); }))
    glossy_sum_.assign(path_sum_.size(), 0.f);
  size_t i = 0;
  for (int y = y0; y < y1; ++y)
    for (int x = x0; x < x1; ++x, ++i) {
      const size_t p = pixel(x, y);
      if (!path_m2_.empty() && counts[i] > 0) {
        // The batch joins the half of its round's parity: its scatter B_h and (even rounds) the half's sum.
        const int h = rounds_at_[std::min<size_t>(path_count_[p], rounds_at_.size() - 1)] & 1;
        const CombineHalf half = path_half(p, h);
        const Vec3 batch = glossy.empty() ? sums[i] : sums[i] - glossy[i];
        float& m2 = path_m2_[2 * p + size_t(h)];
        m2 = float(add_batch(m2, luminance_of(half.path_sum.x, half.path_sum.y, half.path_sum.z), uint32_t(half.paths),
                             luminance_of(batch.x, batch.y, batch.z), counts[i]));
        if (h == 0) {
          path_half_sum_[3 * p + 0] += batch.x;
          path_half_sum_[3 * p + 1] += batch.y;
          path_half_sum_[3 * p + 2] += batch.z;
        }
      }
      path_sum_[3 * p + 0] += sums[i].x;
      path_sum_[3 * p + 1] += sums[i].y;
      path_sum_[3 * p + 2] += sums[i].z;
      path_count_[p] += counts[i];
      if (!glossy_sum_.empty() && !glossy.empty()) {
        glossy_sum_[3 * p + 0] += glossy[i].x;
        glossy_sum_[3 * p + 1] += glossy[i].y;
        glossy_sum_[3 * p + 2] += glossy[i].z;
      }
    }
}

void FrameState::reproject(std::span<const VertexRecord> vertices) {
  if (!reprojector_ || vertices.empty()) return;
  ScopedTimer t(&seconds_reprojecting_);
  reprojector_->reproject(vertices);
}

void FrameState::reproject_packed(std::string_view packed) {
  if (packed.empty()) return;  // most tiles of exact mode and of decoded vertices: no call, no timer
  reproject_packed(std::span<const std::string_view>(&packed, 1));
}

void FrameState::reproject_packed(std::span<const std::string_view> parts) {
  if (!reprojector_ || parts.empty()) return;
  ScopedTimer t(&seconds_reprojecting_);
  reprojector_->reproject_packed(parts, *codec_);
}

void FrameState::add_exact(std::span<const ExactSample> samples) {
  if (!reprojector_ || samples.empty()) return;
  ScopedTimer t(&seconds_reprojecting_);
  reprojector_->add_exact(samples);
}

void FrameState::set_count_unit(uint32_t units) {
  count_unit_ = units;
  set_sample_weight(units);
}

void FrameState::set_sample_weight(uint32_t units) {
  if (reprojector_) reprojector_->set_sample_weight(units);
}

void FrameState::refresh_counts(bool active_only) {
  if (!reprojector_) return;
  ScopedTimer t(&seconds_reprojecting_);
  ScopedTimer d(&seconds_downsampling_);
  PixelReprojection pr;
  pr.count = std::move(mprime_);
  pr.statistics = variance_rule();
  pr.effective = std::move(reprojected_effective_);
  if (edge_pixels_) pr.area_weights = &edge_pixels_->weights();
  reprojector_->downsample_pixels_into(&pr, active_only ? std::span<const uint8_t>(skip_) : std::span<const uint8_t>(),
                                       DownsampleParts::kCounts);
  if (edge_pixels_) edge_pixels_->drop(&pr);
  mprime_ = std::move(pr.count);
  if (variance_rule()) reprojected_effective_ = std::move(pr.effective);
  reprojection_partial_ = active_only;
}

PixelReprojection FrameState::reprojected_radiance(bool counts_too) {
  ScopedTimer t(&seconds_reprojecting_);
  ScopedTimer d(&seconds_downsampling_);
  PixelReprojection pr;
  pr.statistics = variance_rule();
  if (counts_too) {
    pr.count = std::move(mprime_);
    pr.effective = std::move(reprojected_effective_);
  }
  if (edge_pixels_) pr.area_weights = &edge_pixels_->weights();
  reprojector_->downsample_pixels_into(&pr, {}, counts_too ? DownsampleParts::kBoth : DownsampleParts::kRadiance);
  if (edge_pixels_) edge_pixels_->drop(&pr);
  if (counts_too) {
    mprime_ = std::move(pr.count);
    if (variance_rule()) reprojected_effective_ = std::move(pr.effective);
    reprojection_partial_ = false;
  }
  return pr;
}

CombineHalf FrameState::path_half(size_t p, int h) const {
  const uint32_t rounds = rounds_at_[std::min<size_t>(path_count_[p], rounds_at_.size() - 1)];
  const uint32_t even = even_paths_[std::min<size_t>(rounds, even_paths_.size() - 1)];
  CombineHalf half;
  half.paths = h == 0 ? even : path_count_[p] - even;
  // Rounds 0, 2, 4, ... are half 0's: (rounds + 1) / 2 of them; the rest half 1's.
  half.path_variance = path_sample_variance(path_m2_[2 * p + size_t(h)], h == 0 ? (rounds + 1) / 2 : rounds / 2);
  const Vec3 even_sum(path_half_sum_[3 * p], path_half_sum_[3 * p + 1], path_half_sum_[3 * p + 2]);
  if (h == 0) {
    half.path_sum = even_sum;
  } else {
    Vec3 all(path_sum_[3 * p], path_sum_[3 * p + 1], path_sum_[3 * p + 2]);
    if (!glossy_sum_.empty()) all = all - Vec3(glossy_sum_[3 * p], glossy_sum_[3 * p + 1], glossy_sum_[3 * p + 2]);
    half.path_sum = all - even_sum;
  }
  return half;
}

Image FrameState::cross_image(const PixelReprojection& rp) const {
  Image out(width_, height_, 3);
  const double weight = unit_weight(), discount = opts_.reprojected_weight;
  tbb::parallel_for(0, height_, [&](int y) {
    for (int x = 0; x < width_; ++x) {
      const size_t p = pixel(x, y);
      CombineHalf half[2] = {path_half(p, 0), path_half(p, 1)};
      if (rp.half_subpixels[2 * p] + rp.half_subpixels[2 * p + 1] == 0) {
        // Not split (an area-weighted pixel, or no reprojected samples): the count-based combination.
        const Vec3 sum = half[0].path_sum + half[1].path_sum;
        out.set_rgb(
            x, y,
            combine_weighted(sum, path_count_[p], weight * double(reprojected_effective_[p]), rp.radiance.rgb(x, y)));
        continue;
      }
      for (int h = 0; h < 2; ++h) {
        const size_t k = 2 * p + size_t(h);
        half[h].lrp = Vec3(rp.half_radiance[3 * k], rp.half_radiance[3 * k + 1], rp.half_radiance[3 * k + 2]);
        half[h].subpixels = rp.half_subpixels[k];
        half[h].effective = rp.half_effective[k];
        half[h].rp_variance = rp.half_variance[k];
      }
      out.set_rgb(x, y, combine_halves(half[0], half[1], weight, discount));
    }
  });
  return out;
}

double FrameState::diffuse_share(size_t p) const {
  if (glossy_sum_.empty()) return 1;
  const double all = luminance_of(path_sum_[3 * p], path_sum_[3 * p + 1], path_sum_[3 * p + 2]);
  const double glossy = luminance_of(glossy_sum_[3 * p], glossy_sum_[3 * p + 1], glossy_sum_[3 * p + 2]);
  return all > 0 ? std::clamp(1 - glossy / all, 0.0, 1.0) : 1.0;
}

double FrameState::pixel_samples(size_t p) const {
  // Reprojected samples improve only the diffuse part of the pixel: they count by its share d.
  const double d = diffuse_share(p);
  if (variance_rule() && !reprojected_effective_.empty())
    return effective_samples(path_count_[p], d * reprojected_effective_[p], unit_weight());
  return d == 1 ? weighted_samples(path_count_[p], mprime_[p], unit_weight())
                : double(path_count_[p]) + d * double(unit_weight()) * double(mprime_[p]);
}

int FrameState::next_paths_per_pixel() const { return round_paths(opts_, paths_done_); }

bool FrameState::finish_round() {
  EPR_DCHECK(!done_);
  paths_done_ += next_paths_per_pixel();
  ++progress_.round;
  const bool skipping = opts_.mode == RenderMode::kSkip;
  // M' is needed every round for skipping -- but only where pixels are still active: a skipped pixel
  // stays skipped, so its M' decides nothing until the last round --, and L_rp not at all: it is
  // brought up to date for the last round and the images. The progress figures below see skipped
  // pixels' M' as of the last round they were active in, until the last round refreshes every pixel.
  if (paths_done_ >= opts_.spp) {
    refresh_counts(false);
  } else if (skipping) {
    refresh_counts(true);
  }
  const uint64_t target = uint64_t(opts_.spp);
  uint64_t active = 0, skipped = 0;
  for (size_t p = 0; p < skip_.size(); ++p) {
    const uint64_t m = path_count_[p];
    EPR_DCHECK_LE(m, uint64_t(paths_done_));  // no pixel traces more paths than the rounds asked for
    if (!skip_[p]) {
      if (m >= target || (skipping && pixel_samples(p) >= double(target) && m >= uint64_t(opts_.min_paths))) {
        skip_[p] = 1;
        if (m < target) ++skipped;
      }
    }
    active += !skip_[p];
  }
  done_ = active == 0 || paths_done_ >= opts_.spp;
  if (done_ && reprojection_partial_) refresh_counts(false);
  progress_.pixels_active = active;
  progress_.pixels_skipped += skipped;
  update_sample_progress();
  return !done_;
}

void FrameState::update_sample_progress() {
  uint64_t traced = 0;
  double sum_spp = 0, sum_m = 0, sum_mp = 0, min_spp = 1e300;
  for (size_t p = 0; p < skip_.size(); ++p) {
    const uint64_t m = path_count_[p], mp = mprime_[p];
    traced += m;
    sum_m += double(m);
    sum_mp += double(mp) / count_unit_;
    const double spp = pixel_samples(p);
    EPR_DCHECK_GE(spp, double(m));  // reprojected samples add to the traced ones, never subtract
    sum_spp += spp;
    min_spp = std::min(min_spp, spp);
  }
  const double n = double(skip_.size());
  progress_.paths_traced = traced;
  progress_.mean_paths = sum_m / n;
  progress_.mean_reprojected = sum_mp / n;
  progress_.mean_spp = sum_spp / n;
  progress_.min_spp = min_spp;
  // Paths a skipped pixel did not trace, against plain path tracing at P.
  if (done_) EPR_CHECK_LE(traced, uint64_t(opts_.spp) * uint64_t(skip_.size()));
  progress_.paths_skipped = done_ ? uint64_t(opts_.spp) * uint64_t(skip_.size()) - traced : 0;
}

void FrameState::tile_inputs(int x0, int y0, int x1, int y1, std::vector<uint8_t>* skip,
                             std::vector<uint32_t>* first_sample) const {
  skip->clear();
  first_sample->clear();
  const size_t n = size_t(x1 - x0) * size_t(y1 - y0);
  skip->reserve(n);
  first_sample->reserve(n);
  for (int y = y0; y < y1; ++y)
    for (int x = x0; x < x1; ++x) {
      const size_t p = pixel(x, y);
      skip->push_back(skip_[p]);
      first_sample->push_back(path_count_[p]);
    }
}

int FrameState::path_budget(int x, int y) const {
  const int k = next_paths_per_pixel();
  const size_t p = pixel(x, y);
  if (!budgets_paths() || skip_[p] || k <= 1) return k;
  // The skip test of finish_round() with M + n paths: pixel_samples() grows by one per path.
  const double have = pixel_samples(p), target = double(opts_.spp);
  const int floor_paths = std::max(1, opts_.min_paths - int(path_count_[p]));
  int n = std::clamp(int(std::ceil(target - have)), floor_paths, k);
  while (n > floor_paths && have + double(n - 1) >= target) --n;
  while (n < k && have + double(n) < target) ++n;
  return n;
}

bool FrameState::budgets_paths() const {
  return opts_.path_budget && opts_.mode == RenderMode::kSkip && !variance_rule() && reprojects_;
}

void FrameState::tile_paths(int x0, int y0, int x1, int y1, std::vector<uint32_t>* paths) const {
  paths->clear();
  if (!budgets_paths()) return;  // every pixel traces k: nothing to visit (the default)
  const int k = next_paths_per_pixel();
  bool fewer = false;
  for (int y = y0; y < y1; ++y)
    for (int x = x0; x < x1; ++x) {
      paths->push_back(uint32_t(path_budget(x, y)));
      fewer |= paths->back() < uint32_t(k) && !skip_[pixel(x, y)];
    }
  if (!fewer) paths->clear();
}

bool FrameState::tile_idle(int x0, int y0, int x1, int y1) const {
  for (int y = y0; y < y1; ++y)
    for (int x = x0; x < x1; ++x)
      if (!skip_[pixel(x, y)]) return false;
  return true;
}

ReprojectionCounts FrameState::counts() const { return reprojector_ ? reprojector_->counts() : released_counts_; }

FrameSnapshot FrameState::save() {
  FrameSnapshot s;
  s.width = width_;
  s.height = height_;
  frame_fields(s, fields());
  if (reprojector_) {
    s.has_accumulation = true;
    s.accumulation = reprojector_->read();
    s.counts = reprojector_->counts();
  }
  return s;
}

FrameView FrameState::view() {
  FrameView v;
  v.width = width_;
  v.height = height_;
  frame_fields(v, fields());
  if (reprojector_) {
    v.has_accumulation = true;
    v.grid_width = opts_.subpixels * width_;
    v.grid_height = opts_.subpixels * height_;
    v.subpixels = opts_.subpixels;
    v.counts = reprojector_->counts();
    Reprojector* r = reprojector_.get();
    v.visit_cells = [r](size_t max_cells, const std::function<void(std::span<const AccumulationCell>)>& visit) {
      r->visit_cells(max_cells, visit);
    };
  }
  return v;
}

FrameView view_of(const FrameSnapshot& s) {
  FrameView v;
  v.width = s.width;
  v.height = s.height;
  frame_fields(v, s);
  v.reprojected = s.reprojected;
  v.has_accumulation = s.has_accumulation;
  if (s.has_accumulation) {
    const SubpixelAccumulation* a = &s.accumulation;
    v.grid_width = a->width;
    v.grid_height = a->height;
    v.subpixels = a->subpixels;
    v.counts = s.counts;
    const auto* cells = &s.cells;
    v.visit_cells = [a, cells](size_t max_cells, const std::function<void(std::span<const AccumulationCell>)>& visit) {
      const size_t n = a->size();
      if (!*cells && (a->sum.size() != 3 * n || a->count.size() != n))
        throw std::invalid_argument("the snapshot's accumulation does not match its grid size");
      std::vector<AccumulationCell> chunk(std::min(max_cells, n));
      for (size_t off = 0; off < n; off += max_cells) {
        const size_t m = std::min(max_cells, n - off);
        if (*cells) {
          (*cells)(off, {chunk.data(), m});
        } else {
          for (size_t k = 0; k < m; ++k) {
            const size_t i = off + k;
            chunk[k] = {a->sum[3 * i], a->sum[3 * i + 1], a->sum[3 * i + 2], a->count[i]};
          }
        }
        visit({chunk.data(), m});
      }
    };
  }
  return v;
}

void FrameState::restore(const FrameSnapshot& s) {
  const size_t n = size_t(width_) * size_t(height_);
  if (s.width != width_ || s.height != height_)
    throw std::invalid_argument("the snapshot is of a " + std::to_string(s.width) + "x" + std::to_string(s.height) +
                                " frame, this frame is " + std::to_string(width_) + "x" + std::to_string(height_));
  if (s.path_sum.size() != 3 * n || (!s.glossy_sum.empty() && s.glossy_sum.size() != 3 * n) ||
      s.path_count.size() != n || s.mprime.size() != n || (!s.reprojected.empty() && s.reprojected.size() != 3 * n) ||
      s.skip.size() != n)
    throw std::invalid_argument("the snapshot's per-pixel arrays do not match the frame size");
  if (s.path_m2.size() != path_m2_.size() || s.reprojected_effective.size() != reprojected_effective_.size() ||
      s.path_half_sum.size() != path_half_sum_.size())
    throw std::invalid_argument(path_m2_.empty()    ? "the snapshot has the variance combination's moments, this frame "
                                                      "combines with the fixed rule"
                                : s.path_m2.empty() ? "the snapshot has no moments for the variance combination"
                                                    : "the snapshot's variance combination has no halves (it "
                                                      "predates the cross-weighted rule)");
  if (s.has_accumulation != (reprojector_ != nullptr))
    throw std::invalid_argument(s.has_accumulation
                                    ? "the snapshot has a reprojection accumulation, this frame reprojects nothing"
                                    : "the snapshot has no reprojection accumulation");
  if (s.paths_done < 0 || s.paths_done > opts_.spp)
    throw std::invalid_argument("the snapshot's path count is out of range");
  if (reprojector_ && s.cells) {
    // From a source read on demand (a checkpoint file): the grid is checked first; if the source
    // fails midway the reprojector is reset and the exception propagates, the rest unchanged.
    const SubpixelAccumulation& a = s.accumulation;
    if (a.width != opts_.subpixels * width_ || a.height != opts_.subpixels * height_ ||
        a.subpixels != opts_.subpixels || a.size() != reprojector_->cell_count())
      throw std::invalid_argument("the accumulation to restore is not of this reprojector's subpixel grid");
    if (s.counts.occluded < s.counts.backfacing)
      throw std::invalid_argument("occluded counts include the backfacing ones");
    size_t next = 0;
    reprojector_->restore_cells(
        [&](std::span<AccumulationCell> out) {
          s.cells(next, out);
          next += out.size();
        },
        s.counts);
  } else if (reprojector_) {
    reprojector_->restore(s.accumulation, s.counts);  // checks the grid; throws before any change below
  }
  Fields f = fields();
  frame_fields(f, s);
  reprojection_partial_ = reprojector_ != nullptr;  // the snapshot may hold a partial refresh
}

void FrameState::glossy_images(FrameImages* out) const {
  if (glossy_sum_.empty()) return;
  out->glossy_sum = Image(width_, height_, 3);
  out->glossy_sum.data = glossy_sum_;
}

void FrameState::count_images(FrameImages* out) const {
  out->path_count = Image(width_, height_, 1);
  out->reprojected = Image(width_, height_, 1);
  tbb::parallel_for(0, height_, [&](int y) {
    for (int x = 0; x < width_; ++x) {
      const size_t p = pixel(x, y);
      out->path_count.at(x, y)[0] = float(path_count_[p]);
      out->reprojected.at(x, y)[0] = float(mprime_[p]) / float(count_unit_);
    }
  });
}

FrameImages FrameState::release_images() {
  FrameImages out;
  out.reprojected_weight = opts_.reprojected_weight;
  if (reprojector_) {
    PixelReprojection rp = reprojected_radiance(true);
    if (variance_rule()) out.cross_combined = cross_image(rp);
    out.reprojection = std::move(rp.radiance);
    released_counts_ = reprojector_->counts();
    reprojector_.reset();
  }
  count_images(&out);
  out.path_sum.width = width_;
  out.path_sum.height = height_;
  out.path_sum.data = std::move(path_sum_);
  path_sum_.clear();
  glossy_images(&out);
  glossy_sum_.clear();
  return out;
}

FrameImages FrameState::images(bool preview) {
  FrameImages out;
  out.reprojected_weight = opts_.reprojected_weight;
  // L_rp is not kept between rounds: it is downsampled from the accumulation here, every pixel. M'
  // comes along (and is kept) unless this is a skip-mode preview, which shows the skipped pixels' M'
  // as of the last round they were active in (their L_rp is current).
  if (reprojector_) {
    const bool was_partial = reprojection_partial_;
    const bool keep_counts = preview && opts_.mode == RenderMode::kSkip;
    PixelReprojection rp = reprojected_radiance(!keep_counts);
    if (variance_rule()) out.cross_combined = cross_image(rp);
    out.reprojection = std::move(rp.radiance);
    if (was_partial && !reprojection_partial_) update_sample_progress();  // M' of the skipped pixels changed
  }
  // The path sums as they are; combined_image() and pathtrace_image() make the rest when asked.
  out.path_sum.width = width_;
  out.path_sum.height = height_;
  out.path_sum.data = path_sum_;
  glossy_images(&out);
  count_images(&out);
  return out;
}

nlohmann::json FrameState::statistics(const RenderOptions& opts, uint64_t worker_culled) const {
  const ReprojectionCounts c = counts();
  const ReprojectionOutcomes o = ReprojectionOutcomes::of(c, worker_culled);
  const FrameProgress& p = progress();
  return {
      {"mode", to_string(opts.mode)},
      {"reproject", to_string(opts.reproject)},
      {"sampler", to_string(opts.sampler)},
      {"subpixels", opts.subpixels},
      {"epsilon_fraction", opts.epsilon},
      {"reprojected_weight", opts.reprojected_weight},
      {"combine", to_string(opts.combine)},
      {"roulette", roulette_name(opts.rr.resolved(lit_from_outside_).mode)},
      {"tile_size", opts.tile_size},
      {"taper_tiles", opts.taper_tiles},
      {"rounds", p.round},
      {"paths_traced", p.paths_traced},
      {"paths_skipped", p.paths_skipped},
      {"pixels_skipped", p.pixels_skipped},
      {"edge_pixels", edge_pixels_ ? edge_pixels_->count() : 0},
      {"area_weighted_pixels", edge_pixels_ ? edge_pixels_->weighted() : 0},
      {"seconds_edge_pixels", edge_pixels_ ? edge_pixels_->seconds() : 0.0},
      {"mean_paths_per_pixel", p.mean_paths},
      {"mean_reprojected_per_pixel", p.mean_reprojected},
      {"mean_spp", p.mean_spp},
      {"min_spp", p.min_spp},
      {"reprojected_samples", c.accepted + c.exact},
      {"accepted", c.accepted},
      {"occluded", c.occluded},
      {"backfacing", c.backfacing},
      {"culled_master", c.culled},
      {"culled_worker", o.culled_by_workers},
      {"not_diffuse", c.not_diffuse},
      {"invalid", c.invalid},
      {"exact_samples", c.exact},
      {"considered", o.considered},
      {"accepted_percent", o.accepted_percent()},
      {"occluded_percent", o.occluded_percent()},
      {"culled_percent", o.culled_percent()},
      {"seconds_reprojecting", seconds_reprojecting()},
      {"seconds_downsampling", seconds_downsampling()},
  };
}

}  // namespace epr
