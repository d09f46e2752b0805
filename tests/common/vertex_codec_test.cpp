// VertexCodec: the 16-byte wire encoding of VertexRecord (common/vertex_codec.h). Checks the stated
// error bounds on many records, the rejections, idempotence, the byte layout, and bits computed here
// from the documented formulas.
#include "common/vertex_codec.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

#include "common/rng.h"
#include "tests/common/vertex_codec_reference.h"

namespace epr {
namespace {

constexpr float kInf = std::numeric_limits<float>::infinity();
constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

Bounds3 cornell_bounds() {
  Bounds3 b;
  b.extend(Vec3(-1, 0, -1));
  b.extend(Vec3(1, 2, 1));
  return b;
}

// Deterministic test randomness from the project's counter-based hash.
class TestRandom {
 public:
  explicit TestRandom(uint64_t seed) : seed_(seed) {}
  float uniform() { return bits_to_unit_float(hash_key(seed_, 0, 0, n_++)); }
  float uniform(float a, float b) { return a + (b - a) * uniform(); }
  Vec3 unit_vector() {
    const double z = 1.0 - 2.0 * uniform();
    const double r = std::sqrt(std::max(0.0, 1.0 - z * z));
    const double phi = 2.0 * 3.14159265358979323846 * uniform();
    return {float(r * std::cos(phi)), float(r * std::sin(phi)), float(z)};
  }
  uint64_t bits() { return hash_key(seed_, 1, 0, n_++); }

