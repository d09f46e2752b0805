// See cpu_reprojector.h.
#include "master/cpu_reprojector.h"

#include <tbb/blocked_range.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <array>
#include <cstring>
#include <stdexcept>

#include "master/reprojection_image.h"

namespace epr {

namespace {
constexpr uint32_t kNone = 0xffffffffu;
constexpr size_t kChunk = 32768;           // records per pass pair (per thread when parallel)
constexpr size_t kMaxChunk = 16 * kChunk;  // (16 threads and more)
constexpr size_t kBlock = 2048;            // records per classification task (pass A's prefetches stay in L2)
constexpr size_t kPrefetchDistance = 32;   // accumulation: cells prefetched this many targets ahead
constexpr size_t kSerialBelow = kChunk;    // calls of fewer records: one thread
constexpr size_t kOwnersPerThread = 4;     // accumulation tasks per thread (load balance)
constexpr size_t kMaxOwners = 256;
constexpr size_t kStripesPerOwner = 16;
constexpr uint32_t kMinStripeShift = 6, kMaxStripeShift = 20;
}  // namespace

CpuReprojector::CpuReprojector(const Camera& camera, const DeepFramebuffer& dfb, const ReprojectorSettings& settings)
    : CpuReprojector(camera, detail::plane_grid_for(camera, dfb, settings), settings) {}

CpuReprojector::CpuReprojector(const Camera& camera, detail::PlaneGrid grid, const ReprojectorSettings& settings)
    : settings_(settings),
      params_(detail::make_kernel_params(camera, grid.subpixels, settings.epsilon, settings.joint_test)),
      grid_(std::move(grid)),
      subpixels_(grid_.subpixels) {
  detail::validate_reprojector_inputs(camera, grid_, settings);
  const size_t texels = grid_.texel_plane.size();
  // 16-bit plane indices when the table has fewer than 0xffff entries (as GL): kUncovered -> 0xffff.
  // Narrowed before the accumulation is allocated, so that both indices are never held beside it.
  if (grid_.planes.size() / 4 < kNarrowUncovered) {
    narrow_plane_.resize(grid_.texel_plane.size());
    tbb::parallel_for(tbb::blocked_range<size_t>(0, narrow_plane_.size()), [&](const tbb::blocked_range<size_t>& r) {
      for (size_t i = r.begin(); i < r.end(); ++i) narrow_plane_[i] = uint16_t(grid_.texel_plane[i]);
    });
    std::vector<uint32_t>().swap(grid_.texel_plane);
  }
  cells_.resize(texels);
  target_.resize(kChunk);
}

namespace {
// The threads this call may use: the arena's, capped by a tbb::global_control (epr render --threads,
// reproject_bench --cpu-threads).
size_t usable_threads() {
  const size_t arena = size_t(std::max(1, tbb::this_task_arena::max_concurrency()));
  const size_t limit = tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism);
  return std::max<size_t>(1, std::min(arena, limit));
}
}  // namespace

CpuReprojector::Owners CpuReprojector::owners_for(size_t n) const {
  const size_t threads = usable_threads();
  Owners o;
  if (n < kSerialBelow || threads == 1) return o;
  while (o.tasks < kOwnersPerThread * threads && o.tasks < kMaxOwners) o.tasks *= 2;
  o.mask = uint32_t(o.tasks - 1);
  o.shift = kMinStripeShift;
  while (o.shift < kMaxStripeShift && (cells_.size() >> (o.shift + 1)) >= kStripesPerOwner * o.tasks) ++o.shift;
  return o;
}

size_t CpuReprojector::chunk_for(const Owners& o) {
  const size_t threads = usable_threads();
  const size_t chunk = o.tasks == 1 ? kChunk : std::min(kChunk * threads, kMaxChunk);
  if (target_.size() < chunk) target_.resize(chunk);
  if (o.tasks > 1) {
    if (binned_.size() < chunk) binned_.resize(chunk);
    const size_t starts = (chunk + kBlock - 1) / kBlock * (o.tasks + 1);
    if (bin_start_.size() < starts) bin_start_.resize(starts);
  }
  return chunk;
}

