// See gl_reprojector.h. The GLSL mirrors detail::classify (reprojection_kernel.h) operation for
// operation; `precise` keeps the compiler from re-associating or fusing (llvmpipe also lowers ffma).
#include "master/gl_reprojector.h"

#include <algorithm>
#include <cstring>
#include <stdexcept>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "common/log.h"
#include "master/reprojection_image.h"

namespace epr {

namespace {

// ---- reprojection kernel -------------------------------------------------------------------------
constexpr const char* kReprojectShader = R"(
#extension GL_NV_shader_atomic_float : require
layout(local_size_x = WORKGROUP_SIZE) in;

uniform samplerBuffer records;       // RGB32F, 3 texels per record: position, normal, radiance
uniform usamplerBuffer texel_plane;  // R16UI or R32UI per texel: plane index, UNCOVERED if uncovered
uniform samplerBuffer planes;        // RGBA32F per plane: N.xyz, d
#if PREFETCH
uniform usamplerBuffer cell_view;    // RGBA32UI view of `cells`, only read to warm the cache
#endif
struct Cell { float r, g, b; uint n; };
layout(std430, binding = 0) buffer Accumulation { Cell cells[]; };
layout(std430, binding = 1) buffer Counters { uint counters[]; };  // 4 per invocation

uniform int first;    // texel of the batch's first record in `records`
uniform uint count;   // records in the batch
uniform vec3 eye, forward_, right_, up_;
uniform float tan_half_x, tan_half_y, width_, height_, s, grid_w, grid_h, epsilon;
uniform uint grid_wi;

void main() {
  uint gid = gl_GlobalInvocationID.x;
  uint stride = gl_NumWorkGroups.x * gl_WorkGroupSize.x;
  uint n_accepted = 0u, n_culled = 0u, n_backfacing = 0u, n_occluded = 0u;
  for (uint i = gid; i < count; i += stride) {
    int base = first + 3 * int(i);
    vec3 p = texelFetch(records, base).xyz;
    // Camera::project, expression for expression.
    precise float dx = p.x - eye.x;
    precise float dy = p.y - eye.y;
    precise float dz = p.z - eye.z;
    precise float z = dx * forward_.x + dy * forward_.y + dz * forward_.z;
    if (!(z > 0.0)) { n_culled++; continue; }
    precise float sx = (dx * right_.x + dy * right_.y + dz * right_.z) / z;
    precise float sy = (dx * up_.x + dy * up_.y + dz * up_.z) / z;
    precise float rx = (sx / tan_half_x + 1.0) * 0.5 * width_;
    precise float ry = (1.0 - sy / tan_half_y) * 0.5 * height_;
    precise float gx = rx * s;
    precise float gy = ry * s;
    if (!(gx >= 0.0 && gx < grid_w && gy >= 0.0 && gy < grid_h)) { n_culled++; continue; }
    vec3 n = texelFetch(records, base + 1).xyz;
    precise float ex = eye.x - p.x;
    precise float ey = eye.y - p.y;
    precise float ez = eye.z - p.z;
    precise float facing = n.x * ex + n.y * ey + n.z * ez;
    if (!(facing > 0.0)) { n_backfacing++; continue; }
    uint idx = uint(gy) * grid_wi + uint(gx);
#if PREFETCH
    // Issue the cell's cache miss as a vector gather now, next to the plane-index gather, so that
    // both misses overlap; the atomics below then hit the cache. (The value is used so that the
    // fetch is kept: a saturated count also stops accumulation.)
    uint warm = texelFetch(cell_view, int(idx)).w;
#endif
    uint plane = texelFetch(texel_plane, int(idx)).x;
#if PREFETCH
    if (warm == 0xffffffffu) { n_occluded++; continue; }
#endif
    if (plane == UNCOVERED) { n_occluded++; continue; }
    vec4 t = texelFetch(planes, int(plane));
    precise float dist = p.x * t.x + p.y * t.y + p.z * t.z - t.w;
    if (!(abs(dist) <= epsilon)) { n_occluded++; continue; }
    n_accepted++;
    vec3 L = texelFetch(records, base + 2).xyz;
    atomicAdd(cells[idx].r, L.r);
    atomicAdd(cells[idx].g, L.g);
    atomicAdd(cells[idx].b, L.b);
    atomicAdd(cells[idx].n, 1u);
  }
  counters[4u * gid + 0u] += n_accepted;
  counters[4u * gid + 1u] += n_culled;
  counters[4u * gid + 2u] += n_backfacing;
  counters[4u * gid + 3u] += n_occluded;
}
)";

// ---- exact-mode samples --------------------------------------------------------------------------
constexpr const char* kExactShader = R"(
#extension GL_NV_shader_atomic_float : require
layout(local_size_x = WORKGROUP_SIZE) in;
uniform usamplerBuffer samples;  // RGBA32UI per sample: subpixel, radiance bits (validated on the CPU)
struct Cell { float r, g, b; uint n; };
layout(std430, binding = 0) buffer Accumulation { Cell cells[]; };
uniform int first;
uniform uint count;
void main() {
  uint stride = gl_NumWorkGroups.x * gl_WorkGroupSize.x;
  for (uint i = gl_GlobalInvocationID.x; i < count; i += stride) {
    uvec4 e = texelFetch(samples, first + int(i));
    atomicAdd(cells[e.x].r, uintBitsToFloat(e.y));
    atomicAdd(cells[e.x].g, uintBitsToFloat(e.z));
    atomicAdd(cells[e.x].b, uintBitsToFloat(e.w));
    atomicAdd(cells[e.x].n, 1u);
  }
}
)";

