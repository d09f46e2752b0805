// See gl_reprojector.h; the shaders it runs are in gl_reprojector_shaders.cpp.
#include "master/gl_reprojector.h"

#include <fmt/format.h>

#include <algorithm>
#include <bit>
#include <cstring>
#include <stdexcept>
#include <string>
#include <vector>

#include "common/log.h"
#include "master/gl_reprojector_shaders.h"
#include "master/reprojection_image.h"

namespace epr {

namespace {

constexpr size_t kRecordBytes = 36;  // 9 floats
constexpr size_t kPackedBytes = VertexCodec::kPackedBytes;
constexpr int kSlots = 2;
constexpr size_t kCounters = 5;  // per invocation: accepted, culled, backfacing, other occluded, not diffuse

}  // namespace

std::string GlReprojector::shader_source(const char* body, const ReprojectorSettings& s, bool narrow_planes,
                                         bool packed) {
  return fmt::format(
      "#version 450\n#extension GL_NV_shader_atomic_float : require\n#define WORKGROUP_SIZE {}\n#define PREFETCH "
      "{}\n#define UNCOVERED {}\n#define PACKED {}\n"
      "#define GLOSSY {}\n#define COUNTERS {}u\n{}{}",
      s.workgroup_size, s.prefetch ? 1 : 0, narrow_planes ? "0xffffu" : "0xffffffffu", packed ? 1 : 0,
      s.reproject_glossy ? 1 : 0, kCounters, packed ? gl_shaders::kPackedDecode : "", body);
}

GlReprojector::GlReprojector(GlContext& ctx, const Camera& camera, const DeepFramebuffer& dfb,
                             const ReprojectorSettings& settings)
    : ctx_(&ctx), settings_(settings) {
  init(camera, detail::plane_grid_for(camera, dfb, settings));
}

GlReprojector::GlReprojector(const Camera& camera, const DeepFramebuffer& dfb, const ReprojectorSettings& settings)
    : owned_ctx_(std::make_unique<GlContext>()), ctx_(owned_ctx_.get()), settings_(settings) {
  init(camera, detail::plane_grid_for(camera, dfb, settings));
}

GlReprojector::GlReprojector(GlContext& ctx, const Camera& camera, detail::PlaneGrid grid,
                             const ReprojectorSettings& settings)
    : ctx_(&ctx), settings_(settings) {
  init(camera, std::move(grid));
}

GlReprojector::GlReprojector(const Camera& camera, detail::PlaneGrid grid, const ReprojectorSettings& settings)
    : owned_ctx_(std::make_unique<GlContext>()), ctx_(owned_ctx_.get()), settings_(settings) {
  init(camera, std::move(grid));
}

GlReprojector::~GlReprojector() {
  try {
    ctx_->check_thread();
  } catch (const std::exception&) {
    // GL objects can only be deleted where the context is current; leak them rather than crash.
    logger("master")->error("GlReprojector destroyed on a thread its GL context is not current on; GL objects leak");
    for (auto* p : {&reproject_prog_, &packed_prog_, &exact_prog_, &downsample_prog_, &decode_prog_})
      (void)p->release();
    for (auto* p : {&ring_, &planes_buf_, &crease_range_buf_, &creases_buf_, &counter_buf_, &pixels_buf_, &codec_buf_})
      (void)p->release();
    for (auto* p : {&records_tex_, &samples_tex_, &planes_tex_, &crease_range_tex_, &creases_tex_}) (void)p->release();
    for (Band& b : bands_) {
      (void)b.acc.release();
      (void)b.texel_plane.release();
      (void)b.acc_view.release();
      (void)b.texel_plane_tex.release();
    }
    (void)owned_ctx_.release();
    return;
  }
  for (GLsync& f : fences_)
    if (f) ctx_->gl().DeleteSync(f);
}

void GlReprojector::init(const Camera& camera, detail::PlaneGrid grid) {
  ctx_->check_thread();
  detail::validate_reprojector_inputs(camera, grid, settings_);
  if (!ctx_->has_extension("GL_NV_shader_atomic_float"))
    throw GlUnavailable(
        "the GL reprojector needs GL_NV_shader_atomic_float (Mesa llvmpipe has it); use the cpu back-end");
  size_grid(camera, grid);
  plan_bands();
  // 16-bit plane indices when there are few enough planes (halves the largest randomly accessed
  // array after the accumulation).
  const bool narrow = grid.planes.size() / 4 < 0xffff;
  compile_programs(narrow);
  create_upload_ring();
  upload_plane_index(&grid, narrow);  // frees the grid's plane index
  create_accumulation();
  upload_plane_tables(grid);
  create_counters();
  set_fixed_uniforms(grid.first_creased);
  reset();
  ctx_->check_error("GlReprojector setup");
}

void GlReprojector::size_grid(const Camera& camera, const detail::PlaneGrid& grid) {
  params_ = detail::make_kernel_params(camera, grid.subpixels, settings_.epsilon, settings_.joint_test);
  map_downsample_ = settings_.gl_map_downsample;
  subpixels_ = grid.subpixels;
  grid_w_ = grid.width;
  grid_h_ = grid.height;
  settings_.batch_points = (settings_.batch_points + 3) / 4 * 4;  // slots stay 16-byte aligned
  slot_bytes_ = settings_.batch_points * kRecordBytes;
  invocations_ = size_t(settings_.workgroups) * size_t(settings_.workgroup_size);
  const size_t cells = size_t(grid_w_) * size_t(grid_h_);
  if (grid.texel_plane.size() != cells) throw std::invalid_argument("plane grid: texel_plane is not width x height");
  if (cells > size_t(UINT32_MAX))
    throw std::runtime_error(
        fmt::format("subpixel grid {}x{}: more subpixels than 32-bit indices address", grid_w_, grid_h_));
}

void GlReprojector::plan_bands() {
  // Bands of whole pixel rows, each within the largest SSBO and buffer texture this GL allows.
  const auto& gl = ctx_->gl();
  GLint max_ssbo = 0, max_tbo = 0;
  gl.GetIntegerv(GL_MAX_SHADER_STORAGE_BLOCK_SIZE, &max_ssbo);
  gl.GetIntegerv(GL_MAX_TEXTURE_BUFFER_SIZE, &max_tbo);
  const size_t ssbo_bytes = size_t(std::max(max_ssbo, 0)), tbo_texels = size_t(std::max(max_tbo, 0));
  if (kSlots * settings_.batch_points * 3 > tbo_texels)
    throw std::runtime_error(
        fmt::format("batch_points {} exceeds this GL's buffer-texture limit", settings_.batch_points));
  size_t limit = std::min(ssbo_bytes / 16, tbo_texels);  // subpixels per band
  if (settings_.gl_max_band_cells) limit = std::min(limit, settings_.gl_max_band_cells);
  const size_t pixel_row_cells = size_t(grid_w_) * size_t(subpixels_);  // S grid rows
  const size_t max_pixel_rows = limit / pixel_row_cells;
  if (max_pixel_rows == 0)
    throw std::runtime_error(fmt::format(
        "subpixel grid {}x{}: one row of pixels ({} subpixels) exceeds this GL's limits ({} MiB of shader storage, {} "
        "buffer-texture texels{})",
        grid_w_, grid_h_, pixel_row_cells, ssbo_bytes >> 20, tbo_texels,
        settings_.gl_max_band_cells ? fmt::format(", gl_max_band_cells {}", settings_.gl_max_band_cells) : ""));
  const size_t pixel_rows = size_t(grid_h_ / subpixels_);
  const size_t n_bands = (pixel_rows + max_pixel_rows - 1) / max_pixel_rows;
  const int band_rows = int((pixel_rows + n_bands - 1) / n_bands) * subpixels_;  // equal bands but the last
  band_cells_ = size_t(band_rows) * size_t(grid_w_);
  bands_.clear();
  for (int row0 = 0; row0 < grid_h_; row0 += band_rows) {
    Band b;
    b.row0 = row0;
    b.rows = std::min(band_rows, grid_h_ - row0);
    b.first_cell = size_t(row0) * size_t(grid_w_);
    b.cells = size_t(b.rows) * size_t(grid_w_);
    bands_.push_back(std::move(b));
  }
  if (bands_.size() > 1) {
    pending_.resize(slot_bytes_);
    bin_band_.resize(slot_bytes_ / kPackedBytes);
    bin_count_.resize(bands_.size());
    bin_offset_.resize(bands_.size());
  }
}

void GlReprojector::compile_programs(bool narrow) {
  reproject_prog_ = std::make_unique<GlProgram>(*ctx_, shader_source(gl_shaders::kReprojectShader, settings_, narrow));
  packed_prog_ =
      std::make_unique<GlProgram>(*ctx_, shader_source(gl_shaders::kReprojectShader, settings_, narrow, true));
  exact_prog_ = std::make_unique<GlProgram>(*ctx_, shader_source(gl_shaders::kExactShader, settings_, narrow));
}

void GlReprojector::create_upload_ring() {
  // Persistently mapped; read by the kernels through two buffer-texture views.
  const auto& gl = ctx_->gl();
  const GLbitfield map_flags = GL_MAP_WRITE_BIT | GL_MAP_PERSISTENT_BIT | GL_MAP_COHERENT_BIT;
  ring_ = std::make_unique<GlBuffer>(*ctx_);
  gl.NamedBufferStorage(ring_->id(), GLsizeiptr(kSlots * slot_bytes_), nullptr, map_flags);
  ring_map_ =
      static_cast<unsigned char*>(gl.MapNamedBufferRange(ring_->id(), 0, GLsizeiptr(kSlots * slot_bytes_), map_flags));
  if (!ring_map_) throw std::runtime_error("could not map the reprojection upload buffer");
  records_tex_ = texture_view(*ring_, GL_RGB32F);
  samples_tex_ = texture_view(*ring_, GL_RGBA32UI);
}

std::unique_ptr<GlTexture> GlReprojector::texture_view(const GlBuffer& buffer, GLenum format) {
  auto tex = std::make_unique<GlTexture>(*ctx_, GL_TEXTURE_BUFFER);
  ctx_->gl().TextureBuffer(tex->id(), format, buffer.id());
  return tex;
}

void GlReprojector::upload_plane_index(detail::PlaneGrid* grid, bool narrow) {
  // Per band: the plane index of its texels (narrow: converted and uploaded a chunk at a time, so the
  // CPU side never holds more than a chunk of it). The grid's 4-byte index is then freed, so that it
  // is never held beside the accumulation.
  const auto& gl = ctx_->gl();
  constexpr size_t kChunk = size_t(1) << 20;
  std::vector<uint16_t> staging;
  for (Band& b : bands_) {
    b.texel_plane = std::make_unique<GlBuffer>(*ctx_);
    const uint32_t* src = grid->texel_plane.data() + b.first_cell;
    if (narrow) {
      gl.NamedBufferStorage(b.texel_plane->id(), GLsizeiptr(b.cells * 2), nullptr, GL_DYNAMIC_STORAGE_BIT);
      for (size_t off = 0; off < b.cells; off += kChunk) {
        const size_t m = std::min(kChunk, b.cells - off);
        staging.resize(m);
        for (size_t i = 0; i < m; ++i) staging[i] = uint16_t(src[off + i]);  // kUncovered -> 0xffff
        gl.NamedBufferSubData(b.texel_plane->id(), GLintptr(off * 2), GLsizeiptr(m * 2), staging.data());
      }
    } else {
      gl.NamedBufferStorage(b.texel_plane->id(), GLsizeiptr(b.cells * 4), src, 0);
    }
    b.texel_plane_tex = texture_view(*b.texel_plane, narrow ? GL_R16UI : GL_R32UI);
    ctx_->check_error("GlReprojector setup (plane index)");
  }
  std::vector<uint32_t>().swap(grid->texel_plane);
}

void GlReprojector::create_accumulation() {
  // Per band, mappable for reading (the round's downsample reads the cells in place, see
  // downsample_pixels_into).
  for (Band& b : bands_) {
    b.acc = std::make_unique<GlBuffer>(*ctx_);
    ctx_->gl().NamedBufferStorage(b.acc->id(), GLsizeiptr(b.cells * 16), nullptr,
                                  GL_DYNAMIC_STORAGE_BIT | GL_MAP_READ_BIT);
    b.acc_view = texture_view(*b.acc, GL_RGBA32UI);
    ctx_->check_error("GlReprojector setup (band buffers)");
  }
}

void GlReprojector::upload_table(const void* data, size_t bytes, GLenum format, size_t texel_bytes,
                                 std::unique_ptr<GlBuffer>* buffer, std::unique_ptr<GlTexture>* texture) {
  const std::array<uint32_t, 4> zero{};  // GL wants a non-empty buffer
  if (bytes == 0) {
    data = zero.data();
    bytes = texel_bytes;
  }
  *buffer = std::make_unique<GlBuffer>(*ctx_);
  ctx_->gl().NamedBufferStorage((*buffer)->id(), GLsizeiptr(bytes), data, 0);
  *texture = texture_view(**buffer, format);
}

void GlReprojector::upload_plane_tables(const detail::PlaneGrid& grid) {
  upload_table(grid.planes.data(), grid.planes.size() * 4, GL_RGBA32F, 16, &planes_buf_, &planes_tex_);
  upload_table(grid.crease_range.data(), grid.crease_range.size() * 4, GL_RG32UI, 8, &crease_range_buf_,
               &crease_range_tex_);
  upload_table(grid.creases.data(), grid.creases.size() * 4, GL_RGBA32F, 16, &creases_buf_, &creases_tex_);
}

void GlReprojector::create_counters() {
  const auto& gl = ctx_->gl();
  counter_buf_ = std::make_unique<GlBuffer>(*ctx_);
  gl.NamedBufferStorage(counter_buf_->id(), GLsizeiptr(invocations_ * kCounters * 4), nullptr, GL_DYNAMIC_STORAGE_BIT);
  // The packed kernels' codec parameters (lo_q, cell as doubles), set per call when they change.
  codec_buf_ = std::make_unique<GlBuffer>(*ctx_);
  gl.NamedBufferStorage(codec_buf_->id(), GLsizeiptr(sizeof(codec_params_)), codec_params_.data(),
                        GL_DYNAMIC_STORAGE_BIT);
}

void GlReprojector::set_fixed_uniforms(uint32_t first_creased) {
  // Uniforms that never change (the same in the record and the packed kernel); the sample weight
  // only by set_sample_weight().
  const auto& gl = ctx_->gl();
  const auto& k = params_;
  for (const GlProgram* rp : {reproject_prog_.get(), packed_prog_.get()}) {
    const GLuint p = rp->id();
    gl.ProgramUniform1i(p, rp->uniform(rp == packed_prog_.get() ? "words" : "records"), 0);
    gl.ProgramUniform1i(p, rp->uniform("texel_plane"), 1);
    gl.ProgramUniform1i(p, rp->uniform("planes"), 2);
    gl.ProgramUniform1i(p, rp->uniform("crease_range"), 5);
    gl.ProgramUniform1i(p, rp->uniform("creases"), 6);
    gl.ProgramUniform1ui(p, rp->uniform("first_creased"), first_creased);
    gl.ProgramUniform1f(p, rp->uniform("crease_tolerance"), k.crease_tolerance);
    gl.ProgramUniform1f(p, rp->uniform("min_normal_cosine"), k.min_normal_cosine);
    if (settings_.prefetch) gl.ProgramUniform1i(p, rp->uniform("cell_view"), 3);
    gl.ProgramUniform3f(p, rp->uniform("eye"), k.eye.x, k.eye.y, k.eye.z);
    gl.ProgramUniform3f(p, rp->uniform("forward_"), k.forward.x, k.forward.y, k.forward.z);
    gl.ProgramUniform3f(p, rp->uniform("right_"), k.right.x, k.right.y, k.right.z);
    gl.ProgramUniform3f(p, rp->uniform("up_"), k.up.x, k.up.y, k.up.z);
    gl.ProgramUniform1f(p, rp->uniform("tan_half_x"), k.tan_half_x);
    gl.ProgramUniform1f(p, rp->uniform("tan_half_y"), k.tan_half_y);
    gl.ProgramUniform1f(p, rp->uniform("width_"), k.width);
    gl.ProgramUniform1f(p, rp->uniform("height_"), k.height);
    gl.ProgramUniform1f(p, rp->uniform("s"), k.s);
    gl.ProgramUniform1f(p, rp->uniform("grid_w"), k.grid_w);
    gl.ProgramUniform1f(p, rp->uniform("grid_h"), k.grid_h);
    gl.ProgramUniform1f(p, rp->uniform("epsilon"), k.epsilon);
    gl.ProgramUniform1ui(p, rp->uniform("grid_wi"), k.grid_wi);
    gl.ProgramUniform1ui(p, rp->uniform("weight"), sample_weight_);
  }
  loc_first_ = reproject_prog_->uniform("first");
  loc_count_ = reproject_prog_->uniform("count");
  loc_packed_first_ = packed_prog_->uniform("first");
  loc_packed_count_ = packed_prog_->uniform("count");
  const GLuint e = exact_prog_->id();
  gl.ProgramUniform1i(e, exact_prog_->uniform("samples"), 4);
  loc_exact_first_ = exact_prog_->uniform("first");
  loc_exact_count_ = exact_prog_->uniform("count");
  loc_base_ = reproject_prog_->uniform("band_base");
  loc_packed_base_ = packed_prog_->uniform("band_base");
  loc_exact_base_ = exact_prog_->uniform("band_base");
  static_assert(kCounters == kGpuCounters);
}

unsigned char* GlReprojector::acquire_slot(int slot) {
  GLsync& f = fences_[slot];
  if (f) {
    const GLenum r = ctx_->gl().ClientWaitSync(f, GL_SYNC_FLUSH_COMMANDS_BIT, GLuint64(600) * 1000000000ull);
    ctx_->gl().DeleteSync(f);
    f = nullptr;
    if (r == GL_TIMEOUT_EXPIRED || r == GL_WAIT_FAILED)
      throw std::runtime_error("GL reprojection batch did not finish");
  }
  return ring_map_ + size_t(slot) * slot_bytes_;
}

void GlReprojector::bind_band(const Band& b, Kernel kernel) {
  const auto& gl = ctx_->gl();
  gl.BindBufferBase(GL_SHADER_STORAGE_BUFFER, 0, b.acc->id());
  if (kernel == Kernel::kExact) {
    gl.ProgramUniform1ui(exact_prog_->id(), loc_exact_base_, GLuint(b.first_cell));
    return;
  }
  gl.BindTextureUnit(1, b.texel_plane_tex->id());
  if (settings_.prefetch) gl.BindTextureUnit(3, b.acc_view->id());
  if (kernel == Kernel::kPacked)
    gl.ProgramUniform1ui(packed_prog_->id(), loc_packed_base_, GLuint(b.first_cell));
  else
    gl.ProgramUniform1ui(reproject_prog_->id(), loc_base_, GLuint(b.first_cell));
}

void GlReprojector::dispatch(int slot, size_t first_record, size_t count, Kernel kernel) {
  const auto& gl = ctx_->gl();
  gl.BindBufferBase(GL_SHADER_STORAGE_BUFFER, 1, counter_buf_->id());
  if (kernel == Kernel::kExact) {
    gl.UseProgram(exact_prog_->id());
    gl.BindTextureUnit(4, samples_tex_->id());
    gl.ProgramUniform1i(exact_prog_->id(), loc_exact_first_, GLint(size_t(slot) * slot_bytes_ / 16 + first_record));
    gl.ProgramUniform1ui(exact_prog_->id(), loc_exact_count_, GLuint(count));
  } else {
    const bool packed = kernel == Kernel::kPacked;
    const GLuint p = packed ? packed_prog_->id() : reproject_prog_->id();
    gl.UseProgram(p);
    // The packed kernel reads the ring as RGBA32UI texels (one per 16-byte record), the record
    // kernel as RGB32F texels (three per record).
    gl.BindTextureUnit(0, packed ? samples_tex_->id() : records_tex_->id());
    gl.BindTextureUnit(2, planes_tex_->id());
    gl.BindTextureUnit(5, crease_range_tex_->id());
    gl.BindTextureUnit(6, creases_tex_->id());
    if (packed) gl.BindBufferBase(GL_SHADER_STORAGE_BUFFER, 3, codec_buf_->id());
    const size_t first = packed ? size_t(slot) * slot_bytes_ / kPackedBytes + first_record
                                : size_t(slot) * slot_bytes_ / 12 + 3 * first_record;
    gl.ProgramUniform1i(p, packed ? loc_packed_first_ : loc_first_, GLint(first));
    gl.ProgramUniform1ui(p, packed ? loc_packed_count_ : loc_count_, GLuint(count));
  }
  const size_t groups = std::min<size_t>(
      size_t(settings_.workgroups), (count + size_t(settings_.workgroup_size) - 1) / size_t(settings_.workgroup_size));
  gl.DispatchCompute(GLuint(std::max<size_t>(groups, 1)), 1, 1);
  gl.MemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
  gl.UseProgram(0);
}

void GlReprojector::fence(int slot) { fences_[slot] = ctx_->gl().FenceSync(GL_SYNC_GPU_COMMANDS_COMPLETE, 0); }

void GlReprojector::bin_offsets(size_t n) {
  std::fill(bin_count_.begin(), bin_count_.end(), size_t(0));
  for (size_t j = 0; j < n; ++j)
    if (bin_band_[j] != kNoBand) ++bin_count_[bin_band_[j]];
  size_t offset = 0;
  for (size_t b = 0; b < bands_.size(); ++b) {
    bin_offset_[b] = offset;
    offset += bin_count_[b];
  }
}

void GlReprojector::dispatch_bands(int slot, Kernel kernel) {
  bool any = false;
  for (size_t b = 0; b < bands_.size(); ++b) {
    if (!bin_count_[b]) continue;
    bind_band(bands_[b], kernel);
    dispatch(slot, bin_offset_[b] - bin_count_[b], bin_count_[b], kernel);  // bin_offset_: the group's end by now
    any = true;
  }
  if (any) fence(slot);
}

size_t GlReprojector::record_bytes(Kernel kernel) {
  return kernel == Kernel::kRecords ? kRecordBytes : kPackedBytes;  // packed records and exact samples: 16
}

unsigned char* GlReprojector::pending_slot(Kernel kernel) {
  if (pending_n_ && pending_kernel_ != kernel) flush_pending();
  if ((pending_n_ + 1) * record_bytes(kernel) > slot_bytes_) flush_pending();
  pending_kernel_ = kernel;
  return pending_.data() + pending_n_ * record_bytes(kernel);
}

void GlReprojector::flush_pending() {
  if (!pending_n_) return;
  const int slot = next_slot_;
  next_slot_ = (next_slot_ + 1) % kSlots;
  unsigned char* out = acquire_slot(slot);
  const size_t bytes = record_bytes(pending_kernel_), n = pending_n_;
  pending_n_ = 0;
  bin_offsets(n);
  for (size_t j = 0; j < n; ++j) std::memcpy(out + (bin_offset_[bin_band_[j]]++) * bytes, &pending_[j * bytes], bytes);
  dispatch_bands(slot, pending_kernel_);
  uploaded(pending_kernel_, n);
}

void GlReprojector::uploaded(Kernel kernel, size_t n) {
  if (kernel == Kernel::kExact) return;
  points_since_fold_ += n;
  if (points_since_fold_ >= settings_.counter_fold_points) fold_counters();
}

uint32_t GlReprojector::band_of(const Vec3& position, const Vec3& normal) {
  uint32_t texel = 0;
  switch (detail::project_and_face(params_, position, normal, &texel)) {
    case detail::Decision::kCulled:
      ++cpu_counts_.culled;
      return kNoBand;
    case detail::Decision::kBackfacing:
      ++cpu_counts_.backfacing;
      ++cpu_counts_.occluded;
      return kNoBand;
    default:
      return uint32_t(texel / band_cells_);
  }
}

// One band: the records go straight into ring slots, each slot dispatched when full. Several bands:
// they wait in pending_ with their band (flush_pending() groups them by band).
template <class Put>
void GlReprojector::stream(Kernel kernel, size_t n, Put&& put) {
  const size_t bytes = record_bytes(kernel);
  if (bands_.size() > 1) {
    for (size_t i = 0; i < n; ++i) {
      unsigned char* dst = pending_slot(kernel);
      const uint32_t band = put(i, dst, true);
      if (band != kNoBand) bin_band_[pending_n_++] = band;
    }
    return;
  }
  const size_t per_slot = slot_bytes_ / bytes;
  for (size_t i = 0; i < n;) {
    const int slot = next_slot_;
    next_slot_ = (next_slot_ + 1) % kSlots;
    unsigned char* out = acquire_slot(slot);
    size_t m = 0;
    for (; i < n && m < per_slot; ++i)
      if (put(i, out + m * bytes, false) != kNoBand) ++m;
    if (m) {
      bind_band(bands_[0], kernel);
      dispatch(slot, 0, m, kernel);
      fence(slot);
    }
    uploaded(kernel, m);
  }
}

void GlReprojector::reproject(std::span<const VertexRecord> records) {
  ctx_->check_thread();
  static_assert(sizeof(VertexRecord) == 40 && offsetof(VertexRecord, radiance) == 24);
  // Steps 1-2 on the CPU; with several bands also 3-4 as far as the band (the shader repeats them
  // with the same arithmetic and reaches the same texel). The 36 bytes of float data are uploaded.
  stream(Kernel::kRecords, records.size(), [&](size_t i, unsigned char* dst, bool binned) {
    const VertexRecord& r = records[i];
    if (!r.diffuse() && !settings_.reproject_glossy) {
      ++cpu_counts_.not_diffuse;
      return kNoBand;
    }
    if (!detail::record_is_finite(r)) {
      ++cpu_counts_.invalid;
      return kNoBand;
    }
    const uint32_t band = binned ? band_of(r.position, r.normal) : 0u;
    if (band != kNoBand) std::memcpy(dst, &r, kRecordBytes);
    return band;
  });
}

void GlReprojector::set_codec(const VertexCodec& codec) {
  std::array<double, 8> p{};
  for (size_t a = 0; a < 3; ++a) {
    p[a] = codec.quantisation_origin()[a];
    p[4 + a] = codec.quantisation_cell()[a];
  }
  if (p == codec_params_) return;
  if (pending_n_ && pending_kernel_ == Kernel::kPacked) flush_pending();  // decoded with the former parameters
  codec_params_ = p;
  // Ordered after the dispatches already issued, which read the former parameters.
  ctx_->gl().NamedBufferSubData(codec_buf_->id(), 0, GLsizeiptr(sizeof(p)), p.data());
}

void GlReprojector::set_sample_weight(uint32_t units) {
  ctx_->check_thread();
  if (units == sample_weight_) return;
  if (pending_n_ && pending_kernel_ != Kernel::kExact) flush_pending();  // accepted at the former weight
  sample_weight_ = units;
  // Ordered after the dispatches already issued, which keep the former value.
  const auto& gl = ctx_->gl();
  for (const GlProgram* rp : {reproject_prog_.get(), packed_prog_.get()})
    gl.ProgramUniform1ui(rp->id(), rp->uniform("weight"), units);
}

void GlReprojector::copy_packed(const unsigned char* src, size_t n, unsigned char* dst) {
  if constexpr (std::endian::native == std::endian::little) {
    std::memcpy(dst, src, n * kPackedBytes);  // the wire form is the texel layout
  } else {
    for (size_t i = 0; i < n; ++i) {
      const PackedVertex v = VertexCodec::load(src + i * kPackedBytes);
      const uint32_t w[4] = {uint32_t(v.position_bits), uint32_t(v.position_bits >> 32), v.normal_bits,
                             v.radiance_bits};
      std::memcpy(dst + i * kPackedBytes, w, kPackedBytes);
    }
  }
}

// The wire records are copied into the upload slot as they are; the shader decodes them (each field
// only when the vertex gets that far) and counts the glossy ones. With several bands the CPU decodes
// position and normal first to find the band (and counts glossy, culled and back-facing records);
// the candidates wait in pending_.
void GlReprojector::reproject_packed(std::span<const std::string_view> parts, const VertexCodec& codec) {
  for (const std::string_view packed : parts) reproject_packed_part(packed, codec);
}

void GlReprojector::reproject_packed_part(std::string_view packed, const VertexCodec& codec) {
  ctx_->check_thread();
  const size_t total = packed.size() / kPackedBytes;
  if (total == 0) return;
  set_codec(codec);
  const auto* src = reinterpret_cast<const unsigned char*>(packed.data());
  stream(Kernel::kPacked, total, [&](size_t i, unsigned char* dst, bool binned) {
    const unsigned char* record = src + i * kPackedBytes;
    uint32_t band = 0;
    if (binned) {
      const PackedVertex v = VertexCodec::load(record);
      if (!settings_.reproject_glossy && !VertexCodec::decode_diffuse(v.position_bits)) {
        ++cpu_counts_.not_diffuse;
        return kNoBand;
      }
      band = band_of(codec.decode_position(v.position_bits), VertexCodec::decode_normal(v.normal_bits));
    }
    if (band != kNoBand) copy_packed(record, 1, dst);
    return band;
  });
}

std::vector<VertexRecord> GlReprojector::decode_packed(std::string_view packed, const VertexCodec& codec) {
  ctx_->check_thread();
  const auto& gl = ctx_->gl();
  const size_t n = packed.size() / kPackedBytes;
  std::vector<VertexRecord> out(n);
  if (n == 0) return out;
  if (!decode_prog_)
    decode_prog_ = std::make_unique<GlProgram>(*ctx_, shader_source(gl_shaders::kDecodeShader, settings_, true, true));
  set_codec(codec);
  constexpr size_t kChunk = size_t(1) << 20;  // records per dispatch (64-invocation groups: < 65535 of them)
  const size_t chunk = std::min(n, kChunk);
  GlBuffer in(*ctx_), decoded(*ctx_);
  gl.NamedBufferStorage(in.id(), GLsizeiptr(chunk * kPackedBytes), nullptr, GL_DYNAMIC_STORAGE_BIT);
  gl.NamedBufferStorage(decoded.id(), GLsizeiptr(chunk * 48), nullptr, 0);
  GlTexture tex(*ctx_, GL_TEXTURE_BUFFER);
  gl.TextureBuffer(tex.id(), GL_RGBA32UI, in.id());
  const GLuint p = decode_prog_->id();
  gl.ProgramUniform1i(p, decode_prog_->uniform("words"), 5);
  std::vector<unsigned char> words(chunk * kPackedBytes);
  std::vector<uint32_t> raw(chunk * 12);
  const auto* src = reinterpret_cast<const unsigned char*>(packed.data());
  for (size_t first = 0; first < n; first += chunk) {
    const size_t m = std::min(chunk, n - first);
    copy_packed(src + first * kPackedBytes, m, words.data());
    gl.NamedBufferSubData(in.id(), 0, GLsizeiptr(m * kPackedBytes), words.data());
    gl.UseProgram(p);
    gl.ProgramUniform1ui(p, decode_prog_->uniform("count"), GLuint(m));
    gl.BindTextureUnit(5, tex.id());
    gl.BindBufferBase(GL_SHADER_STORAGE_BUFFER, 2, decoded.id());
    gl.BindBufferBase(GL_SHADER_STORAGE_BUFFER, 3, codec_buf_->id());
    gl.DispatchCompute(GLuint((m + 63) / 64), 1, 1);
    gl.MemoryBarrier(GL_BUFFER_UPDATE_BARRIER_BIT);
    gl.UseProgram(0);
    gl.GetNamedBufferSubData(decoded.id(), 0, GLsizeiptr(m * 48), raw.data());
    ctx_->check_error("GlReprojector::decode_packed");
    const auto vec = [](const uint32_t* b) {
      return Vec3(std::bit_cast<float>(b[0]), std::bit_cast<float>(b[1]), std::bit_cast<float>(b[2]));
    };
    for (size_t i = 0; i < m; ++i) {
      const uint32_t* w = &raw[12 * i];
      VertexRecord& r = out[first + i];
      r.position = vec(w);
      r.normal = vec(w + 4);
      r.radiance = vec(w + 8);
      r.flags = w[3] ? VertexRecord::kDiffuse : 0;
    }
  }
  return out;
}

void GlReprojector::add_exact(std::span<const ExactSample> samples) {
  ctx_->check_thread();
  const size_t cells = size_t(grid_w_) * size_t(grid_h_);
  stream(Kernel::kExact, samples.size(), [&](size_t i, unsigned char* dst, bool binned) {
    const ExactSample& s = samples[i];
    if (!(s.subpixel < cells && detail::finite_bits(s.radiance.x) && detail::finite_bits(s.radiance.y) &&
          detail::finite_bits(s.radiance.z))) {
      ++cpu_counts_.invalid;
      return kNoBand;
    }
    std::memcpy(dst, &s, sizeof(ExactSample));
    ++cpu_counts_.exact;
    return binned ? s.subpixel / uint32_t(band_cells_) : 0u;
  });
}

}  // namespace epr
