// The GL reprojector's packed path: the compute shader decodes the 16-byte wire records itself, and
// must decode them bit for bit as VertexCodec does (then the decisions, counts and sums follow from
// the shared kernel; reprojector_test.cpp checks that for real-like vertices).
#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "common/vertex_codec.h"
#include "master/cpu_reprojector.h"
#include "master/gl_context.h"
#include "master/gl_reprojector.h"
#include "test_scenes.h"

namespace epr {
namespace {

constexpr uint64_t kQMask = (uint64_t(1) << 21) - 1;

PackedVertex word(uint64_t qx, uint64_t qy, uint64_t qz, bool diffuse, uint16_t ox, uint16_t oy, uint32_t radiance) {
  PackedVertex p;
  p.position_bits =
      (qx & kQMask) | (qy & kQMask) << 21 | (qz & kQMask) << 42 | (diffuse ? VertexCodec::kDiffuseBit : 0);
  p.normal_bits = uint32_t(ox) | uint32_t(oy) << 16;
  p.radiance_bits = radiance;
  return p;
}

// Random words, every quantised coordinate on every axis, and every edge case of each field: q at
// both ends of each axis, the diffuse bit both ways, snorm16 -32768 / -32767 / -1 / 0 / 1 / 32767 in every combination
// (the folded lower hemisphere, its equator and the poles), exponent 0 with non-zero mantissas, exponents whose values
// are float subnormals (E < 10), the largest exponent and mantissa.
std::string edge_and_random_words(size_t random_count, uint32_t seed) {
  std::vector<PackedVertex> w;
  const uint64_t qs[] = {0, 1, kQMask / 2, kQMask / 2 + 1, kQMask - 1, kQMask};
  const uint16_t snorms[] = {0x8000, 0x8001, 0xffff, 0, 1, 0x7fff, 0x4000, 0xc000};
  const uint32_t exps[] = {0, 1, 2, 9, 10, 11, 127, 128, 136, 200, 254, 255};
  const uint32_t mants[] = {0, 1, 127, 128, 255};
  for (uint64_t q : qs)
    for (int axis = 0; axis < 3; ++axis)
      for (bool diffuse : {false, true})
        w.push_back(word(axis == 0 ? q : 17, axis == 1 ? q : 17, axis == 2 ? q : 17, diffuse, 0, 0, 0x88010203u));
  for (uint16_t ox : snorms)
    for (uint16_t oy : snorms) w.push_back(word(5, 6, 7, true, ox, oy, 0));
  for (uint32_t e : exps)
    for (uint32_t r : mants)
      for (uint32_t b : mants) w.push_back(word(1, 2, 3, true, 0, 0, e << 24 | b << 16 | 0x5a << 8 | r));
  std::mt19937_64 rng(seed);
  // Every q on every axis (exhaustive: 2^21 words), each with a random normal, radiance and diffuse bit.
  for (uint64_t q = 0; q <= kQMask; ++q) {
    const uint64_t r = rng();
    w.push_back(word(q, kQMask - q, q ^ 0x15555, (r >> 63) != 0, uint16_t(r), uint16_t(r >> 16), uint32_t(r >> 32)));
  }
  for (size_t i = 0; i < random_count; ++i) {
    PackedVertex p;
    p.position_bits = rng();
    const uint64_t r = rng();
    p.normal_bits = uint32_t(r);
    p.radiance_bits = uint32_t(r >> 32);
    w.push_back(p);
  }
  std::string bytes(w.size() * VertexCodec::kPackedBytes, '\0');
  for (size_t i = 0; i < w.size(); ++i)
    VertexCodec::store(w[i], reinterpret_cast<unsigned char*>(bytes.data()) + i * VertexCodec::kPackedBytes);
  return bytes;
}

bool same_bits(const Vec3& a, const Vec3& b) { return std::memcmp(&a, &b, sizeof(Vec3)) == 0; }

class GlPacked : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(gl_available()) << "OSMesa unavailable: run scripts/setup.sh (libosmesa6)";
    ctx_ = std::make_unique<GlContext>();
  }
  std::unique_ptr<GlContext> ctx_;
};

