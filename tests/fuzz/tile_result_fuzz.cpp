// libFuzzer target: the master's ingestion of SubmitTile streams (wire/tile_result_stream.h,
// TileResultAssembler), fed chunks built from the fuzz input.
//
// The first input byte picks one of three modes:
//   * recorded stream (byte % 4 == 1): the rest is a SubmitTile stream as it arrives on the wire --
//     a 4-byte little-endian length and a serialised TileResultChunk, repeated -- against one of three
//     fixed leases. Its seeds (corpus/tile_result/recorded_*.bin) are TileResultWriter's real output,
//     written by the tile_result_seeds program built from this file, so mutations start deep;
//   * round trip (byte % 4 == 0): FuzzedDataProvider picks a lease (image and tile size, subpixels,
//     payload kind, paths per pixel, skip mask, codec bounds, chunk limits, per-tile vertex cap) and
//     describes a worker's TileResult (pixel sums with NaN / negative values, vertex records inside
//     and outside the codec bounds, exact samples); TileResultWriter splits it and the assembler must
//     accept every chunk and rebuild exactly what the writer sent;
//   * hostile stream (otherwise): a lease as above, then a sequence of chunks -- header, PixelPaths,
//     VertexBatch, ExactSamples, trailer, an empty chunk, or raw bytes parsed as a TileResultChunk --
//     each field either consistent with the lease (so the stream gets deep) or fuzzed.
// Everywhere the assembler must answer every chunk, an error must be final, and a stream it calls
// complete must satisfy every promise of AssembledTile.
// Decoded vertices then go through the reprojection kernel's projection and facing test
// (master/reprojection_kernel.h), which must keep every accepted subpixel inside the grid.
#include <fuzzer/FuzzedDataProvider.h>
#include <google/protobuf/stubs/logging.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "common/camera.h"
#include "common/tile.h"
#include "common/vertex_codec.h"
#include "master/reprojection_kernel.h"
#include "wire/tile_result_stream.h"