// Downsampling next to the accumulation: one invocation per pixel averages the means of its non-empty
// subpixels and sums their counts (reprojection_image.h), so a round's end reads back W x H pixels
// instead of the whole S*W x S*H grid (16x less for S = 4).
constexpr const char* kDownsampleShader = R"(
layout(local_size_x = 64) in;
struct Cell { float r, g, b; uint n; };
layout(std430, binding = 0) readonly buffer Accumulation { Cell cells[]; };
layout(std430, binding = 2) writeonly buffer Pixels { vec4 pixels[]; };
uniform uint image_w;
uniform uint image_h;
uniform uint subpixels;
uniform uint grid_w;
void main() {
  uint p = gl_GlobalInvocationID.x;
  if (p >= image_w * image_h) return;
  uint x = p % image_w, y = p / image_w;
  vec3 mean = vec3(0.0);
  uint total = 0u, non_empty = 0u;
  for (uint j = 0u; j < subpixels; ++j)
    for (uint i = 0u; i < subpixels; ++i) {
      Cell c = cells[(y * subpixels + j) * grid_w + x * subpixels + i];
      if (c.n == 0u) continue;
      mean += vec3(c.r, c.g, c.b) / float(c.n);
      total += c.n;
      non_empty += 1u;
    }
  pixels[p] = vec4(non_empty > 0u ? mean / float(non_empty) : vec3(0.0), uintBitsToFloat(total));
}
)";

constexpr size_t kRecordBytes = 36;  // 9 floats
constexpr int kSlots = 2;

std::string shader_source(const char* body, const ReprojectorSettings& s, bool narrow_planes) {
  return fmt::format("#version 450\n#define WORKGROUP_SIZE {}\n#define PREFETCH {}\n#define UNCOVERED {}\n{}",
                     s.workgroup_size, s.prefetch ? 1 : 0, narrow_planes ? "0xffffu" : "0xffffffffu", body);
}

}  // namespace

GlReprojector::GlReprojector(GlContext& ctx, const Camera& camera, const DeepFramebuffer& dfb,
                             const ReprojectorSettings& settings)
    : ctx_(&ctx), settings_(settings) {
  init(camera, dfb);
}

GlReprojector::GlReprojector(const Camera& camera, const DeepFramebuffer& dfb, const ReprojectorSettings& settings)
    : owned_ctx_(std::make_unique<GlContext>()), ctx_(owned_ctx_.get()), settings_(settings) {
  init(camera, dfb);
}

