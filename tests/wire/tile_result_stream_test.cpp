// The SubmitTile stream: a real tile through TileResultWriter and TileResultAssembler comes back
// bit-identical (vertices up to the codec's own rounding); every protocol violation is refused with
// a reason; non-finite radiance is dropped and counted instead; chunks respect the limits.
#include "wire/tile_result_stream.h"

#include <gtest/gtest.h>
#include <malloc.h>

#include <cmath>
#include <cstring>
#include <functional>
#include <limits>

#include "common/builtin_scenes.h"
#include "tests/common/vertex_codec_reference.h"
#include "worker/tile_renderer.h"

namespace epr {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
constexpr float kInf = std::numeric_limits<float>::infinity();
constexpr int kWidth = 48, kHeight = 40;

// A Cornell box traced for real, as a worker would.
struct CornellFixture {
  Scene scene = make_builtin_scene("cornell");
  EmbreeScene embree{scene};
  Camera camera{scene.camera, kWidth, kHeight};
  PathTracer tracer{embree, camera, 7, RussianRoulette::paper()};

  TileResult render(VertexFilter::Mode mode, const TileRect& rect, int paths_per_pixel,
                    std::vector<uint8_t>* skip_out = nullptr, std::vector<uint32_t>* first_out = nullptr) const {
    VertexFilter filter;
    filter.mode = mode;
    filter.subpixels = 2;
    TileRenderer renderer(tracer, filter);
    std::vector<uint8_t> skip(size_t(rect.pixel_count()));
    std::vector<uint32_t> first(size_t(rect.pixel_count()));
    for (size_t i = 0; i < skip.size(); ++i) {
      skip[i] = i % 7 == 3;        // some pixels skipped
      first[i] = uint32_t(i % 5);  // non-uniform first sample indices
    }
    TileRequest req;
    req.rect = rect;
    req.skip = skip;
    req.first_sample = first;
    req.paths_per_pixel = paths_per_pixel;
    TileResult r = renderer.render(req);
    if (skip_out) *skip_out = skip;
    if (first_out) *first_out = first;
    return r;
  }
};

const CornellFixture& cornell() {
  static const CornellFixture f;
  return f;
}

TileResultIdentity identity() { return {42, "job-1", 3, 5, "worker-a"}; }

// The whole 512 x 256 image as one tile (big_tile()'s frame).
TileExpectation big_tile_expectation(const Bounds3& bounds, const TileResultLimits& limits) {
  TileExpectation e;
  e.job_id = "job-1";
  e.round = 3;
  e.tile_index = 5;
  e.x1 = 512;
  e.y1 = 256;
  e.image_width = 512;
  e.image_height = 256;
  e.codec_bounds = bounds;
  e.limits = limits;
  return e;
}

TileExpectation expectation(const TileRect& rect, TileExpectation::Payload payload, const Bounds3& bounds,
                            TileResultLimits limits = {}) {
  TileExpectation e;
  e.job_id = "job-1";
  e.round = 3;
  e.tile_index = 5;
  e.x0 = uint32_t(rect.x0);
  e.y0 = uint32_t(rect.y0);
  e.x1 = uint32_t(rect.x1);
  e.y1 = uint32_t(rect.y1);
  e.image_width = kWidth;
  e.image_height = kHeight;
  e.subpixels = 2;
  e.codec_bounds = bounds;
  e.payload = payload;
  e.limits = limits;
  return e;
}

// Feeds every chunk; fails the test on the first refusal.
AssembledTile assemble(const std::vector<v1::TileResultChunk>& chunks, TileExpectation e) {
  TileResultAssembler a(std::move(e));
  for (size_t i = 0; i < chunks.size(); ++i) {
    const auto err = a.add(chunks[i]);
    EXPECT_FALSE(err) << "chunk " << i << ": " << *err;
    if (err) return {};
  }
  EXPECT_TRUE(a.complete());
  return a.complete() ? a.take() : AssembledTile{};
}

bool bit_equal(const Vec3& a, const Vec3& b) { return std::memcmp(&a, &b, sizeof(Vec3)) == 0; }

void expect_same_pixels(const TileResult& r, const AssembledTile& t) {
  ASSERT_EQ(t.path_sum.size(), r.path_sum.size());
  ASSERT_EQ(t.path_counts(), r.path_count);
  for (size_t i = 0; i < r.path_sum.size(); ++i) EXPECT_TRUE(bit_equal(t.path_sum[i], r.path_sum[i])) << "pixel " << i;
}

// ---- round trips of real tiles --------------------------------------------------------------------

TEST(TileResultStream, CullModeRoundTripIsExact) {
  const auto& f = cornell();
  const TileRect rect{8, 4, 40, 30};
  const TileResult r = f.render(VertexFilter::Mode::kCull, rect, 2);
  ASSERT_GT(r.vertices.size(), 1000u);
  const Bounds3 bounds = f.scene.bounds();
  // Small limits so that every kind of data needs several chunks.
  const TileResultLimits limits{500, 8 * 1024};
  const auto chunks = split_tile_result(r, identity(), bounds, limits);
  ASSERT_GE(chunks.size(), 4u);
  EXPECT_TRUE(chunks.front().has_header());
  EXPECT_TRUE(chunks.back().has_trailer());
  int pixel_chunks = 0;
  for (const auto& c : chunks) {
    EXPECT_LE(c.ByteSizeLong(), limits.max_chunk_bytes);
    pixel_chunks += c.has_pixels();
    if (c.has_vertices()) {
      EXPECT_LE(c.vertices().count(), limits.max_vertices_per_chunk);
    }
  }
  EXPECT_GE(pixel_chunks, 2);

  const AssembledTile t = assemble(chunks, expectation(rect, TileExpectation::Payload::kVertices, bounds, limits));
  expect_same_pixels(r, t);
  EXPECT_EQ(t.x0, 8u);
  EXPECT_EQ(t.y1, 30u);
  EXPECT_EQ(t.lease_id, 42u);
  EXPECT_EQ(t.worker_id, "worker-a");
  EXPECT_EQ(t.dropped_pixel_sums, 0u);
  // Every culled vertex is inside the scene, so the codec takes them all; decoded = codec round trip.
  const VertexCodec codec(bounds);
  ASSERT_EQ(t.vertices.size(), r.vertices.size());
  for (size_t i = 0; i < r.vertices.size(); ++i) {
    PackedVertex p;
    ASSERT_TRUE(codec.encode(r.vertices[i], &p));
    const VertexRecord want = codec.decode(p);
    EXPECT_TRUE(bit_equal(t.vertices[i].position, want.position)) << i;
    EXPECT_TRUE(bit_equal(t.vertices[i].normal, want.normal)) << i;
    EXPECT_TRUE(bit_equal(t.vertices[i].radiance, want.radiance)) << i;
    EXPECT_EQ(t.vertices[i].flags, want.flags) << i;
  }
  // Worker stats map TileStats.
  const v1::TileWorkerStats& s = t.worker_stats;
  EXPECT_EQ(s.paths_traced(), r.stats.paths.paths);
  EXPECT_EQ(s.rays_traced(), r.stats.paths.rays);
  EXPECT_EQ(s.vertices_produced(), r.stats.vertices_recorded);
  EXPECT_EQ(s.culled_frustum(), r.stats.culled_frustum);
  EXPECT_EQ(s.culled_facing(), r.stats.culled_facing);
  EXPECT_EQ(s.culled_not_diffuse(), r.stats.culled_glossy);
  EXPECT_EQ(s.encode_rejected(), 0u);
  EXPECT_EQ(s.non_finite_dropped(), r.stats.paths.nonfinite_dropped);
  EXPECT_DOUBLE_EQ(s.seconds_tracing(), r.stats.seconds);
  EXPECT_GT(s.culled_frustum() + s.culled_facing(), 0u);
}

TEST(TileResultStream, ExactModeRoundTripKeepsFloats) {
  const auto& f = cornell();
  const TileRect rect{0, 0, 24, 20};
  const TileResult r = f.render(VertexFilter::Mode::kExact, rect, 1);
  ASSERT_GT(r.visible.size(), 100u);
  EXPECT_TRUE(r.vertices.empty());
  const Bounds3 bounds = f.scene.bounds();
  const TileResultLimits limits{64, 1 << 20};
  const auto chunks = split_tile_result(r, identity(), bounds, limits);
  EXPECT_EQ(chunks.front().header().exact_sample_count(), r.visible.size());
  EXPECT_EQ(chunks.front().header().vertex_count(), 0u);
  for (const auto& c : chunks) {
    if (c.has_exact_samples()) {
      EXPECT_LE(c.exact_samples().subpixel_size(), 64);
    }
  }

  const AssembledTile t = assemble(chunks, expectation(rect, TileExpectation::Payload::kExactSamples, bounds, limits));
  expect_same_pixels(r, t);
  ASSERT_EQ(t.exact_samples.size(), r.visible.size());
  for (size_t i = 0; i < r.visible.size(); ++i) {
    EXPECT_EQ(t.exact_samples[i].first, r.visible[i].subpixel);
    EXPECT_TRUE(bit_equal(t.exact_samples[i].second, r.visible[i].radiance)) << i;
  }
  EXPECT_EQ(t.worker_stats.exact_occluded(), r.stats.exact_occluded);
  // Exact mode's visibility rays are counted as rays.
  EXPECT_EQ(t.worker_stats.rays_traced(), r.stats.paths.rays + r.stats.exact_occluded + r.visible.size());
}

TEST(TileResultStream, PathTracingRoundTripHasNoVertices) {
  const auto& f = cornell();
  const TileRect rect{40, 32, 48, 40};  // the image's bottom-right corner tile
  const TileResult r = f.render(VertexFilter::Mode::kNone, rect, 3);
  const auto chunks = split_tile_result(r, identity(), f.scene.bounds(), {});
  ASSERT_EQ(chunks.size(), 3u);  // header, one PixelPaths, trailer
  EXPECT_EQ(chunks[0].header().vertex_encoding(), v1::VERTEX_ENCODING_UNSPECIFIED);
  auto e = expectation(rect, TileExpectation::Payload::kPathsOnly, f.scene.bounds());
  // The strict path-count check agrees with the renderer's skip mask.
  std::vector<uint8_t> skip;
  f.render(VertexFilter::Mode::kNone, rect, 3, &skip);
  e.paths_per_pixel = 3;
  e.skip = skip;
  const AssembledTile t = assemble(chunks, e);
  expect_same_pixels(r, t);
  // Checked against the lease, the counts are kept as the lease's count and skip mask, not per pixel.
  EXPECT_TRUE(t.path_count.empty());
  EXPECT_EQ(t.paths_per_pixel, 3u);
  EXPECT_EQ(t.skip, skip);
}

TEST(TileResultStream, ChunksOfAFullTileInAnyOrderAreAccepted) {
  const auto& f = cornell();
  const TileRect rect{0, 0, 16, 16};
  const TileResult r = f.render(VertexFilter::Mode::kCull, rect, 1);
  auto chunks = split_tile_result(r, identity(), f.scene.bounds(), {300, 1 << 20});
  ASSERT_GE(chunks.size(), 4u);
  // Header first, trailer last, the rest reversed (the proto allows any order in between).
  std::reverse(chunks.begin() + 1, chunks.end() - 1);
  const AssembledTile t =
      assemble(chunks, expectation(rect, TileExpectation::Payload::kVertices, f.scene.bounds(), {300, 1 << 20}));
  expect_same_pixels(r, t);
  EXPECT_EQ(t.vertices.size(), r.vertices.size());
}

// ---- chunk limits -----------------------------------------------------------------------------------

// A synthetic tile: 512 x 256 pixels (more than one PixelPaths chunk's 65536) and 100k vertices.
TileResult big_tile() {
  TileResult r;
  r.rect = {0, 0, 512, 256};
  const size_t n = size_t(r.rect.pixel_count());
  r.path_sum.resize(n);
  r.path_count.resize(n);
  for (size_t i = 0; i < n; ++i) {
    r.path_sum[i] = Vec3(float(i % 97) * 0.25f, 1.f / float(i + 1), 3.f);
    r.path_count[i] = uint32_t(1 + (i % 4));
  }
  r.vertices.resize(100'000);
  for (size_t i = 0; i < r.vertices.size(); ++i) {
    const float t = float(i) / float(r.vertices.size());
    r.vertices[i] = {Vec3(t, 1 - t, 0.5f * t), Vec3(0, 1, 0), Vec3(t, 2 * t, 0.1f), VertexRecord::kDiffuse};
  }
  return r;
}

TEST(TileResultStream, BigTileRespectsTheChunkLimits) {
  const TileResult r = big_tile();
  const Bounds3 bounds{Vec3(0.f), Vec3(1.f)};
  for (const TileResultLimits limits :
       {TileResultLimits{65536, 2u << 20}, TileResultLimits{100'000, 256 * 1024}, TileResultLimits{1000, 2u << 20}}) {
    SCOPED_TRACE(testing::Message() << limits.max_vertices_per_chunk << " vertices, " << limits.max_chunk_bytes
                                    << " bytes");
    TileResultWriter w(r, identity(), bounds, limits);
    v1::TileResultChunk c;
    uint64_t vertices = 0, pixels = 0, chunks = 0;
    while (w.next(&c)) {
      ++chunks;
      EXPECT_LE(c.ByteSizeLong(), limits.max_chunk_bytes);
      if (c.has_vertices()) {
        EXPECT_LE(c.vertices().count(), limits.max_vertices_per_chunk);
        vertices += c.vertices().count();
      }
      if (c.has_pixels()) {
        EXPECT_LE(c.pixels().path_count_size(), 65536);
        pixels += uint64_t(c.pixels().path_count_size());
      }
      c.Clear();
    }
    EXPECT_EQ(vertices, 100'000u);
    EXPECT_EQ(pixels, 512u * 256u);
    EXPECT_GT(chunks, 4u);
    const TileExpectation e = big_tile_expectation(bounds, limits);
    const AssembledTile t = assemble(split_tile_result(r, identity(), bounds, limits), e);
    EXPECT_EQ(t.vertices.size(), 100'000u);
    EXPECT_EQ(t.path_counts(), r.path_count);
  }
}

// The master keeps the vertices packed (TileExpectation::keep_packed) and moves each batch's bytes out
// of its chunk: the bytes, in order, are the vertices a decoding assembler returns.
TEST(TileResultStream, KeptPackedVerticesAreTheDecodedOnes) {
  const TileResult r = big_tile();
  const Bounds3 bounds{Vec3(0.f), Vec3(1.f)};
  const TileResultLimits limits{30'000, 2u << 20};  // 4 vertex batches
  TileExpectation e = big_tile_expectation(bounds, limits);
  auto chunks = split_tile_result(r, identity(), bounds, limits);
  const AssembledTile decoded = assemble(chunks, e);
  e.keep_packed = true;
  TileResultAssembler a(e);
  for (auto& c : chunks) ASSERT_FALSE(a.add(&c));
  ASSERT_TRUE(a.complete());
  const AssembledTile packed = a.take();
  EXPECT_TRUE(packed.vertices.empty());
  EXPECT_EQ(packed.vertex_count(), 100'000u);
  ASSERT_EQ(packed.packed_vertices.size(), 16u * 100'000u);
  std::vector<VertexRecord> unpacked;
  ASSERT_TRUE(VertexCodec(bounds).decode_batch(packed.packed_vertices, &unpacked));
  ASSERT_EQ(unpacked.size(), decoded.vertices.size());
  for (size_t i = 0; i < unpacked.size(); ++i)
    ASSERT_EQ(std::memcmp(&unpacked[i], &decoded.vertices[i], sizeof(VertexRecord)), 0) << "vertex " << i;
  EXPECT_EQ(packed.path_counts(), r.path_count);
  // A short count is still caught at the trailer.
  e.limits = limits;
  auto again = split_tile_result(r, identity(), bounds, limits);
  TileResultAssembler b(e);
  std::optional<std::string> err;
  for (auto& c : again) {
    if (c.has_vertices() && c.vertices().count() == 30'000) {
      c.mutable_vertices()->set_count(29'999);
      c.mutable_vertices()->mutable_packed()->resize(16 * 29'999);
    }
    if ((err = b.add(&c))) break;
  }
  ASSERT_TRUE(err);
  EXPECT_NE(err->find("trailer after"), std::string::npos) << *err;
}

TEST(TileResultStream, WriterDropsWhatTheCodecRefusesAndCountsIt) {
  TileResult r;
  r.rect = {0, 0, 2, 1};
  r.path_sum = {Vec3(1.f), Vec3(kNaN, 0, 0)};  // a non-finite sum is sent as 0, its count kept
  r.path_count = {1, 1};
  r.stats.paths.nonfinite_dropped = 2;
  const Vec3 up(0, 1, 0);
  r.vertices = {
      {Vec3(0.5f), up, Vec3(1.f), VertexRecord::kDiffuse},         // fine
      {Vec3(50.f), up, Vec3(1.f), VertexRecord::kDiffuse},         // outside the bounds
      {Vec3(0.5f), Vec3(0.f), Vec3(1.f), VertexRecord::kDiffuse},  // bad normal
      {Vec3(0.5f), up, Vec3(kInf, 0, 0), VertexRecord::kDiffuse},  // non-finite radiance
      {Vec3(0.25f), up, Vec3(2.f), 0},                             // fine, glossy
  };
  r.visible = {{3, Vec3(1.f)}, {4, Vec3(kNaN)}, {5, Vec3(-1.f, 0, 0)}};
  const Bounds3 bounds{Vec3(0.f), Vec3(1.f)};
  TileResultWriter w(r, identity(), bounds, {});
  EXPECT_EQ(w.header().vertex_count(), 2u);
  EXPECT_EQ(w.header().exact_sample_count(), 1u);
  EXPECT_EQ(w.header().vertex_encoding(), v1::VERTEX_ENCODING_PACKED16);
  EXPECT_EQ(w.stats().encode_rejected(), 2u);
  // 2 from the tracer, 1 pixel sum, 1 vertex, 2 exact samples.
  EXPECT_EQ(w.stats().non_finite_dropped(), 6u);
  const auto chunks = split_tile_result(r, identity(), bounds, {});
  const auto& px = chunks[1].pixels();
  EXPECT_EQ(px.radiance_sum(3), 0.f);
  EXPECT_EQ(px.path_count(1), 1u);
}

// The worker's path: TileRenderer with the codec bounds packs the vertices while tracing; the stream
// must be the one the writer makes from the records, byte for byte, and those bytes the plain formulas'.
TEST(TileResultStream, VerticesPackedWhileTracingGiveTheSameStream) {
  const CornellFixture& f = cornell();
  const Bounds3 bounds = f.scene.bounds();
  const TileRect rect{8, 4, 40, 36};
  TileRequest req;
  req.rect = rect;
  req.paths_per_pixel = 3;
  TileResultLimits limits;
  limits.max_vertices_per_chunk = 97;  // several vertex chunks
  for (const VertexFilter::Mode mode : {VertexFilter::Mode::kAll, VertexFilter::Mode::kCull}) {
    VertexFilter filter;
    filter.mode = mode;
    filter.subpixels = 2;
    const TileResult records = TileRenderer(f.tracer, filter).render(req);
    const TileResult packed = TileRenderer(f.tracer, filter, bounds).render(req);
    ASSERT_TRUE(packed.packed_bounds.has_value());
    EXPECT_TRUE(packed.vertices.empty());
    EXPECT_FALSE(records.packed_bounds.has_value());
    ASSERT_GT(records.vertices.size(), 500u);

    EncodeCounts want_counts;
    const std::string want = test::ReferenceEncoder(bounds).encode_all(records.vertices, &want_counts);
    EXPECT_EQ(packed.packed_vertices, want);
    EXPECT_EQ(packed.encode_counts.accepted, want_counts.accepted);
    EXPECT_EQ(packed.encode_counts.rejected_total(), want_counts.rejected_total());

    auto a = split_tile_result(records, identity(), bounds, limits);
    auto b = split_tile_result(packed, identity(), bounds, limits);
    ASSERT_EQ(a.size(), b.size());
    EXPECT_GT(a.size(), 6u);
    for (auto* chunks : {&a, &b})  // the tracing wall time is the one field that may differ
      chunks->back().mutable_trailer()->mutable_stats()->set_seconds_tracing(0);
    for (size_t i = 0; i < a.size(); ++i)
      EXPECT_EQ(a[i].SerializeAsString(), b[i].SerializeAsString()) << "chunk " << i;
  }
  // Exact mode and path tracing ignore the bounds.
  VertexFilter exact;
  exact.mode = VertexFilter::Mode::kExact;
  exact.subpixels = 2;
  const TileResult e = TileRenderer(f.tracer, exact, bounds).render(req);
  EXPECT_FALSE(e.packed_bounds.has_value());
  EXPECT_TRUE(e.packed_vertices.empty());
  EXPECT_FALSE(e.visible.empty());
}

TEST(TileResultStream, WriterRefusesVerticesPackedWithOtherBounds) {
  const CornellFixture& f = cornell();
  VertexFilter filter;
  filter.mode = VertexFilter::Mode::kCull;
  const TileResult packed = TileRenderer(f.tracer, filter, f.scene.bounds()).render({{0, 0, 8, 8}, {}, {}, 2});
  Bounds3 other = f.scene.bounds();
  other.hi.x = std::nextafter(other.hi.x, kInf);  // one ulp: a different quantisation
  EXPECT_THROW(TileResultWriter(packed, identity(), other, {}), std::invalid_argument);
  EXPECT_NO_THROW(TileResultWriter(packed, identity(), f.scene.bounds(), {}));
  EXPECT_THROW(TileRenderer(f.tracer, filter, Bounds3{Vec3(1.f), Vec3(0.f)}), std::invalid_argument);
}

// ---- protocol violations ------------------------------------------------------------------------------

// A small valid stream to break in one place at a time: a 4 x 2 tile, 3 vertices.
struct SmallStream {
  TileRect rect{4, 2, 8, 4};
  Bounds3 bounds{Vec3(0.f), Vec3(1.f)};
  TileResult result;
  std::vector<v1::TileResultChunk> chunks;

  explicit SmallStream(bool exact = false) {
    result.rect = rect;
    result.path_sum.assign(8, Vec3(0.5f));
    result.path_count.assign(8, 1);
    if (exact) {
      result.visible = {{0, Vec3(1.f)}, {17, Vec3(2.f)}, {100, Vec3(3.f)}};
    } else {
      for (int i = 0; i < 3; ++i)
        result.vertices.push_back({Vec3(0.1f * float(i + 1)), Vec3(0, 0, 1), Vec3(1.f), VertexRecord::kDiffuse});
    }
    chunks = split_tile_result(result, identity(), bounds, {});
    // header, pixels, vertices or exact samples, trailer
    EXPECT_EQ(chunks.size(), 4u);
  }
  TileExpectation expected(bool exact = false) const {
    TileExpectation e = expectation(
        rect, exact ? TileExpectation::Payload::kExactSamples : TileExpectation::Payload::kVertices, bounds);
    return e;
  }
};

// Feeds `chunks`; returns the first error (empty if all were accepted).
std::optional<std::string> first_error(const std::vector<v1::TileResultChunk>& chunks, const TileExpectation& e,
                                       bool* complete = nullptr) {
  TileResultAssembler a(e);
  for (const auto& c : chunks)
    if (auto err = a.add(c)) return err;
  if (complete) *complete = a.complete();
  return std::nullopt;
}

struct Violation {
  const char* name;
  const char* reason_contains;
  std::function<void(std::vector<v1::TileResultChunk>&, TileExpectation&)> mutate;
};

// Per-pixel path counts of the lease (the skip rule's budget): accepted and kept pixel by pixel.
TEST(TileResultStream, PerPixelPathCountsOfTheLeaseAreCheckedAndKept) {
  SmallStream s;
  s.result.path_count = {1, 2, 1, 2, 2, 2, 1, 2};
  const auto chunks = split_tile_result(s.result, identity(), s.bounds, {});
  TileExpectation e = s.expected();
  e.paths_per_pixel = 2;
  e.paths = s.result.path_count;
  const AssembledTile t = assemble(chunks, e);
  EXPECT_EQ(t.path_counts(), s.result.path_count);
}

TEST(TileResultStream, EveryViolationIsRefusedWithAReason) {
  const std::vector<Violation> violations = {
      {"header not first", "first chunk must be the header", [](auto& c, auto&) { std::swap(c[0], c[1]); }},
      {"header twice", "second header", [](auto& c, auto&) { c.insert(c.begin() + 1, c[0]); }},
      {"wrong job", "job_id", [](auto& c, auto&) { c[0].mutable_header()->set_job_id("job-2"); }},
      {"wrong round", "round", [](auto& c, auto&) { c[0].mutable_header()->set_round(4); }},
      {"wrong tile", "tile_index", [](auto& c, auto&) { c[0].mutable_header()->set_tile_index(6); }},
      {"wrong pixel count", "pixel_count", [](auto& c, auto&) { c[0].mutable_header()->set_pixel_count(9); }},
      {"unknown encoding", "unknown vertex_encoding",
       [](auto& c, auto&) { c[0].mutable_header()->set_vertex_encoding(v1::VertexEncoding(7)); }},
      {"missing encoding", "vertex_encoding is required",
       [](auto& c, auto&) { c[0].mutable_header()->set_vertex_encoding(v1::VERTEX_ENCODING_UNSPECIFIED); }},
      {"first_pixel out of range", "outside the tile",
       [](auto& c, auto&) { c[1].mutable_pixels()->set_first_pixel(8); }},
      {"pixel run past the end", "outside the tile", [](auto& c, auto&) { c[1].mutable_pixels()->set_first_pixel(1); }},
      {"first_pixel overflow", "outside the tile",
       [](auto& c, auto&) { c[1].mutable_pixels()->set_first_pixel(0xffffffffu); }},
      {"radiance count", "radiance values", [](auto& c, auto&) { c[1].mutable_pixels()->add_radiance_sum(1.f); }},
      {"empty pixels", "without pixels", [](auto& c, auto&) { c[1].mutable_pixels()->Clear(); }},
      {"pixels twice", "sent twice", [](auto& c, auto&) { c.insert(c.begin() + 2, c[1]); }},
      {"implausible path count", "implausible",
       [](auto& c, auto&) { c[1].mutable_pixels()->set_path_count(2, 0xffffffffu); }},
      {"path count not the lease's", "lease asks for",
       [](auto& c, auto& e) {
         e.paths_per_pixel = 2;  // the stream says 1
       }},
      {"path count not the pixel's budget", "lease asks for",
       [](auto& c, auto& e) {
         e.paths_per_pixel = 2;
         e.paths.assign(8, 1);  // the stream says 1 everywhere
         e.paths[3] = 2;
       }},
      {"skipped pixel with paths", "lease asks for",
       [](auto& c, auto& e) {
         e.paths_per_pixel = 1;
         e.skip.assign(8, 0);
         e.skip[5] = 1;
       }},
      {"batch over the limit", "max_vertices_per_chunk", [](auto& c, auto& e) { e.limits.max_vertices_per_chunk = 2; }},
      {"packed bytes != 16 * count", "16 each",
       [](auto& c, auto&) { c[2].mutable_vertices()->mutable_packed()->push_back('x'); }},
      {"count != packed", "16 each", [](auto& c, auto&) { c[2].mutable_vertices()->set_count(2); }},
      {"more vertices than announced", "more vertices",
       [](auto& c, auto&) { c[0].mutable_header()->set_vertex_count(2); }},
      {"fewer vertices than announced", "of the 4 vertices announced",
       [](auto& c, auto&) { c[0].mutable_header()->set_vertex_count(4); }},
      {"trailer before every pixel", "pixels", [](auto& c, auto&) { c.erase(c.begin() + 1); }},
      {"chunk after the trailer", "after the trailer", [](auto& c, auto&) { c.push_back(c[1]); }},
      {"trailer twice", "after the trailer", [](auto& c, auto&) { c.push_back(c.back()); }},
      {"empty chunk", "without a part", [](auto& c, auto&) { c.insert(c.begin() + 1, v1::TileResultChunk()); }},
      {"vertices for a path-tracing job", "takes none",
       [](auto& c, auto& e) { e.payload = TileExpectation::Payload::kPathsOnly; }},
      {"vertices for an exact job", "takes none",
       [](auto& c, auto& e) { e.payload = TileExpectation::Payload::kExactSamples; }},
      {"vertices over the per-tile cap", "per-tile limit", [](auto& c, auto& e) { e.max_vertices_per_tile = 2; }},
      {"chunk over max_chunk_bytes", "max_chunk_bytes", [](auto& c, auto& e) { e.limits.max_chunk_bytes = 40; }},
  };
  const SmallStream base;
  {
    bool complete = false;
    const auto err = first_error(base.chunks, base.expected(), &complete);
    ASSERT_FALSE(err) << *err;
    ASSERT_TRUE(complete);
  }
  for (const auto& v : violations) {
    SCOPED_TRACE(v.name);
    auto chunks = base.chunks;
    auto e = base.expected();
    v.mutate(chunks, e);
    const auto err = first_error(chunks, e);
    ASSERT_TRUE(err.has_value());
    EXPECT_NE(err->find(v.reason_contains), std::string::npos) << *err;
  }
}

TEST(TileResultStream, ExactSampleViolationsAreRefused) {
  const SmallStream base(/*exact=*/true);
  ASSERT_FALSE(first_error(base.chunks, base.expected(true)));
  const uint32_t grid = 2 * kWidth * 2 * kHeight;  // S = 2
  const std::vector<Violation> violations = {
      {"subpixel out of range", "subpixel grid",
       [&](auto& c, auto&) { c[2].mutable_exact_samples()->set_subpixel(1, grid); }},
      {"radiance count", "radiance values", [](auto& c, auto&) { c[2].mutable_exact_samples()->add_radiance(1.f); }},
      {"more than announced", "more exact samples",
       [](auto& c, auto&) { c[0].mutable_header()->set_exact_sample_count(2); }},
      {"fewer than announced", "exact samples announced",
       [](auto& c, auto&) { c[0].mutable_header()->set_exact_sample_count(4); }},
      {"over the limit", "max_vertices_per_chunk", [](auto& c, auto& e) { e.limits.max_vertices_per_chunk = 2; }},
      {"exact samples for a vertex job", "not in exact mode",
       [](auto& c, auto& e) { e.payload = TileExpectation::Payload::kVertices; }},
  };
  for (const auto& v : violations) {
    SCOPED_TRACE(v.name);
    auto chunks = base.chunks;
    auto e = base.expected(true);
    v.mutate(chunks, e);
    const auto err = first_error(chunks, e);
    ASSERT_TRUE(err.has_value());
    EXPECT_NE(err->find(v.reason_contains), std::string::npos) << *err;
  }
}

TEST(TileResultStream, ErrorsAreFinal) {
  const SmallStream base;
  TileResultAssembler a(base.expected());
  auto bad = base.chunks[0];
  bad.mutable_header()->set_job_id("other");
  const auto err = a.add(bad);
  ASSERT_TRUE(err);
  // The correct stream afterwards does not revive it.
  for (const auto& c : base.chunks) EXPECT_EQ(a.add(c), err);
  EXPECT_FALSE(a.complete());
  EXPECT_THROW(a.take(), std::logic_error);
}

/// Bytes the process has allocated from the heap (glibc: small blocks plus mmap'd large ones).
size_t heap_bytes() {
  const struct mallinfo2 m = mallinfo2();
  return m.uordblks + m.hblkhd;
}

// Found by tests/fuzz (regressions/tile_result/oom-header-reserves-160mb): a header announcing the
// per-tile maximum of vertices or exact samples made the master reserve for all of them before a
// single one arrived (160 MB per stream for 4 Mi vertices). Now memory follows the data received.
TEST(TileResultStream, AHeaderAloneAllocatesLittle) {
  for (const bool exact : {false, true}) {
    SCOPED_TRACE(exact ? "exact samples" : "vertices");
    const SmallStream base(exact);
    TileExpectation e = base.expected(exact);
    e.max_vertices_per_tile = 8u << 20;  // the master's default (JobManagerOptions::max_queued_vertices)
    TileResultAssembler a(e);
    v1::TileResultChunk header = base.chunks[0];
    if (exact)
      header.mutable_header()->set_exact_sample_count(8u << 20);
    else
      header.mutable_header()->set_vertex_count(8u << 20);
    const size_t before = heap_bytes();
    ASSERT_FALSE(a.add(header));
    const size_t grown = heap_bytes() - std::min(heap_bytes(), before);
    EXPECT_LT(grown, size_t(16) << 20) << grown << " bytes for a header";
    // The data that does arrive is taken as usual; the stream is refused only at the trailer.
    for (size_t i = 1; i + 1 < base.chunks.size(); ++i) EXPECT_FALSE(a.add(base.chunks[i])) << i;
    const auto err = a.add(base.chunks.back());
    ASSERT_TRUE(err);
    EXPECT_NE(err->find("announced"), std::string::npos) << *err;
  }
}

// Many small batches up to the announced count: the vertex array grows geometrically, and what comes
// out is every vertex in order.
TEST(TileResultStream, ManySmallBatchesAssembleInOrder) {
  TileResult r;
  r.rect = {0, 0, 4, 4};
  r.path_sum.assign(16, Vec3(0.25f));
  r.path_count.assign(16, 1);
  for (int i = 0; i < 5000; ++i)
    r.vertices.push_back({Vec3(float(i % 100) / 100.f, float(i / 100) / 50.f, 0.5f), Vec3(0, 0, 1), Vec3(float(i)),
                          VertexRecord::kDiffuse});
  const Bounds3 bounds{Vec3(0.f), Vec3(1.f)};
  TileResultLimits limits;
  limits.max_vertices_per_chunk = 7;
  const auto chunks = split_tile_result(r, identity(), bounds, limits);
  ASSERT_GT(chunks.size(), 700u);
  const AssembledTile t = assemble(chunks, expectation(r.rect, TileExpectation::Payload::kVertices, bounds, limits));
  ASSERT_EQ(t.vertices.size(), r.vertices.size());
  const VertexCodec codec(bounds);
  for (size_t i = 0; i < r.vertices.size(); ++i) {
    PackedVertex p;
    ASSERT_TRUE(codec.encode(r.vertices[i], &p));
    const VertexRecord want = codec.decode(p);
    ASSERT_EQ(std::memcmp(&t.vertices[i], &want, sizeof(VertexRecord)), 0) << i;
  }
}

TEST(TileResultStream, BadExpectationsThrow) {
  const SmallStream base;
  auto e = base.expected();
  e.x1 = kWidth + 1;
  EXPECT_THROW(TileResultAssembler{e}, std::invalid_argument);
  e = base.expected();
  e.y1 = e.y0;
  EXPECT_THROW(TileResultAssembler{e}, std::invalid_argument);
  e = base.expected();
  e.skip.assign(3, 0);
  EXPECT_THROW(TileResultAssembler{e}, std::invalid_argument);
  e = base.expected();
  e.codec_bounds = Bounds3{Vec3(1.f), Vec3(0.f)};
  EXPECT_THROW(TileResultAssembler{e}, std::invalid_argument);
}

// ---- non-finite radiance: dropped and counted, never an error -----------------------------------------

TEST(TileResultStream, NonFiniteRadianceIsDroppedAndCounted) {
  {
    SmallStream s;
    auto* px = s.chunks[1].mutable_pixels();
    px->set_radiance_sum(3 * 2 + 1, kNaN);  // pixel 2
    px->set_radiance_sum(3 * 5 + 0, kInf);  // pixel 5
    px->set_radiance_sum(3 * 6 + 2, -1.f);  // pixel 6: negative radiance
    const AssembledTile t = assemble(s.chunks, s.expected());
    EXPECT_EQ(t.dropped_pixel_sums, 3u);
    for (int i : {2, 5, 6}) {
      EXPECT_TRUE(bit_equal(t.path_sum[size_t(i)], Vec3(0.f))) << i;
      EXPECT_EQ(t.path_counts()[size_t(i)], 1u) << i;  // the sample index is still used up
    }
    EXPECT_TRUE(bit_equal(t.path_sum[0], Vec3(0.5f)));
    EXPECT_EQ(t.vertices.size(), 3u);
  }
  {
    SmallStream s(/*exact=*/true);
    auto* ex = s.chunks[2].mutable_exact_samples();
    ex->set_radiance(0, kNaN);
    ex->set_radiance(3 * 2 + 1, -kInf);
    const AssembledTile t = assemble(s.chunks, s.expected(true));
    EXPECT_EQ(t.dropped_exact_samples, 2u);
    ASSERT_EQ(t.exact_samples.size(), 1u);
    EXPECT_EQ(t.exact_samples[0].first, 17u);
    EXPECT_TRUE(bit_equal(t.exact_samples[0].second, Vec3(2.f)));
  }
}

}  // namespace
}  // namespace epr
