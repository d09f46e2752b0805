// Compact wire encoding of VertexRecord: 16 bytes per vertex instead of 40 (epr.v1
// VERTEX_ENCODING_PACKED16, proto/epr/v1/worker_service.proto). Workers encode the vertices of a tile,
// the master decodes them for the reprojector; its GL/CPU kernels may also read the words directly,
// so the layout below is the contract.
//
// Layout (all words little-endian on the wire: bytes 0-7 position, 8-11 normal, 12-15 radiance):
//
//   position_bits (uint64)  bits  0-20 qx, 21-41 qy, 42-62 qz, bit 63 = VertexRecord::kDiffuse
//     Each coordinate is quantised to 21 bits inside the *quantisation box*: the scene bounds grown
//     on every side by margin = max(E * 2^-10, 2^-20 m), E the largest extent of the bounds (so hit
//     points a rounding error outside a wall still encode, and flat bounds still have a range).
//     In double precision, per axis a:
//         lo_q = lo_a - margin,  extent = (hi_a + margin) - lo_q
//         q    = min(floor((p_a - lo_q) / extent * 2^21), 2^21 - 1)
//         decoded p_a = float(lo_q + (q + 0.5) * (extent / 2^21))      (centre of the cell)
//     Positions outside the quantisation box (or non-finite) are REJECTED, never clamped: a point
//     that far outside the scene is a bug upstream, and clamping would move it onto the box.
//   normal_bits (uint32)    bits 0-15 ox, 16-31 oy: octahedral map (Cigolle et al. 2014) of the
//     normal, each coordinate as snorm16: q = round(o * 32767) stored as int16 two's complement
//     (GL_RG16_SNORM compatible; -32768 decodes as -1). Axis-aligned normals are exact. The encoder
//     accepts any finite non-zero normal (it is normalised); the decoder returns unit length. The
//     lower hemisphere (z < 0; -0 counts as upper) is folded with o' = ((1 - |oy|) sgn ox,
//     (1 - |ox|) sgn oy), where sgn keeps the sign of zero (copysign): decoding can yield -0 on the
//     equator and re-encoding it must land on the same code.
//   radiance_bits (uint32)  bits 0-7 r, 8-15 g, 16-23 b, 24-31 E: shared-exponent RGB with 8-bit
//     mantissas and an 8-bit exponent (Ward's RGBE, the Radiance .hdr format), value = m * 2^(E-136),
//     E = 0 meaning black. We trade RGB9E5's 9th mantissa bit for range: RGB9E5 stops at 65408 and
//     loses relative precision below ~6e-5, which real radiance values cross (NEE near an emitter,
//     scenes in other units); this format covers [2^-135, 1.69e38] and never clamps. Encoding rounds
//     to nearest, decoding is exact. NaN, infinite, negative, or >= 1.69e38 radiance is REJECTED;
//     -0 counts as 0. Every 128-bit pattern decodes to a finite, non-negative radiance.
//
// Error bounds (checked by tests/common/vertex_codec_test.cpp):
//   position  per axis <= extent_a / 2^22 + ulp_float(max(|lo_q|, |hi_q|)): half a cell plus the
//             float rounding of the decoded value. Cornell box (2 m cube around the origin):
//             0.48 um + 0.24 um ~= 0.72 um, about 1/1400 of the default plane-test epsilon
//             (0.03 % of the 3.46 m diagonal ~= 1.04 mm).
//   normal    angle <= 6.6e-5 rad (0.0038 deg): rounding moves each octahedral coordinate by at most
//             1/65534, the octahedron point by at most sqrt(6)/65534, and the direction by at most
//             asin(sqrt(3) * sqrt(6) / 65534) = 6.47e-5 rad, plus float rounding. Consequently the sign
//             of dot(normal, d) survives for every unit d with |dot(normal, d)| > 6.6e-5 (a facing test
//             can only change for directions within 0.004 deg of grazing). Observed worst: 6.44e-5.
//   radiance  per channel |decoded - original| <= max_channel / 255 (0.39 %) when the max channel is
//             >= 2^-128; below that the absolute error is <= 2^-137. The error of a channel is relative
//             to the largest channel, so a channel much dimmer than the others is coarse (a 1 % blue
//             beside red keeps ~2.5 levels); rounding to nearest makes that a systematic error of at
//             most the same 0.39 % of the max channel per vertex.
//
// Determinism: encode and decode use only IEEE basic operations (+ - * / sqrt), floor (as an exact
// truncation), frexp and ldexp (read from / built into a double's exponent bits) -- all exact or
// correctly rounded; the tree builds with -ffp-contract=off -- so the same record gives the same bits
// on every machine. The encoder is written for speed but computes exactly these operations: the
// per-vertex choices (fold, floor) are bit selects instead of branches, and encode_batch runs the
// same operations on four records at once in vector lanes (AVX2 where the CPU has it). Both are
// checked bit for bit against the plain formulas (tests/common/vertex_codec_reference.h).
// encode(decode(bits)) == bits for every output of encode when the scene bounds are not far from the
// origin relative to their size (|coordinates| < ~4 extents, so the float spacing is below half a cell).
#pragma once

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "common/math.h"
#include "common/vertex_record.h"

