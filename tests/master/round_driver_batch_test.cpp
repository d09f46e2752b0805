// RoundDriver::apply of several tiles at once (the master's batched reprojection) gives the same
// FrameState as apply() of each tile in turn, bit for bit: path sums, the subpixel accumulation,
// counts, M' and the images -- with batches large enough for the CPU reprojector's parallel path.
#include <gtest/gtest.h>

#include <cstring>
#include <ctime>
#include <random>
#include <span>
#include <vector>

#include "common/camera.h"
#include "common/tile.h"
#include "common/vertex_codec.h"
#include "master/deep_framebuffer.h"
#include "master/round_driver.h"
#include "test_scenes.h"
#include "wire/tile_result_stream.h"

namespace epr {
namespace {

enum class Kind { kPacked, kDecoded, kExact, kMixed };

struct Fixture {
  Scene scene = test::scene_named("cornell");
  RenderOptions opts;
  std::unique_ptr<Camera> camera;
  std::vector<TileRect> rects;

  Fixture() {
    // Small, so that many vertices land in each subpixel (16384 subpixels, 16 tiles).
    opts.width = 32;
    opts.height = 32;
    opts.spp = 4;
    opts.mode = RenderMode::kSkip;
    opts.reproject = ReprojectMethod::kCpu;
    opts.tile_size = 8;
    camera = std::make_unique<Camera>(scene.camera, opts.width, opts.height);
    rects = make_tiles(opts);
  }

