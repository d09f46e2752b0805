// VertexCodec: see vertex_codec.h for the layout, the error bounds and why they hold.
#include "common/vertex_codec.h"

#include <algorithm>
#include <atomic>
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
constexpr int kRadianceBias = 136;            // value = mantissa * 2^(E - 136); E = 128 + frexp exponent
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

// `cond ? a : b` through bit masks: the encoder's data-dependent choices (the sign of a normal's z, a
// negative octahedral coordinate) are close to random per vertex, and a mispredicted branch costs
// more than the whole arithmetic of a field. The value is exactly a or b.
inline double select(bool cond, double a, double b) {
  const uint64_t m = uint64_t(0) - uint64_t(cond);
  return std::bit_cast<double>((std::bit_cast<uint64_t>(a) & m) | (std::bit_cast<uint64_t>(b) & ~m));
}

// floor() of a value of magnitude < 2^31, exactly, without the library call (the build targets
// baseline x86-64, where std::floor is not an instruction) and without a branch.
inline double floor_small(double x) {
  const double t = double(int64_t(x));  // truncation toward zero, exact
  return t - select(x < t, 1.0, 0.0);   // t - 0 == t exactly; t is never -0
}

inline uint32_t snorm16(double o) {
  const double q = floor_small(o * kSnormMax + 0.5);  // o in [-1, 1]: q in [-32767, 32767]
  return uint32_t(uint16_t(int16_t(q)));
}

// The two fields, inlined into try_encode (the public static functions call them too). Every
// per-vertex decision that depends on the data is a select, not a branch; the only branches are the
// rejections, which real records never take.

inline EncodeError encode_normal_impl(const Vec3& n, uint32_t* bits) {
  if (!is_finite(n) || is_black(n)) return EncodeError::kBadNormal;
  const double x = n.x, y = n.y, z = n.z;
  const double l1 = std::fabs(x) + std::fabs(y) + std::fabs(z);  // > 0, exact enough: a scale only
  const double ox = x / l1, oy = y / l1;
  // The lower hemisphere is folded over the diagonals (computed always, kept only where z < 0).
  const double fx = (1.0 - std::fabs(oy)) * sign_of(ox);
  const double fy = (1.0 - std::fabs(ox)) * sign_of(oy);
  const bool lower = z < 0;
  *bits = snorm16(select(lower, fx, ox)) | (snorm16(select(lower, fy, oy)) << 16);
  return EncodeError::kOk;
}

inline EncodeError encode_radiance_impl(const Vec3& rgb, uint32_t* bits) {
  if (!is_finite(rgb)) return EncodeError::kNonFiniteRadiance;
  if (rgb.x < 0 || rgb.y < 0 || rgb.z < 0) return EncodeError::kNegativeRadiance;
  const double c[3] = {rgb.x, rgb.y, rgb.z};
  const double mx = std::max(c[0], std::max(c[1], c[2]));
  // frexp's exponent: mx = f * 2^ex, f in [0.5, 1), so mx * 2^(8 - ex) is in [128, 256). A positive
  // float widened to double is a normal double: ex comes straight from its exponent bits. Black
  // (mx = +-0) needs no case of its own: ex = -1022 gives e = 1, every m rounds to 0, and all-zero
  // mantissas encode as 0 below.
  const int ex = int((std::bit_cast<uint64_t>(mx) >> 52) & 0x7ff) - 1022;
  int e = std::max(ex + 128, 1);  // e = 1 below 2^-128: fewer mantissa bits, absolute error only
  uint32_t m[3];
  for (int attempt = 0; attempt < 2; ++attempt) {
    const double scale = codec_detail::pow2(kRadianceBias - e);  // exact power of two; exponent in [-120, 135]
    // c * scale + 0.5 > 0: truncation is floor.
    for (int i = 0; i < 3; ++i) m[i] = uint32_t(c[i] * scale + 0.5);
    if (std::max(m[0], std::max(m[1], m[2])) < 256) break;
    ++e;  // the max channel rounded up to 256 (about 1 vertex in 256): one exponent step more and it is 128
  }
  if (e > 255) return EncodeError::kRadianceOverflow;
  const uint32_t keep = uint32_t(0) - uint32_t((m[0] | m[1] | m[2]) != 0);
  *bits = (m[0] | (m[1] << 8) | (m[2] << 16) | (uint32_t(e) << 24)) & keep;
  return EncodeError::kOk;
}

