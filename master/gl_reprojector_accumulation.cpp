// GlReprojector's accumulation as a whole (gl_reprojector.h): counts, read-back, downsampling,
// reset, restore and the span-wise visit and restore of the bands used by checkpoints.
#include <fmt/format.h>

#include <algorithm>
#include <functional>
#include <stdexcept>
#include <vector>

#include "master/gl_reprojector.h"
#include "master/gl_reprojector_shaders.h"
#include "master/reprojection_image.h"

namespace epr {

std::array<uint64_t, GlReprojector::kGpuCounters> GlReprojector::read_gpu_counters() const {
  std::vector<uint32_t> c(invocations_ * kGpuCounters);
  ctx_->gl().GetNamedBufferSubData(counter_buf_->id(), 0, GLsizeiptr(c.size() * 4), c.data());
  std::array<uint64_t, kGpuCounters> sum{};
  for (size_t i = 0; i < c.size(); ++i) sum[i % kGpuCounters] += c[i];
  return sum;
}

void GlReprojector::fold_counters() {
  const std::array<uint64_t, kGpuCounters> gpu = read_gpu_counters();
  for (size_t k = 0; k < kGpuCounters; ++k) folded_[k] += gpu[k];
  const GLuint zero = 0;
  ctx_->gl().ClearNamedBufferData(counter_buf_->id(), GL_R32UI, GL_RED_INTEGER, GL_UNSIGNED_INT, &zero);
  points_since_fold_ = 0;
}

ReprojectionCounts GlReprojector::counts() const {
  ctx_->check_thread();
  // The pending records' decisions are the GPU's: dispatch them (a const call that completes the
  // work already submitted).
  const_cast<GlReprojector*>(this)->flush_pending();
  const std::array<uint64_t, kGpuCounters> gpu = read_gpu_counters();
  ReprojectionCounts r = cpu_counts_;
  r.not_diffuse += folded_[4] + gpu[4];
  r.accepted += folded_[0] + gpu[0];
  r.culled += folded_[1] + gpu[1];
  r.backfacing += folded_[2] + gpu[2];
  r.occluded += folded_[2] + gpu[2] + folded_[3] + gpu[3];
  return r;
}

// Maps every band's accumulation for reading (waits for the dispatches that write them); returns
// false (nothing mapped) if one cannot be mapped.
bool GlReprojector::map_bands(std::vector<const AccumulationCell*>* mapped) {
  const auto& gl = ctx_->gl();
  gl.MemoryBarrier(GL_CLIENT_MAPPED_BUFFER_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
  mapped->assign(bands_.size(), nullptr);
  for (size_t b = 0; b < bands_.size(); ++b) {
    (*mapped)[b] = static_cast<const AccumulationCell*>(
        gl.MapNamedBufferRange(bands_[b].acc->id(), 0, GLsizeiptr(bands_[b].cells * 16), GL_MAP_READ_BIT));
    if (!(*mapped)[b]) {
      unmap_bands(b);
      return false;
    }
  }
  return true;
}

void GlReprojector::unmap_bands(size_t n) {
  for (size_t b = 0; b < n; ++b) ctx_->gl().UnmapNamedBuffer(bands_[b].acc->id());
}

SubpixelAccumulation GlReprojector::read() {
  ctx_->check_thread();
  flush_pending();
  const size_t cells = size_t(grid_w_) * size_t(grid_h_);
  SubpixelAccumulation a;
  a.width = grid_w_;
  a.height = grid_h_;
  a.subpixels = subpixels_;
  a.sum.resize(3 * cells);
  a.count.resize(cells);
  std::vector<const AccumulationCell*> mapped;
  if (!map_bands(&mapped)) {
    ctx_->check_error("GlReprojector::read (map)");
    throw std::runtime_error("GlReprojector::read: cannot map the accumulation");
  }
  for (size_t b = 0; b < bands_.size(); ++b) {
    const AccumulationCell* c = mapped[b];
    float* sum = a.sum.data() + 3 * bands_[b].first_cell;
    uint32_t* count = a.count.data() + bands_[b].first_cell;
    for (size_t k = 0; k < bands_[b].cells; ++k) {
      sum[3 * k] = c[k].r;
      sum[3 * k + 1] = c[k].g;
      sum[3 * k + 2] = c[k].b;
      count[k] = c[k].n;
    }
  }
  unmap_bands(bands_.size());
  ctx_->check_error("GlReprojector::read");
  return a;
}

void GlReprojector::downsample_pixels_into(PixelReprojection* result, std::span<const uint8_t> skip,
                                           DownsampleParts parts) {
  ctx_->check_thread();
  flush_pending();
  const auto& gl = ctx_->gl();
  if (map_downsample_) {
    // The accumulation mapped for reading (waits for the dispatches that write it) and downsampled
    // by the CPU code in place: on a software GL (llvmpipe) the buffer is host memory, and this is
    // several times cheaper than a compute pass plus its read-back. Same result as
    // downsample(read()).
    std::vector<const AccumulationCell*> mapped;
    if (!map_bands(&mapped))
      ctx_->check_error("GlReprojector::downsample_pixels (map)");
    else {
      try {
        if (bands_.size() == 1) {
          downsample_cells({mapped[0], bands_[0].cells}, grid_w_, grid_h_, subpixels_, skip, result, parts);
        } else {
          downsample_bands(mapped, bands_[0].rows, grid_w_, grid_h_, subpixels_, skip, result, parts);
        }
      } catch (...) {
        unmap_bands(bands_.size());
        throw;
      }
      unmap_bands(bands_.size());
      ctx_->check_error("GlReprojector::downsample_pixels");
      return;
    }
  }
  // The compute pass, band by band; it writes every pixel (no mask) and knows no area weights.
  if (result->area_weights && !result->area_weights->pixels.empty())
    throw std::runtime_error("GlReprojector: area-weighted pixels need the mapped downsampling");
  const int W = grid_w_ / subpixels_, H = grid_h_ / subpixels_;
  const size_t band_pixels = size_t(W) * size_t(bands_[0].rows / subpixels_);  // the largest band's
  if (!downsample_prog_) {
    downsample_prog_ =
        std::make_unique<GlProgram>(*ctx_, shader_source(gl_shaders::kDownsampleShader, settings_, true));
    pixels_buf_ = std::make_unique<GlBuffer>(*ctx_);
    gl.NamedBufferStorage(pixels_buf_->id(), GLsizeiptr(band_pixels * 16), nullptr, GL_DYNAMIC_STORAGE_BIT);
  }
  PixelReprojection out;
  out.radiance = Image(W, H, 3);
  out.count.assign(size_t(W) * size_t(H), 0);
  std::vector<float> raw(4 * band_pixels);
  const GLuint p = downsample_prog_->id();
  for (const Band& b : bands_) {
    const int h = b.rows / subpixels_;
    const size_t pixels = size_t(W) * size_t(h), first_pixel = size_t(b.row0 / subpixels_) * size_t(W);
    gl.UseProgram(p);
    gl.ProgramUniform1ui(p, downsample_prog_->uniform("image_w"), GLuint(W));
    gl.ProgramUniform1ui(p, downsample_prog_->uniform("image_h"), GLuint(h));
    gl.ProgramUniform1ui(p, downsample_prog_->uniform("subpixels"), GLuint(subpixels_));
    gl.ProgramUniform1ui(p, downsample_prog_->uniform("grid_w"), GLuint(grid_w_));
    gl.BindBufferBase(GL_SHADER_STORAGE_BUFFER, 0, b.acc->id());
    gl.BindBufferBase(GL_SHADER_STORAGE_BUFFER, 2, pixels_buf_->id());
    // 64 pixels per workgroup, in rows of at most 65535 workgroups (the guaranteed maximum count).
    const size_t groups = (pixels + 63) / 64;
    gl.DispatchCompute(GLuint(std::min<size_t>(groups, 65535)), GLuint((groups + 65534) / 65535), 1);
    gl.MemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
    gl.UseProgram(0);
    gl.GetNamedBufferSubData(pixels_buf_->id(), 0, GLsizeiptr(pixels * 16), raw.data());
    ctx_->check_error("GlReprojector::downsample_pixels");
    for (size_t i = 0; i < pixels; ++i) {
      const size_t q = first_pixel + i;
      out.radiance.data[3 * q] = raw[4 * i];
      out.radiance.data[3 * q + 1] = raw[4 * i + 1];
      out.radiance.data[3 * q + 2] = raw[4 * i + 2];
      uint32_t n;
      std::memcpy(&n, &raw[4 * i + 3], 4);
      out.count[q] = n;
    }
  }
  // Every pixel (the compute pass has no mask), of the parts asked for.
  if (parts != DownsampleParts::kRadiance) result->count = std::move(out.count);
  if (parts != DownsampleParts::kCounts) result->radiance = std::move(out.radiance);
}

void GlReprojector::reset() {
  ctx_->check_thread();
  pending_n_ = 0;  // submitted before the reset: dropped with the rest
  const GLuint zero = 0;
  for (const Band& b : bands_)
    ctx_->gl().ClearNamedBufferData(b.acc->id(), GL_R32UI, GL_RED_INTEGER, GL_UNSIGNED_INT, &zero);
  ctx_->gl().ClearNamedBufferData(counter_buf_->id(), GL_R32UI, GL_RED_INTEGER, GL_UNSIGNED_INT, &zero);
  cpu_counts_ = {};
  folded_ = {};
  points_since_fold_ = 0;
}

void GlReprojector::restore(const SubpixelAccumulation& acc, const ReprojectionCounts& counts) {
  ctx_->check_thread();
  const size_t cells = size_t(grid_w_) * size_t(grid_h_);
  if (acc.width != grid_w_ || acc.height != grid_h_ || acc.subpixels != subpixels_ || acc.sum.size() != 3 * cells ||
      acc.count.size() != cells)
    throw std::invalid_argument("the accumulation to restore is not of this reprojector's subpixel grid");
  if (counts.occluded < counts.backfacing) throw std::invalid_argument("occluded counts include the backfacing ones");
  // The SSBO layout, {float r, g, b; uint n} per subpixel, filled a chunk at a time.
  size_t next = 0;
  restore_cells(
      [&](std::span<AccumulationCell> out) {
        for (AccumulationCell& c : out) {
          c = {acc.sum[3 * next], acc.sum[3 * next + 1], acc.sum[3 * next + 2], acc.count[next]};
          ++next;
        }
      },
      counts);
}

void GlReprojector::visit_cells(size_t max_cells, const std::function<void(std::span<const AccumulationCell>)>& visit) {
  ctx_->check_thread();
  flush_pending();
  const auto& gl = ctx_->gl();
  // One band mapped at a time (on llvmpipe the buffer is host memory: nothing is copied).
  for (const Band& b : bands_) {
    const auto* c = static_cast<const AccumulationCell*>(
        gl.MapNamedBufferRange(b.acc->id(), 0, GLsizeiptr(b.cells * 16), GL_MAP_READ_BIT));
    if (!c) {
      ctx_->check_error("GlReprojector::visit_cells (map)");
      throw std::runtime_error("GlReprojector::visit_cells: cannot map the accumulation");
    }
    try {
      for (size_t off = 0; off < b.cells; off += max_cells) visit({c + off, std::min(max_cells, b.cells - off)});
    } catch (...) {
      gl.UnmapNamedBuffer(b.acc->id());
      throw;
    }
    gl.UnmapNamedBuffer(b.acc->id());
  }
  ctx_->check_error("GlReprojector::visit_cells");
}

void GlReprojector::restore_cells(const std::function<void(std::span<AccumulationCell>)>& fill,
                                  const ReprojectionCounts& counts) {
  ctx_->check_thread();
  if (counts.occluded < counts.backfacing) throw std::invalid_argument("occluded counts include the backfacing ones");
  const auto& gl = ctx_->gl();
  constexpr size_t kChunk = size_t(1) << 20;
  std::vector<AccumulationCell> raw(std::min(kChunk, cell_count()));
  try {
    for (const Band& b : bands_)
      for (size_t off = 0; off < b.cells; off += kChunk) {
        const size_t m = std::min(kChunk, b.cells - off);
        fill({raw.data(), m});
        gl.NamedBufferSubData(b.acc->id(), GLintptr(off * 16), GLsizeiptr(m * 16), raw.data());
      }
  } catch (...) {
    reset();
    throw;
  }
  const GLuint zero = 0;
  gl.ClearNamedBufferData(counter_buf_->id(), GL_R32UI, GL_RED_INTEGER, GL_UNSIGNED_INT, &zero);
  ctx_->check_error("GlReprojector::restore_cells");
  pending_n_ = 0;  // replaced by the restored state
  folded_ = {counts.accepted, counts.culled, counts.backfacing, counts.occluded - counts.backfacing, 0};
  cpu_counts_ = {};
  cpu_counts_.not_diffuse = counts.not_diffuse;
  cpu_counts_.invalid = counts.invalid;
  cpu_counts_.exact = counts.exact;
  points_since_fold_ = 0;
}

}  // namespace epr