  // One round's tiles: random path sums, `per_tile` vertices each of the given kind (many land in
  // the same subpixels of this small frame, so the float sums depend on the order they are added in).
  std::vector<AssembledTile> tiles(Kind kind, size_t per_tile, uint32_t seed) const {
    const DeepFramebuffer dfb = build_deep_framebuffer_cpu(scene, *camera, opts.subpixels);
    const VertexCodec codec(scene.bounds());
    std::mt19937 rng(seed);
    std::uniform_real_distribution<float> u(0, 2);
    std::vector<AssembledTile> out;
    for (size_t t = 0; t < rects.size(); ++t) {
      const TileRect& r = rects[t];
      AssembledTile a;
      a.x0 = uint32_t(r.x0), a.y0 = uint32_t(r.y0), a.x1 = uint32_t(r.x1), a.y1 = uint32_t(r.y1);
      const size_t n = size_t(r.x1 - r.x0) * size_t(r.y1 - r.y0);
      for (size_t i = 0; i < n; ++i) {
        a.path_sum.push_back({u(rng), u(rng), u(rng)});
        a.path_count.push_back(1);
      }
      const std::vector<VertexRecord> v = test::real_like_points(scene, dfb, *camera, per_tile, seed + uint32_t(t));
      const Kind k = kind == Kind::kMixed ? Kind(t % 3) : kind;
      if (k == Kind::kPacked) {
        codec.encode_batch(v, &a.packed_vertices);
      } else if (k == Kind::kDecoded) {
        a.vertices = v;
      } else {
        const uint32_t subpixels = uint32_t(dfb.width) * uint32_t(dfb.height);
        for (const VertexRecord& r : v) a.exact_samples.push_back({uint32_t(rng() % subpixels), r.radiance});
      }
      // A tile now and then with two kinds (applied alone) or none.
      if (kind == Kind::kMixed && t % 7 == 3) codec.encode_batch(v, &a.packed_vertices);
      if (kind == Kind::kMixed && t % 11 == 5) a.vertices.clear(), a.packed_vertices.clear(), a.exact_samples.clear();
      out.push_back(std::move(a));
    }
    return out;
  }
};

template <typename T>
bool same_bits(const std::vector<T>& a, const std::vector<T>& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(T)) == 0;
}

void expect_same(RoundDriver& a, RoundDriver& b) {
  const FrameSnapshot x = a.frame().save(), y = b.frame().save();
  EXPECT_TRUE(same_bits(x.path_sum, y.path_sum));
  EXPECT_TRUE(same_bits(x.path_count, y.path_count));
  EXPECT_TRUE(same_bits(x.mprime, y.mprime));
  EXPECT_TRUE(same_bits(x.reprojected, y.reprojected));
  EXPECT_TRUE(same_bits(x.skip, y.skip));
  ASSERT_TRUE(x.has_accumulation && y.has_accumulation);
  EXPECT_TRUE(same_bits(x.accumulation.sum, y.accumulation.sum)) << "reprojected radiance sums differ";
  EXPECT_TRUE(same_bits(x.accumulation.count, y.accumulation.count));
  EXPECT_EQ(x.counts.accepted, y.counts.accepted);
  EXPECT_EQ(x.counts.occluded, y.counts.occluded);
  EXPECT_EQ(x.counts.culled, y.counts.culled);
  EXPECT_EQ(x.counts.exact, y.counts.exact);
  EXPECT_EQ(x.counts.invalid, y.counts.invalid);
}

// Applies two rounds: `a` tile by tile, `b` in batches of `batch` tiles; compares after each round
// and the final images.
void compare(Kind kind, size_t per_tile, size_t batch) {
  Fixture f;
  RoundDriver a(f.opts, *f.camera, f.scene, nullptr), b(f.opts, *f.camera, f.scene, nullptr);
  for (int round = 0; round < 2; ++round) {
    const std::vector<AssembledTile> tiles = f.tiles(kind, per_tile, 100 + uint32_t(round));
    for (const AssembledTile& t : tiles) a.apply(t);
    std::vector<const AssembledTile*> ptrs;
    for (const AssembledTile& t : tiles) ptrs.push_back(&t);
    for (size_t i = 0; i < ptrs.size(); i += batch)
      b.apply(std::span<const AssembledTile* const>(ptrs).subspan(i, std::min(batch, ptrs.size() - i)));
    expect_same(a, b);
    EXPECT_EQ(a.close(), b.close());
    expect_same(a, b);
  }
  const FrameImages ia = a.frame().images(), ib = b.frame().images();
  EXPECT_TRUE(same_bits(combined_image(ia).data, combined_image(ib).data));
  EXPECT_TRUE(same_bits(ia.reprojection.data, ib.reprojection.data));
}

TEST(RoundDriverBatch, PackedBatchesOnTheParallelPathMatchTileByTile) {
  // 16 tiles of 12000 vertices: batches of 8 are 96000 records (parallel), the whole round 192000.
  compare(Kind::kPacked, 12000, 8);
  compare(Kind::kPacked, 12000, 1000);
}

TEST(RoundDriverBatch, DecodedVerticesAndExactSamplesMatchTileByTile) {
  compare(Kind::kDecoded, 12000, 8);
  compare(Kind::kExact, 6000, 8);
}

TEST(RoundDriverBatch, MixedKindsKeepTheTileOrder) { compare(Kind::kMixed, 4000, 1000); }

TEST(FrameImages, ReleasedImagesEqualTheImagesAndTheCountsStay) {
  Fixture f;
  RoundDriver a(f.opts, *f.camera, f.scene, nullptr);
  for (int round = 0; round < 2; ++round) {
    for (const AssembledTile& t : f.tiles(Kind::kMixed, 2000, 40 + uint32_t(round))) a.apply(t);
    a.close();
  }
  FrameState& frame = a.frame();
  const FrameImages kept = frame.images();
  nlohmann::json before = frame.statistics(f.opts, 0);
  const FrameImages released = frame.release_images();
  for (auto [x, y] : {std::pair{&kept.path_sum, &released.path_sum},
                      {&kept.reprojection, &released.reprojection},
                      {&kept.path_count, &released.path_count},
                      {&kept.reprojected, &released.reprojected}}) {
    EXPECT_EQ(x->width, y->width);
    EXPECT_EQ(x->channels, y->channels);
    EXPECT_TRUE(same_bits(x->data, y->data));
  }
  EXPECT_FALSE(released.reprojection.data.empty());
  EXPECT_TRUE(frame.reprojects());
  // The reprojector is gone, its counts are not.
  nlohmann::json after = frame.statistics(f.opts, 0);
  for (auto* j : {&before, &after}) j->erase("seconds_reprojecting"), j->erase("seconds_downsampling");
  EXPECT_EQ(before, after);
  EXPECT_GT(after["accepted"].get<uint64_t>(), 0u);
  EXPECT_TRUE(frame.path_sums().empty());
}

TEST(RoundDriverBatch, TheComparisonSeesTheOrder) {
  // The fixture is sensitive to order: the same tiles in reverse give other float sums. (Decoded
  // vertices: packed radiance has a short shared-exponent mantissa, so a few packed samples per
  // subpixel often add up exactly in any order.)
  Fixture f;
  RoundDriver a(f.opts, *f.camera, f.scene, nullptr), b(f.opts, *f.camera, f.scene, nullptr);
  const std::vector<AssembledTile> tiles = f.tiles(Kind::kDecoded, 12000, 7);
  std::vector<const AssembledTile*> ptrs;
  for (const AssembledTile& t : tiles) ptrs.push_back(&t);
  a.apply(ptrs);
  std::reverse(ptrs.begin(), ptrs.end());
  b.apply(ptrs);
  const FrameSnapshot x = a.frame().save(), y = b.frame().save();
  EXPECT_TRUE(same_bits(x.accumulation.count, y.accumulation.count));
  EXPECT_FALSE(same_bits(x.accumulation.sum, y.accumulation.sum));
}

}  // namespace
}  // namespace epr