// ---- four records at a time -----------------------------------------------------------------------
// encode_batch's kernel: the arithmetic of try_encode, lane by lane, on four records at once (GCC/Clang
// vector extensions; each lane does exactly the IEEE operations the scalar code does, in the same
// order, so the bits are the same -- tests/common/vertex_codec_test.cpp checks it on millions of
// records against the plain formulas). Built twice on x86-64, for AVX2 (four doubles per instruction)
// and for the baseline (two), chosen at load time. A group of four is written only if every record
// in it is representable; otherwise the caller encodes that group with try_encode, which also says
// why a record is refused.

using D4 = double __attribute__((vector_size(32)));
using I4 = int64_t __attribute__((vector_size(32)));
using W4 = int32_t __attribute__((vector_size(16)));

// The helpers are always inlined into the kernel (so they take its target); no 32-byte vector ever
// crosses a call, hence no ABI concern (-Wpsabi).
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic ignored "-Wpsabi"
#endif
#define EPR_LANES inline __attribute__((always_inline))
EPR_LANES D4 splat(double v) { return D4{v, v, v, v}; }
EPR_LANES I4 splat_i(int64_t v) { return I4{v, v, v, v}; }
EPR_LANES D4 select4(I4 m, D4 a, D4 b) { return (D4)(((I4)a & m) | ((I4)b & ~m)); }
EPR_LANES D4 abs4(D4 v) { return (D4)((I4)v & splat_i(INT64_MAX)); }
EPR_LANES D4 max4(D4 a, D4 b) { return select4(a < b, b, a); }  // std::max(a, b)
EPR_LANES D4 floor4(D4 x) {                                     // floor_small, lane by lane (|x| < 2^31)
  const D4 t = __builtin_convertvector(__builtin_convertvector(x, W4), D4);
  return t - select4(x < t, splat(1.0), splat(0.0));
}
EPR_LANES W4 snorm4(D4 o) {  // snorm16, lane by lane; the low 16 bits are the code
  return __builtin_convertvector(floor4(o * splat(kSnormMax) + splat(0.5)), W4) & W4{0xffff, 0xffff, 0xffff, 0xffff};
}
EPR_LANES D4 pow2_4(I4 k) { return (D4)((k + splat_i(1023)) << 52); }  // codec_detail::pow2, lane by lane