GlReprojector::~GlReprojector() {
  try {
    ctx_->check_thread();
  } catch (const std::exception&) {
    // GL objects can only be deleted where the context is current; leak them rather than crash.
    logger("master")->error("GlReprojector destroyed on a thread its GL context is not current on; GL objects leak");
    for (auto* p : {&reproject_prog_, &exact_prog_, &downsample_prog_}) (void)p->release();
    for (auto* p : {&ring_, &texel_plane_buf_, &planes_buf_, &acc_buf_, &counter_buf_, &pixels_buf_}) (void)p->release();
    for (auto* p : {&records_tex_, &samples_tex_, &texel_plane_tex_, &planes_tex_, &acc_view_tex_}) (void)p->release();
    (void)owned_ctx_.release();
    return;
  }
  for (GLsync& f : fences_)
    if (f) ctx_->gl().DeleteSync(f);
}

void GlReprojector::init(const Camera& camera, const DeepFramebuffer& dfb) {
  ctx_->check_thread();
  detail::validate_reprojector_inputs(camera, dfb, settings_);
  if (!ctx_->has_extension("GL_NV_shader_atomic_float"))
    throw GlUnavailable("the GL reprojector needs GL_NV_shader_atomic_float (Mesa llvmpipe has it); use the cpu back-end");
  const auto& gl = ctx_->gl();
  params_ = detail::make_kernel_params(camera, dfb.subpixels, settings_.epsilon);
  map_downsample_ = settings_.gl_map_downsample;
  subpixels_ = dfb.subpixels;
  grid_w_ = dfb.width;
  grid_h_ = dfb.height;
  settings_.batch_points = (settings_.batch_points + 3) / 4 * 4;  // slots stay 16-byte aligned
  slot_bytes_ = settings_.batch_points * kRecordBytes;
  invocations_ = size_t(settings_.workgroups) * size_t(settings_.workgroup_size);
  const size_t cells = dfb.texel_count();

  GLint max_ssbo = 0, max_tbo = 0;
  gl.GetIntegerv(GL_MAX_SHADER_STORAGE_BLOCK_SIZE, &max_ssbo);
  gl.GetIntegerv(GL_MAX_TEXTURE_BUFFER_SIZE, &max_tbo);
  if (cells * 16 > size_t(unsigned(max_ssbo)) || cells > size_t(max_tbo))
    throw std::runtime_error(fmt::format(
        "subpixel grid {}x{} needs {} MiB of shader storage; this GL allows {} MiB (use the cpu back-end or a lower S)",
        grid_w_, grid_h_, cells * 16 >> 20, unsigned(max_ssbo) >> 20));
  if (kSlots * settings_.batch_points * 3 > size_t(max_tbo))
    throw std::runtime_error(fmt::format("batch_points {} exceeds this GL's buffer-texture limit", settings_.batch_points));

  // Compact deep framebuffer; 16-bit plane indices when there are few enough planes (halves the
  // largest randomly accessed array after the accumulation).
  const detail::PlaneGrid grid = detail::make_plane_grid(dfb);
  const bool narrow = grid.planes.size() / 4 < 0xffff;
  reproject_prog_ = std::make_unique<GlProgram>(*ctx_, shader_source(kReprojectShader, settings_, narrow));
  exact_prog_ = std::make_unique<GlProgram>(*ctx_, shader_source(kExactShader, settings_, narrow));

  // Upload ring, persistently mapped.
  const GLbitfield map_flags = GL_MAP_WRITE_BIT | GL_MAP_PERSISTENT_BIT | GL_MAP_COHERENT_BIT;
  ring_ = std::make_unique<GlBuffer>(*ctx_);
  gl.NamedBufferStorage(ring_->id(), GLsizeiptr(kSlots * slot_bytes_), nullptr, map_flags);
  ring_map_ = static_cast<unsigned char*>(gl.MapNamedBufferRange(ring_->id(), 0, GLsizeiptr(kSlots * slot_bytes_), map_flags));
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

  // Accumulation and counters.
  acc_buf_ = std::make_unique<GlBuffer>(*ctx_);
  // Mappable for reading: the round's downsample reads the cells in place (downsample_pixels).
  gl.NamedBufferStorage(acc_buf_->id(), GLsizeiptr(cells * 16), nullptr, GL_DYNAMIC_STORAGE_BIT | GL_MAP_READ_BIT);
  acc_view_tex_ = std::make_unique<GlTexture>(*ctx_, GL_TEXTURE_BUFFER);
  gl.TextureBuffer(acc_view_tex_->id(), GL_RGBA32UI, acc_buf_->id());
  counter_buf_ = std::make_unique<GlBuffer>(*ctx_);
  gl.NamedBufferStorage(counter_buf_->id(), GLsizeiptr(invocations_ * 16), nullptr, GL_DYNAMIC_STORAGE_BIT);

  // Uniforms that never change.
  const GLuint p = reproject_prog_->id();
  const GlProgram& rp = *reproject_prog_;
  gl.ProgramUniform1i(p, rp.uniform("records"), 0);
  gl.ProgramUniform1i(p, rp.uniform("texel_plane"), 1);
  gl.ProgramUniform1i(p, rp.uniform("planes"), 2);
  if (settings_.prefetch) gl.ProgramUniform1i(p, rp.uniform("cell_view"), 3);
  const auto& k = params_;
  gl.ProgramUniform3f(p, rp.uniform("eye"), k.eye.x, k.eye.y, k.eye.z);
  gl.ProgramUniform3f(p, rp.uniform("forward_"), k.forward.x, k.forward.y, k.forward.z);
  gl.ProgramUniform3f(p, rp.uniform("right_"), k.right.x, k.right.y, k.right.z);
  gl.ProgramUniform3f(p, rp.uniform("up_"), k.up.x, k.up.y, k.up.z);
  gl.ProgramUniform1f(p, rp.uniform("tan_half_x"), k.tan_half_x);
  gl.ProgramUniform1f(p, rp.uniform("tan_half_y"), k.tan_half_y);
  gl.ProgramUniform1f(p, rp.uniform("width_"), k.width);
  gl.ProgramUniform1f(p, rp.uniform("height_"), k.height);
  gl.ProgramUniform1f(p, rp.uniform("s"), k.s);
  gl.ProgramUniform1f(p, rp.uniform("grid_w"), k.grid_w);
  gl.ProgramUniform1f(p, rp.uniform("grid_h"), k.grid_h);
  gl.ProgramUniform1f(p, rp.uniform("epsilon"), k.epsilon);
  gl.ProgramUniform1ui(p, rp.uniform("grid_wi"), k.grid_wi);
  loc_first_ = rp.uniform("first");
  loc_count_ = rp.uniform("count");
  const GLuint e = exact_prog_->id();
  gl.ProgramUniform1i(e, exact_prog_->uniform("samples"), 4);
  loc_exact_first_ = exact_prog_->uniform("first");
  loc_exact_count_ = exact_prog_->uniform("count");

  reset();
  ctx_->check_error("GlReprojector setup");
}

