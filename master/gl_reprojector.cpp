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

std::string shader_source(const char* body, const ReprojectorSettings& s, bool narrow_planes, bool packed = false) {
  return fmt::format(
      "#version 450\n#extension GL_NV_shader_atomic_float : require\n#define WORKGROUP_SIZE {}\n#define PREFETCH "
      "{}\n#define UNCOVERED {}\n#define PACKED {}\n"
      "#define GLOSSY {}\n#define COUNTERS {}u\n{}{}",
      s.workgroup_size, s.prefetch ? 1 : 0, narrow_planes ? "0xffffu" : "0xffffffffu", packed ? 1 : 0,
      s.reproject_glossy ? 1 : 0, kCounters, packed ? gl_shaders::kPackedDecode : "", body);
}

}  // namespace

GlReprojector::GlReprojector(GlContext& ctx, const Camera& camera, const DeepFramebuffer& dfb,
                             const ReprojectorSettings& settings)
    : ctx_(&ctx), settings_(settings) {
  init(camera, detail::plane_grid_for(camera, dfb, settings));
}

GlReprojector::GlReprojector(const Camera& camera, const DeepFramebuffer& dfb, const ReprojectorSettings& settings)
    : owned_ctx_(std::make_unique<GlContext>()), ctx_(owned_ctx_.get()), settings_(settings) {
  init(camera, detail::plane_grid_for(camera, dfb, settings));
}

GlReprojector::GlReprojector(GlContext& ctx, const Camera& camera, const detail::PlaneGrid& grid,
                             const ReprojectorSettings& settings)
    : ctx_(&ctx), settings_(settings) {
  init(camera, grid);
}

GlReprojector::GlReprojector(const Camera& camera, const detail::PlaneGrid& grid, const ReprojectorSettings& settings)
    : owned_ctx_(std::make_unique<GlContext>()), ctx_(owned_ctx_.get()), settings_(settings) {
  init(camera, grid);
}

GlReprojector::~GlReprojector() {
  try {
    ctx_->check_thread();
  } catch (const std::exception&) {
    // GL objects can only be deleted where the context is current; leak them rather than crash.
    logger("master")->error("GlReprojector destroyed on a thread its GL context is not current on; GL objects leak");
    for (auto* p : {&reproject_prog_, &packed_prog_, &exact_prog_, &downsample_prog_, &decode_prog_})
      (void)p->release();
    for (auto* p : {&ring_, &texel_plane_buf_, &planes_buf_, &crease_range_buf_, &creases_buf_, &acc_buf_,
                    &counter_buf_, &pixels_buf_, &codec_buf_})
      (void)p->release();
    for (auto* p : {&records_tex_, &samples_tex_, &texel_plane_tex_, &planes_tex_, &crease_range_tex_, &creases_tex_,
                    &acc_view_tex_})
      (void)p->release();
    (void)owned_ctx_.release();
    return;
  }
  for (GLsync& f : fences_)
    if (f) ctx_->gl().DeleteSync(f);
}