// Encodes groups of four records of in[0, n) into `dst` (16 bytes each) as long as every record of a
// group is representable; returns how many records it encoded (a multiple of 4): it stops before the
// first group that is not, or when fewer than four are left.
EPR_LANES size_t encode_groups_body(const VertexRecord* in, size_t n, const double* lo_q, const double* extent,
                                    unsigned char* dst) {
  const D4 cells = splat(kCells);
  const D4 dmax = splat(std::numeric_limits<double>::max());
  size_t done = 0;
  for (; done + 4 <= n; done += 4) {
    const VertexRecord* r = in + done;
    if (((r[0].flags | r[1].flags | r[2].flags | r[3].flags) & ~VertexRecord::kDiffuse) != 0) break;
    I4 ok = splat_i(-1);
    // Position: q = min(floor((p - lo_q) / extent * 2^21), 2^21 - 1) inside [0, 2^21]; NaN and
    // infinities fail the range test.
    W4 q[3];
    for (int a = 0; a < 3; ++a) {
      const D4 p{double(r[0].position[a]), double(r[1].position[a]), double(r[2].position[a]),
                 double(r[3].position[a])};
      D4 t = (p - splat(lo_q[a])) / splat(extent[a]) * cells;
      const I4 in_box = (t >= splat(0.0)) & (t <= cells);
      ok &= in_box;
      t = select4(in_box, t, splat(0.0));
      const W4 qa = __builtin_convertvector(t, W4);
      const W4 top = W4{1, 1, 1, 1} * int32_t(kCoordMask);
      q[a] = (qa < top) ? qa : top;
    }
    // Normal: octahedral, folded where z < 0. A finite non-zero normal has 0 < l1 <= DBL_MAX.
    const D4 nx{double(r[0].normal.x), double(r[1].normal.x), double(r[2].normal.x), double(r[3].normal.x)};
    const D4 ny{double(r[0].normal.y), double(r[1].normal.y), double(r[2].normal.y), double(r[3].normal.y)};
    const D4 nz{double(r[0].normal.z), double(r[1].normal.z), double(r[2].normal.z), double(r[3].normal.z)};
    const D4 l1_raw = abs4(nx) + abs4(ny) + abs4(nz);
    const I4 n_ok = (l1_raw > splat(0.0)) & (l1_raw <= dmax);
    ok &= n_ok;
    const D4 l1 = select4(n_ok, l1_raw, splat(1.0));
    const D4 ox = select4(n_ok, nx, splat(0.0)) / l1, oy = select4(n_ok, ny, splat(0.0)) / l1;
    const D4 one = splat(1.0);
    const I4 sign = splat_i(INT64_MIN);
    const D4 fx = (one - abs4(oy)) * (D4)(((I4)ox & sign) | (I4)one);  // sign_of: copysign(1, ox)
    const D4 fy = (one - abs4(ox)) * (D4)(((I4)oy & sign) | (I4)one);
    const I4 lower = nz < splat(0.0);
    const W4 normal = snorm4(select4(lower, fx, ox)) | (snorm4(select4(lower, fy, oy)) << 16);
    // Radiance: shared exponent, one more step where the max channel rounded up to 256.
    D4 c[3];
    I4 r_ok = splat_i(-1);
    for (int i = 0; i < 3; ++i) {
      c[i] = D4{double(r[0].radiance[i]), double(r[1].radiance[i]), double(r[2].radiance[i]), double(r[3].radiance[i])};
      r_ok &= (c[i] >= splat(0.0)) & (c[i] <= dmax);  // NaN, infinite and negative fail
    }
    ok &= r_ok;
    for (int i = 0; i < 3; ++i) c[i] = select4(r_ok, c[i], splat(0.0));
    const D4 mx = max4(c[0], max4(c[1], c[2]));
    const I4 ex = (((I4)mx >> 52) & splat_i(0x7ff)) - splat_i(1022);
    I4 e = ex + splat_i(128);
    e = (e < splat_i(1)) ? splat_i(1) : e;
    W4 m[3];
    D4 scale = pow2_4(splat_i(kRadianceBias) - e);
    for (int i = 0; i < 3; ++i) m[i] = __builtin_convertvector(c[i] * scale + splat(0.5), W4);
    const W4 mmax0 = (m[0] > m[1]) ? m[0] : m[1];
    const W4 mmax = (mmax0 > m[2]) ? mmax0 : m[2];
    const I4 up = __builtin_convertvector(mmax >= W4{256, 256, 256, 256}, I4);  // -1 where it rounded up
    e -= up;
    scale = pow2_4(splat_i(kRadianceBias) - e);
    for (int i = 0; i < 3; ++i) m[i] = __builtin_convertvector(c[i] * scale + splat(0.5), W4);
    ok &= e <= splat_i(255);
    const W4 e32 = __builtin_convertvector(e, W4);
    const W4 nonzero = (m[0] | m[1] | m[2]) != W4{0, 0, 0, 0};
    const W4 radiance = (m[0] | (m[1] << 8) | (m[2] << 16) | (e32 << 24)) & nonzero;
    if (!(ok[0] & ok[1] & ok[2] & ok[3])) break;
    for (int k = 0; k < 4; ++k) {
      PackedVertex pv;
      pv.position_bits = uint64_t(uint32_t(q[0][k])) | (uint64_t(uint32_t(q[1][k])) << VertexCodec::kPositionBits) |
                         (uint64_t(uint32_t(q[2][k])) << (2 * VertexCodec::kPositionBits)) |
                         (r[k].diffuse() ? VertexCodec::kDiffuseBit : 0);
      pv.normal_bits = uint32_t(normal[k]);
      pv.radiance_bits = uint32_t(radiance[k]);
      VertexCodec::store(pv, dst + (done + k) * VertexCodec::kPackedBytes);
    }
  }
  return done;
}