namespace epr {

namespace codec_detail {
/// 2^k as a double, exactly, for -1022 <= k <= 1023 (= std::ldexp(1.0, k) there, without the call).
inline double pow2(int k) { return std::bit_cast<double>(uint64_t(k + 1023) << 52); }
}  // namespace codec_detail

struct PackedVertex {
  uint64_t position_bits = 0;
  uint32_t normal_bits = 0;
  uint32_t radiance_bits = 0;

  bool operator==(const PackedVertex&) const = default;
};
static_assert(sizeof(PackedVertex) == 16, "PackedVertex is the 16-byte wire record");

/// Why encode() refused a record. The worker counts these (TileWorkerStats.encode_rejected and
/// non_finite_dropped) instead of sending the vertex.
enum class EncodeError : uint8_t {
  kOk = 0,
  kNonFinitePosition,
  kOutsideBounds,      // outside the quantisation box (scene bounds plus margin)
  kBadNormal,          // zero or non-finite
  kNonFiniteRadiance,  // NaN or infinite channel
  kNegativeRadiance,   // a channel < 0
  kRadianceOverflow,   // a channel >= 1.69e38 (the format's maximum)
  kUnknownFlags,       // flags other than VertexRecord::kDiffuse: not representable
  kCount
};
const char* to_string(EncodeError e);

/// Per-reason counts of a batch encode.
struct EncodeCounts {
  uint64_t accepted = 0;
  std::array<uint64_t, size_t(EncodeError::kCount)> rejected{};  // indexed by EncodeError; [kOk] unused

  uint64_t rejected_total() const;
  uint64_t operator[](EncodeError e) const { return rejected[size_t(e)]; }
  EncodeCounts& operator+=(const EncodeCounts& o) {
    accepted += o.accepted;
    for (size_t i = 0; i < rejected.size(); ++i) rejected[i] += o.rejected[i];
    return *this;
  }
};

class VertexCodec {
 public:
  static constexpr size_t kPackedBytes = 16;
  static constexpr int kPositionBits = 21;
  static constexpr uint64_t kDiffuseBit = uint64_t(1) << 63;

  /// `scene_bounds`: world space, metres; finite and non-empty (lo <= hi per axis, a single point
  /// is fine). Throws std::invalid_argument otherwise. Master and worker must pass bit-identical
  /// bounds (epr.v1 RenderSettings.codec_bounds) to agree on the quantisation.
  explicit VertexCodec(const Bounds3& scene_bounds);

  EncodeError try_encode(const VertexRecord& v, PackedVertex* out) const;
  /// True and `*out` set if `v` is representable; false (and `*out` untouched) otherwise.
  bool encode(const VertexRecord& v, PackedVertex* out) const { return try_encode(v, out) == EncodeError::kOk; }
  /// Total: every bit pattern gives finite positions inside the quantisation box, a unit normal and
  /// finite non-negative radiance. Flags carry only kDiffuse.
  VertexRecord decode(const PackedVertex& p) const;

  /// The fields of decode() one at a time (inline: reprojection kernels decode packed vertices in
  /// place, and only as far as each vertex needs -- see CpuReprojector::reproject_packed).
  Vec3 decode_position(uint64_t position_bits) const {
    Vec3 p;
    for (int a = 0; a < 3; ++a) {
      const uint64_t q = (position_bits >> (a * kPositionBits)) & ((uint64_t(1) << kPositionBits) - 1);
      p[a] = float(lo_q_[a] + (double(q) + 0.5) * cell_[a]);
    }
    return p;
  }
  static bool decode_diffuse(uint64_t position_bits) { return (position_bits & kDiffuseBit) != 0; }
  /// decode_position's operands per axis, lo_q and extent / 2^21, for kernels that decode positions
  /// themselves (the GL reprojector's compute shader).
  const std::array<double, 3>& quantisation_origin() const { return lo_q_; }
  const std::array<double, 3>& quantisation_cell() const { return cell_; }