TEST_F(GlPacked, ShaderDecodesEveryFieldBitForBitAsVertexCodec) {
  const Scene scene = test::scene_named("cornell");
  const Camera cam(scene.camera, 32, 32);
  const DeepFramebuffer dfb = build_deep_framebuffer_cpu(scene, cam, 2);
  GlReprojector gl(*ctx_, cam, dfb, ReprojectorSettings{});
  Bounds3 far_away;  // far from the origin relative to its size: the float rounding of the result matters
  far_away.lo = {1000.f, -2000.5f, 3e4f};
  far_away.hi = {1001.f, -1999.f, 3.0001e4f};
  Bounds3 flat;  // a single point: the margin alone gives the range
  flat.lo = flat.hi = {0.25f, -3.f, 7.f};
  Bounds3 huge;
  huge.lo = {-3e6f, -1e-3f, 0.f};
  huge.hi = {5e6f, 1e-3f, 1e5f};
  const std::string words = edge_and_random_words(100000, 77);
  const size_t n = words.size() / VertexCodec::kPackedBytes;
  for (const Bounds3& b : {scene.bounds(), far_away, flat, huge}) {
    const VertexCodec codec(b);
    const std::vector<VertexRecord> got = gl.decode_packed(words, codec);
    ASSERT_EQ(got.size(), n);
    size_t bad_position = 0, bad_normal = 0, bad_radiance = 0, bad_flags = 0, subnormal = 0;
    for (size_t i = 0; i < n; ++i) {
      const VertexRecord want = codec.decode(
          VertexCodec::load(reinterpret_cast<const unsigned char*>(words.data()) + i * VertexCodec::kPackedBytes));
      bad_position += !same_bits(got[i].position, want.position);
      bad_normal += !same_bits(got[i].normal, want.normal);
      bad_radiance += !same_bits(got[i].radiance, want.radiance);
      bad_flags += got[i].flags != want.flags;
      for (int c = 0; c < 3; ++c) subnormal += std::fpclassify(want.radiance[c]) == FP_SUBNORMAL;
      if (!same_bits(got[i].position, want.position) || !same_bits(got[i].normal, want.normal) ||
          !same_bits(got[i].radiance, want.radiance)) {
        if (bad_position + bad_normal + bad_radiance < 10)
          ADD_FAILURE() << "record " << i << ": GL (" << got[i].position.x << " " << got[i].position.y << " "
                        << got[i].position.z << ") (" << got[i].normal.x << " " << got[i].normal.y << " "
                        << got[i].normal.z << ") (" << got[i].radiance.x << " " << got[i].radiance.y << " "
                        << got[i].radiance.z << ") vs codec (" << want.position.x << " " << want.position.y << " "
                        << want.position.z << ") (" << want.normal.x << " " << want.normal.y << " " << want.normal.z
                        << ") (" << want.radiance.x << " " << want.radiance.y << " " << want.radiance.z << ")";
      }
    }
    EXPECT_EQ(bad_position, 0u);
    EXPECT_EQ(bad_normal, 0u);
    EXPECT_EQ(bad_radiance, 0u);
    EXPECT_EQ(bad_flags, 0u);
    EXPECT_GT(subnormal, 100u) << "the set must exercise subnormal radiance";
  }
}

