// Unpacking a TileLease for the tile renderer: the skip mask's bit order, per-pixel or uniform first
// sample indices, the vertex filter of each mode, refusal of leases that cannot be traced safely, and
// strip rendering that is bit-identical to rendering the tile at once.
#include "worker/tile_lease.h"

#include <gtest/gtest.h>

#include <cstring>
#include <limits>

#include "common/builtin_scenes.h"
#include "wire/convert.h"

namespace epr {
namespace {

TEST(SkipBits, LeastSignificantBitFirst) {
  // Byte 0 = 0b00000101: pixels 0 and 2; byte 1 = 0b10000000: pixel 15.
  const std::string bits{char(0x05), char(0x80)};
  const auto skip = unpack_skip_bits(bits, 16);
  ASSERT_TRUE(skip);
  std::vector<uint8_t> want(16, 0);
  want[0] = want[2] = want[15] = 1;
  EXPECT_EQ(*skip, want);
  EXPECT_EQ(pack_skip_bits(want), bits);
}

TEST(SkipBits, RoundTripAndLengths) {
  for (size_t n : {1u, 7u, 8u, 9u, 63u, 1024u, 1031u}) {
    std::vector<uint8_t> skip(n);
    for (size_t i = 0; i < n; ++i) skip[i] = (i * 2654435761u) % 5 < 2;
    const std::string bits = pack_skip_bits(skip);
    EXPECT_EQ(bits.size(), (n + 7) / 8);
    const auto back = unpack_skip_bits(bits, n);
    ASSERT_TRUE(back) << n;
    EXPECT_EQ(*back, skip) << n;
    // Wrong lengths are refused; empty means "none skipped".
    EXPECT_FALSE(unpack_skip_bits(bits + '\0', n)) << n;
    if (n > 8) {
      EXPECT_FALSE(unpack_skip_bits(bits.substr(1), n)) << n;
    }
    EXPECT_TRUE(unpack_skip_bits("", n)->empty());
  }
  // Unused high bits of the last byte are ignored.
  EXPECT_EQ(*unpack_skip_bits(std::string(1, char(0xfe)), 1), std::vector<uint8_t>{0});
}

// A lease of a 48 x 40 Cornell box job as the master would send it.
v1::TileLease make_lease(RenderMode mode = RenderMode::kReproject, ReprojectMethod method = ReprojectMethod::kGl) {
  static const Scene scene = make_builtin_scene("cornell");
  RenderOptions o;
  o.width = 48;
  o.height = 40;
  o.mode = mode;
  o.reproject = method;
  o.subpixels = 2;
  v1::TileLease lease;
  lease.set_lease_id(9);
  lease.set_job_id("job-1");
  lease.set_round(2);
  lease.set_tile_index(3);
  auto* r = lease.mutable_rect();
  r->set_x0(16);
  r->set_y0(8);
  r->set_x1(40);
  r->set_y1(30);
  lease.set_paths_per_pixel(2);
  lease.set_uniform_first_sample_index(4);
  lease.set_seed(11);
  to_render_settings(o, scene.camera, scene.bounds(), lease.mutable_settings());
  lease.mutable_scene()->set_builtin("builtin:cornell");
  return lease;
}

TEST(TileLease, UnpacksAValidLease) {
  v1::TileLease lease = make_lease();
  LeasedTile t;
  ASSERT_FALSE(unpack_tile_lease(lease, &t));
  EXPECT_EQ(t.rect.x0, 16);
  EXPECT_EQ(t.rect.y1, 30);
  EXPECT_TRUE(t.skip.empty());
  ASSERT_EQ(t.first_sample.size(), 24u * 22u);
  for (uint32_t f : t.first_sample) EXPECT_EQ(f, 4u);
  EXPECT_EQ(t.paths_per_pixel, 2);
  EXPECT_EQ(t.filter.mode, VertexFilter::Mode::kCull);
  EXPECT_EQ(t.filter.subpixels, 2);

  // Per-pixel first samples and a skip mask.
  std::vector<uint8_t> skip(24 * 22);
  skip[5] = skip[100] = 1;
  lease.set_skip_bits(pack_skip_bits(skip));
  for (int i = 0; i < 24 * 22; ++i) lease.add_first_sample_index(uint32_t(i));
  ASSERT_FALSE(unpack_tile_lease(lease, &t));
  EXPECT_EQ(t.skip, skip);
  EXPECT_EQ(t.first_sample[77], 77u);
  const TileRequest req = t.request();
  EXPECT_EQ(req.skip.size(), skip.size());
  EXPECT_EQ(req.first_sample.size(), skip.size());
  // A strip views its rows of the arrays.
  const TileRequest strip = t.strip(10, 12);
  EXPECT_EQ(strip.rect.y0, 10);
  EXPECT_EQ(strip.first_sample.size(), 48u);
  EXPECT_EQ(strip.first_sample[0], 48u);
  EXPECT_TRUE(strip.paths.empty());

  // Per-pixel path counts (the skip rule's budget): kept, and a strip views its rows of them.
  for (int i = 0; i < 24 * 22; ++i) lease.add_pixel_paths(1 + uint32_t(i % 2));
  ASSERT_FALSE(unpack_tile_lease(lease, &t));
  EXPECT_EQ(t.paths.size(), skip.size());
  const TileRequest budget = t.strip(10, 12);
  ASSERT_EQ(budget.paths.size(), 48u);
  EXPECT_EQ(budget.paths[0], 1u);
  EXPECT_EQ(budget.paths[1], 2u);
}

// Every roulette the wire names (common/roulette.h) is traced, the default (unspecified) too; an
// unnamed number is refused.
TEST(TileLease, TakesEveryRouletteMode) {
  const auto* modes = v1::RussianRouletteMode_descriptor();
  ASSERT_GE(modes->value_count(), 6);
  for (int i = 0; i < modes->value_count(); ++i) {
    v1::TileLease lease = make_lease();
    lease.mutable_settings()->mutable_russian_roulette()->set_mode(v1::RussianRouletteMode(modes->value(i)->number()));
    LeasedTile t;
    EXPECT_FALSE(unpack_tile_lease(lease, &t)) << modes->value(i)->name();
  }
  v1::TileLease lease = make_lease();
  lease.mutable_settings()->mutable_russian_roulette()->set_mode(v1::RussianRouletteMode(modes->value_count() + 7));
  LeasedTile t;
  EXPECT_TRUE(unpack_tile_lease(lease, &t));
}

TEST(TileLease, VertexFilterFollowsTheMode) {
  EXPECT_EQ(vertex_filter_for(make_lease(RenderMode::kPathTrace).settings()).mode, VertexFilter::Mode::kNone);
  EXPECT_EQ(vertex_filter_for(make_lease(RenderMode::kReproject, ReprojectMethod::kGl).settings()).mode,
            VertexFilter::Mode::kCull);
  EXPECT_EQ(vertex_filter_for(make_lease(RenderMode::kSkip, ReprojectMethod::kCpu).settings()).mode,
            VertexFilter::Mode::kCull);
  EXPECT_EQ(vertex_filter_for(make_lease(RenderMode::kSkip, ReprojectMethod::kExact).settings()).mode,
            VertexFilter::Mode::kExact);
  v1::TileLease lease = make_lease();
  lease.mutable_settings()->mutable_reprojection()->set_reproject_glossy(true);
  EXPECT_TRUE(vertex_filter_for(lease.settings()).reproject_glossy);
  lease.mutable_settings()->mutable_reprojection()->set_method(v1::REPROJECTION_METHOD_UNSPECIFIED);
  EXPECT_EQ(vertex_filter_for(lease.settings()).mode, VertexFilter::Mode::kCull);
}

TEST(TileLease, RefusesLeasesThatCannotBeTraced) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const std::vector<std::pair<const char*, std::function<void(v1::TileLease&)>>> cases = {
      {"tile outside the image", [](auto& l) { l.mutable_rect()->set_x1(49); }},
      {"empty tile", [](auto& l) { l.mutable_rect()->set_y1(8); }},
      {"skip_bits too short", [](auto& l) { l.set_skip_bits("\x01"); }},
      {"first_sample_index count", [](auto& l) { l.add_first_sample_index(1); }},
      {"paths_per_pixel 0", [](auto& l) { l.set_paths_per_pixel(0); }},
      {"pixel_paths count", [](auto& l) { l.add_pixel_paths(1); }},
      {"pixel_paths above paths_per_pixel",
       [](auto& l) {
         for (int i = 0; i < 24 * 22; ++i) l.add_pixel_paths(i == 7 ? 3 : 2);
       }},
      {"pixel_paths 0 for a traced pixel",
       [](auto& l) {
         for (int i = 0; i < 24 * 22; ++i) l.add_pixel_paths(i == 7 ? 0 : 1);
       }},
      {"sample index overflow", [](auto& l) { l.set_uniform_first_sample_index(0xffffffffu); }},
      {"image too large", [](auto& l) { l.mutable_settings()->set_width(100000); }},
      {"unknown mode", [](auto& l) { l.mutable_settings()->set_mode(v1::RenderMode(9)); }},
      {"unspecified mode", [](auto& l) { l.mutable_settings()->set_mode(v1::RENDER_MODE_UNSPECIFIED); }},
      {"unknown method",
       [](auto& l) { l.mutable_settings()->mutable_reprojection()->set_method(v1::ReprojectionMethod(7)); }},
      {"subpixels 0", [](auto& l) { l.mutable_settings()->mutable_reprojection()->set_subpixels(0); }},
      {"subpixels 17", [](auto& l) { l.mutable_settings()->mutable_reprojection()->set_subpixels(17); }},
      {"NaN codec bounds", [=](auto& l) { l.mutable_settings()->mutable_codec_bounds()->mutable_lo()->set_x(nan); }},
      {"inverted codec bounds",
       [](auto& l) { l.mutable_settings()->mutable_codec_bounds()->mutable_lo()->set_x(5.f); }},
      {"camera eye == look",
       [](auto& l) { *l.mutable_settings()->mutable_camera()->mutable_eye() = l.settings().camera().look(); }},
      {"NaN fov", [=](auto& l) { l.mutable_settings()->mutable_camera()->set_fov_y_degrees(nan); }},
      {"termination 1",
       [](auto& l) { l.mutable_settings()->mutable_russian_roulette()->set_termination_probability(1.f); }},
      {"max_depth 0", [](auto& l) { l.mutable_settings()->mutable_russian_roulette()->set_max_depth(0); }},
  };
  for (const auto& [name, mutate] : cases) {
    v1::TileLease lease = make_lease();
    mutate(lease);
    LeasedTile t;
    EXPECT_TRUE(unpack_tile_lease(lease, &t).has_value()) << name;
  }
  // Path tracing needs no codec bounds.
  v1::TileLease pt = make_lease(RenderMode::kPathTrace);
  pt.mutable_settings()->clear_codec_bounds();
  LeasedTile t;
  EXPECT_FALSE(unpack_tile_lease(pt, &t));
}

bool same_bits(const void* a, const void* b, size_t n) { return std::memcmp(a, b, n) == 0; }

TEST(TileLease, StripsAreBitIdenticalToOneCall) {
  const Scene scene = make_builtin_scene("cornell");
  const EmbreeScene embree(scene);
  for (const ReprojectMethod method : {ReprojectMethod::kGl, ReprojectMethod::kExact}) {
    v1::TileLease lease = make_lease(RenderMode::kSkip, method);
    std::vector<uint8_t> skip(24 * 22);
    for (size_t i = 0; i < skip.size(); i += 7) skip[i] = 1;
    lease.set_skip_bits(pack_skip_bits(skip));
    LeasedTile t;
    ASSERT_FALSE(unpack_tile_lease(lease, &t));
    const Camera camera(from_proto(lease.settings().camera()), 48, 40);
    const PathTracer tracer(embree, camera, lease.seed(), from_proto(lease.settings().russian_roulette()));
    const TileRenderer renderer(tracer, t.filter);
    const TileResult whole = renderer.render(t.request());
    int strips = 0;
    const auto parts = render_leased_tile(
        renderer, t,
        [&] {
          ++strips;
          return false;
        },
        /*strip_paths=*/100);
    ASSERT_TRUE(parts);
    EXPECT_GT(strips, 5);
    ASSERT_EQ(parts->path_sum.size(), whole.path_sum.size());
    EXPECT_TRUE(same_bits(parts->path_sum.data(), whole.path_sum.data(), whole.path_sum.size() * sizeof(Vec3)));
    EXPECT_EQ(parts->path_count, whole.path_count);
    ASSERT_EQ(parts->vertices.size(), whole.vertices.size());
    EXPECT_TRUE(same_bits(parts->vertices.data(), whole.vertices.data(), whole.vertices.size() * sizeof(VertexRecord)));
    ASSERT_EQ(parts->visible.size(), whole.visible.size());
    EXPECT_TRUE(same_bits(parts->visible.data(), whole.visible.data(), whole.visible.size() * sizeof(VisibleSample)));
    // Strips rendered into one result (TileRenderer::render_into) add up to one call's stats.
    EXPECT_EQ(parts->rect.y0, whole.rect.y0);
    EXPECT_EQ(parts->rect.y1, whole.rect.y1);
    EXPECT_EQ(parts->stats.paths.paths, whole.stats.paths.paths);
    EXPECT_EQ(parts->stats.paths.vertices, whole.stats.paths.vertices);
    EXPECT_EQ(parts->stats.paths.rays, whole.stats.paths.rays);
    EXPECT_EQ(parts->stats.vertices_recorded, whole.stats.vertices_recorded);
    EXPECT_EQ(parts->stats.culled_frustum, whole.stats.culled_frustum);
    EXPECT_EQ(parts->stats.culled_facing, whole.stats.culled_facing);
    EXPECT_EQ(parts->stats.culled_glossy, whole.stats.culled_glossy);
    EXPECT_EQ(parts->stats.exact_occluded, whole.stats.exact_occluded);
    EXPECT_GT(parts->stats.seconds, 0.0);
    EXPECT_GT(whole.vertices.size() + whole.visible.size(), 0u);

    // Packed while tracing (WorkerNode's renderer): the strips' bytes and counts concatenate to one call's.
    if (method != ReprojectMethod::kExact) {
      const TileRenderer packing(tracer, t.filter, from_proto(lease.settings().codec_bounds()));
      const TileResult one = packing.render(t.request());
      const auto strips_packed = render_leased_tile(packing, t, {}, /*strip_paths=*/100);
      ASSERT_TRUE(strips_packed);
      EXPECT_GT(one.packed_vertices.size(), 0u);
      EXPECT_EQ(strips_packed->packed_vertices, one.packed_vertices);
      EXPECT_EQ(strips_packed->encode_counts.accepted, one.encode_counts.accepted);
      EXPECT_EQ(strips_packed->encode_counts.accepted * VertexCodec::kPackedBytes, one.packed_vertices.size());
      EXPECT_TRUE(strips_packed->packed_bounds.has_value());
      EXPECT_TRUE(strips_packed->vertices.empty());
    }

    // Cancelled after the second strip: no result.
    int calls = 0;
    EXPECT_FALSE(render_leased_tile(
        renderer, t, [&] { return ++calls > 2; }, 100));
    EXPECT_EQ(calls, 3);
  }
}

}  // namespace
}  // namespace epr