 private:
  uint64_t seed_;
  uint32_t n_ = 0;
};

double angle_between(const Vec3& a, const Vec3& b) {
  const double ax = a.x, ay = a.y, az = a.z, bx = b.x, by = b.y, bz = b.z;
  const double cx = ay * bz - az * by, cy = az * bx - ax * bz, cz = ax * by - ay * bx;
  return std::atan2(std::sqrt(cx * cx + cy * cy + cz * cz), ax * bx + ay * by + az * bz);
}

double ddot(const Vec3& a, const Vec3& b) { return double(a.x) * b.x + double(a.y) * b.y + double(a.z) * b.z; }

VertexRecord record(Vec3 p, Vec3 n, Vec3 l, bool diffuse = true) {
  VertexRecord v;
  v.position = p;
  v.normal = n;
  v.radiance = l;
  v.flags = diffuse ? VertexRecord::kDiffuse : 0u;
  return v;
}

// ---- layout ---------------------------------------------------------------------------------------

TEST(VertexCodecLayout, SixteenBytesLittleEndian) {
  static_assert(sizeof(PackedVertex) == 16);
  PackedVertex p{0x0807060504030201ull, 0x0c0b0a09u, 0x100f0e0du};
  unsigned char bytes[16];
  VertexCodec::store(p, bytes);
  for (int i = 0; i < 16; ++i) EXPECT_EQ(bytes[i], i + 1) << "byte " << i;
  EXPECT_EQ(VertexCodec::load(bytes), p);
}

TEST(VertexCodecLayout, BatchIsSixteenBytesPerVertexAndRoundTrips) {
  const VertexCodec codec(cornell_bounds());
  TestRandom rng(7);
  std::vector<VertexRecord> in;
  for (int i = 0; i < 1000; ++i) {
    in.push_back(record(Vec3(rng.uniform(-1, 1), rng.uniform(0, 2), rng.uniform(-1, 1)), rng.unit_vector(),
                        Vec3(rng.uniform(0, 20), rng.uniform(0, 20), rng.uniform(0, 20)), i % 3 != 0));
  }
  std::string bytes = "xy";  // appends after existing content
  EXPECT_EQ(codec.encode_batch(in, &bytes), in.size());
  ASSERT_EQ(bytes.size(), 2 + 16 * in.size());

  std::vector<VertexRecord> out;
  ASSERT_TRUE(codec.decode_batch(std::string_view(bytes).substr(2), &out));
  ASSERT_EQ(out.size(), in.size());
  for (size_t i = 0; i < in.size(); ++i) {
    PackedVertex p;
    ASSERT_TRUE(codec.encode(in[i], &p));
    const VertexRecord d = codec.decode(p);
    EXPECT_EQ(out[i].position, d.position);
    EXPECT_EQ(out[i].normal, d.normal);
    EXPECT_EQ(out[i].radiance, d.radiance);
    EXPECT_EQ(out[i].flags, d.flags);
  }
  EXPECT_FALSE(codec.decode_batch(std::string_view(bytes).substr(1), &out));  // 16 n + 1 bytes
  EXPECT_EQ(out.size(), in.size());                                           // nothing appended
}

TEST(VertexCodecLayout, BatchSkipsAndCountsRejectedRecords) {
  const VertexCodec codec(cornell_bounds());
  const Vec3 p(0, 1, 0), n(0, 0, 1), l(1, 1, 1);
  std::vector<VertexRecord> in = {
      record(p, n, l),
      record(p, n, Vec3(kNaN, 1, 1)),
      record(p, n, Vec3(1, -0.5f, 1)),
      record(Vec3(5, 1, 0), n, l),
      record(p, Vec3(0.f), l),
      record(p, n, l),
  };
  in.push_back(record(p, n, l));
  in.back().flags |= 2u;
  std::string bytes;
  EncodeCounts counts;
  EXPECT_EQ(codec.encode_batch(in, &bytes, &counts), 2u);
  EXPECT_EQ(bytes.size(), 32u);
  EXPECT_EQ(counts.accepted, 2u);
  EXPECT_EQ(counts.rejected_total(), 5u);
  EXPECT_EQ(counts[EncodeError::kNonFiniteRadiance], 1u);
  EXPECT_EQ(counts[EncodeError::kNegativeRadiance], 1u);
  EXPECT_EQ(counts[EncodeError::kOutsideBounds], 1u);
  EXPECT_EQ(counts[EncodeError::kBadNormal], 1u);
  EXPECT_EQ(counts[EncodeError::kUnknownFlags], 1u);
}

// ---- position -------------------------------------------------------------------------------------

void check_positions(const Bounds3& b, uint64_t seed, bool expect_tight) {
  const VertexCodec codec(b);
  const Vec3 bound = codec.position_error_bounds();
  TestRandom rng(seed);
  double worst[3] = {0, 0, 0};
  for (int i = 0; i < 20000; ++i) {
    Vec3 p;
    for (int a = 0; a < 3; ++a) p[a] = rng.uniform(b.lo[a], b.hi[a]);
    if (i < 8) p = Vec3(i & 1 ? b.hi.x : b.lo.x, i & 2 ? b.hi.y : b.lo.y, i & 4 ? b.hi.z : b.lo.z);
    PackedVertex packed;
    ASSERT_TRUE(codec.encode(record(p, Vec3(0, 1, 0), Vec3(1.f)), &packed)) << p.x << " " << p.y << " " << p.z;
    const Vec3 d = codec.decode(packed).position;
    for (int a = 0; a < 3; ++a) {
      const double err = std::fabs(double(d[a]) - double(p[a]));
      worst[a] = std::max(worst[a], err);
      ASSERT_LE(err, bound[a]) << "axis " << a << " at " << p[a];
    }
  }
  // The bound is not vacuous: the observed error reaches at least a third of it (unless the float
  // spacing exceeds the cell, when the cell centre rounds back to the original float).
  if (expect_tight) {
    for (int a = 0; a < 3; ++a) EXPECT_GT(worst[a], bound[a] / 3) << "axis " << a;
  }
}

TEST(VertexCodecPosition, RoundTripWithinBound) {
  check_positions(cornell_bounds(), 1, true);
  Bounds3 off_centre;
  off_centre.extend(Vec3(10, -5, 0.25f));
  off_centre.extend(Vec3(13, -4.5f, 40));
  // y: 0.58 m quantisation range at |y| ~ 5 m, where floats are 0.48 um apart and cells 0.28 um.
  check_positions(off_centre, 2, false);
}

TEST(VertexCodecPosition, CornellBoundIsFarBelowEpsilon) {
  const VertexCodec codec(cornell_bounds());
  const float bound = codec.position_error_bound();
  // Half a cell (2.0039 m / 2^22 = 0.478 um) plus the float spacing at 2 m (0.238 um).
  EXPECT_NEAR(bound, 0.478e-6 + 0.238e-6, 0.01e-6);
  const float epsilon = 0.0003f * cornell_bounds().diagonal_length();  // default plane-test tolerance
  EXPECT_LT(bound * 1000, epsilon);
}

TEST(VertexCodecPosition, FlatBoundsStillEncode) {
  Bounds3 b;  // a single quad in the plane y = 1
  b.extend(Vec3(-1, 1, -1));
  b.extend(Vec3(1, 1, 1));
  const VertexCodec codec(b);
  PackedVertex p;
  ASSERT_TRUE(codec.encode(record(Vec3(0.3f, 1, -0.7f), Vec3(0, 1, 0), Vec3(1.f)), &p));
  const Vec3 d = codec.decode(p).position;
  EXPECT_NEAR(d.y, 1.0f, codec.position_error_bounds().y);
  EXPECT_NEAR(d.x, 0.3f, codec.position_error_bounds().x);
}

TEST(VertexCodecPosition, SlightlyOutsideIsKeptFarOutsideIsRejected) {
  const VertexCodec codec(cornell_bounds());
  PackedVertex p;
  // A hit point a rounding error outside the wall x = -1 still encodes, within the bound.
  const Vec3 just_out(std::nextafter(-1.f, -2.f) - 1e-6f, 2.0000005f, 1.000001f);
  ASSERT_TRUE(codec.encode(record(just_out, Vec3(1, 0, 0), Vec3(1.f)), &p));
  const Vec3 d = codec.decode(p).position;
  for (int a = 0; a < 3; ++a) EXPECT_LE(std::fabs(d[a] - just_out[a]), codec.position_error_bounds()[a]);
  // Beyond the margin (2 m * 2^-10 = 1.95 mm) positions are rejected, never clamped.
  EXPECT_EQ(codec.try_encode(record(Vec3(-1.003f, 1, 0), Vec3(1, 0, 0), Vec3(1.f)), &p), EncodeError::kOutsideBounds);
  EXPECT_EQ(codec.try_encode(record(Vec3(0, 2.01f, 0), Vec3(1, 0, 0), Vec3(1.f)), &p), EncodeError::kOutsideBounds);
  EXPECT_EQ(codec.try_encode(record(Vec3(0, 1, kNaN), Vec3(1, 0, 0), Vec3(1.f)), &p), EncodeError::kNonFinitePosition);
  EXPECT_EQ(codec.try_encode(record(Vec3(kInf, 1, 0), Vec3(1, 0, 0), Vec3(1.f)), &p), EncodeError::kNonFinitePosition);
}

TEST(VertexCodecPosition, RejectsUnusableBounds) {
  EXPECT_THROW(VertexCodec(Bounds3{}), std::invalid_argument);  // empty
  Bounds3 b = cornell_bounds();
  b.hi.y = kInf;
  EXPECT_THROW(VertexCodec{b}, std::invalid_argument);
  b = cornell_bounds();
  b.lo.z = kNaN;
  EXPECT_THROW(VertexCodec{b}, std::invalid_argument);
}

// ---- normal ---------------------------------------------------------------------------------------

std::vector<Vec3> test_normals(int random_count) {
  std::vector<Vec3> ns = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
  // The octahedron's edges and fold lines, where the mapping changes branch.
  for (float z : {-0.7f, -1e-7f, -0.f, 0.f, 1e-7f, 0.7f}) {
    for (float x : {-1.f, -0.5f, 0.f, 0.5f, 1.f}) {
      for (float y : {-1.f, -1e-6f, 0.f, 1e-6f, 1.f}) {
        if (x != 0 || y != 0 || z != 0) ns.push_back(normalize(Vec3(x, y, z)));
      }
    }
  }
  TestRandom rng(3);
  for (int i = 0; i < random_count; ++i) ns.push_back(rng.unit_vector());
  return ns;
}

TEST(VertexCodecNormal, RoundTripWithinAngleBoundAndUnitLength) {
  const double bound = VertexCodec::normal_error_bound_radians();
  double worst = 0;
  for (const Vec3& n : test_normals(200000)) {
    uint32_t bits = 0;
    ASSERT_EQ(VertexCodec::encode_normal(n, &bits), EncodeError::kOk);
    const Vec3 d = VertexCodec::decode_normal(bits);
    const double angle = angle_between(n, d);
    worst = std::max(worst, angle);
    ASSERT_LE(angle, bound) << n.x << " " << n.y << " " << n.z;
    ASSERT_NEAR(std::sqrt(ddot(d, d)), 1.0, 2e-7);
    uint32_t again = 0;  // idempotent, also on the folds where decoding yields -0
    ASSERT_EQ(VertexCodec::encode_normal(d, &again), EncodeError::kOk);
    ASSERT_EQ(again, bits) << n.x << " " << n.y << " " << n.z;
  }
  EXPECT_GT(worst, bound / 4);  // the bound is not vacuous
}

TEST(VertexCodecNormal, AxisNormalsAreExactAndScaleDoesNotMatter) {
  for (const Vec3& n : {Vec3(1, 0, 0), Vec3(-1, 0, 0), Vec3(0, 1, 0), Vec3(0, -1, 0), Vec3(0, 0, 1), Vec3(0, 0, -1)}) {
    uint32_t bits = 0;
    ASSERT_EQ(VertexCodec::encode_normal(n, &bits), EncodeError::kOk);
    EXPECT_EQ(VertexCodec::decode_normal(bits), n);
    uint32_t scaled = 0;
    ASSERT_EQ(VertexCodec::encode_normal(n * 37.5f, &scaled), EncodeError::kOk);
    EXPECT_EQ(scaled, bits);
  }
  uint32_t bits = 0;
  EXPECT_EQ(VertexCodec::encode_normal(Vec3(0.f), &bits), EncodeError::kBadNormal);
  EXPECT_EQ(VertexCodec::encode_normal(Vec3(kNaN, 0, 1), &bits), EncodeError::kBadNormal);
  EXPECT_EQ(VertexCodec::encode_normal(Vec3(0, kInf, 1), &bits), EncodeError::kBadNormal);
}

// A facing test dot(n, d) > 0 must not change its answer through the codec unless d is within the
// bound of grazing.
TEST(VertexCodecNormal, NeverFlipsTheSideOfANonGrazingDirection) {
  const double bound = VertexCodec::normal_error_bound_radians();
  TestRandom rng(11);
  int tested = 0;
  for (const Vec3& n : test_normals(20000)) {
    uint32_t bits = 0;
    ASSERT_EQ(VertexCodec::encode_normal(n, &bits), EncodeError::kOk);
    const Vec3 m = VertexCodec::decode_normal(bits);
    // A tangent direction t perpendicular to n (in double), then d = c n + sqrt(1 - c^2) t for
    // |c| just above the bound and a little further; and a worst case: t chosen along the error.
    const Frame f = Frame::from_normal(n);
    const Vec3 err = m - n * float(ddot(m, n));
    const Vec3 along_error = length(err) > 0 ? normalize(err) : f.s;
    const float phi = rng.uniform(0, 2 * kPi);
    for (const Vec3& t : {f.s * std::cos(phi) + f.t * std::sin(phi), along_error, -along_error}) {
      for (double c : {1.02 * bound, -1.02 * bound, 2 * bound, -2 * bound, 1e-3, -1e-3, 0.3, -0.3}) {
        const double s = std::sqrt(1 - c * c);
        const double dx = c * n.x + s * t.x, dy = c * n.y + s * t.y, dz = c * n.z + s * t.z;
        const double len = std::sqrt(dx * dx + dy * dy + dz * dz);
        const double orig = (dx * n.x + dy * n.y + dz * n.z) / len;
        if (!(std::fabs(orig) > bound)) continue;  // t not exactly perpendicular after rounding
        const double dec = (dx * m.x + dy * m.y + dz * m.z) / len;
        ASSERT_EQ(orig > 0, dec > 0) << "n=" << n.x << "," << n.y << "," << n.z << " cos=" << orig;
        ++tested;
      }
    }
  }
  EXPECT_GT(tested, 300000);
}

// ---- radiance -------------------------------------------------------------------------------------

TEST(VertexCodecRadiance, RelativeErrorWithinBound) {
  const double bound = VertexCodec::radiance_relative_error_bound();
  TestRandom rng(5);
  double worst = 0;
  for (int i = 0; i < 200000; ++i) {
    // Magnitudes from 1e-30 to 1e30, channels with independent spreads down to 1e-6 of the max.
    const float scale = std::pow(10.f, rng.uniform(-30, 30));
    Vec3 l;
    for (int c = 0; c < 3; ++c) l[c] = scale * rng.uniform() * std::pow(10.f, rng.uniform(-6, 0));
    if (i % 7 == 0) l[i % 3] = 0;
    uint32_t bits = 0;
    ASSERT_EQ(VertexCodec::encode_radiance(l, &bits), EncodeError::kOk);
    const Vec3 d = VertexCodec::decode_radiance(bits);
    const double mx = max_component(l);
    for (int c = 0; c < 3; ++c) {
      ASSERT_TRUE(std::isfinite(d[c]) && d[c] >= 0);
      if (mx == 0) {
        ASSERT_EQ(d[c], 0.f);
        continue;
      }
      if (mx < 0x1p-128) {  // below the normal range: absolute error only
        ASSERT_LE(std::fabs(double(d[c]) - double(l[c])), 0x1p-137);
        continue;
      }
      const double rel = std::fabs(double(d[c]) - double(l[c])) / mx;
      worst = std::max(worst, rel);
      ASSERT_LE(rel, bound) << l[c] << " -> " << d[c] << " (max " << mx << ")";
    }
  }
  EXPECT_GT(worst, bound / 2);
}

TEST(VertexCodecRadiance, RepresentableValuesAreExactIncludingTheExtremes) {
  for (const Vec3& l : {Vec3(17, 12, 4), Vec3(0.f), Vec3(1, 0.5f, 0.25f), Vec3(255, 1, 0), Vec3(0, 0x1p-130f, 0),
                        Vec3(VertexCodec::max_radiance(), 0, 0x1p119f)}) {
    uint32_t bits = 0;
    ASSERT_EQ(VertexCodec::encode_radiance(l, &bits), EncodeError::kOk);
    EXPECT_EQ(VertexCodec::decode_radiance(bits), l) << l.x << " " << l.y << " " << l.z;
  }
  EXPECT_FLOAT_EQ(VertexCodec::max_radiance(), 255.f * 0x1p119f);
}

TEST(VertexCodecRadiance, RejectsNonFiniteNegativeAndOverflow) {
  uint32_t bits = 0x12345678u;
  for (int c = 0; c < 3; ++c) {
    Vec3 l(1.f);
    l[c] = kNaN;
    EXPECT_EQ(VertexCodec::encode_radiance(l, &bits), EncodeError::kNonFiniteRadiance);
    l[c] = kInf;
    EXPECT_EQ(VertexCodec::encode_radiance(l, &bits), EncodeError::kNonFiniteRadiance);
    l[c] = -kInf;
    EXPECT_EQ(VertexCodec::encode_radiance(l, &bits), EncodeError::kNonFiniteRadiance);
    l[c] = -1e-30f;
    EXPECT_EQ(VertexCodec::encode_radiance(l, &bits), EncodeError::kNegativeRadiance);
    l[c] = std::numeric_limits<float>::max();
    EXPECT_EQ(VertexCodec::encode_radiance(l, &bits), EncodeError::kRadianceOverflow);
    l[c] = 255.5f * 0x1p119f;  // rounds up past the largest code
    EXPECT_EQ(VertexCodec::encode_radiance(l, &bits), EncodeError::kRadianceOverflow);
  }
  EXPECT_EQ(bits, 0x12345678u);  // untouched on failure
  // -0 is not negative.
  ASSERT_EQ(VertexCodec::encode_radiance(Vec3(-0.f, 2, 0), &bits), EncodeError::kOk);
  EXPECT_EQ(VertexCodec::decode_radiance(bits), Vec3(0, 2, 0));

  const VertexCodec codec(cornell_bounds());
  PackedVertex p;
  EXPECT_FALSE(codec.encode(record(Vec3(0, 1, 0), Vec3(0, 1, 0), Vec3(1, kNaN, 1)), &p));
  EXPECT_FALSE(codec.encode(record(Vec3(0, 1, 0), Vec3(0, 1, 0), Vec3(1, 1, -2)), &p));
}

// ---- whole records --------------------------------------------------------------------------------

TEST(VertexCodecRecord, DecoderIsTotal) {
  const VertexCodec codec(cornell_bounds());
  const Bounds3 box = codec.quantisation_box();
  TestRandom rng(13);
  for (int i = 0; i < 100000; ++i) {
    const uint64_t a = rng.bits(), b = rng.bits();
    const PackedVertex p{a, uint32_t(b), uint32_t(b >> 32)};
    const VertexRecord v = codec.decode(p);
    ASSERT_TRUE(is_finite(v.position) && is_finite(v.normal) && is_finite(v.radiance));
    for (int k = 0; k < 3; ++k) {
      ASSERT_GE(v.position[k], box.lo[k]);
      ASSERT_LE(v.position[k], box.hi[k]);
      ASSERT_GE(v.radiance[k], 0.f);
    }
    ASSERT_NEAR(length(v.normal), 1.f, 2e-7f);
    ASSERT_EQ(v.diffuse(), (a >> 63) != 0);
  }
}

TEST(VertexCodecRecord, EncodeDecodeEncodeIsIdempotent) {
  for (const Bounds3& b : {cornell_bounds(), Bounds3{Vec3(-30, -2, 5), Vec3(40, 18, 90)}}) {
    const VertexCodec codec(b);
    TestRandom rng(17);
    for (int i = 0; i < 50000; ++i) {
      const VertexRecord v =
          record(Vec3(rng.uniform(b.lo.x, b.hi.x), rng.uniform(b.lo.y, b.hi.y), rng.uniform(b.lo.z, b.hi.z)),
                 rng.unit_vector(), Vec3(rng.uniform(0, 50), rng.uniform(0, 5), rng.uniform(0, 0.5f)), i % 2 == 0);
      PackedVertex p1, p2;
      ASSERT_TRUE(codec.encode(v, &p1));
      ASSERT_TRUE(codec.encode(codec.decode(p1), &p2));
      ASSERT_EQ(p1, p2) << "record " << i;
    }
  }
}

TEST(VertexCodecRecord, FlagsCarryOnlyDiffuse) {
  const VertexCodec codec(cornell_bounds());
  PackedVertex p;
  ASSERT_TRUE(codec.encode(record(Vec3(0, 1, 0), Vec3(0, 1, 0), Vec3(1.f), true), &p));
  EXPECT_NE(p.position_bits & VertexCodec::kDiffuseBit, 0u);
  EXPECT_TRUE(codec.decode(p).diffuse());
  ASSERT_TRUE(codec.encode(record(Vec3(0, 1, 0), Vec3(0, 1, 0), Vec3(1.f), false), &p));
  EXPECT_EQ(p.position_bits & VertexCodec::kDiffuseBit, 0u);
  EXPECT_FALSE(codec.decode(p).diffuse());
  VertexRecord v = record(Vec3(0, 1, 0), Vec3(0, 1, 0), Vec3(1.f));
  v.flags |= 1u << 5;
  EXPECT_EQ(codec.try_encode(v, &p), EncodeError::kUnknownFlags);
}

// Bits worked out from the formulas in vertex_codec.h, not copied from the encoder's output.
TEST(VertexCodecRecord, BitsFollowTheDocumentedFormula) {
  // Radiance: (1, 0.5, 0.25): max 1 = 0.5 * 2^1, so E = 128 + 1 = 129, scale 2^(136 - 129) = 128.
  uint32_t bits = 0;
  ASSERT_EQ(VertexCodec::encode_radiance(Vec3(1, 0.5f, 0.25f), &bits), EncodeError::kOk);
  EXPECT_EQ(bits, 128u | (64u << 8) | (32u << 16) | (129u << 24));
  // (17, 12, 4): 17 = 0.53125 * 2^5, E = 133, scale 2^3 = 8: mantissas 136, 96, 32.
  ASSERT_EQ(VertexCodec::encode_radiance(Vec3(17, 12, 4), &bits), EncodeError::kOk);
  EXPECT_EQ(bits, 136u | (96u << 8) | (32u << 16) | (133u << 24));
  // (0.3, 0.2, 0.1): 0.3 = 0.6 * 2^-1, E = 127, scale 2^9 = 512: round(153.6) = 154,
  // round(102.4) = 102, round(51.2) = 51 (computed on the floats 0.3f, 0.2f, 0.1f).
  ASSERT_EQ(VertexCodec::encode_radiance(Vec3(0.3f, 0.2f, 0.1f), &bits), EncodeError::kOk);
  EXPECT_EQ(bits, 154u | (102u << 8) | (51u << 16) | (127u << 24));
  // (255.9, 0, 0): mantissa rounds to 256 at E = 136, so E = 137 and 255.9 / 2 rounds to 128.
  ASSERT_EQ(VertexCodec::encode_radiance(Vec3(255.9f, 0, 0), &bits), EncodeError::kOk);
  EXPECT_EQ(bits, 128u | (137u << 24));

  // Normals: octahedral coordinates as snorm16 (q = round(o * 32767), int16 two's complement).
  const struct {
    Vec3 n;
    uint32_t bits;
  } normals[] = {
      {{0, 0, 1}, 0x00000000u},   // o = (0, 0)
      {{1, 0, 0}, 0x00007fffu},   // o = (1, 0)
      {{-1, 0, 0}, 0x00008001u},  // o = (-1, 0): -32767 = 0x8001
      {{0, -1, 0}, 0x80010000u},  // o = (0, -1)
      {{0, 0, -1}, 0x7fff7fffu},  // folded: o = ((1 - 0) * +1, (1 - 0) * +1), sign(0) = +1
      {{1, 1, 0}, 0x40004000u},   // o = (0.5, 0.5): 16383.5 rounds half up to 16384 = 0x4000
  };
  for (const auto& t : normals) {
    ASSERT_EQ(VertexCodec::encode_normal(t.n, &bits), EncodeError::kOk);
    EXPECT_EQ(bits, t.bits) << t.n.x << " " << t.n.y << " " << t.n.z;
  }
  // (1, 2, -2), not normalised: L1 = 5, o = (0.2, 0.4) before the fold; folded: ((1 - 0.4) * 1, (1 - 0.2) * 1)
  // = (0.6, 0.8): round(19660.2) = 19660 = 0x4ccc, round(26213.6) = 26214 = 0x6666.
  ASSERT_EQ(VertexCodec::encode_normal(Vec3(1, 2, -2), &bits), EncodeError::kOk);
  EXPECT_EQ(bits, 0x4cccu | (0x6666u << 16));

  // Position in the Cornell bounds [-1,1] x [0,2] x [-1,1]: margin = 2 * 2^-10 = 2^-9, each axis
  // has lo_q = lo - 2^-9 and extent = 2 + 2^-8. The centre (0, 1, 0) is exactly half way: q = 2^20.
  const VertexCodec codec(cornell_bounds());
  PackedVertex p;
  ASSERT_TRUE(codec.encode(record(Vec3(0, 1, 0), Vec3(0, 0, 1), Vec3(1, 0.5f, 0.25f), true), &p));
  const uint64_t half = uint64_t(1) << 20;
  EXPECT_EQ(p.position_bits, half | (half << 21) | (half << 42) | (uint64_t(1) << 63));
  EXPECT_EQ(p.normal_bits, 0u);
  EXPECT_EQ(p.radiance_bits, 128u | (64u << 8) | (32u << 16) | (129u << 24));
  // The corner lo: t = 2^-9 / (2 + 2^-8) * 2^21 = 2^12 / (1 + 2^-9) = 2044.0078..., q = 2044.
  // The corner hi: t = (2 + 2^-9) / (2 + 2^-8) * 2^21 = 2^21 - 2044.0078..., q = 2^21 - 2045.
  ASSERT_TRUE(codec.encode(record(Vec3(-1, 2, 1), Vec3(0, 0, 1), Vec3(0.f), false), &p));
  EXPECT_EQ(p.position_bits, 2044u | ((uint64_t(1 << 21) - 2045) << 21) | ((uint64_t(1 << 21) - 2045) << 42));
  EXPECT_EQ(p.radiance_bits, 0u);

  // On the wire: little-endian words, position first.
  unsigned char wire[16];
  VertexCodec::store(PackedVertex{0x8000010000100000ull | 0x2a, 0x7fff8001u, 0x81204080u}, wire);
  const unsigned char expected[16] = {0x2a, 0x00, 0x10, 0x00, 0x00, 0x01, 0x00, 0x80,
                                      0x01, 0x80, 0xff, 0x7f, 0x80, 0x40, 0x20, 0x81};
  EXPECT_EQ(std::memcmp(wire, expected, 16), 0);
}

// ---- the optimised encoder against the plain formulas ---------------------------------------------

// Records of every kind the encoder distinguishes, mostly valid: positions inside and around the
// quantisation box (some on exact cell boundaries when the cells are powers of two), normals of any
// length and octant with +-0 components, radiance over the whole exponent range including -0, round-up
// cases (mantissa 255.5 and up) and overflow, now and then a NaN, an infinity, a negative channel, a
// zero normal or an unknown flag.
std::vector<VertexRecord> mixed_records(const Bounds3& b, size_t n, uint64_t seed) {
  TestRandom rnd(seed);
  std::vector<VertexRecord> out(n);
  const float specials[] = {0.f, -0.f, kNaN, kInf, -kInf, 1e-45f, std::numeric_limits<float>::max(), 1.f, -1.f};
  auto special = [&] { return specials[rnd.bits() % (sizeof(specials) / sizeof(specials[0]))]; };
  for (VertexRecord& v : out) {
    const uint64_t kind = rnd.bits() % 64;
    for (int a = 0; a < 3; ++a) {
      const float ext = b.hi[a] - b.lo[a];
      const float grow = std::max(ext * 0.01f, 1e-6f);
      v.position[a] = rnd.uniform(b.lo[a] - grow, b.hi[a] + grow);
      if (rnd.bits() % 8 == 0) v.position[a] = rnd.bits() % 2 ? b.lo[a] : b.hi[a];
      if (rnd.bits() % 8 == 0) v.position[a] = float(int(rnd.bits() % 64) - 32) * 0x1p-40f;  // cell corners near 0
    }
    v.normal = rnd.unit_vector() * rnd.uniform(0.001f, 1000.f);
    if (rnd.bits() % 4 == 0) v.normal[int(rnd.bits() % 3)] = rnd.bits() % 2 ? 0.f : -0.f;
    if (rnd.bits() % 8 == 0) v.normal = Vec3(0.f), v.normal[int(rnd.bits() % 3)] = rnd.bits() % 2 ? 1.f : -1.f;
    for (int c = 0; c < 3; ++c) {
      const int e = int(rnd.bits() % 280) - 150;  // 2^-150 .. 2^129
      v.radiance[c] = float(std::ldexp(double(rnd.uniform(0.5f, 1.f)), e));
      if (rnd.bits() % 16 == 0) v.radiance[c] = rnd.bits() % 2 ? 0.f : -0.f;
      if (rnd.bits() % 16 == 0) v.radiance[c] = float(std::ldexp(255.5 + rnd.uniform(0.f, 0.5f), e));
    }
    v.flags = uint32_t(rnd.bits() % 2);
    if (kind == 0) v.position[int(rnd.bits() % 3)] = special();
    if (kind == 1) v.normal[int(rnd.bits() % 3)] = special();
    if (kind == 2) v.radiance[int(rnd.bits() % 3)] = special();
    if (kind == 3) v.radiance[int(rnd.bits() % 3)] = -rnd.uniform(0.f, 1.f);
    if (kind == 4) v.flags = 2;
    if (kind == 5) v.normal = Vec3(0.f);
  }
  return out;
}

std::vector<Bounds3> reference_bounds() {
  std::vector<Bounds3> bounds;
  bounds.push_back(cornell_bounds());
  Bounds3 point;  // a single point: cells of 2^-40 m, so many positions sit exactly on a cell boundary
  point.extend(Vec3(0.f));
  bounds.push_back(point);
  Bounds3 far;  // far from the origin relative to its size
  far.extend(Vec3(1000.f, -2000.f, 3000.f));
  far.extend(Vec3(1001.5f, -1999.f, 3000.25f));
  bounds.push_back(far);
  Bounds3 big;
  big.extend(Vec3(-500.f, 0.f, -731.3f));
  big.extend(Vec3(500.f, 12.f, 731.3f));
  bounds.push_back(big);
  return bounds;
}

TEST(VertexCodecReference, TryEncodeMatchesThePlainFormulasBitForBit) {
  for (const Bounds3& b : reference_bounds()) {
    const VertexCodec codec(b);
    const test::ReferenceEncoder ref(b);
    const auto recs = mixed_records(b, 400'000, 7);
    size_t accepted = 0, mismatches = 0;
    for (const VertexRecord& v : recs) {
      PackedVertex got{1, 2, 3}, want{1, 2, 3};
      const EncodeError eg = codec.try_encode(v, &got), ew = ref.encode(v, &want);
      if (eg != ew || (ew == EncodeError::kOk && !(got == want))) {
        if (++mismatches <= 5)
          ADD_FAILURE() << "record " << v.position.x << " " << v.position.y << " " << v.position.z << " / "
                        << v.normal.x << " " << v.normal.y << " " << v.normal.z << " / " << v.radiance.x << " "
                        << v.radiance.y << " " << v.radiance.z << " flags " << v.flags << ": " << to_string(eg)
                        << " vs " << to_string(ew);
      }
      accepted += ew == EncodeError::kOk;
    }
    EXPECT_EQ(mismatches, 0u);
    EXPECT_GT(accepted, recs.size() / 2);         // mostly valid records ...
    EXPECT_LT(accepted, recs.size() * 99 / 100);  // ... and every rejection exercised
  }
}

class VertexCodecBatchKernel : public ::testing::TestWithParam<bool> {
 protected:
  void SetUp() override { VertexCodec::force_baseline_kernel(GetParam()); }
  void TearDown() override { VertexCodec::force_baseline_kernel(false); }
};

TEST_P(VertexCodecBatchKernel, EncodeBatchGivesTheBytesAndCountsOfThePlainFormulas) {
  // encode_batch takes four records at a time and falls back to try_encode for a group holding a
  // rejected record: batches of every length and rejections at every offset. Both builds of the
  // kernel (AVX2 where the CPU has it, and the baseline).
  if (GetParam()) {
    EXPECT_STREQ(VertexCodec::batch_kernel(), "baseline");
  }
  for (const Bounds3& b : reference_bounds()) {
    const VertexCodec codec(b);
    const test::ReferenceEncoder ref(b);
    const auto recs = mixed_records(b, 200'000, 11);
    EncodeCounts want_counts;
    const std::string want = ref.encode_all(recs, &want_counts);
    TestRandom rnd(3);
    std::string got = "x";  // appends after what is there
    EncodeCounts got_counts;
    for (size_t i = 0; i < recs.size();) {
      const size_t len = std::min<size_t>(recs.size() - i, rnd.bits() % 41);
      codec.encode_batch(std::span(recs).subspan(i, len), &got, &got_counts);
      i += len;
    }
    ASSERT_EQ(got.size(), want.size() + 1);
    EXPECT_EQ(got[0], 'x');
    EXPECT_TRUE(got.compare(1, std::string::npos, want) == 0);
    EXPECT_EQ(got_counts.accepted, want_counts.accepted);
    for (size_t e = 1; e < size_t(EncodeError::kCount); ++e)
      EXPECT_EQ(got_counts.rejected[e], want_counts.rejected[e]) << to_string(EncodeError(e));
    // Mostly-valid records in long runs (the worker's case): whole groups of four.
    std::vector<VertexRecord> valid;
    for (const VertexRecord& v : recs) {
      PackedVertex p;
      if (ref.encode(v, &p) == EncodeError::kOk) valid.push_back(v);
    }
    EncodeCounts c1, c2;
    std::string all;
    EXPECT_EQ(codec.encode_batch(valid, &all, &c1), valid.size());
    EXPECT_EQ(all, ref.encode_all(valid, &c2));
  }
}

INSTANTIATE_TEST_SUITE_P(Kernels, VertexCodecBatchKernel, ::testing::Values(false, true),
                         [](const auto& info) { return info.param ? "Baseline" : "Native"; });

}  // namespace
}  // namespace epr