namespace {

using namespace epr;

[[noreturn]] void bug(const std::string& what) {
  std::fprintf(stderr, "tile_result_fuzz: %s\n", what.c_str());
  std::abort();
}

void require(bool ok, const char* what) {
  if (!ok) bug(what);
}

bool finite_non_negative(const Vec3& v) { return is_finite(v) && v.x >= 0 && v.y >= 0 && v.z >= 0; }

float any_float(FuzzedDataProvider& in) {
  switch (in.ConsumeIntegralInRange(0, 7)) {
    case 0:
      return std::nanf("");
    case 1:
      return INFINITY;
    case 2:
      return -1.f;
    case 3:
      return 0.f;
    case 4:
      return in.ConsumeFloatingPoint<float>();
    default:
      return in.ConsumeFloatingPointInRange(0.f, 100.f);
  }
}

Vec3 any_vec(FuzzedDataProvider& in) {
  const float x = any_float(in), y = any_float(in), z = any_float(in);
  return {x, y, z};
}

Vec3 vec_in(FuzzedDataProvider& in, const Bounds3& b) {
  Vec3 v;
  for (int a = 0; a < 3; ++a) v[a] = in.ConsumeFloatingPointInRange(b.lo[a], b.hi[a]);
  return v;
}

struct Lease {
  TileExpectation e;
  uint32_t pixels = 0;
};

/// A lease the master could hand out.
Lease make_lease(FuzzedDataProvider& in) {
  Lease l;
  TileExpectation& e = l.e;
  e.job_id = in.ConsumeBool() ? "job-1" : in.ConsumeRandomLengthString(24);
  e.round = in.ConsumeIntegralInRange<uint32_t>(0, 3);
  e.tile_index = in.ConsumeIntegralInRange<uint32_t>(0, 3);
  e.image_width = in.ConsumeIntegralInRange<uint32_t>(1, 48);
  e.image_height = in.ConsumeIntegralInRange<uint32_t>(1, 48);
  e.x0 = in.ConsumeIntegralInRange<uint32_t>(0, e.image_width - 1);
  e.x1 = in.ConsumeIntegralInRange<uint32_t>(e.x0 + 1, e.image_width);
  e.y0 = in.ConsumeIntegralInRange<uint32_t>(0, e.image_height - 1);
  e.y1 = in.ConsumeIntegralInRange<uint32_t>(e.y0 + 1, e.image_height);
  e.subpixels = in.ConsumeIntegralInRange<uint32_t>(1, 4);
  if (in.ConsumeBool()) {
    e.codec_bounds = {{-1.02f, 0.f, -1.04f}, {1.f, 1.99f, 0.99f}};  // the Cornell box
  } else {
    for (int a = 0; a < 3; ++a) {
      e.codec_bounds.lo[a] = in.ConsumeFloatingPointInRange(-1e6f, 1e6f);
      e.codec_bounds.hi[a] = e.codec_bounds.lo[a] + in.ConsumeFloatingPointInRange(0.f, 1e3f);
    }
  }
  e.payload = TileExpectation::Payload(in.ConsumeIntegralInRange(0, 2));
  e.paths_per_pixel = in.ConsumeBool() ? 0 : in.ConsumeIntegralInRange<uint32_t>(1, 16);
  l.pixels = (e.x1 - e.x0) * (e.y1 - e.y0);
  if (in.ConsumeBool()) {
    e.skip.resize(l.pixels);
    for (uint8_t& s : e.skip) s = in.ConsumeIntegralInRange<uint8_t>(0, 3) == 0;
  }
  e.limits.max_vertices_per_chunk = in.ConsumeIntegralInRange<uint32_t>(1, 4096);
  e.limits.max_chunk_bytes = in.ConsumeIntegralInRange<uint32_t>(256, 1 << 18);
  e.max_vertices_per_tile = in.ConsumeBool() ? 0 : in.ConsumeIntegralInRange<uint64_t>(1, 1 << 14);
  try {
    TileResultAssembler probe(e);
  } catch (const std::invalid_argument& err) {
    bug(std::string("a well-formed lease was refused: ") + err.what());
  }
  return l;
}

/// What a complete stream promises (AssembledTile's comments), and the reprojection kernel's bounds.
void check_tile(const Lease& l, const v1::TileResultHeader& header, const AssembledTile& t) {
  const TileExpectation& e = l.e;
  require(t.x0 == e.x0 && t.y0 == e.y0 && t.x1 == e.x1 && t.y1 == e.y1, "tile rectangle differs from the lease");
  const std::vector<uint32_t> counts = t.path_counts();
  require(t.path_sum.size() == l.pixels && counts.size() == l.pixels, "per-pixel arrays of the wrong size");
  for (uint32_t i = 0; i < l.pixels; ++i) {
    require(finite_non_negative(t.path_sum[i]), "pixel sum not finite and non-negative");
    if (e.paths_per_pixel > 0) {
      const uint32_t want = (!e.skip.empty() && e.skip[i]) ? 0 : e.paths_per_pixel;
      require(counts[i] == want, "path count differs from the lease");
    }
  }
  require(t.vertices.size() == header.vertex_count(), "vertex count differs from the header");
  require(t.exact_samples.size() + t.dropped_exact_samples == header.exact_sample_count(),
          "exact sample count differs from the header");
  if (e.payload != TileExpectation::Payload::kVertices)
    require(t.vertices.empty(), "vertices for a job that takes none");
  if (e.payload != TileExpectation::Payload::kExactSamples)
    require(t.exact_samples.empty(), "exact samples for a job not in exact mode");
  if (e.max_vertices_per_tile > 0) require(t.vertices.size() <= e.max_vertices_per_tile, "per-tile vertex cap ignored");
  const uint64_t grid = uint64_t(e.subpixels) * e.image_width * e.subpixels * e.image_height;
  for (const auto& [subpixel, radiance] : t.exact_samples) {
    require(subpixel < grid, "exact sample outside the subpixel grid");
    require(finite_non_negative(radiance), "exact sample radiance not finite and non-negative");
  }

  const VertexCodec codec(e.codec_bounds);
  const Bounds3 box = codec.quantisation_box();
  CameraSpec spec;  // the Cornell box's camera, looking at the middle of the codec bounds
  spec.look = (e.codec_bounds.lo + e.codec_bounds.hi) * 0.5f;
  spec.eye = spec.look + Vec3(0.f, 0.f, 3.9f + (e.codec_bounds.hi.z - e.codec_bounds.lo.z));
  const Camera cam(spec, int(e.image_width), int(e.image_height));
  detail::KernelParams k;  // master/reprojection_kernel.cpp's make_kernel_params
  k.eye = cam.eye();
  k.forward = cam.forward();
  k.right = cam.right();
  k.up = cam.up();
  k.tan_half_x = cam.tan_half_x();
  k.tan_half_y = cam.tan_half_y();
  k.width = float(cam.width());
  k.height = float(cam.height());
  k.s = float(e.subpixels);
  k.grid_w = float(e.subpixels * e.image_width);
  k.grid_h = float(e.subpixels * e.image_height);
  k.grid_wi = e.subpixels * e.image_width;
  // A deep framebuffer covered everywhere by the plane z = middle of the bounds (the kernel reads
  // texel_plane[texel]: ASan checks the index).
  detail::PlaneGrid planes;
  planes.width = int(k.grid_wi);
  planes.height = int(e.subpixels * e.image_height);
  planes.texel_plane.assign(grid, 0);
  planes.planes = {0.f, 0.f, 1.f, spec.look.z};
  k.epsilon = 1e-3f * (1.f + std::fabs(spec.look.z));
  for (const VertexRecord& v : t.vertices) {
    require(detail::record_is_finite(v), "decoded vertex not finite");
    for (int a = 0; a < 3; ++a)
      require(v.position[a] >= box.lo[a] && v.position[a] <= box.hi[a], "decoded vertex outside the quantisation box");
    require(std::fabs(length(v.normal) - 1.f) < 1e-4f, "decoded normal not unit length");
    require(finite_non_negative(v.radiance), "decoded radiance not finite and non-negative");
    require((v.flags & ~VertexRecord::kDiffuse) == 0, "decoded flags other than diffuse");
    uint32_t texel = 0;
    if (detail::project_and_face(k, v.position, v.normal, &texel) == detail::Decision::kAccepted)
      require(texel < grid, "the kernel's subpixel lies outside the grid");
    uint32_t subpixel = grid;
    if (detail::classify(k, planes, v.position, v.normal, &subpixel) == detail::Decision::kAccepted)
      require(subpixel < grid, "an accepted vertex lands outside the subpixel grid");
  }
}

// ---- round trip: writer -> assembler ---------------------------------------------------------------

void round_trip(FuzzedDataProvider& in, const Lease& l) {
  const TileExpectation& e = l.e;
  TileResult r;
  r.rect = {int(e.x0), int(e.y0), int(e.x1), int(e.y1)};
  for (uint32_t i = 0; i < l.pixels; ++i) {
    r.path_sum.push_back(any_vec(in));
    const bool skipped = !e.skip.empty() && e.skip[i];
    r.path_count.push_back(e.paths_per_pixel > 0 ? (skipped ? 0 : e.paths_per_pixel)
                                                 : in.ConsumeIntegralInRange<uint32_t>(0, 1 << 20));
  }
  const VertexCodec codec(e.codec_bounds);
  if (e.payload == TileExpectation::Payload::kVertices) {
    const size_t n = in.ConsumeIntegralInRange<size_t>(0, 3000);
    for (size_t i = 0; i < n && in.remaining_bytes() > 0; ++i) {
      VertexRecord v;
      v.position = in.ConsumeIntegralInRange(0, 7) == 0 ? any_vec(in) : vec_in(in, e.codec_bounds);
      v.normal = in.ConsumeIntegralInRange(0, 7) == 0 ? any_vec(in)
                                                      : Vec3(in.ConsumeFloatingPointInRange(-1.f, 1.f), 1.f, 0.5f);
      v.radiance = any_vec(in);
      v.flags = in.ConsumeIntegralInRange(0, 15) == 0 ? in.ConsumeIntegral<uint32_t>() : VertexRecord::kDiffuse;
      r.vertices.push_back(v);
    }
  }
  if (e.payload == TileExpectation::Payload::kExactSamples) {
    const uint64_t grid = uint64_t(e.subpixels) * e.image_width * e.subpixels * e.image_height;
    const size_t n = in.ConsumeIntegralInRange<size_t>(0, 3000);
    for (size_t i = 0; i < n && in.remaining_bytes() > 0; ++i)
      r.visible.push_back({uint32_t(in.ConsumeIntegralInRange<uint64_t>(0, grid - 1)), any_vec(in)});
  }
  TileResultIdentity id;
  id.lease_id = 7;
  id.job_id = e.job_id;
  id.round = e.round;
  id.tile_index = e.tile_index;
  id.worker_id = "worker-1";
  // The header carries the job id: a chunk limit smaller than the header is the master's problem,
  // not the stream's (RegisterResponse's limits are far above it).
  if (e.job_id.size() > 64) return;

  const std::vector<v1::TileResultChunk> chunks = split_tile_result(r, id, e.codec_bounds, e.limits);
  TileResultAssembler a(e);
  const uint64_t announced = chunks.front().header().vertex_count();
  const bool over_cap =
      e.max_vertices_per_tile > 0 &&
      (announced > e.max_vertices_per_tile || chunks.front().header().exact_sample_count() > e.max_vertices_per_tile);
  for (const v1::TileResultChunk& c : chunks) {
    if (auto err = a.add(c)) {
      if (over_cap && err->find("exceeds the per-tile limit") != std::string::npos) return;
      bug("the assembler refused a chunk of TileResultWriter: " + *err);
    }
  }
  require(!over_cap, "a header over the per-tile vertex cap was accepted");
  require(a.complete(), "the writer's stream did not complete");
  const v1::TileResultHeader header = *a.header();
  const AssembledTile t = a.take();
  check_tile(l, header, t);

  // Exactly what the writer sent: sums (non-finite or negative ones as 0), counts, vertices as the
  // codec decodes them, the exact samples it kept.
  const std::vector<uint32_t> counts = t.path_counts();
  for (uint32_t i = 0; i < l.pixels; ++i) {
    const Vec3 want = finite_non_negative(r.path_sum[i]) ? r.path_sum[i] : Vec3(0.f);
    require(std::memcmp(&t.path_sum[i], &want, sizeof(Vec3)) == 0, "pixel sum changed on the way");
    require(counts[i] == r.path_count[i], "path count changed on the way");
  }
  size_t next = 0;
  for (const VertexRecord& v : r.vertices) {
    PackedVertex p;
    if (!codec.encode(v, &p)) continue;
    require(next < t.vertices.size(), "fewer vertices than the codec accepted");
    const VertexRecord d = codec.decode(p);
    require(std::memcmp(&d, &t.vertices[next], sizeof(VertexRecord)) == 0, "vertex changed on the way");
    ++next;
  }
  require(next == t.vertices.size(), "more vertices than the codec accepted");
  size_t kept = 0;
  for (const VisibleSample& s : r.visible) {
    if (!finite_non_negative(s.radiance)) continue;
    require(kept < t.exact_samples.size() && t.exact_samples[kept].first == s.subpixel, "exact sample changed");
    ++kept;
  }
  require(kept == t.exact_samples.size(), "more exact samples than were kept");
}

// ---- hostile stream ---------------------------------------------------------------------------------

void hostile_stream(FuzzedDataProvider& in, const Lease& l) {
  const TileExpectation& e = l.e;
  TileResultAssembler a(e);
  uint32_t cursor = 0;  // next pixel a well-behaved sender would send
  std::optional<std::string> error;
  for (int step = 0; step < 64 && in.remaining_bytes() > 0; ++step) {
    v1::TileResultChunk c;
    const bool honest = in.ConsumeIntegralInRange(0, 3) != 0;
    switch (in.ConsumeIntegralInRange(0, 6)) {
      case 0: {
        auto* h = c.mutable_header();
        h->set_lease_id(in.ConsumeIntegral<uint64_t>());
        h->set_job_id(honest ? e.job_id : in.ConsumeRandomLengthString(32));
        h->set_round(honest ? e.round : in.ConsumeIntegral<uint32_t>());
        h->set_tile_index(honest ? e.tile_index : in.ConsumeIntegral<uint32_t>());
        h->mutable_worker_id()->set_id(in.ConsumeRandomLengthString(16));
        h->set_pixel_count(honest ? l.pixels : in.ConsumeIntegral<uint32_t>());
        h->set_vertex_count(in.ConsumeBool() ? in.ConsumeIntegralInRange<uint64_t>(0, 64)
                                             : in.ConsumeIntegral<uint64_t>());
        h->set_exact_sample_count(in.ConsumeBool() ? in.ConsumeIntegralInRange<uint64_t>(0, 64)
                                                   : in.ConsumeIntegral<uint64_t>());
        h->set_vertex_encoding(v1::VertexEncoding(honest ? 1 : in.ConsumeIntegral<int32_t>()));
        break;
      }
      case 1: {
        auto* p = c.mutable_pixels();
        const uint32_t first = honest ? cursor : in.ConsumeIntegral<uint32_t>();
        const uint32_t left = first < l.pixels ? l.pixels - first : 1;
        const uint32_t count =
            honest ? in.ConsumeIntegralInRange<uint32_t>(1, left) : in.ConsumeIntegralInRange<uint32_t>(0, 300);
        p->set_first_pixel(first);
        const uint32_t values = honest ? 3 * count : in.ConsumeIntegralInRange<uint32_t>(0, 3 * count + 3);
        for (uint32_t i = 0; i < values; ++i) p->add_radiance_sum(any_float(in));
        for (uint32_t i = 0; i < count; ++i) {
          const uint32_t pix = first + i;
          const bool skipped = pix < l.pixels && !e.skip.empty() && e.skip[pix];
          p->add_path_count(honest && e.paths_per_pixel > 0 ? (skipped ? 0 : e.paths_per_pixel)
                                                            : in.ConsumeIntegral<uint32_t>());
        }
        if (honest) cursor = first + count;
        break;
      }
      case 2: {
        auto* b = c.mutable_vertices();
        const uint32_t count = in.ConsumeIntegralInRange<uint32_t>(0, 64);
        b->set_count(honest ? count : in.ConsumeIntegral<uint32_t>());
        b->set_packed(
            in.ConsumeBytesAsString(honest ? 16 * size_t(count) : in.ConsumeIntegralInRange<size_t>(0, 1100)));
        break;
      }
      case 3: {
        auto* s = c.mutable_exact_samples();
        const uint32_t n = in.ConsumeIntegralInRange<uint32_t>(0, 64);
        const uint64_t grid = uint64_t(e.subpixels) * e.image_width * e.subpixels * e.image_height;
        for (uint32_t i = 0; i < n; ++i)
          s->add_subpixel(honest ? uint32_t(in.ConsumeIntegralInRange<uint64_t>(0, grid - 1))
                                 : in.ConsumeIntegral<uint32_t>());
        const uint32_t values = honest ? 3 * n : in.ConsumeIntegralInRange<uint32_t>(0, 3 * n + 3);
        for (uint32_t i = 0; i < values; ++i) s->add_radiance(any_float(in));
        break;
      }
      case 4: {
        auto* st = c.mutable_trailer()->mutable_stats();
        st->set_paths_traced(in.ConsumeIntegral<uint64_t>());
        st->set_seconds_tracing(in.ConsumeFloatingPoint<double>());
        break;
      }
      case 5:
        break;  // a chunk without a part
      default: {
        const std::string bytes = in.ConsumeRandomLengthString(2048);
        if (!c.ParseFromString(bytes)) continue;
        break;
      }
    }
    const std::optional<std::string> err = a.add(c);
    if (error) {
      require(err.has_value() && *err == *error, "an error was not final");
      continue;
    }
    if (err) {
      require(!err->empty(), "an empty error reason");
      require(!a.complete() || err->find("after the trailer") != std::string::npos, "error after completion");
      error = err;
      continue;
    }
    if (a.complete()) {
      const v1::TileResultHeader header = *a.header();
      check_tile(l, header, a.take());
      return;
    }
  }
  if (!error) require(!a.complete(), "complete without a trailer");
}

// ---- recorded stream ---------------------------------------------------------------------------------

/// Fixed leases for recorded streams (their seeds are written by tile_result_seeds against these).
Lease fixed_lease(uint8_t which) {
  Lease l;
  TileExpectation& e = l.e;
  e.job_id = "job-1";
  e.round = 2;
  e.tile_index = 1;
  e.image_width = 16;
  e.image_height = 8;
  e.x0 = 8;
  e.x1 = 16;
  e.y0 = 0;
  e.y1 = 4;
  e.subpixels = 2;
  e.codec_bounds = {{-1.02f, 0.f, -1.04f}, {1.f, 1.99f, 0.99f}};
  e.limits.max_vertices_per_chunk = 64;
  e.limits.max_chunk_bytes = 4096;
  e.max_vertices_per_tile = 4096;
  l.pixels = 32;
  switch (which % 3) {
    case 0:
      e.payload = TileExpectation::Payload::kVertices;
      e.paths_per_pixel = 4;
      e.skip.assign(l.pixels, 0);
      for (uint32_t i = 0; i < l.pixels; i += 5) e.skip[i] = 1;
      break;
    case 1:
      e.payload = TileExpectation::Payload::kExactSamples;
      e.paths_per_pixel = 1;
      break;
    default:
      e.payload = TileExpectation::Payload::kPathsOnly;
      e.paths_per_pixel = 0;
      break;
  }
  return l;
}

/// Chunks as they arrive on the wire: a 4-byte little-endian length, then the serialised chunk.
void recorded_stream(const uint8_t* data, size_t size) {
  if (size < 1) return;
  const Lease l = fixed_lease(data[0]);
  TileResultAssembler a(l.e);
  std::optional<std::string> error;
  size_t at = 1;
  while (at + 4 <= size) {
    uint32_t len = 0;
    std::memcpy(&len, data + at, 4);
    at += 4;
    len = uint32_t(std::min<size_t>(len, size - at));
    v1::TileResultChunk c;
    if (!c.ParseFromArray(data + at, int(len))) return;  // gRPC ends such a stream before the assembler
    at += len;
    const std::optional<std::string> err = a.add(c);
    if (error) {
      require(err.has_value() && *err == *error, "an error was not final");
    } else if (err) {
      error = err;
    } else if (a.complete()) {
      const v1::TileResultHeader header = *a.header();
      check_tile(l, header, a.take());
      return;
    }
  }
}

}  // namespace

