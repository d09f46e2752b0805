#include "wire/tile_result_stream.h"

#include <fmt/format.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <stdexcept>

#include "common/tile.h"

namespace epr {
namespace {

// Worst-case serialised bytes per item (see the file comment of the header).
constexpr uint32_t kPixelWireBytes = 12 + 5;
constexpr uint32_t kExactWireBytes = 12 + 5;
// A path count above this is not a count but garbage (paths_per_pixel is bounded far below it).
constexpr uint32_t kMaxPathCount = 1u << 20;
// The assembler reserves at most this many vertices / exact samples on the header's word; beyond it the
// arrays grow geometrically with the data that actually arrives. A header alone (a few bytes) must not
// make the master allocate much: reserving for 4 Mi announced vertices would take 160 MB per stream.
constexpr uint64_t kInitialReserve = 1u << 16;

uint32_t items_per_chunk(uint32_t max_chunk_bytes, uint32_t bytes_per_item, uint32_t cap) {
  const uint32_t room = max_chunk_bytes > TileResultLimits::kChunkFramingBytes
                            ? max_chunk_bytes - TileResultLimits::kChunkFramingBytes
                            : 0;
  return std::max<uint32_t>(1, std::min(cap, room / bytes_per_item));
}

bool finite_non_negative(const Vec3& v) { return is_finite(v) && v.x >= 0 && v.y >= 0 && v.z >= 0; }

bool same_bits(const Bounds3& a, const Bounds3& b) {
  for (int i = 0; i < 3; ++i)
    if (std::bit_cast<uint32_t>(a.lo[i]) != std::bit_cast<uint32_t>(b.lo[i]) ||
        std::bit_cast<uint32_t>(a.hi[i]) != std::bit_cast<uint32_t>(b.hi[i]))
      return false;
  return true;
}

}  // namespace

// ---- worker side ---------------------------------------------------------------------------------

TileResultWriter::TileResultWriter(const TileResult& result, TileResultIdentity identity, const Bounds3& codec_bounds,
                                   const TileResultLimits& limits)
    : result_(result) {
  EncodeCounts counts;
  if (result.packed_bounds) {
    // Encoded while tracing (TileRenderer with codec bounds): the bytes are ready, if the bounds are
    // the ones the master decodes with.
    if (!result.vertices.empty()) throw std::invalid_argument("TileResult has both records and packed vertices");
    if (!same_bits(*result.packed_bounds, codec_bounds))
      throw std::invalid_argument("TileResult's vertices were encoded with other codec bounds than the lease's");
    if (result.packed_vertices.size() % VertexCodec::kPackedBytes != 0)
      throw std::invalid_argument("TileResult's packed vertices are not a whole number of 16-byte records");
    packed_src_ = &result.packed_vertices;
    counts = result.encode_counts;
  } else if (!result.vertices.empty()) {  // path tracing sends no vertices and needs no usable bounds
    const VertexCodec codec(codec_bounds);
    codec.encode_batch(result.vertices, &packed_, &counts);
  }
  const uint64_t vertex_count = packed_src_->size() / VertexCodec::kPackedBytes;
  const uint64_t codec_nonfinite = counts[EncodeError::kNonFiniteRadiance];
  const uint64_t codec_rejected = counts.rejected_total() - codec_nonfinite;

  exact_kept_.reserve(result.visible.size());
  for (size_t i = 0; i < result.visible.size(); ++i)
    if (finite_non_negative(result.visible[i].radiance)) exact_kept_.push_back(uint32_t(i));
  const uint64_t exact_dropped = result.visible.size() - exact_kept_.size();

  uint64_t pixel_dropped = 0;
  for (const Vec3& s : result.path_sum)
    if (!finite_non_negative(s)) ++pixel_dropped;

  header_.set_lease_id(identity.lease_id);
  header_.set_job_id(std::move(identity.job_id));
  header_.set_round(identity.round);
  header_.set_tile_index(identity.tile_index);
  header_.mutable_worker_id()->set_id(std::move(identity.worker_id));
  header_.set_pixel_count(uint32_t(result.path_sum.size()));
  header_.set_vertex_count(vertex_count);
  header_.set_exact_sample_count(exact_kept_.size());
  header_.set_vertex_encoding(vertex_count > 0 ? v1::VERTEX_ENCODING_PACKED16 : v1::VERTEX_ENCODING_UNSPECIFIED);

  const TileStats& s = result.stats;
  stats_.set_paths_traced(s.paths.paths);
  // Exact mode's visibility rays are not in PathStats: one per vertex that reached the ray test.
  stats_.set_rays_traced(s.paths.rays + s.exact_occluded + result.visible.size());
  stats_.set_vertices_produced(s.vertices_recorded);
  stats_.set_culled_frustum(s.culled_frustum);
  stats_.set_culled_facing(s.culled_facing);
  stats_.set_culled_not_diffuse(s.culled_glossy);
  stats_.set_exact_occluded(s.exact_occluded);
  stats_.set_non_finite_dropped(s.paths.nonfinite_dropped + codec_nonfinite + exact_dropped + pixel_dropped);
  stats_.set_encode_rejected(codec_rejected);
  stats_.set_seconds_tracing(s.seconds);

  pixels_per_chunk_ = items_per_chunk(limits.max_chunk_bytes, kPixelWireBytes, TileResultLimits::kMaxPixelsPerChunk);
  vertices_per_chunk_ = items_per_chunk(limits.max_chunk_bytes, VertexCodec::kPackedBytes,
                                        std::max<uint32_t>(1, limits.max_vertices_per_chunk));
  exact_per_chunk_ =
      items_per_chunk(limits.max_chunk_bytes, kExactWireBytes, std::max<uint32_t>(1, limits.max_vertices_per_chunk));
}

bool TileResultWriter::next(v1::TileResultChunk* chunk) {
  for (;;) {
    switch (phase_) {
      case Phase::kHeader:
        *chunk->mutable_header() = header_;
        phase_ = Phase::kPixels;
        cursor_ = 0;
        return true;

      case Phase::kPixels: {
        const size_t n = result_.path_sum.size();
        if (cursor_ >= n) {
          phase_ = Phase::kVertices;
          cursor_ = 0;
          continue;
        }
        const size_t count = std::min<size_t>(pixels_per_chunk_, n - cursor_);
        v1::PixelPaths* p = chunk->mutable_pixels();
        p->set_first_pixel(uint32_t(cursor_));
        p->mutable_radiance_sum()->Reserve(int(3 * count));
        p->mutable_path_count()->Reserve(int(count));
        bool glossy = false;
        for (size_t i = cursor_; i < cursor_ + count; ++i) {
          const Vec3 s = finite_non_negative(result_.path_sum[i]) ? result_.path_sum[i] : Vec3(0.f);
          p->add_radiance_sum(s.x);
          p->add_radiance_sum(s.y);
          p->add_radiance_sum(s.z);
          p->add_path_count(result_.path_count[i]);
          glossy = glossy || (i < result_.glossy_sum.size() && !is_black(result_.glossy_sum[i]));
        }
        if (glossy) {
          p->mutable_glossy_sum()->Reserve(int(3 * count));
          for (size_t i = cursor_; i < cursor_ + count; ++i) {
            const Vec3 s = finite_non_negative(result_.path_sum[i]) ? result_.path_sum[i] : Vec3(0.f);
            const Vec3 g = finite_non_negative(result_.glossy_sum[i]) ? min(result_.glossy_sum[i], s) : Vec3(0.f);
            p->add_glossy_sum(g.x);
            p->add_glossy_sum(g.y);
            p->add_glossy_sum(g.z);
          }
        }
        cursor_ += count;
        return true;
      }

      case Phase::kVertices: {
        const size_t n = packed_src_->size() / VertexCodec::kPackedBytes;
        if (cursor_ >= n) {
          phase_ = Phase::kExact;
          cursor_ = 0;
          continue;
        }
        const size_t count = std::min<size_t>(vertices_per_chunk_, n - cursor_);
        v1::VertexBatch* b = chunk->mutable_vertices();
        b->set_count(uint32_t(count));
        // One copy, straight into the chunk's string (no temporary).
        b->mutable_packed()->assign(packed_src_->data() + cursor_ * VertexCodec::kPackedBytes,
                                    count * VertexCodec::kPackedBytes);
        cursor_ += count;
        return true;
      }

      case Phase::kExact: {
        const size_t n = exact_kept_.size();
        if (cursor_ >= n) {
          phase_ = Phase::kTrailer;
          continue;
        }
        const size_t count = std::min<size_t>(exact_per_chunk_, n - cursor_);
        v1::ExactSamples* e = chunk->mutable_exact_samples();
        e->mutable_subpixel()->Reserve(int(count));
        e->mutable_radiance()->Reserve(int(3 * count));
        for (size_t i = cursor_; i < cursor_ + count; ++i) {
          const VisibleSample& v = result_.visible[exact_kept_[i]];
          e->add_subpixel(v.subpixel);
          e->add_radiance(v.radiance.x);
          e->add_radiance(v.radiance.y);
          e->add_radiance(v.radiance.z);
        }
        cursor_ += count;
        return true;
      }

      case Phase::kTrailer:
        *chunk->mutable_trailer()->mutable_stats() = stats_;
        phase_ = Phase::kDone;
        // The packed vertices are no longer needed once the trailer is out.
        std::string().swap(packed_);
        return true;

      case Phase::kDone:
        return false;
    }
  }
}

std::vector<v1::TileResultChunk> split_tile_result(const TileResult& result, const TileResultIdentity& identity,
                                                   const Bounds3& codec_bounds, const TileResultLimits& limits) {
  TileResultWriter writer(result, identity, codec_bounds, limits);
  std::vector<v1::TileResultChunk> chunks;
  v1::TileResultChunk c;
  while (writer.next(&c)) {
    chunks.push_back(std::move(c));
    c.Clear();
  }
  return chunks;
}

// ---- master side ---------------------------------------------------------------------------------

TileResultAssembler::TileResultAssembler(TileExpectation expected)
    : expected_(std::move(expected)), codec_(expected_.codec_bounds) {
  const auto& e = expected_;
  if (!(e.x0 < e.x1 && e.y0 < e.y1 && e.x1 <= e.image_width && e.y1 <= e.image_height))
    throw std::invalid_argument(fmt::format("tile [{}, {}) x [{}, {}) is empty or outside the {}x{} image", e.x0, e.x1,
                                            e.y0, e.y1, e.image_width, e.image_height));
  if (e.subpixels < 1) throw std::invalid_argument("subpixels must be >= 1");
  const uint64_t n = uint64_t(e.x1 - e.x0) * (e.y1 - e.y0);
  if (n > UINT32_MAX) throw std::invalid_argument("tile too large");
  if (!e.skip.empty() && e.skip.size() != n)
    throw std::invalid_argument(fmt::format("skip has {} entries for a tile of {} pixels", e.skip.size(), n));
  if (!e.paths.empty() && e.paths.size() != n)
    throw std::invalid_argument(fmt::format("paths has {} entries for a tile of {} pixels", e.paths.size(), n));
  pixel_count_ = uint32_t(n);
}

std::optional<std::string> TileResultAssembler::fail(std::string reason) {
  error_ = std::move(reason);
  return error_;
}

std::optional<std::string> TileResultAssembler::add(v1::TileResultChunk* chunk) {
  if (!error_ && !complete_ && header_seen_ && chunk->part_case() == v1::TileResultChunk::kVertices &&
      chunk->ByteSizeLong() <= expected_.limits.max_chunk_bytes)
    return add_vertices(chunk->vertices(), chunk->mutable_vertices()->mutable_packed());
  return add(*chunk);
}

std::optional<std::string> TileResultAssembler::add(const v1::TileResultChunk& chunk) {
  if (error_) return error_;
  if (complete_) return fail("chunk after the trailer");
  if (chunk.ByteSizeLong() > expected_.limits.max_chunk_bytes)
    return fail(fmt::format("chunk of {} bytes exceeds max_chunk_bytes {}", chunk.ByteSizeLong(),
                            expected_.limits.max_chunk_bytes));
  if (chunk.part_case() == v1::TileResultChunk::kHeader) return add_header(chunk.header());
  if (chunk.part_case() == v1::TileResultChunk::PART_NOT_SET) return fail("chunk without a part (unknown field?)");
  if (!header_seen_) return fail("the first chunk must be the header");
  switch (chunk.part_case()) {
    case v1::TileResultChunk::kPixels:
      return add_pixels(chunk.pixels());
    case v1::TileResultChunk::kVertices:
      return add_vertices(chunk.vertices());
    case v1::TileResultChunk::kExactSamples:
      return add_exact(chunk.exact_samples());
    case v1::TileResultChunk::kTrailer:
      return add_trailer(chunk.trailer());
    default:
      return fail("chunk of an unknown kind");
  }
}

std::optional<std::string> TileResultAssembler::add_header(const v1::TileResultHeader& h) {
  if (header_seen_) return fail("a second header");
  const auto& e = expected_;
  if (h.job_id() != e.job_id) return fail(fmt::format("header job_id '{}' is not the lease's job", h.job_id()));
  if (h.round() != e.round) return fail(fmt::format("header round {} is not the lease's round {}", h.round(), e.round));
  if (h.tile_index() != e.tile_index)
    return fail(fmt::format("header tile_index {} is not the lease's tile {}", h.tile_index(), e.tile_index));
  if (h.pixel_count() != pixel_count_)
    return fail(fmt::format("header pixel_count {} is not the tile's area {}", h.pixel_count(), pixel_count_));
  const auto enc = h.vertex_encoding();
  if (enc != v1::VERTEX_ENCODING_UNSPECIFIED && enc != v1::VERTEX_ENCODING_PACKED16)
    return fail(fmt::format("unknown vertex_encoding {}", int(enc)));
  if (h.vertex_count() > 0 && enc != v1::VERTEX_ENCODING_PACKED16)
    return fail("vertex_encoding is required when vertex_count > 0");
  if (h.vertex_count() > 0 && e.payload != TileExpectation::Payload::kVertices)
    return fail(fmt::format("{} vertices announced for a job that takes none", h.vertex_count()));
  if (h.exact_sample_count() > 0 && e.payload != TileExpectation::Payload::kExactSamples)
    return fail(fmt::format("{} exact samples announced for a job that is not in exact mode", h.exact_sample_count()));
  if (e.max_vertices_per_tile > 0 && h.vertex_count() > e.max_vertices_per_tile)
    return fail(
        fmt::format("vertex_count {} exceeds the per-tile limit {}", h.vertex_count(), e.max_vertices_per_tile));
  if (e.max_vertices_per_tile > 0 && h.exact_sample_count() > e.max_vertices_per_tile)
    return fail(fmt::format("exact_sample_count {} exceeds the per-tile limit {}", h.exact_sample_count(),
                            e.max_vertices_per_tile));
  header_ = h;
  header_seen_ = true;
  tile_.lease_id = h.lease_id();
  tile_.worker_id = h.worker_id().id();
  tile_.x0 = e.x0;
  tile_.y0 = e.y0;
  tile_.x1 = e.x1;
  tile_.y1 = e.y1;
  tile_.path_sum.assign(pixel_count_, Vec3(0.f));
  if (e.paths_per_pixel == 0) tile_.path_count.assign(pixel_count_, 0);
  covered_.assign(pixel_count_, 0);
  // Reserve at most kInitialReserve up front (a header alone must not allocate what it announces);
  // grow with the data that arrives.
  if (!e.keep_packed) tile_.vertices.reserve(size_t(std::min<uint64_t>(h.vertex_count(), kInitialReserve)));
  tile_.exact_samples.reserve(size_t(std::min<uint64_t>(h.exact_sample_count(), kInitialReserve)));
  return std::nullopt;
}

std::optional<std::string> TileResultAssembler::add_pixels(const v1::PixelPaths& p) {
  const uint64_t first = p.first_pixel();
  const uint64_t count = uint64_t(p.path_count_size());
  if (count == 0) return fail("PixelPaths without pixels");
  if (count > TileResultLimits::kMaxPixelsPerChunk)
    return fail(fmt::format("PixelPaths of {} pixels exceeds {}", count, TileResultLimits::kMaxPixelsPerChunk));
  if (uint64_t(p.radiance_sum_size()) != 3 * count)
    return fail(fmt::format("PixelPaths has {} radiance values for {} pixels", p.radiance_sum_size(), count));
  if (p.glossy_sum_size() != 0 && uint64_t(p.glossy_sum_size()) != 3 * count)
    return fail(fmt::format("PixelPaths has {} glossy values for {} pixels", p.glossy_sum_size(), count));
  if (first >= pixel_count_ || first + count > pixel_count_)
    return fail(fmt::format("PixelPaths [{}, {}) outside the tile's {} pixels", first, first + count, pixel_count_));
  const auto& e = expected_;
  for (uint64_t k = 0; k < count; ++k) {
    const size_t i = size_t(first + k);
    if (covered_[i]) return fail(fmt::format("pixel {} sent twice", i));
    const uint32_t c = p.path_count(int(k));
    if (e.paths_per_pixel == 0) {
      if (c > kMaxPathCount) return fail(fmt::format("pixel {}: path_count {} is implausible", i, c));
    } else {
      const bool skipped = !e.skip.empty() && e.skip[i];
      const uint32_t want = skipped ? 0 : e.paths.empty() ? e.paths_per_pixel : e.paths[i];
      if (c != want) return fail(fmt::format("pixel {}: path_count {} but the lease asks for {}", i, c, want));
    }
  }
  for (uint64_t k = 0; k < count; ++k) {
    const size_t i = size_t(first + k);
    covered_[i] = 1;
    const Vec3 s(p.radiance_sum(int(3 * k)), p.radiance_sum(int(3 * k + 1)), p.radiance_sum(int(3 * k + 2)));
    if (finite_non_negative(s)) {
      tile_.path_sum[i] = s;
      if (p.glossy_sum_size() != 0) {
        // Glossy parts outside [0, the sum] (only a faulty worker sends them) are clamped into it.
        const Vec3 g(p.glossy_sum(int(3 * k)), p.glossy_sum(int(3 * k + 1)), p.glossy_sum(int(3 * k + 2)));
        if (tile_.glossy_sum.empty()) tile_.glossy_sum.assign(pixel_count_, Vec3(0.f));
        tile_.glossy_sum[i] = finite_non_negative(g) ? min(g, s) : Vec3(0.f);
      }
    } else {
      tile_.path_sum[i] = Vec3(0.f);  // dropped; the paths still count (their sample indices are used)
      ++tile_.dropped_pixel_sums;
    }
    if (e.paths_per_pixel == 0) tile_.path_count[i] = p.path_count(int(k));
  }
  pixels_covered_ += uint32_t(count);
  return std::nullopt;
}

std::optional<std::string> TileResultAssembler::add_vertices(const v1::VertexBatch& b, std::string* steal) {
  if (expected_.payload != TileExpectation::Payload::kVertices) return fail("VertexBatch for a job that takes none");
  if (b.count() > expected_.limits.max_vertices_per_chunk)
    return fail(fmt::format("VertexBatch of {} vertices exceeds max_vertices_per_chunk {}", b.count(),
                            expected_.limits.max_vertices_per_chunk));
  if (b.packed().size() != uint64_t(b.count()) * VertexCodec::kPackedBytes)
    return fail(fmt::format("VertexBatch packs {} bytes for {} vertices (16 each)", b.packed().size(), b.count()));
  if (tile_.vertex_count() + b.count() > header_.vertex_count())
    return fail(fmt::format("more vertices than the header's vertex_count {}", header_.vertex_count()));
  if (!expected_.keep_packed) {
    // Grow geometrically up to the announced count (decode_batch's own reserve is exact, which would
    // copy the whole array once per batch).
    const uint64_t need = tile_.vertices.size() + b.count();
    if (need > tile_.vertices.capacity())
      tile_.vertices.reserve(
          size_t(std::min<uint64_t>(header_.vertex_count(), std::max<uint64_t>(need, 2 * tile_.vertices.capacity()))));
    codec_.decode_batch(b.packed(), &tile_.vertices);  // total: any bits decode to a finite record
  } else if (steal && tile_.packed_vertices.empty()) {
    tile_.packed_vertices.swap(*steal);  // the usual case: one batch per tile, no copy
  } else {
    tile_.packed_vertices.append(b.packed());  // std::string grows geometrically
  }
  return std::nullopt;
}

std::optional<std::string> TileResultAssembler::add_exact(const v1::ExactSamples& s) {
  if (expected_.payload != TileExpectation::Payload::kExactSamples)
    return fail("ExactSamples for a job that is not in exact mode");
  const uint64_t n = uint64_t(s.subpixel_size());
  if (n > expected_.limits.max_vertices_per_chunk)
    return fail(fmt::format("ExactSamples of {} samples exceeds max_vertices_per_chunk {}", n,
                            expected_.limits.max_vertices_per_chunk));
  if (uint64_t(s.radiance_size()) != 3 * n)
    return fail(fmt::format("ExactSamples has {} radiance values for {} samples", s.radiance_size(), n));
  const uint64_t received = tile_.exact_samples.size() + tile_.dropped_exact_samples;
  if (received + n > header_.exact_sample_count())
    return fail(
        fmt::format("more exact samples than the header's exact_sample_count {}", header_.exact_sample_count()));
  const uint64_t S = expected_.subpixels;
  const uint64_t subpixels = S * expected_.image_width * S * expected_.image_height;
  for (uint64_t k = 0; k < n; ++k)
    if (s.subpixel(int(k)) >= subpixels)
      return fail(fmt::format("exact sample subpixel {} outside the {}x{} subpixel grid", s.subpixel(int(k)),
                              S * expected_.image_width, S * expected_.image_height));
  for (uint64_t k = 0; k < n; ++k) {
    const Vec3 r(s.radiance(int(3 * k)), s.radiance(int(3 * k + 1)), s.radiance(int(3 * k + 2)));
    if (finite_non_negative(r))
      tile_.exact_samples.emplace_back(s.subpixel(int(k)), r);
    else
      ++tile_.dropped_exact_samples;
  }
  return std::nullopt;
}

std::optional<std::string> TileResultAssembler::add_trailer(const v1::TileResultTrailer& t) {
  if (pixels_covered_ != pixel_count_)
    return fail(fmt::format("trailer after {} of the tile's {} pixels", pixels_covered_, pixel_count_));
  if (tile_.vertex_count() != header_.vertex_count())
    return fail(
        fmt::format("trailer after {} of the {} vertices announced", tile_.vertex_count(), header_.vertex_count()));
  const uint64_t exact = tile_.exact_samples.size() + tile_.dropped_exact_samples;
  if (exact != header_.exact_sample_count())
    return fail(fmt::format("trailer after {} of the {} exact samples announced", exact, header_.exact_sample_count()));
  tile_.worker_stats = t.stats();
  complete_ = true;
  return std::nullopt;
}

AssembledTile TileResultAssembler::take() {
  if (!complete_) throw std::logic_error("TileResultAssembler::take() before the trailer");
  AssembledTile out = std::move(tile_);
  tile_ = AssembledTile{};
  if (expected_.paths_per_pixel > 0) {
    out.paths_per_pixel = expected_.paths_per_pixel;
    out.skip = std::move(expected_.skip);  // checked against every pixel's count; not needed here any more
    out.paths = std::move(expected_.paths);
    expected_.skip.clear();
    expected_.paths.clear();
  }
  return out;
}

std::vector<uint32_t> AssembledTile::path_counts() const {
  if (paths_per_pixel == 0) return path_count;
  std::vector<uint32_t> out(path_sum.size(), paths_per_pixel);
  for (size_t i = 0; i < paths.size() && i < out.size(); ++i) out[i] = paths[i];
  for (size_t i = 0; i < skip.size() && i < out.size(); ++i)
    if (skip[i]) out[i] = 0;
  return out;
}

}  // namespace epr