unsigned char* GlReprojector::acquire_slot(int slot) {
  GLsync& f = fences_[slot];
  if (f) {
    const GLenum r = ctx_->gl().ClientWaitSync(f, GL_SYNC_FLUSH_COMMANDS_BIT, GLuint64(600) * 1000000000ull);
    ctx_->gl().DeleteSync(f);
    f = nullptr;
    if (r == GL_TIMEOUT_EXPIRED || r == GL_WAIT_FAILED) throw std::runtime_error("GL reprojection batch did not finish");
  }
  return ring_map_ + size_t(slot) * slot_bytes_;
}

void GlReprojector::dispatch(int slot, size_t count, bool exact) {
  const auto& gl = ctx_->gl();
  gl.BindBufferBase(GL_SHADER_STORAGE_BUFFER, 0, acc_buf_->id());
  gl.BindBufferBase(GL_SHADER_STORAGE_BUFFER, 1, counter_buf_->id());
  if (exact) {
    gl.UseProgram(exact_prog_->id());
    gl.BindTextureUnit(4, samples_tex_->id());
    gl.ProgramUniform1i(exact_prog_->id(), loc_exact_first_, GLint(size_t(slot) * slot_bytes_ / 16));
    gl.ProgramUniform1ui(exact_prog_->id(), loc_exact_count_, GLuint(count));
  } else {
    gl.UseProgram(reproject_prog_->id());
    gl.BindTextureUnit(0, records_tex_->id());
    gl.BindTextureUnit(1, texel_plane_tex_->id());
    gl.BindTextureUnit(2, planes_tex_->id());
    if (settings_.prefetch) gl.BindTextureUnit(3, acc_view_tex_->id());
    gl.ProgramUniform1i(reproject_prog_->id(), loc_first_, GLint(size_t(slot) * slot_bytes_ / 12));
    gl.ProgramUniform1ui(reproject_prog_->id(), loc_count_, GLuint(count));
  }
  const size_t groups = std::min<size_t>(size_t(settings_.workgroups),
                                         (count + size_t(settings_.workgroup_size) - 1) / size_t(settings_.workgroup_size));
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
    if (n) dispatch(slot, n, false);
    points_since_fold_ += n;
    if (points_since_fold_ >= settings_.counter_fold_points) fold_counters();
  }
}