#ifndef EPR_TILE_SEEDS
extern "C" int LLVMFuzzerInitialize(int*, char***) {
  google::protobuf::SetLogHandler(nullptr);  // parse complaints about invalid UTF-8 are expected here
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  // The first byte picks the mode; a recorded stream is a serialised SubmitTile stream after it.
  if (size < 1) return 0;
  if (data[0] % 4 == 1) {
    recorded_stream(data + 1, size - 1);
    return 0;
  }
  FuzzedDataProvider in(data + 1, size - 1);
  const Lease lease = make_lease(in);
  if (data[0] % 4 == 0)
    round_trip(in, lease);
  else
    hostile_stream(in, lease);
  return 0;
}
#else
// tile_result_seeds DIR: writes the recorded-stream seeds of corpus/tile_result/ (TileResultWriter's
// output for the fixed leases, deterministic).
#include <fstream>
#include <random>

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: %s OUTPUT_DIR\n", argv[0]);
    return 2;
  }
  std::mt19937 rng(2024);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  for (uint8_t which = 0; which < 3; ++which) {
    const Lease l = fixed_lease(which);
    const TileExpectation& e = l.e;
    TileResult r;
    r.rect = {int(e.x0), int(e.y0), int(e.x1), int(e.y1)};
    for (uint32_t i = 0; i < l.pixels; ++i) {
      r.path_sum.push_back(i == 3 ? Vec3(std::nanf(""), 0.f, 1.f) : Vec3(u(rng), u(rng), u(rng)));
      const bool skipped = !e.skip.empty() && e.skip[i];
      r.path_count.push_back(e.paths_per_pixel > 0 ? (skipped ? 0 : e.paths_per_pixel) : 1 + i % 3);
    }
    if (e.payload == TileExpectation::Payload::kVertices)
      for (int i = 0; i < 150; ++i) {
        VertexRecord v;
        v.position = {-1.f + 2.f * u(rng), 1.99f * u(rng), -1.f + 2.f * u(rng)};
        v.normal = {u(rng) - 0.5f, u(rng) - 0.5f, 1.f};
        v.radiance = i % 37 == 0 ? Vec3(INFINITY, 0.f, 0.f) : Vec3(u(rng), u(rng), 4.f * u(rng));
        v.flags = VertexRecord::kDiffuse;
        r.vertices.push_back(v);
      }
    if (e.payload == TileExpectation::Payload::kExactSamples)
      for (uint32_t i = 0; i < 90; ++i)
        r.visible.push_back({(i * 37) % (4 * 16 * 8), Vec3(u(rng), -0.f, i % 41 == 0 ? -1.f : u(rng))});
    TileResultIdentity id;
    id.lease_id = 11;
    id.job_id = e.job_id;
    id.round = e.round;
    id.tile_index = e.tile_index;
    id.worker_id = "worker-7";
    std::string out(1, char(4 * which + 1));  // mode 1 (recorded), lease `which`
    out += char(which);
    for (const v1::TileResultChunk& c : split_tile_result(r, id, e.codec_bounds, e.limits)) {
      const std::string bytes = c.SerializeAsString();
      const uint32_t len = uint32_t(bytes.size());
      out.append(reinterpret_cast<const char*>(&len), 4);
      out += bytes;
    }
    const char* names[] = {"recorded_vertices", "recorded_exact", "recorded_paths_only"};
    std::ofstream(std::string(argv[1]) + "/" + names[which] + ".bin", std::ios::binary) << out;
  }
  return 0;
}
#endif