// Counting sort of one block's accepted records by owner, each owner's in input order.
// `counted`: the classification has already counted the block's records per owner into
// start[owner + 1] (see bin_counts).
template <class Radiance>
void CpuReprojector::bin_block(size_t block, size_t begin, size_t end, const Owners& o, const Radiance& radiance_of,
                               bool counted) {
  uint32_t* start = &bin_start_[block * (o.tasks + 1)];
  if (!counted) {
    std::fill(start, start + o.tasks + 1, 0u);
    for (size_t i = begin; i < end; ++i) {
      const uint32_t t = target_[i];
      if (t != kNone) ++start[((t >> o.shift) & o.mask) + 1];
    }
  }
  std::array<uint32_t, kMaxOwners> cursor;
  for (size_t k = 0; k < o.tasks; ++k) {
    start[k + 1] += start[k];
    cursor[k] = start[k];
  }
  Entry* out = &binned_[begin];
  for (size_t i = begin; i < end; ++i) {
    const uint32_t t = target_[i];
    if (t == kNone) continue;
    const Vec3 L = radiance_of(i);
    out[cursor[(t >> o.shift) & o.mask]++] = {t, L.x, L.y, L.z};
  }
}

uint32_t* CpuReprojector::bin_counts(size_t block, const Owners& o) {
  if (o.tasks == 1) return nullptr;
  uint32_t* start = &bin_start_[block * (o.tasks + 1)];
  std::fill(start, start + o.tasks + 1, 0u);
  return start;
}

// One task per owner: its bins of blocks 0, 1, ... in turn (so its subpixels get their records in
// input order), cells prefetched kPrefetchDistance records ahead across the bins.
void CpuReprojector::accumulate_owned(size_t blocks, const Owners& o, uint32_t weight) {
  const float w = float(weight);
  tbb::parallel_for(
      tbb::blocked_range<size_t>(0, o.tasks, 1),
      [&](const tbb::blocked_range<size_t>& owners) {
        for (size_t k = owners.begin(); k < owners.end(); ++k) {
          auto lo = [&](size_t b) { return b * kBlock + bin_start_[b * (o.tasks + 1) + k]; };
          auto hi = [&](size_t b) { return b * kBlock + bin_start_[b * (o.tasks + 1) + k + 1]; };
          size_t pb = 0, pi = lo(0), pend = hi(0);  // the prefetch cursor
          auto prefetch_next = [&] {
            while (pi == pend && ++pb < blocks) pi = lo(pb), pend = hi(pb);
            if (pb < blocks) __builtin_prefetch(&cells_[binned_[pi++].target], 1);
          };
          for (size_t d = 0; d < kPrefetchDistance; ++d) prefetch_next();
          for (size_t b = 0; b < blocks; ++b) {
            for (size_t i = lo(b), e = hi(b); i < e; ++i) {
              prefetch_next();
              const Entry& en = binned_[i];
              Cell& c = cells_[en.target];
              c.r += w * en.r;
              c.g += w * en.g;
              c.b += w * en.b;
              c.n += weight;
            }
          }
        }
      },
      tbb::simple_partitioner());
}

template <class Radiance>
void CpuReprojector::accumulate_serial(size_t n, const Radiance& radiance_of, uint32_t weight) {
  const float w = float(weight);
  for (size_t i = 0; i < n; ++i) {
    if (i + kPrefetchDistance < n) {
      const uint32_t ahead = target_[i + kPrefetchDistance];
      if (ahead != kNone) __builtin_prefetch(&cells_[ahead], 1);
    }
    const uint32_t t = target_[i];
    if (t == kNone) continue;
    const Vec3 L = radiance_of(i);
    Cell& c = cells_[t];
    c.r += w * L.x;
    c.g += w * L.y;
    c.b += w * L.z;
    c.n += weight;
  }
}

