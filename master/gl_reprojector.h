// The OpenGL reprojector ("gl"): a compute shader on OSMesa/llvmpipe (or any GL 4.5 driver with
// GL_NV_shader_atomic_float).
//
// Data on the GL side:
//   - upload ring: 2 slots of batch_points records in one persistently mapped, coherent buffer; a
//     fence per slot keeps the CPU from overwriting a batch the GPU still reads. reproject() copies
//     36 bytes per record (position, normal, radiance as float32: lossless, so decisions are
//     bit-identical to the CPU back-end), filtering glossy (unless reproject_glossy) and non-finite
//     records on the way. reproject_packed() copies the 16-byte wire records as they are (one memcpy
//     per slot, up to 2.25 x batch_points of them) and a second variant of the kernel decodes them:
//     the GLSL of VertexCodec's decode_position / decode_normal (in double, as the codec) /
//     decode_radiance, bit-identical to it, each field decoded only when the vertex gets that far;
//     the kernel also counts the glossy ones. The codec's quantisation (lo_q, cell per axis) is a
//     32-byte SSBO, re-uploaded when a call passes a different codec. Records are read through
//     buffer textures (RGB32F, resp. RGBA32UI; texelFetch): llvmpipe vectorises texel fetches but
//     runs SSBO loads lane by lane, so this is ~3x faster.
//   - compact deep framebuffer (reprojection_kernel.h): plane index per texel (R16UI when the
//     frame shows fewer than 65535 distinct planes, else R32UI; one buffer texture per band, see
//     Limits) + RGBA32F plane table, buffer textures. The plane-index gather and the accumulation prefetch are issued
//     back to back so that their cache misses overlap.
//   - accumulation: SSBO of {float r, g, b; uint n} per subpixel (one per band), updated with atomicAdd (float
//     atomics from GL_NV_shader_atomic_float). Optionally prefetched by a vector gather through an
//     RGBA32UI view (ReprojectorSettings::prefetch), which overlaps the cache misses of 8 lanes
//     before the per-lane atomics serialise them.
//   - counters: 5 uints per shader invocation (accepted, culled, backfacing, other occluded, not
//     diffuse), written without atomics (each invocation owns its slots); summed on the CPU by
//     counts(), and folded into 64-bit host totals every counter_fold_points (2^31) points so that
//     no 32-bit slot can overflow.
// Each batch is one glDispatchCompute (one per band that has points, with several bands) of
// `workgroups` x `workgroup_size` invocations running a grid-stride loop. llvmpipe's worker threads (LP_NUM_THREADS)
// run the workgroups; llvmpipe executes a dispatch synchronously, so the copy of the next batch does not overlap it
// (the copy is ~4 % of the time). Throughput figures: bench/reproject_bench.cpp. On llvmpipe the cost is dominated by
// the per-lane atomic loops (4 atomics per accepted point) and the two random accesses per point (plane index,
// accumulation cell).
//
// Limits and bands. One SSBO may not exceed GL_MAX_SHADER_STORAGE_BLOCK_SIZE (llvmpipe: 128 MiB =
// 8M subpixels) nor a buffer texture GL_MAX_TEXTURE_BUFFER_SIZE texels, both queried at
// construction. The subpixel grid is therefore split into bands of whole grid rows, a multiple of S
// rows each (a pixel's subpixels lie in one band), of at most that many subpixels (and at most
// ReprojectorSettings::gl_max_band_cells); the bands are of equal height but the last. Each band
// has its own accumulation SSBO, its prefetch view and its plane-index buffer texture; only one
// band is bound at a time, at the bindings a single-band frame uses (so no more binding points).
// A frame that fits in one band (llvmpipe: up to 8M subpixels, e.g. 1024 x 512 at S = 4) runs
// exactly as before: one dispatch per batch, no work on the CPU besides the copy. With several
// bands (1920 x 1080 at S = 4: 4 bands; 3840 x 2160: 16), reproject() and reproject_packed() bin
// each batch by band on the CPU with the kernel's own detail::project_and_face (packed: after
// VertexCodec's decode of the position and the normal, bit-identical to the shader's): culled and
// back-facing points are counted on the CPU and not uploaded, the others are copied into the
// upload slot grouped by band, and each band with points gets one dispatch over its group with its
// buffers bound; the shader computes the same texel and subtracts the band's first subpixel.
// add_exact() bins by subpixel index. read(), restore(), reset(), downsample_pixels_into() (the
// mapped path maps every band; the compute path runs per band) go band by band; counts() and
// decode_packed() do not depend on bands. Grids are addressed with 32-bit subpixel indices
// (ExactSample), so up to 4G subpixels; memory on the GL side is 16 B of accumulation and 2 B
// (fewer than 65535 planes) or 4 B of plane index per subpixel, nothing of the plane grid is kept
// on the CPU side (on llvmpipe the buffers are host memory: all of it is in the process's RSS).
#pragma once

#include <array>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "master/gl_context.h"
#include "master/gl_program.h"
#include "master/reprojection_kernel.h"
#include "master/reprojector.h"