void GlReprojector::init(const Camera& camera, const detail::PlaneGrid& grid) {
  ctx_->check_thread();
  detail::validate_reprojector_inputs(camera, grid, settings_);
  if (!ctx_->has_extension("GL_NV_shader_atomic_float"))
    throw GlUnavailable(
        "the GL reprojector needs GL_NV_shader_atomic_float (Mesa llvmpipe has it); use the cpu back-end");
  const auto& gl = ctx_->gl();
  params_ = detail::make_kernel_params(camera, grid.subpixels, settings_.epsilon, settings_.joint_test);
  map_downsample_ = settings_.gl_map_downsample;
  subpixels_ = grid.subpixels;
  grid_w_ = grid.width;
  grid_h_ = grid.height;
  settings_.batch_points = (settings_.batch_points + 3) / 4 * 4;  // slots stay 16-byte aligned
  slot_bytes_ = settings_.batch_points * kRecordBytes;
  invocations_ = size_t(settings_.workgroups) * size_t(settings_.workgroup_size);
  const size_t cells = grid.texel_plane.size();

  GLint max_ssbo = 0, max_tbo = 0;
  gl.GetIntegerv(GL_MAX_SHADER_STORAGE_BLOCK_SIZE, &max_ssbo);
  gl.GetIntegerv(GL_MAX_TEXTURE_BUFFER_SIZE, &max_tbo);
  if (cells * 16 > size_t(unsigned(max_ssbo)) || cells > size_t(max_tbo))
    throw std::runtime_error(fmt::format(
        "subpixel grid {}x{} needs {} MiB of shader storage; this GL allows {} MiB (use the cpu back-end or a lower S)",
        grid_w_, grid_h_, cells * 16 >> 20, unsigned(max_ssbo) >> 20));
  if (kSlots * settings_.batch_points * 3 > size_t(max_tbo))
    throw std::runtime_error(
        fmt::format("batch_points {} exceeds this GL's buffer-texture limit", settings_.batch_points));

  // Compact deep framebuffer; 16-bit plane indices when there are few enough planes (halves the
  // largest randomly accessed array after the accumulation).
  const bool narrow = grid.planes.size() / 4 < 0xffff;
  reproject_prog_ = std::make_unique<GlProgram>(*ctx_, shader_source(gl_shaders::kReprojectShader, settings_, narrow));
  packed_prog_ =
      std::make_unique<GlProgram>(*ctx_, shader_source(gl_shaders::kReprojectShader, settings_, narrow, true));
  exact_prog_ = std::make_unique<GlProgram>(*ctx_, shader_source(gl_shaders::kExactShader, settings_, narrow));

  // Upload ring, persistently mapped.
  const GLbitfield map_flags = GL_MAP_WRITE_BIT | GL_MAP_PERSISTENT_BIT | GL_MAP_COHERENT_BIT;
  ring_ = std::make_unique<GlBuffer>(*ctx_);
  gl.NamedBufferStorage(ring_->id(), GLsizeiptr(kSlots * slot_bytes_), nullptr, map_flags);
  ring_map_ =
      static_cast<unsigned char*>(gl.MapNamedBufferRange(ring_->id(), 0, GLsizeiptr(kSlots * slot_bytes_), map_flags));
  if (!ring_map_) throw std::runtime_error("could not map the reprojection upload buffer");
  records_tex_ = std::make_unique<GlTexture>(*ctx_, GL_TEXTURE_BUFFER);
  gl.TextureBuffer(records_tex_->id(), GL_RGB32F, ring_->id());
  samples_tex_ = std::make_unique<GlTexture>(*ctx_, GL_TEXTURE_BUFFER);
  gl.TextureBuffer(samples_tex_->id(), GL_RGBA32UI, ring_->id());

  texel_plane_buf_ = std::make_unique<GlBuffer>(*ctx_);
  texel_plane_tex_ = std::make_unique<GlTexture>(*ctx_, GL_TEXTURE_BUFFER);
  if (narrow) {
    std::vector<uint16_t> narrow_index(cells);
    for (size_t i = 0; i < cells; ++i) narrow_index[i] = uint16_t(grid.texel_plane[i]);  // kUncovered -> 0xffff
    gl.NamedBufferStorage(texel_plane_buf_->id(), GLsizeiptr(cells * 2), narrow_index.data(), 0);
    gl.TextureBuffer(texel_plane_tex_->id(), GL_R16UI, texel_plane_buf_->id());
  } else {
    gl.NamedBufferStorage(texel_plane_buf_->id(), GLsizeiptr(cells * 4), grid.texel_plane.data(), 0);
    gl.TextureBuffer(texel_plane_tex_->id(), GL_R32UI, texel_plane_buf_->id());
  }
  std::vector<float> planes = grid.planes;
  if (planes.empty()) planes.assign(4, 0.f);  // GL wants a non-empty buffer
  planes_buf_ = std::make_unique<GlBuffer>(*ctx_);
  gl.NamedBufferStorage(planes_buf_->id(), GLsizeiptr(planes.size() * 4), planes.data(), 0);
  planes_tex_ = std::make_unique<GlTexture>(*ctx_, GL_TEXTURE_BUFFER);
  gl.TextureBuffer(planes_tex_->id(), GL_RGBA32F, planes_buf_->id());
  std::vector<uint32_t> crease_range = grid.crease_range;
  if (crease_range.empty()) crease_range.assign(2, 0u);
  crease_range_buf_ = std::make_unique<GlBuffer>(*ctx_);
  gl.NamedBufferStorage(crease_range_buf_->id(), GLsizeiptr(crease_range.size() * 4), crease_range.data(), 0);
  crease_range_tex_ = std::make_unique<GlTexture>(*ctx_, GL_TEXTURE_BUFFER);
  gl.TextureBuffer(crease_range_tex_->id(), GL_RG32UI, crease_range_buf_->id());
  std::vector<float> creases = grid.creases;
  if (creases.empty()) creases.assign(4, 0.f);
  creases_buf_ = std::make_unique<GlBuffer>(*ctx_);
  gl.NamedBufferStorage(creases_buf_->id(), GLsizeiptr(creases.size() * 4), creases.data(), 0);
  creases_tex_ = std::make_unique<GlTexture>(*ctx_, GL_TEXTURE_BUFFER);
  gl.TextureBuffer(creases_tex_->id(), GL_RGBA32F, creases_buf_->id());

  // Accumulation and counters.
  acc_buf_ = std::make_unique<GlBuffer>(*ctx_);
  // Mappable for reading: the round's downsample reads the cells in place (downsample_pixels).
  gl.NamedBufferStorage(acc_buf_->id(), GLsizeiptr(cells * 16), nullptr, GL_DYNAMIC_STORAGE_BIT | GL_MAP_READ_BIT);
  acc_view_tex_ = std::make_unique<GlTexture>(*ctx_, GL_TEXTURE_BUFFER);
  gl.TextureBuffer(acc_view_tex_->id(), GL_RGBA32UI, acc_buf_->id());
  counter_buf_ = std::make_unique<GlBuffer>(*ctx_);
  gl.NamedBufferStorage(counter_buf_->id(), GLsizeiptr(invocations_ * kCounters * 4), nullptr, GL_DYNAMIC_STORAGE_BIT);
  // The packed kernels' codec parameters (lo_q, cell as doubles), set per call when they change.
  codec_buf_ = std::make_unique<GlBuffer>(*ctx_);
  gl.NamedBufferStorage(codec_buf_->id(), GLsizeiptr(sizeof(codec_params_)), codec_params_.data(),
                        GL_DYNAMIC_STORAGE_BIT);

  // Uniforms that never change (the same in the record and the packed kernel).
  const auto& k = params_;
  for (const GlProgram* rp : {reproject_prog_.get(), packed_prog_.get()}) {
    const GLuint p = rp->id();
    gl.ProgramUniform1i(p, rp->uniform(rp == packed_prog_.get() ? "words" : "records"), 0);
    gl.ProgramUniform1i(p, rp->uniform("texel_plane"), 1);
    gl.ProgramUniform1i(p, rp->uniform("planes"), 2);
    gl.ProgramUniform1i(p, rp->uniform("crease_range"), 5);
    gl.ProgramUniform1i(p, rp->uniform("creases"), 6);
    gl.ProgramUniform1ui(p, rp->uniform("first_creased"), grid.first_creased);
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
  }
  loc_first_ = reproject_prog_->uniform("first");
  loc_count_ = reproject_prog_->uniform("count");
  loc_packed_first_ = packed_prog_->uniform("first");
  loc_packed_count_ = packed_prog_->uniform("count");
  const GLuint e = exact_prog_->id();
  gl.ProgramUniform1i(e, exact_prog_->uniform("samples"), 4);
  loc_exact_first_ = exact_prog_->uniform("first");
  loc_exact_count_ = exact_prog_->uniform("count");

  static_assert(kCounters == kGpuCounters);
  reset();
  ctx_->check_error("GlReprojector setup");
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

void GlReprojector::dispatch(int slot, size_t count, Kernel kernel) {
  const auto& gl = ctx_->gl();
  gl.BindBufferBase(GL_SHADER_STORAGE_BUFFER, 0, acc_buf_->id());
  gl.BindBufferBase(GL_SHADER_STORAGE_BUFFER, 1, counter_buf_->id());
  if (kernel == Kernel::kExact) {
    gl.UseProgram(exact_prog_->id());
    gl.BindTextureUnit(4, samples_tex_->id());
    gl.ProgramUniform1i(exact_prog_->id(), loc_exact_first_, GLint(size_t(slot) * slot_bytes_ / 16));
    gl.ProgramUniform1ui(exact_prog_->id(), loc_exact_count_, GLuint(count));
  } else {
    const bool packed = kernel == Kernel::kPacked;
    const GLuint p = packed ? packed_prog_->id() : reproject_prog_->id();
    gl.UseProgram(p);
    // The packed kernel reads the ring as RGBA32UI texels (one per 16-byte record).
    gl.BindTextureUnit(0, packed ? samples_tex_->id() : records_tex_->id());
    gl.BindTextureUnit(1, texel_plane_tex_->id());
    gl.BindTextureUnit(2, planes_tex_->id());
    gl.BindTextureUnit(5, crease_range_tex_->id());
    gl.BindTextureUnit(6, creases_tex_->id());
    if (settings_.prefetch) gl.BindTextureUnit(3, acc_view_tex_->id());
    if (packed) gl.BindBufferBase(GL_SHADER_STORAGE_BUFFER, 3, codec_buf_->id());
    gl.ProgramUniform1i(p, packed ? loc_packed_first_ : loc_first_,
                        GLint(size_t(slot) * slot_bytes_ / (packed ? kPackedBytes : 12)));
    gl.ProgramUniform1ui(p, packed ? loc_packed_count_ : loc_count_, GLuint(count));
  }
  const size_t groups = std::min<size_t>(
      size_t(settings_.workgroups), (count + size_t(settings_.workgroup_size) - 1) / size_t(settings_.workgroup_size));
  gl.DispatchCompute(GLuint(std::max<size_t>(groups, 1)), 1, 1);
  gl.MemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
  fences_[slot] = gl.FenceSync(GL_SYNC_GPU_COMMANDS_COMPLETE, 0);
  gl.UseProgram(0);
}

void GlReprojector::reproject(std::span<const VertexRecord> records) {
  ctx_->check_thread();
  static_assert(sizeof(VertexRecord) == 40 && offsetof(VertexRecord, radiance) == 24);
  size_t i = 0;
  while (i < records.size()) {
    const int slot = next_slot_;
    next_slot_ = (next_slot_ + 1) % kSlots;
    unsigned char* out = acquire_slot(slot);
    size_t n = 0;
    // Filter (steps 1-2 of the semantics) and copy the 36 bytes of float data of each record.
    for (; i < records.size() && n < settings_.batch_points; ++i) {
      const VertexRecord& r = records[i];
      if (!r.diffuse() && !settings_.reproject_glossy) {
        ++cpu_counts_.not_diffuse;
        continue;
      }
      if (!detail::record_is_finite(r)) {
        ++cpu_counts_.invalid;
        continue;
      }
      std::memcpy(out + n * kRecordBytes, &r, kRecordBytes);
      ++n;
    }
    if (n) dispatch(slot, n, Kernel::kRecords);
    points_since_fold_ += n;
    if (points_since_fold_ >= settings_.counter_fold_points) fold_counters();
  }
}

void GlReprojector::set_codec(const VertexCodec& codec) {
  std::array<double, 8> p{};
  for (size_t a = 0; a < 3; ++a) {
    p[a] = codec.quantisation_origin()[a];
    p[4 + a] = codec.quantisation_cell()[a];
  }
  if (p == codec_params_) return;
  codec_params_ = p;
  // Ordered after the dispatches already issued, which read the former parameters.
  ctx_->gl().NamedBufferSubData(codec_buf_->id(), 0, GLsizeiptr(sizeof(p)), p.data());
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
// only when the vertex gets that far) and counts the glossy ones.
void GlReprojector::reproject_packed(std::string_view packed, const VertexCodec& codec) {
  ctx_->check_thread();
  const size_t total = packed.size() / kPackedBytes;
  if (total == 0) return;
  set_codec(codec);
  const auto* src = reinterpret_cast<const unsigned char*>(packed.data());
  const size_t per_slot = slot_bytes_ / kPackedBytes;
  for (size_t i = 0; i < total;) {
    const int slot = next_slot_;
    next_slot_ = (next_slot_ + 1) % kSlots;
    const size_t n = std::min(total - i, per_slot);
    copy_packed(src + i * kPackedBytes, n, acquire_slot(slot));
    dispatch(slot, n, Kernel::kPacked);
    i += n;
    points_since_fold_ += n;
    if (points_since_fold_ >= settings_.counter_fold_points) fold_counters();
  }
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
  const size_t per_slot = slot_bytes_ / sizeof(ExactSample);
  const size_t cells = size_t(grid_w_) * size_t(grid_h_);
  size_t i = 0;
  while (i < samples.size()) {
    const int slot = next_slot_;
    next_slot_ = (next_slot_ + 1) % kSlots;
    unsigned char* out = acquire_slot(slot);
    size_t n = 0;
    for (; i < samples.size() && n < per_slot; ++i) {
      const ExactSample& s = samples[i];
      if (!(s.subpixel < cells && detail::finite_bits(s.radiance.x) && detail::finite_bits(s.radiance.y) &&
            detail::finite_bits(s.radiance.z))) {
        ++cpu_counts_.invalid;
        continue;
      }
      std::memcpy(out + n * sizeof(ExactSample), &s, sizeof(ExactSample));
      ++n;
    }
    cpu_counts_.exact += n;
    if (n) dispatch(slot, n, Kernel::kExact);
  }
}

std::array<uint64_t, GlReprojector::kGpuCounters> GlReprojector::read_gpu_counters() const {
  std::vector<uint32_t> c(invocations_ * kCounters);
  ctx_->gl().GetNamedBufferSubData(counter_buf_->id(), 0, GLsizeiptr(c.size() * 4), c.data());
  std::array<uint64_t, kGpuCounters> sum{};
  for (size_t i = 0; i < c.size(); ++i) sum[i % kCounters] += c[i];
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
  const std::array<uint64_t, kGpuCounters> gpu = read_gpu_counters();
  ReprojectionCounts r = cpu_counts_;
  r.not_diffuse += folded_[4] + gpu[4];
  r.accepted = folded_[0] + gpu[0];
  r.culled = folded_[1] + gpu[1];
  r.backfacing = folded_[2] + gpu[2];
  r.occluded = r.backfacing + folded_[3] + gpu[3];
  return r;
}

SubpixelAccumulation GlReprojector::read() {
  ctx_->check_thread();
  const size_t cells = size_t(grid_w_) * size_t(grid_h_);
  std::vector<float> raw(4 * cells);
  ctx_->gl().GetNamedBufferSubData(acc_buf_->id(), 0, GLsizeiptr(raw.size() * 4), raw.data());
  ctx_->check_error("GlReprojector::read");
  SubpixelAccumulation a;
  a.width = grid_w_;
  a.height = grid_h_;
  a.subpixels = subpixels_;
  a.sum.resize(3 * cells);
  a.count.resize(cells);
  for (size_t i = 0; i < cells; ++i) {
    a.sum[3 * i] = raw[4 * i];
    a.sum[3 * i + 1] = raw[4 * i + 1];
    a.sum[3 * i + 2] = raw[4 * i + 2];
    std::memcpy(&a.count[i], &raw[4 * i + 3], 4);
  }
  return a;
}

void GlReprojector::downsample_pixels_into(PixelReprojection* result, std::span<const uint8_t> skip, bool counts_only) {
  ctx_->check_thread();
  const auto& gl = ctx_->gl();
  if (map_downsample_) {
    // The accumulation mapped for reading (waits for the dispatches that write it) and downsampled
    // by the CPU code in place: on a software GL (llvmpipe) the buffer is host memory, and this is
    // several times cheaper than a compute pass plus its read-back. Same result as
    // downsample(read()).
    const size_t cells = size_t(grid_w_) * size_t(grid_h_);
    gl.MemoryBarrier(GL_CLIENT_MAPPED_BUFFER_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
    const void* mapped = gl.MapNamedBufferRange(acc_buf_->id(), 0, GLsizeiptr(cells * 16), GL_MAP_READ_BIT);
    if (!mapped) ctx_->check_error("GlReprojector::downsample_pixels (map)");
    if (mapped) {
      try {
        downsample_cells({static_cast<const AccumulationCell*>(mapped), cells}, grid_w_, grid_h_, subpixels_, skip,
                         result, counts_only);
      } catch (...) {
        gl.UnmapNamedBuffer(acc_buf_->id());
        throw;
      }
      gl.UnmapNamedBuffer(acc_buf_->id());
      ctx_->check_error("GlReprojector::downsample_pixels");
      return;
    }
  }
  const int W = grid_w_ / subpixels_, H = grid_h_ / subpixels_;
  const size_t pixels = size_t(W) * size_t(H);
  if (!downsample_prog_) {
    downsample_prog_ =
        std::make_unique<GlProgram>(*ctx_, shader_source(gl_shaders::kDownsampleShader, settings_, true));
    pixels_buf_ = std::make_unique<GlBuffer>(*ctx_);
    gl.NamedBufferStorage(pixels_buf_->id(), GLsizeiptr(pixels * 16), nullptr, GL_DYNAMIC_STORAGE_BIT);
  }
  const GLuint p = downsample_prog_->id();
  gl.UseProgram(p);
  gl.ProgramUniform1ui(p, downsample_prog_->uniform("image_w"), GLuint(W));
  gl.ProgramUniform1ui(p, downsample_prog_->uniform("image_h"), GLuint(H));
  gl.ProgramUniform1ui(p, downsample_prog_->uniform("subpixels"), GLuint(subpixels_));
  gl.ProgramUniform1ui(p, downsample_prog_->uniform("grid_w"), GLuint(grid_w_));
  gl.BindBufferBase(GL_SHADER_STORAGE_BUFFER, 0, acc_buf_->id());
  gl.BindBufferBase(GL_SHADER_STORAGE_BUFFER, 2, pixels_buf_->id());
  gl.DispatchCompute(GLuint((pixels + 63) / 64), 1, 1);
  gl.MemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT);
  gl.UseProgram(0);
  std::vector<float> raw(4 * pixels);
  gl.GetNamedBufferSubData(pixels_buf_->id(), 0, GLsizeiptr(raw.size() * 4), raw.data());
  ctx_->check_error("GlReprojector::downsample_pixels");
  PixelReprojection out{Image(W, H, 3), std::vector<uint64_t>(pixels, 0)};
  for (size_t i = 0; i < pixels; ++i) {
    out.radiance.data[3 * i] = raw[4 * i];
    out.radiance.data[3 * i + 1] = raw[4 * i + 1];
    out.radiance.data[3 * i + 2] = raw[4 * i + 2];
    uint32_t n;
    std::memcpy(&n, &raw[4 * i + 3], 4);
    out.count[i] = n;
  }
  *result = std::move(out);  // every pixel: the compute pass has no mask
}

void GlReprojector::reset() {
  ctx_->check_thread();
  const GLuint zero = 0;
  ctx_->gl().ClearNamedBufferData(acc_buf_->id(), GL_R32UI, GL_RED_INTEGER, GL_UNSIGNED_INT, &zero);
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
  // The SSBO layout: {float r, g, b; uint n} per subpixel.
  std::vector<float> raw(4 * cells);
  for (size_t i = 0; i < cells; ++i) {
    raw[4 * i] = acc.sum[3 * i];
    raw[4 * i + 1] = acc.sum[3 * i + 1];
    raw[4 * i + 2] = acc.sum[3 * i + 2];
    std::memcpy(&raw[4 * i + 3], &acc.count[i], 4);
  }
  const auto& gl = ctx_->gl();
  gl.NamedBufferSubData(acc_buf_->id(), 0, GLsizeiptr(raw.size() * 4), raw.data());
  const GLuint zero = 0;
  gl.ClearNamedBufferData(counter_buf_->id(), GL_R32UI, GL_RED_INTEGER, GL_UNSIGNED_INT, &zero);
  ctx_->check_error("GlReprojector::restore");
  // The GPU decides accepted, culled and occluded (backfacing apart); the CPU the rest.
  folded_ = {counts.accepted, counts.culled, counts.backfacing, counts.occluded - counts.backfacing, 0};
  cpu_counts_ = {};
  cpu_counts_.not_diffuse = counts.not_diffuse;
  cpu_counts_.invalid = counts.invalid;
  cpu_counts_.exact = counts.exact;
  points_since_fold_ = 0;
}

}  // namespace epr