  /// Appends the 16-byte encoding of every representable record of `in` to `out` (little-endian);
  /// returns how many were appended. Rejections are counted in `counts` if given.
  size_t encode_batch(std::span<const VertexRecord> in, std::string* out, EncodeCounts* counts = nullptr) const;
  /// encode_batch encodes four records at a time with a kernel built twice on x86-64: for AVX2 and for
  /// the baseline ISA (the same bits either way). Which one runs: "avx2" or "baseline".
  static const char* batch_kernel();
  /// Makes encode_batch use the baseline build even where AVX2 is available (tests, benchmarks).
  static void force_baseline_kernel(bool on);
  /// Appends the records encoded in `bytes` to `out`. False (nothing appended) unless
  /// bytes.size() is a multiple of 16.
  bool decode_batch(std::string_view bytes, std::vector<VertexRecord>* out) const;

  /// Wire form of one record: 16 bytes, little-endian words, at `dst`.
  static void store(const PackedVertex& p, unsigned char* dst);
  static PackedVertex load(const unsigned char* src) {
    PackedVertex p;
    if constexpr (std::endian::native == std::endian::little) {
      std::memcpy(&p.position_bits, src, 8);
      std::memcpy(&p.normal_bits, src + 8, 4);
      std::memcpy(&p.radiance_bits, src + 12, 4);
    } else {
      for (int i = 0; i < 8; ++i) p.position_bits |= uint64_t(src[i]) << (8 * i);
      for (int i = 0; i < 4; ++i) p.normal_bits |= uint32_t(src[8 + i]) << (8 * i);
      for (int i = 0; i < 4; ++i) p.radiance_bits |= uint32_t(src[12 + i]) << (8 * i);
    }
    return p;
  }

  /// Largest per-axis position error of a decoded vertex, metres (the maximum of the per-axis bounds).
  float position_error_bound() const;
  /// Per-axis position error bounds, metres.
  Vec3 position_error_bounds() const;
  /// Angle between an encoded normal and its decoded version, radians.
  static float normal_error_bound_radians();
  /// |decoded - original| per channel, as a fraction of the original's largest channel.
  static float radiance_relative_error_bound();

  /// The box positions are quantised in: the scene bounds plus the margin (see the file comment).
  Bounds3 quantisation_box() const;

  // The three fields on their own (pure; exposed for tests and for kernels that mirror them).
  /// kOk and `*bits` set, or kBadNormal. `n` need not be unit length.
  static EncodeError encode_normal(const Vec3& n, uint32_t* bits);
  static Vec3 decode_normal(uint32_t bits) {
    // snorm16 pair; -32768 decodes as -1.
    double x = std::max(-1.0, double(int16_t(uint16_t(bits & 0xffffu))) / 32767.0);
    double y = std::max(-1.0, double(int16_t(uint16_t(bits >> 16))) / 32767.0);
    const double z = 1.0 - std::fabs(x) - std::fabs(y);
    if (z < 0) {  // unfold the lower hemisphere; copysign keeps the sign of zero
      const double fx = (1.0 - std::fabs(y)) * std::copysign(1.0, x);
      const double fy = (1.0 - std::fabs(x)) * std::copysign(1.0, y);
      x = fx;
      y = fy;
    }
    const double len = std::sqrt(x * x + y * y + z * z);  // >= 1/sqrt(3): never zero
    return {float(x / len), float(y / len), float(z / len)};
  }
  /// kOk and `*bits` set, or kNonFiniteRadiance / kNegativeRadiance / kRadianceOverflow.
  static EncodeError encode_radiance(const Vec3& rgb, uint32_t* bits);
  static Vec3 decode_radiance(uint32_t bits) {
    const int e = int(bits >> 24);
    if (e == 0) return Vec3(0.f);
    const double scale = codec_detail::pow2(e - 136);  // value = m * 2^(E - 136); e - 136 in [-135, 119]
    // m * 2^(e-136) with m < 256 and e >= 1 is a float (possibly subnormal): the casts are exact.
    return {float(double(bits & 0xffu) * scale), float(double((bits >> 8) & 0xffu) * scale),
            float(double((bits >> 16) & 0xffu) * scale)};
  }
  /// Largest radiance channel value the format represents (255 * 2^119 ~= 1.69e38).
  static float max_radiance();

 private:
  std::array<double, 3> lo_q_{};    // quantisation box lower corner, metres
  std::array<double, 3> extent_{};  // quantisation box size, metres, > 0
  std::array<double, 3> cell_{};    // extent / 2^21, metres
  Vec3 error_bounds_;
};

}  // namespace epr