namespace epr {

struct AccumulationCell;

class GlReprojector final : public Reprojector {
 public:
  /// Uses `ctx` (current on this thread; must outlive the reprojector).
  GlReprojector(GlContext& ctx, const Camera& camera, const DeepFramebuffer& dfb, const ReprojectorSettings& settings);
  /// Creates and owns a context, current on the calling thread.
  GlReprojector(const Camera& camera, const DeepFramebuffer& dfb, const ReprojectorSettings& settings);
  /// From the compact deep framebuffer (built for `settings`, see detail::validate_reprojector_inputs).
  GlReprojector(GlContext& ctx, const Camera& camera, detail::PlaneGrid grid, const ReprojectorSettings& settings);
  GlReprojector(const Camera& camera, detail::PlaneGrid grid, const ReprojectorSettings& settings);
  ~GlReprojector() override;

  void reproject(std::span<const VertexRecord> records) override;
  using Reprojector::reproject_packed;
  void reproject_packed(std::span<const std::string_view> parts, const VertexCodec& codec) override;
  void add_exact(std::span<const ExactSample> samples) override;
  ReprojectionCounts counts() const override;
  SubpixelAccumulation read() override;
  void downsample_pixels_into(PixelReprojection* out, std::span<const uint8_t> skip = {},
                              DownsampleParts parts = DownsampleParts::kBoth) override;
  void reset() override;
  void restore(const SubpixelAccumulation& acc, const ReprojectionCounts& counts) override;
  void visit_cells(size_t max_cells, const std::function<void(std::span<const AccumulationCell>)>& visit) override;
  void restore_cells(const std::function<void(std::span<AccumulationCell>)>& fill,
                     const ReprojectionCounts& counts) override;
  size_t cell_count() const override { return size_t(grid_w_) * size_t(grid_h_); }
  std::string_view backend() const override { return "gl"; }
  void set_sample_weight(uint32_t units) override;

  GlContext& context() { return *ctx_; }
  /// Bands the subpixel grid is split into (see Limits above), and the subpixels of each but the last.
  size_t band_count() const { return bands_.size(); }
  size_t band_cells() const { return band_cells_; }

  /// The packed kernel's decoding on its own: each 16-byte record of `packed` decoded by the GLSL that
  /// reproject_packed() runs (bit-identical to VertexCodec::decode; for tests).
  std::vector<VertexRecord> decode_packed(std::string_view packed, const VertexCodec& codec);

 private:
  // Construction, stage by stage (init runs them in this order).
  void init(const Camera& camera, detail::PlaneGrid grid);
  void size_grid(const Camera& camera, const detail::PlaneGrid& grid);  // kernel parameters, grid and slot sizes
  void plan_bands();                                                    // bands_ within this GL's limits
  void compile_programs(bool narrow_planes);
  void create_upload_ring();
  void upload_plane_index(detail::PlaneGrid* grid, bool narrow_planes);  // per band; frees grid->texel_plane
  void create_accumulation();                                            // per band
  void upload_plane_tables(const detail::PlaneGrid& grid);               // planes, crease ranges, creases
  void create_counters();                                                // and the codec's parameters
  void set_fixed_uniforms(uint32_t first_creased);
  /// A buffer-texture view of `buffer` as `format` texels.
  std::unique_ptr<GlTexture> texture_view(const GlBuffer& buffer, GLenum format);
  /// An immutable buffer of `bytes` from `data` (one zero texel of `texel_bytes` if empty: GL wants a
  /// non-empty buffer) and its view as `format` texels.
  void upload_table(const void* data, size_t bytes, GLenum format, size_t texel_bytes,
                    std::unique_ptr<GlBuffer>* buffer, std::unique_ptr<GlTexture>* texture);
  /// The #version line and the #defines of `s` before a shader body.
  static std::string shader_source(const char* body, const ReprojectorSettings& s, bool narrow_planes,
                                   bool packed = false);
  /// Waits until `slot` of the upload ring is free and returns its mapped bytes.
  unsigned char* acquire_slot(int slot);
  enum class Kernel { kRecords, kPacked, kExact };
  /// One dispatch of `kernel` over `count` records from record `first_record` of the slot, with the
  /// band bound by bind_band(). No fence.
  void dispatch(int slot, size_t first_record, size_t count, Kernel kernel);
  /// reproject_packed() of one part (GL accumulates atomically: several calls give the same state as one).
  void reproject_packed_part(std::string_view packed, const VertexCodec& codec);
  /// Uploads the codec's quantisation (lo_q, cell) for the packed kernels if it changed.
  void set_codec(const VertexCodec& codec);
  /// The wire records as RGBA32UI texels (a memcpy on little-endian hosts).
  static void copy_packed(const unsigned char* src, size_t n, unsigned char* dst);

  std::unique_ptr<GlContext> owned_ctx_;
  GlContext* ctx_;
  ReprojectorSettings settings_;
  detail::KernelParams params_;
  int subpixels_ = 4, grid_w_ = 0, grid_h_ = 0;
  size_t slot_bytes_ = 0;
  size_t invocations_ = 0;

