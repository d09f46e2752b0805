// VertexCodec: see vertex_codec.h for the layout, the error bounds and why they hold.
#include "common/vertex_codec.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <string>

namespace epr {
namespace {

constexpr double kCells = double(uint64_t(1) << VertexCodec::kPositionBits);  // 2^21
constexpr uint64_t kCoordMask = (uint64_t(1) << VertexCodec::kPositionBits) - 1;
constexpr double kSnormMax = 32767.0;
constexpr int kRadianceBias = 136;  // value = mantissa * 2^(E - 136); E = 128 + frexp exponent
constexpr float kNormalErrorBound = 6.6e-5f;  // asin(sqrt(18) / 65534) = 6.47e-5, plus float rounding
constexpr float kRadianceErrorBound = 1.0f / 255.0f;

// Sign including that of zero: the fold of a decoded normal can produce -0 (on the octahedron's
// equator), and keeping its sign is what makes encode(decode(bits)) == bits there.
double sign_of(double v) { return std::copysign(1.0, v); }

// Spacing of floats at magnitude |x| (x finite).
double float_ulp(double x) {
  const float f = float(std::fabs(x));
  return double(std::nextafter(f, std::numeric_limits<float>::infinity())) - double(f);
}

// floor() of a value of magnitude < 2^52, exactly, without the library call (the build targets
// baseline x86-64, where std::floor is not an instruction).
double floor_small(double x) {
  const double t = double(int64_t(x));  // truncation toward zero, exact
  return x < t ? t - 1.0 : t;
}

uint32_t snorm16(double o) {
  const double q = floor_small(o * kSnormMax + 0.5);  // o in [-1, 1]: q in [-32767, 32767]
  return uint32_t(uint16_t(int16_t(q)));
}


}  // namespace

const char* to_string(EncodeError e) {
  switch (e) {
    case EncodeError::kOk: return "ok";
    case EncodeError::kNonFinitePosition: return "non-finite position";
    case EncodeError::kOutsideBounds: return "position outside the quantisation box";
    case EncodeError::kBadNormal: return "zero or non-finite normal";
    case EncodeError::kNonFiniteRadiance: return "non-finite radiance";
    case EncodeError::kNegativeRadiance: return "negative radiance";
    case EncodeError::kRadianceOverflow: return "radiance above the format maximum";
    case EncodeError::kUnknownFlags: return "flags other than diffuse";
    case EncodeError::kCount: break;
  }
  return "unknown";
}

uint64_t EncodeCounts::rejected_total() const {
  uint64_t n = 0;
  for (size_t i = 1; i < rejected.size(); ++i) n += rejected[i];
  return n;
}

// ---- construction -------------------------------------------------------------------------------

VertexCodec::VertexCodec(const Bounds3& b) {
  for (int a = 0; a < 3; ++a) {
    if (!std::isfinite(b.lo[a]) || !std::isfinite(b.hi[a]) || !(b.lo[a] <= b.hi[a])) {
      throw std::invalid_argument("VertexCodec: scene bounds must be finite and non-empty");
    }
  }
  double largest = 0;
  for (int a = 0; a < 3; ++a) largest = std::max(largest, double(b.hi[a]) - double(b.lo[a]));
  const double margin = std::max(std::ldexp(largest, -10), std::ldexp(1.0, -20));
  float bounds[3];
  for (int a = 0; a < 3; ++a) {
    lo_q_[a] = double(b.lo[a]) - margin;
    extent_[a] = (double(b.hi[a]) + margin) - lo_q_[a];
    cell_[a] = extent_[a] / kCells;  // exact: division by a power of two
    const double far = std::max(std::fabs(lo_q_[a]), std::fabs(lo_q_[a] + extent_[a]));
    bounds[a] = float(cell_[a] * 0.5 + float_ulp(far));
    // Round the bound up so that the float we report is never below the true bound.
    if (double(bounds[a]) < cell_[a] * 0.5 + float_ulp(far)) {
      bounds[a] = std::nextafter(bounds[a], std::numeric_limits<float>::infinity());
    }
  }
  error_bounds_ = Vec3(bounds[0], bounds[1], bounds[2]);
}

Bounds3 VertexCodec::quantisation_box() const {
  Bounds3 box;
  for (int a = 0; a < 3; ++a) {
    box.lo[a] = float(lo_q_[a]);
    box.hi[a] = float(lo_q_[a] + extent_[a]);
  }
  return box;
}

float VertexCodec::position_error_bound() const { return max_component(error_bounds_); }
Vec3 VertexCodec::position_error_bounds() const { return error_bounds_; }
float VertexCodec::normal_error_bound_radians() { return kNormalErrorBound; }
float VertexCodec::radiance_relative_error_bound() { return kRadianceErrorBound; }
float VertexCodec::max_radiance() { return float(std::ldexp(255.0, 255 - kRadianceBias)); }

// ---- normal: octahedral snorm16 x 2 ---------------------------------------------------------------

EncodeError VertexCodec::encode_normal(const Vec3& n, uint32_t* bits) {
  if (!is_finite(n) || is_black(n)) return EncodeError::kBadNormal;
  const double x = n.x, y = n.y, z = n.z;
  const double l1 = std::fabs(x) + std::fabs(y) + std::fabs(z);  // > 0, exact enough: a scale only
  double ox = x / l1, oy = y / l1;
  if (z < 0) {  // fold the lower hemisphere over the diagonals
    const double fx = (1.0 - std::fabs(oy)) * sign_of(ox);
    const double fy = (1.0 - std::fabs(ox)) * sign_of(oy);
    ox = fx;
    oy = fy;
  }
  *bits = snorm16(ox) | (snorm16(oy) << 16);
  return EncodeError::kOk;
}


// ---- radiance: shared-exponent RGB, 8-bit mantissas, 8-bit exponent -------------------------------

EncodeError VertexCodec::encode_radiance(const Vec3& rgb, uint32_t* bits) {
  if (!is_finite(rgb)) return EncodeError::kNonFiniteRadiance;
  if (rgb.x < 0 || rgb.y < 0 || rgb.z < 0) return EncodeError::kNegativeRadiance;
  const double c[3] = {rgb.x, rgb.y, rgb.z};
  const double mx = std::max(c[0], std::max(c[1], c[2]));
  if (mx == 0) {
    *bits = 0;
    return EncodeError::kOk;
  }
  // frexp's exponent: mx = f * 2^ex, f in [0.5, 1), so mx * 2^(8 - ex) is in [128, 256). mx is a
  // positive float widened to double, hence a normal double: ex comes straight from its exponent bits.
  const int ex = int((std::bit_cast<uint64_t>(mx) >> 52) & 0x7ff) - 1022;
  int e = std::max(ex + 128, 1);  // e = 1 below 2^-128: fewer mantissa bits, absolute error only
  uint32_t m[3];
  for (int attempt = 0; attempt < 2; ++attempt) {
    const double scale = codec_detail::pow2(kRadianceBias - e);  // exact power of two; exponent in [-120, 135]
    // c * scale + 0.5 > 0: truncation is floor.
    for (int i = 0; i < 3; ++i) m[i] = uint32_t(c[i] * scale + 0.5);
    if (std::max(m[0], std::max(m[1], m[2])) < 256) break;
    ++e;  // the max channel rounded up to 256: one exponent step more and it is 128
  }
  if (e > 255) return EncodeError::kRadianceOverflow;
  *bits = ((m[0] | m[1] | m[2]) == 0) ? 0u : (m[0] | (m[1] << 8) | (m[2] << 16) | (uint32_t(e) << 24));
  return EncodeError::kOk;
}


// ---- whole records --------------------------------------------------------------------------------

EncodeError VertexCodec::try_encode(const VertexRecord& v, PackedVertex* out) const {
  if ((v.flags & ~VertexRecord::kDiffuse) != 0) return EncodeError::kUnknownFlags;
  if (!is_finite(v.position)) return EncodeError::kNonFinitePosition;
  uint32_t normal = 0, radiance = 0;
  if (const EncodeError e = encode_normal(v.normal, &normal); e != EncodeError::kOk) return e;
  if (const EncodeError e = encode_radiance(v.radiance, &radiance); e != EncodeError::kOk) return e;

  uint64_t pos = 0;
  for (int a = 0; a < 3; ++a) {
    // One correctly rounded division, then an exact scaling by 2^21: the bits depend on nothing else.
    const double t = (double(v.position[a]) - lo_q_[a]) / extent_[a] * kCells;
    if (!(t >= 0 && t <= kCells)) return EncodeError::kOutsideBounds;
    const uint64_t q = std::min(uint64_t(t), kCoordMask);  // t >= 0: truncation is floor
    pos |= q << (a * kPositionBits);
  }
  if (v.diffuse()) pos |= kDiffuseBit;

  out->position_bits = pos;
  out->normal_bits = normal;
  out->radiance_bits = radiance;
  return EncodeError::kOk;
}

VertexRecord VertexCodec::decode(const PackedVertex& p) const {
  VertexRecord v;
  v.position = decode_position(p.position_bits);
  v.normal = decode_normal(p.normal_bits);
  v.radiance = decode_radiance(p.radiance_bits);
  v.flags = (p.position_bits & kDiffuseBit) ? VertexRecord::kDiffuse : 0u;
  return v;
}

// ---- wire form and batches ------------------------------------------------------------------------

void VertexCodec::store(const PackedVertex& p, unsigned char* dst) {
  if constexpr (std::endian::native == std::endian::little) {
    std::memcpy(dst, &p.position_bits, 8);
    std::memcpy(dst + 8, &p.normal_bits, 4);
    std::memcpy(dst + 12, &p.radiance_bits, 4);
  } else {
    for (int i = 0; i < 8; ++i) dst[i] = (unsigned char)(p.position_bits >> (8 * i));
    for (int i = 0; i < 4; ++i) dst[8 + i] = (unsigned char)(p.normal_bits >> (8 * i));
    for (int i = 0; i < 4; ++i) dst[12 + i] = (unsigned char)(p.radiance_bits >> (8 * i));
  }
}


size_t VertexCodec::encode_batch(std::span<const VertexRecord> in, std::string* out, EncodeCounts* counts) const {
  const size_t start = out->size();
  out->resize(start + in.size() * kPackedBytes);
  auto* dst = reinterpret_cast<unsigned char*>(out->data()) + start;
  size_t n = 0;
  for (const VertexRecord& v : in) {
    PackedVertex p;
    const EncodeError err = try_encode(v, &p);
    if (err == EncodeError::kOk) {
      store(p, dst + n * kPackedBytes);
      ++n;
    }
    if (counts) {
      if (err == EncodeError::kOk) ++counts->accepted;
      else ++counts->rejected[size_t(err)];
    }
  }
  out->resize(start + n * kPackedBytes);
  return n;
}

bool VertexCodec::decode_batch(std::string_view bytes, std::vector<VertexRecord>* out) const {
  if (bytes.size() % kPackedBytes != 0) return false;
  const size_t n = bytes.size() / kPackedBytes;
  const auto* src = reinterpret_cast<const unsigned char*>(bytes.data());
  const size_t start = out->size();
  out->resize(start + n);
  VertexRecord* dst = out->data() + start;
  for (size_t i = 0; i < n; ++i) dst[i] = decode(load(src + i * kPackedBytes));
  return true;
}

}  // namespace epr
