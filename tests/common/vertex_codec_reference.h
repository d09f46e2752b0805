// The vertex encoding written the plain way, straight from the formulas of common/vertex_codec.h
// (std::floor, std::frexp, std::ldexp, one branch per case): the reference VertexCodec's optimised
// encoder must match bit for bit, error code included (tests/common/vertex_codec_test.cpp on random
// records, tests/wire/tile_result_stream_test.cpp on traced ones).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "common/vertex_codec.h"

namespace epr::test {

class ReferenceEncoder {
 public:
  explicit ReferenceEncoder(const Bounds3& b) {
    double largest = 0;
    for (int a = 0; a < 3; ++a) largest = std::max(largest, double(b.hi[a]) - double(b.lo[a]));
    const double margin = std::max(std::ldexp(largest, -10), std::ldexp(1.0, -20));
    for (int a = 0; a < 3; ++a) {
      lo_q_[a] = double(b.lo[a]) - margin;
      extent_[a] = (double(b.hi[a]) + margin) - lo_q_[a];
    }
  }

  static EncodeError normal(const Vec3& n, uint32_t* bits) {
    if (!std::isfinite(n.x) || !std::isfinite(n.y) || !std::isfinite(n.z)) return EncodeError::kBadNormal;
    if (n.x == 0 && n.y == 0 && n.z == 0) return EncodeError::kBadNormal;
    const double x = n.x, y = n.y, z = n.z;
    const double l1 = std::fabs(x) + std::fabs(y) + std::fabs(z);
    double ox = x / l1, oy = y / l1;
    if (z < 0) {
      const double fx = (1.0 - std::fabs(oy)) * std::copysign(1.0, ox);
      const double fy = (1.0 - std::fabs(ox)) * std::copysign(1.0, oy);
      ox = fx;
      oy = fy;
    }
    auto snorm = [](double o) { return uint32_t(uint16_t(int16_t(std::floor(o * 32767.0 + 0.5)))); };
    *bits = snorm(ox) | (snorm(oy) << 16);
    return EncodeError::kOk;
  }

  static EncodeError radiance(const Vec3& rgb, uint32_t* bits) {
    if (!std::isfinite(rgb.x) || !std::isfinite(rgb.y) || !std::isfinite(rgb.z)) return EncodeError::kNonFiniteRadiance;
    if (rgb.x < 0 || rgb.y < 0 || rgb.z < 0) return EncodeError::kNegativeRadiance;
    const double c[3] = {rgb.x, rgb.y, rgb.z};
    const double mx = std::max(c[0], std::max(c[1], c[2]));
    if (mx == 0) {
      *bits = 0;
      return EncodeError::kOk;
    }
    int ex = 0;
    std::frexp(mx, &ex);
    int e = std::max(ex + 128, 1);
    uint32_t m[3];
    for (int attempt = 0; attempt < 2; ++attempt) {
      const double scale = std::ldexp(1.0, 136 - e);
      for (int i = 0; i < 3; ++i) m[i] = uint32_t(std::floor(c[i] * scale + 0.5));
      if (std::max(m[0], std::max(m[1], m[2])) < 256) break;
      ++e;
    }
    if (e > 255) return EncodeError::kRadianceOverflow;
    *bits = ((m[0] | m[1] | m[2]) == 0) ? 0u : (m[0] | (m[1] << 8) | (m[2] << 16) | (uint32_t(e) << 24));
    return EncodeError::kOk;
  }

  EncodeError encode(const VertexRecord& v, PackedVertex* out) const {
    if ((v.flags & ~VertexRecord::kDiffuse) != 0) return EncodeError::kUnknownFlags;
    if (!std::isfinite(v.position.x) || !std::isfinite(v.position.y) || !std::isfinite(v.position.z))
      return EncodeError::kNonFinitePosition;
    uint32_t nb = 0, rb = 0;
    if (const EncodeError e = normal(v.normal, &nb); e != EncodeError::kOk) return e;
    if (const EncodeError e = radiance(v.radiance, &rb); e != EncodeError::kOk) return e;
    uint64_t pos = 0;
    for (int a = 0; a < 3; ++a) {
      const double t = (double(v.position[a]) - lo_q_[a]) / extent_[a] * 2097152.0;
      if (!(t >= 0 && t <= 2097152.0)) return EncodeError::kOutsideBounds;
      const uint64_t q = std::min<uint64_t>(uint64_t(std::floor(t)), (uint64_t(1) << 21) - 1);
      pos |= q << (21 * a);
    }
    if (v.flags & VertexRecord::kDiffuse) pos |= uint64_t(1) << 63;
    *out = {pos, nb, rb};
    return EncodeError::kOk;
  }

  /// The wire bytes of the accepted records, in order, and the counts.
  std::string encode_all(const std::vector<VertexRecord>& in, EncodeCounts* counts) const {
    std::string bytes;
    for (const VertexRecord& v : in) {
      PackedVertex p;
      const EncodeError e = encode(v, &p);
      if (e == EncodeError::kOk) {
        unsigned char b[16];
        VertexCodec::store(p, b);
        bytes.append(reinterpret_cast<const char*>(b), 16);
        ++counts->accepted;
      } else {
        ++counts->rejected[size_t(e)];
      }
    }
    return bytes;
  }

 private:
  double lo_q_[3], extent_[3];
};

}  // namespace epr::test