  std::unique_ptr<GlProgram> reproject_prog_, packed_prog_, exact_prog_, downsample_prog_, decode_prog_;
  std::unique_ptr<GlBuffer> pixels_buf_;  // W x H vec4: L_rp, M' (uint bits); created on first use
  bool map_downsample_ = true;            // ReprojectorSettings::gl_map_downsample
  std::unique_ptr<GlBuffer> ring_, planes_buf_, crease_range_buf_, creases_buf_, counter_buf_, codec_buf_;
  std::array<double, 8> codec_params_{};  // as in codec_buf_: lo_q.xyz, 0, cell.xyz, 0
  std::unique_ptr<GlTexture> records_tex_, samples_tex_, planes_tex_, crease_range_tex_, creases_tex_;
  /// A band of grid rows [row0, row0 + rows): its accumulation (acc, viewed as RGBA32UI by
  /// acc_view for the prefetch) and its plane index per texel (texel_plane, viewed by texel_plane_tex).
  struct Band {
    int row0 = 0, rows = 0;
    size_t first_cell = 0, cells = 0;  // row0 * grid_w, rows * grid_w
    std::unique_ptr<GlBuffer> acc, texel_plane;
    std::unique_ptr<GlTexture> acc_view, texel_plane_tex;
  };
  std::vector<Band> bands_;
  size_t band_cells_ = 0;  // subpixels of every band but the last: band of subpixel i = i / band_cells_
  // Several bands: records are binned on arrival and gathered in pending_ (the CPU side, up to a
  // slot's worth, across calls) so that small calls (one tile each) do not cost a dispatch per band;
  // flush_pending() copies them into a slot grouped by band and dispatches each band's group. Every
  // call that reads or replaces the accumulation or the counts flushes first (reset and restore
  // drop them).
  static constexpr uint32_t kNoBand = 0xffffffffu;
  std::vector<unsigned char> pending_;
  std::vector<uint32_t> bin_band_;  // per pending record: its band
  size_t pending_n_ = 0;
  Kernel pending_kernel_ = Kernel::kRecords;
  std::vector<size_t> bin_count_, bin_offset_;  // per band: records in the slot, next free record
  static size_t record_bytes(Kernel kernel);
  /// Makes room for a record of `kernel` in pending_ (flushing it if full or of another kernel) and
  /// returns where its bytes go; the caller keeps it by setting bin_band_[pending_n_++].
  unsigned char* pending_slot(Kernel kernel);
  void flush_pending();
  /// Streams records [0, n) to `kernel`'s dispatches, through ring slots (one band) or pending_
  /// (several). `put(i, dst, binned)` takes record i: it counts a record decided on the CPU and
  /// returns kNoBand, else writes the record's bytes at dst and returns its band (any value unless
  /// `binned`).
  template <class Put>
  void stream(Kernel kernel, size_t n, Put&& put);
  /// Counts `n` records uploaded to `kernel` towards the next fold of the GPU counters.
  void uploaded(Kernel kernel, size_t n);
  /// Steps 3-4 on the CPU: counts a culled or back-facing point and returns kNoBand, else its band.
  uint32_t band_of(const Vec3& position, const Vec3& normal);
  /// Counts the records of bin_band_[0, n) per band and turns them into offsets in the slot.
  void bin_offsets(size_t n);
  /// Dispatches `kernel` over the slot's records grouped by band (bin_count_), then fences the slot.
  void dispatch_bands(int slot, Kernel kernel);
  void bind_band(const Band& b, Kernel kernel);
  void fence(int slot);
  /// Maps every band's accumulation for reading into (*mapped)[band]; false (none mapped) on failure.
  bool map_bands(std::vector<const AccumulationCell*>* mapped);
  void unmap_bands(size_t n);  // bands [0, n)
  unsigned char* ring_map_ = nullptr;
  GLsync fences_[2] = {nullptr, nullptr};
  int next_slot_ = 0;
  GLint loc_first_ = -1, loc_count_ = -1, loc_packed_first_ = -1, loc_packed_count_ = -1;
  GLint loc_exact_first_ = -1, loc_exact_count_ = -1;
  GLint loc_base_ = -1, loc_packed_base_ = -1, loc_exact_base_ = -1;  // the bound band's first subpixel
  static constexpr size_t kGpuCounters = 5;
  /// Sums of the GPU's per-invocation counters (accepted, culled, backfacing, occluded, not diffuse).
  std::array<uint64_t, kGpuCounters> read_gpu_counters() const;
  /// Moves the GPU counters into folded_ (keeps the 32-bit GPU counters far from overflow).
  void fold_counters();

  // Decided on the CPU: not_diffuse (records; packed too with several bands), invalid, exact; with
  // several bands also culled and backfacing (= occluded) points, which are not uploaded.
  ReprojectionCounts cpu_counts_;
  std::array<uint64_t, kGpuCounters> folded_{};
  uint64_t points_since_fold_ = 0;
};

}  // namespace epr