// reproject() of the decoded records, decoding straight into the upload slot (decoded records are
// always finite: none is invalid).
void GlReprojector::reproject_packed(std::string_view packed, const VertexCodec& codec) {
  ctx_->check_thread();
  const size_t total = packed.size() / VertexCodec::kPackedBytes;
  const auto* src = reinterpret_cast<const unsigned char*>(packed.data());
  size_t i = 0;
  while (i < total) {
    const int slot = next_slot_;
    next_slot_ = (next_slot_ + 1) % kSlots;
    unsigned char* out = acquire_slot(slot);
    size_t n = 0;
    for (; i < total && n < settings_.batch_points; ++i) {
      const PackedVertex p = VertexCodec::load(src + i * VertexCodec::kPackedBytes);
      if (!VertexCodec::decode_diffuse(p.position_bits) && !settings_.reproject_glossy) {
        ++cpu_counts_.not_diffuse;
        continue;
      }
      const Vec3 v[3] = {codec.decode_position(p.position_bits), VertexCodec::decode_normal(p.normal_bits),
                         VertexCodec::decode_radiance(p.radiance_bits)};
      static_assert(sizeof(v) == kRecordBytes);
      std::memcpy(out + n * kRecordBytes, v, kRecordBytes);
      ++n;
    }
    if (n) dispatch(slot, n, false);
    points_since_fold_ += n;
    if (points_since_fold_ >= settings_.counter_fold_points) fold_counters();
  }
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
    if (n) dispatch(slot, n, true);
  }
}

std::array<uint64_t, 4> GlReprojector::read_gpu_counters() const {
  std::vector<uint32_t> c(invocations_ * 4);
  ctx_->gl().GetNamedBufferSubData(counter_buf_->id(), 0, GLsizeiptr(c.size() * 4), c.data());
  std::array<uint64_t, 4> sum{};
  for (size_t i = 0; i < c.size(); ++i) sum[i % 4] += c[i];
  return sum;
}

void GlReprojector::fold_counters() {
  const std::array<uint64_t, 4> gpu = read_gpu_counters();
  for (int k = 0; k < 4; ++k) folded_[size_t(k)] += gpu[size_t(k)];
  const GLuint zero = 0;
  ctx_->gl().ClearNamedBufferData(counter_buf_->id(), GL_R32UI, GL_RED_INTEGER, GL_UNSIGNED_INT, &zero);
  points_since_fold_ = 0;
}

ReprojectionCounts GlReprojector::counts() const {
  ctx_->check_thread();
  const std::array<uint64_t, 4> gpu = read_gpu_counters();
  ReprojectionCounts r = cpu_counts_;
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

PixelReprojection GlReprojector::downsample_pixels() {
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
      PixelReprojection out;
      try {
        out = downsample_cells({static_cast<const AccumulationCell*>(mapped), cells}, grid_w_, grid_h_, subpixels_);
      } catch (...) {
        gl.UnmapNamedBuffer(acc_buf_->id());
        throw;
      }
      gl.UnmapNamedBuffer(acc_buf_->id());
      ctx_->check_error("GlReprojector::downsample_pixels");
      return out;
    }
  }
  const int W = grid_w_ / subpixels_, H = grid_h_ / subpixels_;
  const size_t pixels = size_t(W) * size_t(H);
  if (!downsample_prog_) {
    downsample_prog_ = std::make_unique<GlProgram>(*ctx_, shader_source(kDownsampleShader, settings_, true));
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
  return out;
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
  folded_ = {counts.accepted, counts.culled, counts.backfacing, counts.occluded - counts.backfacing};
  cpu_counts_ = {};
  cpu_counts_.not_diffuse = counts.not_diffuse;
  cpu_counts_.invalid = counts.invalid;
  cpu_counts_.exact = counts.exact;
  points_since_fold_ = 0;
}

}  // namespace epr