void CpuReprojector::add_block_counts(const std::vector<std::array<uint32_t, 6>>& block_counts) {
  for (const auto& c : block_counts) {
    counts_.accepted += c[0];
    counts_.culled += c[1];
    counts_.backfacing += c[2];
    counts_.occluded += c[2] + c[3];
    counts_.not_diffuse += c[4];
    counts_.invalid += c[5];
  }
}

// reproject() of the decoded records, decoding in place: the diffuse bit first, position and normal
// for the projection, radiance only for accepted vertices. Decoded records are always finite, so
// none counts as invalid. The field decoders are VertexCodec's own (inline), so the values -- and
// therefore decisions and sums -- are those of reproject(codec.decode(...)).
// The parts are taken as one sequence cut into the same chunks as their concatenation would be (so
// the result is the same bit for bit); a chunk inside one part is read in place, one that spans
// parts is copied together first.
void CpuReprojector::reproject_packed(std::span<const std::string_view> parts, const VertexCodec& codec) {
  constexpr size_t kBytes = VertexCodec::kPackedBytes;
  size_t total = 0;
  for (const std::string_view p : parts) total += p.size() / kBytes;
  const Owners owners = owners_for(total);
  const size_t chunk = chunk_for(owners);
  if (position_.size() < chunk) position_.resize(chunk), normal_.resize(chunk);
  size_t part = 0, in_part = 0;  // the next record: parts[part], record in_part
  for (size_t off = 0; off < total; off += chunk) {
    const size_t n = std::min(chunk, total - off);
    while (in_part == parts[part].size() / kBytes) ++part, in_part = 0;
    const unsigned char* src = reinterpret_cast<const unsigned char*>(parts[part].data()) + in_part * kBytes;
    if (parts[part].size() / kBytes - in_part >= n) {
      in_part += n;
    } else {
      gathered_.resize(chunk * kBytes);
      for (size_t have = 0; have < n;) {
        while (in_part == parts[part].size() / kBytes) ++part, in_part = 0;
        const size_t m = std::min(n - have, parts[part].size() / kBytes - in_part);
        std::memcpy(gathered_.data() + have * kBytes, parts[part].data() + in_part * kBytes, m * kBytes);
        have += m;
        in_part += m;
      }
      src = gathered_.data();
    }
    auto radiance_of = [src](size_t i) {
      return VertexCodec::decode_radiance(VertexCodec::load(src + i * kBytes).radiance_bits);
    };
    const size_t blocks = (n + kBlock - 1) / kBlock;
    std::vector<std::array<uint32_t, 6>> block_counts(blocks);
    auto classify = [&](size_t b) {
      std::array<uint32_t, 6> c{};
      const size_t begin = b * kBlock, end = std::min(n, (b + 1) * kBlock);
      for (size_t i = begin; i < end; ++i) {
        const PackedVertex p = VertexCodec::load(src + i * kBytes);
        target_[i] = kNone;
        if (!VertexCodec::decode_diffuse(p.position_bits) && !settings_.reproject_glossy) {
          ++c[4];
          continue;
        }
        const Vec3 pos = codec.decode_position(p.position_bits);
        uint32_t texel = 0;
        const Vec3 nrm = VertexCodec::decode_normal(p.normal_bits);
        const detail::Decision d = detail::project_and_face(params_, pos, nrm, &texel);
        if (d != detail::Decision::kAccepted) {
          ++c[size_t(d)];
          continue;
        }
        target_[i] = texel;
        position_[i] = pos;
        normal_[i] = nrm;
        prefetch_plane(texel);
      }
      uint32_t* owned = bin_counts(b, owners);
      for (size_t i = begin; i < end; ++i) {
        const uint32_t texel = target_[i];
        if (texel == kNone) continue;
        const detail::Decision d = detail::plane_test_entry(params_, grid_, position_[i], normal_[i], plane_of(texel));
        ++c[size_t(d)];
        if (d != detail::Decision::kAccepted)
          target_[i] = kNone;
        else if (owned)
          ++owned[((texel >> owners.shift) & owners.mask) + 1];
      }
      block_counts[b] = c;
      if (owned) bin_block(b, begin, end, owners, radiance_of, true);
    };
    // A tile's worth of vertices (the master's calls): on the calling thread. Waking TBB's threads
    // (which then spin a while) costs more CPU than it saves there, and the master shares its cores
    // with gRPC; whole frames (the single-process render) go parallel.
    if (owners.tasks == 1) {
      for (size_t b = 0; b < blocks; ++b) classify(b);
      add_block_counts(block_counts);
      accumulate_serial(n, radiance_of, sample_weight_);
    } else {
      tbb::parallel_for(size_t(0), blocks, classify);
      add_block_counts(block_counts);
      accumulate_owned(blocks, owners, sample_weight_);
    }
  }
}