// The kernel built for the baseline ISA (two doubles per SSE2 instruction on x86-64) and, on x86-64,
// for AVX2 (four), picked once per process by what the CPU supports.
size_t encode_groups_baseline(const VertexRecord* in, size_t n, const double* lo_q, const double* extent,
                              unsigned char* dst) {
  return encode_groups_body(in, n, lo_q, extent, dst);
}
#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
__attribute__((target("avx2"))) size_t encode_groups_avx2(const VertexRecord* in, size_t n, const double* lo_q,
                                                          const double* extent, unsigned char* dst) {
  return encode_groups_body(in, n, lo_q, extent, dst);
}
bool cpu_has_avx2() {
  static const bool has = __builtin_cpu_supports("avx2");
  return has;
}
#else
size_t encode_groups_avx2(const VertexRecord* in, size_t n, const double* lo_q, const double* extent,
                          unsigned char* dst) {
  return encode_groups_body(in, n, lo_q, extent, dst);
}
bool cpu_has_avx2() { return false; }
#endif

std::atomic<bool> g_force_baseline{false};

size_t encode_groups(const VertexRecord* in, size_t n, const double* lo_q, const double* extent, unsigned char* dst) {
  if (cpu_has_avx2() && !g_force_baseline.load(std::memory_order_relaxed))
    return encode_groups_avx2(in, n, lo_q, extent, dst);
  return encode_groups_baseline(in, n, lo_q, extent, dst);
}

}  // namespace

const char* to_string(EncodeError e) {
  switch (e) {
    case EncodeError::kOk:
      return "ok";
    case EncodeError::kNonFinitePosition:
      return "non-finite position";
    case EncodeError::kOutsideBounds:
      return "position outside the quantisation box";
    case EncodeError::kBadNormal:
      return "zero or non-finite normal";
    case EncodeError::kNonFiniteRadiance:
      return "non-finite radiance";
    case EncodeError::kNegativeRadiance:
      return "negative radiance";
    case EncodeError::kRadianceOverflow:
      return "radiance above the format maximum";
    case EncodeError::kUnknownFlags:
      return "flags other than diffuse";
    case EncodeError::kCount:
      break;
  }
  return "unknown";
}

const char* VertexCodec::batch_kernel() { return cpu_has_avx2() && !g_force_baseline.load() ? "avx2" : "baseline"; }
void VertexCodec::force_baseline_kernel(bool on) { g_force_baseline.store(on); }

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

EncodeError VertexCodec::encode_normal(const Vec3& n, uint32_t* bits) { return encode_normal_impl(n, bits); }

// ---- radiance: shared-exponent RGB, 8-bit mantissas, 8-bit exponent -------------------------------

EncodeError VertexCodec::encode_radiance(const Vec3& rgb, uint32_t* bits) { return encode_radiance_impl(rgb, bits); }

// ---- whole records --------------------------------------------------------------------------------

EncodeError VertexCodec::try_encode(const VertexRecord& v, PackedVertex* out) const {
  if ((v.flags & ~VertexRecord::kDiffuse) != 0) return EncodeError::kUnknownFlags;
  if (!is_finite(v.position)) return EncodeError::kNonFinitePosition;
  uint32_t normal = 0, radiance = 0;
  if (const EncodeError e = encode_normal_impl(v.normal, &normal); e != EncodeError::kOk) return e;
  if (const EncodeError e = encode_radiance_impl(v.radiance, &radiance); e != EncodeError::kOk) return e;

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
  for (size_t i = 0; i < in.size();) {
    // Whole groups of four while they are representable, then the group that stopped it (or the
    // last 1-3 records) one at a time.
    const size_t groups =
        encode_groups(in.data() + i, in.size() - i, lo_q_.data(), extent_.data(), dst + n * kPackedBytes);
    i += groups;
    n += groups;
    if (counts) counts->accepted += groups;
    for (const size_t stop = std::min(in.size(), i + 4); i < stop; ++i) {
      PackedVertex p;
      const EncodeError err = try_encode(in[i], &p);
      if (err == EncodeError::kOk) {
        store(p, dst + n * kPackedBytes);
        ++n;
      }
      if (counts) {
        if (err == EncodeError::kOk)
          ++counts->accepted;
        else
          ++counts->rejected[size_t(err)];
      }
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