// Reprojecting packed words, GL against CPU: real-like vertices (their radiance words replaced by
// random ones, zero and subnormal exponents included, some diffuse bits cleared) plus the random and
// edge-case words above, in tile-sized calls over several upload slots. Decisions and counts must be
// identical; so must the sums of subpixels that received one sample (the decoded radiance, added to
// 0); sums of several samples agree to float rounding (GL adds them in any order).
TEST_F(GlPacked, WordsGiveTheCpuBackendsDecisionsCountsAndSums) {
  const Scene scene = test::scene_named("cornell");
  CameraSpec narrow = scene.camera;
  narrow.fov_y_degrees *= 0.6f;  // part of the box outside the frustum: culled vertices
  const Camera cam(narrow, 96, 96);
  const DeepFramebuffer dfb = build_deep_framebuffer_cpu(scene, cam, 4);
  const VertexCodec codec(scene.bounds());
  std::string words;
  codec.encode_batch(test::real_like_points(scene, dfb, cam, 300000, 3), &words);
  std::mt19937_64 rng(9);
  for (size_t off = 0; off < words.size(); off += VertexCodec::kPackedBytes) {
    auto* w = reinterpret_cast<unsigned char*>(words.data()) + off;
    PackedVertex v = VertexCodec::load(w);
    const uint64_t r = rng();
    if (r % 3 == 0) v.radiance_bits = uint32_t(r >> 32) & (r % 2 ? 0x0fffffffu : 0xffffffffu);  // E < 16 half the time
    if (r % 7 == 1) v.position_bits &= ~VertexCodec::kDiffuseBit;
    VertexCodec::store(v, w);
  }
  words += edge_and_random_words(100000, 5);
  for (bool glossy : {false, true}) {
    SCOPED_TRACE(glossy ? "reproject_glossy" : "diffuse only");
    ReprojectorSettings s;
    s.epsilon = default_epsilon(scene.bounds());
    s.reproject_glossy = glossy;
    s.batch_points = 1 << 14;  // a 15 000-vertex call spans slots; slots are reused
    GlReprojector gl(*ctx_, cam, dfb, s);
    CpuReprojector cpu(cam, dfb, s);
    const size_t call = 15000 * VertexCodec::kPackedBytes;  // one 64 x 64 tile's worth
    for (size_t off = 0; off < words.size(); off += call) {
      gl.reproject_packed(std::string_view(words).substr(off, call), codec);
      cpu.reproject_packed(std::string_view(words).substr(off, call), codec);
    }
    const ReprojectionCounts cg = gl.counts(), cc = cpu.counts();
    EXPECT_EQ(cg, cc);
    EXPECT_EQ(cc.total(), words.size() / VertexCodec::kPackedBytes);
    EXPECT_GT(cc.accepted, 50000u);
    EXPECT_GT(cc.backfacing, 10000u);
    EXPECT_GT(cc.occluded - cc.backfacing, 10000u);
    EXPECT_GT(cc.culled, 10000u);
    if (glossy)
      EXPECT_EQ(cc.not_diffuse, 0u);
    else
      EXPECT_GT(cc.not_diffuse, 40000u);
    const SubpixelAccumulation ag = gl.read(), ac = cpu.read();
    ASSERT_EQ(ag.size(), ac.size());
    size_t count_diff = 0, single = 0, single_diff = 0, sum_diff = 0, subnormal = 0;
    for (size_t i = 0; i < ag.size(); ++i) {
      count_diff += ag.count[i] != ac.count[i];
      for (int c = 0; c < 3; ++c) {
        const float g = ag.sum[3 * i + c], r = ac.sum[3 * i + c];
        if (ac.count[i] == 1) {
          ++single;
          single_diff += std::bit_cast<uint32_t>(g) != std::bit_cast<uint32_t>(r);
          subnormal += std::fpclassify(r) == FP_SUBNORMAL;
        } else {
          sum_diff += !(g == r || std::fabs(g - r) <= 1e-5f * std::fabs(r));  // == : both may overflow to inf
        }
      }
    }
    EXPECT_EQ(count_diff, 0u) << "subpixels whose counts differ";
    EXPECT_EQ(single_diff, 0u) << "single-sample subpixels whose radiance differs in any bit";
    EXPECT_EQ(sum_diff, 0u) << "sums differing by more than float rounding";
    EXPECT_GT(single, 10000u);
    EXPECT_GT(subnormal, 10u);
  }
}

}  // namespace
}  // namespace epr