void CpuReprojector::reproject(std::span<const VertexRecord> records) {
  const Owners owners = owners_for(records.size());
  const size_t chunk = chunk_for(owners);
  for (size_t off = 0; off < records.size(); off += chunk) {
    const size_t n = std::min(chunk, records.size() - off);
    const VertexRecord* rec = records.data() + off;
    auto radiance_of = [rec](size_t i) { return rec[i].radiance; };
    const size_t blocks = (n + kBlock - 1) / kBlock;
    // Per block: accepted, culled, backfacing, occluded, not_diffuse, invalid.
    std::vector<std::array<uint32_t, 6>> block_counts(blocks);
    tbb::parallel_for(size_t(0), blocks, [&](size_t b) {
      std::array<uint32_t, 6> c{};
      const size_t begin = b * kBlock, end = std::min(n, (b + 1) * kBlock);
      // Pass A: filter, project, face; candidates keep their texel in target_ and their
      // deep-framebuffer entry is prefetched, so that pass B's random lookups overlap.
      for (size_t i = begin; i < end; ++i) {
        const VertexRecord& r = rec[i];
        target_[i] = kNone;
        if (!r.diffuse() && !settings_.reproject_glossy) {
          ++c[4];
          continue;
        }
        if (!detail::record_is_finite(r)) {
          ++c[5];
          continue;
        }
        uint32_t texel = 0;
        const detail::Decision d = detail::project_and_face(params_, r.position, r.normal, &texel);
        if (d != detail::Decision::kAccepted) {
          ++c[size_t(d)];
          continue;
        }
        target_[i] = texel;
        prefetch_plane(texel);
      }
      // Pass B: the plane test of the candidates (counted per owner when parallel).
      uint32_t* owned = bin_counts(b, owners);
      for (size_t i = begin; i < end; ++i) {
        const uint32_t texel = target_[i];
        if (texel == kNone) continue;
        const detail::Decision d =
            detail::plane_test_entry(params_, grid_, rec[i].position, rec[i].normal, plane_of(texel));
        ++c[size_t(d)];
        if (d != detail::Decision::kAccepted)
          target_[i] = kNone;
        else if (owned)
          ++owned[((texel >> owners.shift) & owners.mask) + 1];
      }
      block_counts[b] = c;
      if (owned) bin_block(b, begin, end, owners, radiance_of, true);
    });
    add_block_counts(block_counts);
    if (owners.tasks > 1)
      accumulate_owned(blocks, owners, sample_weight_);
    else
      accumulate_serial(n, radiance_of, sample_weight_);
  }
}

void CpuReprojector::add_exact(std::span<const ExactSample> samples) {
  const Owners owners = owners_for(samples.size());
  const size_t chunk = chunk_for(owners);
  for (size_t off = 0; off < samples.size(); off += chunk) {
    const size_t n = std::min(chunk, samples.size() - off);
    const ExactSample* s = samples.data() + off;
    auto radiance_of = [s](size_t i) { return s[i].radiance; };
    uint64_t valid = 0;
    for (size_t i = 0; i < n; ++i) {
      const bool ok = s[i].subpixel < cells_.size() && detail::finite_bits(s[i].radiance.x) &&
                      detail::finite_bits(s[i].radiance.y) && detail::finite_bits(s[i].radiance.z);
      target_[i] = ok ? s[i].subpixel : kNone;
      valid += ok;
    }
    counts_.exact += valid;
    counts_.invalid += n - valid;
    if (owners.tasks > 1) {
      const size_t blocks = (n + kBlock - 1) / kBlock;
      tbb::parallel_for(size_t(0), blocks, [&](size_t b) {
        bin_block(b, b * kBlock, std::min(n, (b + 1) * kBlock), owners, radiance_of, false);
      });
      accumulate_owned(blocks, owners, 1);
    } else {
      accumulate_serial(n, radiance_of, 1);
    }
  }
}

SubpixelAccumulation CpuReprojector::read() {
  SubpixelAccumulation a;
  a.width = grid_.width;
  a.height = grid_.height;
  a.subpixels = subpixels_;
  a.sum.resize(3 * cells_.size());
  a.count.resize(cells_.size());
  tbb::parallel_for(size_t(0), cells_.size(), [&](size_t i) {
    a.sum[3 * i] = cells_[i].r;
    a.sum[3 * i + 1] = cells_[i].g;
    a.sum[3 * i + 2] = cells_[i].b;
    a.count[i] = cells_[i].n;
  });
  return a;
}

void CpuReprojector::downsample_pixels_into(PixelReprojection* out, std::span<const uint8_t> skip,
                                            DownsampleParts parts) {
  static_assert(sizeof(Cell) == sizeof(AccumulationCell));
  const std::span<const AccumulationCell> cells(reinterpret_cast<const AccumulationCell*>(cells_.data()),
                                                cells_.size());
  downsample_cells(cells, grid_.width, grid_.height, subpixels_, skip, out, parts);
}

void CpuReprojector::reset() {
  std::fill(cells_.begin(), cells_.end(), Cell{});
  counts_ = {};
}

void CpuReprojector::restore(const SubpixelAccumulation& acc, const ReprojectionCounts& counts) {
  if (acc.width != grid_.width || acc.height != grid_.height || acc.subpixels != subpixels_ ||
      acc.sum.size() != 3 * cells_.size() || acc.count.size() != cells_.size())
    throw std::invalid_argument("the accumulation to restore is not of this reprojector's subpixel grid");
  for (size_t i = 0; i < cells_.size(); ++i)
    cells_[i] = {acc.sum[3 * i], acc.sum[3 * i + 1], acc.sum[3 * i + 2], acc.count[i]};
  counts_ = counts;
}

void CpuReprojector::visit_cells(size_t max_cells,
                                 const std::function<void(std::span<const AccumulationCell>)>& visit) {
  static_assert(sizeof(Cell) == sizeof(AccumulationCell));
  const auto* cells = reinterpret_cast<const AccumulationCell*>(cells_.data());
  for (size_t off = 0; off < cells_.size(); off += max_cells)
    visit({cells + off, std::min(max_cells, cells_.size() - off)});
}

void CpuReprojector::restore_cells(const std::function<void(std::span<AccumulationCell>)>& fill,
                                   const ReprojectionCounts& counts) {
  constexpr size_t kChunk = size_t(1) << 20;
  auto* cells = reinterpret_cast<AccumulationCell*>(cells_.data());
  try {
    for (size_t off = 0; off < cells_.size(); off += kChunk) fill({cells + off, std::min(kChunk, cells_.size() - off)});
  } catch (...) {
    reset();
    throw;
  }
  counts_ = counts;
}

}  // namespace epr
