// Checkpoints of the master's jobs (master/server/checkpoint.h): the sealed file format (round trip,
// torn and corrupt files detected, the previous checkpoint used), the reprojectors' accumulation
// export / import (CPU and GL), and a JobManager that is destroyed mid-job and created again on the
// same state directory: it resumes the job, and the result equals an undisturbed run's (M, M' and
// the path sums bit-identical, the combined image within float rounding).
#include "master/server/checkpoint.h"

#include <gtest/gtest.h>
#include <unistd.h>
#include <zlib.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <thread>

#include "common/image.h"
#include "master/gl_context.h"
#include "master/gl_reprojector.h"
#include "master/make_reprojector.h"
#include "master/reprojector.h"
#include "master/server/job_manager.h"
#include "tests/master/traced_vertices.h"
#include "tests/server/in_process_worker.h"
#include "tests/server/job_images.h"
#include "wire/tile_result_stream.h"
#include "worker/embree_scene.h"
#include "worker/path_tracer.h"
#include "worker/tile_renderer.h"

namespace epr {
namespace {
namespace fs = std::filesystem;
using namespace std::chrono_literals;

fs::path fresh_dir(const std::string& name) { return test::fresh_dir("epr-checkpoint-test", name); }

std::string read_bytes(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

void write_bytes(const fs::path& p, const std::string& bytes) {
  std::ofstream(p, std::ios::binary | std::ios::trunc) << bytes;
}

// A progress record with a small frame whose every array holds distinct values.
JobProgressRecord sample_progress(int round) {
  JobProgressRecord r;
  r.state = JobState::kRunning;
  r.triangles = 36;
  r.progress.round = round;
  r.progress.mean_spp = 3.25;
  r.progress.pixels_active = 5;
  r.counts.accepted = 100 + uint64_t(round);
  r.counts.occluded = 40;
  r.counts.backfacing = 10;
  r.counters.rays = 12345;
  r.counters.tiles_committed = 9;
  r.counters.tiles_speculative = 2;  // kept across a restart since format version 2
  r.counters.worker_failures = 3;
  r.counters.seconds_tracing = 1.5;
  r.started_ms = 1'700'000'000'000;
  FrameSnapshot f;
  f.width = 3;
  f.height = 2;
  for (int i = 0; i < 18; ++i) f.path_sum.push_back(0.1 * i + round);
  for (uint32_t i = 0; i < 6; ++i) {
    f.path_count.push_back(i + uint32_t(round));
    f.mprime.push_back(2 * i);
    f.skip.push_back(uint8_t(i % 2));
  }
  for (int i = 0; i < 18; ++i) f.reprojected.push_back(0.5f * float(i));
  f.paths_done = 4 * round;
  f.progress = r.progress;
  f.has_accumulation = true;
  f.accumulation.width = 6;
  f.accumulation.height = 4;
  f.accumulation.subpixels = 2;
  for (int i = 0; i < 72; ++i) f.accumulation.sum.push_back(float(i) * 0.25f);
  for (uint32_t i = 0; i < 24; ++i) f.accumulation.count.push_back(i);
  f.counts = r.counts;
  r.frame = f;
  return r;
}

// ---- the sealed format ----------------------------------------------------------------------------

TEST(CheckpointFormat, SealRoundTripAndDamageDetected) {
  const std::string payload = "the payload \x01\x02\x00 with a zero byte" + std::string(1000, 'x');
  const std::string sealed = seal(RecordKind::kJobProgress, payload);
  EXPECT_EQ(sealed.size(), kSealHeaderBytes + payload.size());
  EXPECT_EQ(unseal(RecordKind::kJobProgress, sealed), payload);

  auto error_of = [](RecordKind kind, const std::string& bytes) -> std::string {
    try {
      unseal(kind, bytes);
    } catch (const CheckpointError& e) {
      return e.what();
    }
    return "";
  };
  EXPECT_NE(error_of(RecordKind::kJobSpec, sealed).find("kind"), std::string::npos) << "a spec read as progress";
  EXPECT_NE(error_of(RecordKind::kJobProgress, sealed.substr(0, sealed.size() - 1)).find("torn"), std::string::npos);
  EXPECT_NE(error_of(RecordKind::kJobProgress, sealed.substr(0, 10)).find("torn"), std::string::npos);
  EXPECT_NE(error_of(RecordKind::kJobProgress, sealed + "y").find("torn"), std::string::npos);
  // Every single flipped byte is detected, header or payload.
  for (size_t i : {size_t(0), size_t(9), size_t(13), size_t(17), size_t(25), size_t(30), kSealHeaderBytes,
                   kSealHeaderBytes + 500, sealed.size() - 1}) {
    std::string bad = sealed;
    bad[i] = char(bad[i] ^ 0x10);
    EXPECT_NE(error_of(RecordKind::kJobProgress, bad), "") << "byte " << i << " flipped went unnoticed";
  }
}

TEST(CheckpointFormat, RecordsRoundTrip) {
  JobSpecRecord spec;
  spec.id = "j000042-beef";
  spec.seq = 42;
  spec.submitted_ms = 1'700'000'000'123;
  spec.scene_hash = "abc123";
  spec.options.width = 40;
  spec.options.height = 24;
  spec.options.spp = 32;
  spec.options.paths_per_round = 8;
  spec.options.mode = RenderMode::kSkip;
  spec.options.reproject = ReprojectMethod::kCpu;
  spec.options.subpixels = 2;
  spec.options.epsilon = 1e-3f;
  spec.options.min_paths = 8;
  spec.options.reprojected_weight = 0.375f;
  spec.options.combine = CombineRule::kVariance;
  spec.options.seed = 99;
  spec.options.tile_size = 16;
  spec.camera.eye = {0.5f, 1.25f, 3.f};
  spec.camera.fov_y_degrees = 45.f;
  spec.name = "a name";
  spec.priority = -3;
  spec.time_budget_seconds = 12.5;
  spec.request_id = "req-1";
  const JobSpecRecord s = decode_job_spec(encode(spec));
  EXPECT_EQ(s.id, spec.id);
  EXPECT_EQ(s.seq, spec.seq);
  EXPECT_EQ(s.submitted_ms, spec.submitted_ms);
  EXPECT_EQ(s.scene_hash, spec.scene_hash);
  EXPECT_EQ(s.options.width, 40);
  EXPECT_EQ(s.options.height, 24);
  EXPECT_EQ(s.options.spp, 32);
  EXPECT_EQ(s.options.paths_per_round, 8);
  EXPECT_EQ(s.options.mode, RenderMode::kSkip);
  EXPECT_EQ(s.options.reproject, ReprojectMethod::kCpu);
  EXPECT_EQ(s.options.subpixels, 2);
  EXPECT_EQ(s.options.epsilon, 1e-3f);
  EXPECT_EQ(s.options.min_paths, 8);
  EXPECT_EQ(s.options.reprojected_weight, 0.375f);       // a resumed job combines and skips with the same W
  EXPECT_EQ(s.options.combine, CombineRule::kVariance);  // ... and the same rule
  EXPECT_EQ(s.options.seed, 99u);
  EXPECT_EQ(s.options.tile_size, 16);
  EXPECT_EQ(s.camera.eye.y, 1.25f);
  EXPECT_EQ(s.camera.fov_y_degrees, 45.f);
  EXPECT_EQ(s.name, "a name");
  EXPECT_EQ(s.priority, -3);
  EXPECT_EQ(s.time_budget_seconds, 12.5);
  EXPECT_EQ(s.request_id, "req-1");

  JobProgressRecord p = sample_progress(3);
  p.previews["combined"] = {1, 2, 3};
  const JobProgressRecord q = decode_job_progress(encode(p));
  EXPECT_EQ(q.state, JobState::kRunning);
  EXPECT_EQ(q.counters, p.counters);
  EXPECT_EQ(q.started_ms, p.started_ms);
  EXPECT_EQ(q.counts, p.counts);
  EXPECT_EQ(q.progress.round, 3);
  EXPECT_EQ(q.previews.at("combined"), (std::vector<unsigned char>{1, 2, 3}));
  ASSERT_TRUE(q.frame);
  EXPECT_EQ(q.frame->path_sum, p.frame->path_sum);
  EXPECT_EQ(q.frame->path_count, p.frame->path_count);
  EXPECT_EQ(q.frame->mprime, p.frame->mprime);
  EXPECT_EQ(q.frame->reprojected, p.frame->reprojected);
  EXPECT_EQ(q.frame->skip, p.frame->skip);
  EXPECT_EQ(q.frame->paths_done, 12);
  EXPECT_EQ(q.frame->accumulation.sum, p.frame->accumulation.sum);
  EXPECT_EQ(q.frame->accumulation.count, p.frame->accumulation.count);
  EXPECT_EQ(q.frame->counts, p.counts);

  // A payload cut short or padded is malformed even under a valid seal.
  const std::string enc = encode(p);
  EXPECT_THROW(decode_job_progress(enc.substr(0, enc.size() - 3)), CheckpointError);
  EXPECT_THROW(decode_job_progress(enc + "z"), CheckpointError);
}

// ---- the store ------------------------------------------------------------------------------------

TEST(CheckpointStore, NewestValidCheckpointWinsAndTornOrCorruptFallsBack) {
  const fs::path base = fresh_dir("store"), dir = base / "nested" / "state";  // created on demand
  CheckpointStore store(dir);
  EXPECT_TRUE(fs::is_directory(dir / "jobs"));
  std::vector<std::string> problems;
  EXPECT_TRUE(store.load_jobs(&problems).empty());
  EXPECT_FALSE(store.load_progress("j1", &problems));
  EXPECT_TRUE(problems.empty());

  JobSpecRecord spec;
  spec.id = "j1";
  spec.seq = 1;
  spec.scene_hash = "h";
  spec.options.width = spec.options.height = 8;
  store.save_spec(spec);
  store.save_progress("j1", sample_progress(1));
  store.save_progress("j1", sample_progress(2));
  auto p = store.load_progress("j1", &problems);
  ASSERT_TRUE(p);
  EXPECT_EQ(p->progress.round, 2);
  EXPECT_TRUE(problems.empty());

  // Torn newest (cut in the middle of its payload): the previous one is used, and the reason given.
  const fs::path newest = dir / "jobs" / "j1" / "progress.ckpt";
  const std::string good = read_bytes(newest);
  write_bytes(newest, good.substr(0, good.size() / 2));
  p = store.load_progress("j1", &problems);
  ASSERT_TRUE(p);
  EXPECT_EQ(p->progress.round, 1);
  ASSERT_EQ(problems.size(), 1u);
  EXPECT_NE(problems[0].find("torn"), std::string::npos) << problems[0];

  // One corrupt byte in the newest: the same.
  std::string bad = good;
  bad[bad.size() - 7] = char(bad[bad.size() - 7] ^ 1);
  write_bytes(newest, bad);
  problems.clear();
  p = store.load_progress("j1", &problems);
  ASSERT_TRUE(p);
  EXPECT_EQ(p->progress.round, 1);
  ASSERT_EQ(problems.size(), 1u);
  EXPECT_NE(problems[0].find("checksum"), std::string::npos) << problems[0];

  // Both damaged: none (the job restarts from round 0); the job itself still loads from its spec.
  write_bytes(dir / "jobs" / "j1" / "progress.prev.ckpt", "EPRSTATE");
  problems.clear();
  EXPECT_FALSE(store.load_progress("j1", &problems));
  EXPECT_EQ(problems.size(), 2u);
  problems.clear();
  const auto jobs = store.load_jobs(&problems);
  ASSERT_EQ(jobs.size(), 1u);
  EXPECT_EQ(jobs[0].spec.id, "j1");
  EXPECT_FALSE(jobs[0].progress);
  EXPECT_EQ(jobs[0].problems.size(), 2u);

  // A job folder with a damaged spec is skipped with a reason; the others load.
  fs::create_directories(dir / "jobs" / "j2");
  write_bytes(dir / "jobs" / "j2" / "spec.ckpt", "garbage");
  problems.clear();
  EXPECT_EQ(store.load_jobs(&problems).size(), 1u);
  ASSERT_EQ(problems.size(), 1u);
  EXPECT_NE(problems[0].find("j2"), std::string::npos);

  // The run counter goes up with every store opened on the folder.
  const uint64_t e1 = store.next_epoch();
  CheckpointStore again(dir);
  EXPECT_EQ(again.next_epoch(), e1 + 1);
  fs::remove_all(base);
}

TEST(CheckpointStore, ScenesAreStoredOnceByHashAndChecked) {
  const fs::path dir = fresh_dir("scenes");
  CheckpointStore store(dir);
  SceneBundleData b;
  b.entry_path = "s.obj";
  b.files = {{"s.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"}, {"t/m.mtl", "newmtl x\n"}};
  const std::string hash = content_hash(b);
  store.save_scene(hash, b);
  const SceneBundleData back = store.load_scene(hash);
  EXPECT_EQ(back.entry_path, b.entry_path);
  EXPECT_EQ(back.files, b.files);
  EXPECT_THROW(store.load_scene(hash.substr(1) + "0"), CheckpointError);
  // Stored under the wrong hash: refused.
  fs::copy_file(dir / "scenes" / (hash + ".scene"), dir / "scenes" / "wrong.scene");
  EXPECT_THROW(store.load_scene("wrong"), CheckpointError);
  fs::remove_all(dir);
}

// ---- reprojector accumulation export / import -------------------------------------------------------

using test::traced_vertices;

TEST(CheckpointReprojector, AccumulationMovesBetweenCpuAndGlAndContinuesIdentically) {
  const Scene scene = load_bundle(bundle_scene("builtin:cornell"), default_cache_root());
  const Camera camera(CameraSpec{}, 24, 16);
  const DeepFramebuffer dfb = build_deep_framebuffer_cpu(scene, camera, 2);
  ReprojectorSettings rs;
  rs.epsilon = default_epsilon(scene.bounds());
  const auto first = traced_vertices(scene, camera, 1, 2), second = traced_vertices(scene, camera, 2, 2);
  ASSERT_GT(first.size(), 100u);

  // The reference: one CPU reprojector sees both batches.
  auto ref = make_reprojector("cpu", camera, dfb, rs);
  ref->reproject(first);
  const SubpixelAccumulation half = ref->read();
  const ReprojectionCounts half_counts = ref->counts();
  ref->reproject(second);
  const SubpixelAccumulation full = ref->read();
  EXPECT_GT(ref->counts().accepted, half_counts.accepted);

  // A new CPU reprojector restored from the first half continues bit-identically.
  auto cpu = make_reprojector("cpu", camera, dfb, rs);
  cpu->restore(half, half_counts);
  EXPECT_EQ(cpu->counts(), half_counts);
  cpu->reproject(second);
  EXPECT_EQ(cpu->read().sum, full.sum);
  EXPECT_EQ(cpu->read().count, full.count);
  EXPECT_EQ(cpu->counts(), ref->counts());

  // The GL reprojector takes the same accumulation, gives it back unchanged, and continues with the
  // same counts (sums within float rounding: GL adds atomically in any order).
  GlContext gl;
  auto g = make_reprojector("gl", camera, dfb, rs, &gl);
  g->restore(half, half_counts);
  EXPECT_EQ(g->counts(), half_counts);
  EXPECT_EQ(g->read().sum, half.sum);
  EXPECT_EQ(g->read().count, half.count);
  g->reproject(second);
  const SubpixelAccumulation gfull = g->read();
  EXPECT_EQ(gfull.count, full.count);
  EXPECT_EQ(g->counts(), ref->counts());
  ASSERT_EQ(gfull.sum.size(), full.sum.size());
  for (size_t i = 0; i < full.sum.size(); ++i)
    ASSERT_NEAR(gfull.sum[i], full.sum[i], 1e-4f * std::max(1.f, std::fabs(full.sum[i]))) << "subpixel value " << i;

  // A grid of another size is refused and changes nothing.
  SubpixelAccumulation wrong = half;
  wrong.width -= 1;
  EXPECT_THROW(g->restore(wrong, half_counts), std::invalid_argument);
  EXPECT_THROW(cpu->restore(wrong, half_counts), std::invalid_argument);
  EXPECT_EQ(cpu->read().count, full.count);
}

// ---- checkpoints written straight from the live frame (format version 3) ------------------------------

// Every cell of a visit, in order.
std::vector<AccumulationCell> visited(Reprojector& r, size_t max_cells) {
  std::vector<AccumulationCell> out;
  r.visit_cells(max_cells, [&](std::span<const AccumulationCell> s) {
    EXPECT_LE(s.size(), max_cells);
    out.insert(out.end(), s.begin(), s.end());
  });
  return out;
}

bool same_cells(const std::vector<AccumulationCell>& a, const SubpixelAccumulation& b) {
  if (a.size() != b.size()) return false;
  for (size_t i = 0; i < a.size(); ++i)
    if (std::memcmp(&a[i].r, &b.sum[3 * i], 12) != 0 || a[i].n != b.count[i]) return false;
  return true;
}

TEST(CheckpointStreamed, CellsVisitedInPlaceAndRestoredIdenticallyWithSeveralGlBands) {
  const Scene scene = load_bundle(bundle_scene("builtin:cornell"), default_cache_root());
  const Camera camera(CameraSpec{}, 24, 16);
  const DeepFramebuffer dfb = build_deep_framebuffer_cpu(scene, camera, 2);
  ReprojectorSettings rs;
  rs.epsilon = default_epsilon(scene.bounds());
  const auto first = traced_vertices(scene, camera, 1, 2), second = traced_vertices(scene, camera, 2, 2);
  GlContext gl;
  for (const char* backend : {"cpu", "gl"})
    for (size_t band_cells : {size_t(0), size_t(48 * 2 * 3)}) {  // GL: one band; 3 pixel rows per band (6 bands)
      if (std::string(backend) == "cpu" && band_cells) continue;
      SCOPED_TRACE(std::string(backend) + " band_cells " + std::to_string(band_cells));
      ReprojectorSettings s = rs;
      s.gl_max_band_cells = band_cells;
      auto a = make_reprojector(backend, camera, dfb, s, &gl);
      if (band_cells) {
        auto* g = dynamic_cast<GlReprojector*>(a.get());
        ASSERT_TRUE(g);
        ASSERT_GT(g->band_count(), 2u);
      }
      a->reproject(first);
      const SubpixelAccumulation acc = a->read();
      EXPECT_EQ(a->cell_count(), acc.size());
      const std::vector<AccumulationCell> cells = visited(*a, 100);  // spans smaller than a band
      EXPECT_TRUE(same_cells(cells, acc));
      EXPECT_TRUE(same_cells(visited(*a, size_t(1) << 20), acc));
      // Restored span by span into a fresh reprojector: the same cells and counts, bit for bit.
      auto b = make_reprojector(backend, camera, dfb, s, &gl);
      size_t next = 0;
      b->restore_cells(
          [&](std::span<AccumulationCell> out) {
            ASSERT_LE(next + out.size(), cells.size());
            std::copy(cells.begin() + long(next), cells.begin() + long(next + out.size()), out.begin());
            next += out.size();
          },
          a->counts());
      EXPECT_EQ(next, cells.size());
      const SubpixelAccumulation back = b->read();
      EXPECT_EQ(back.sum, acc.sum);
      EXPECT_EQ(back.count, acc.count);
      EXPECT_EQ(b->counts(), a->counts());
      // ... and both continue alike (the counts exactly).
      a->reproject(second);
      b->reproject(second);
      EXPECT_EQ(b->read().count, a->read().count);
      EXPECT_EQ(b->counts(), a->counts());
      // A source that fails midway leaves the reprojector reset, and the error propagates.
      size_t calls = 0;
      EXPECT_THROW(b->restore_cells(
                       [&](std::span<AccumulationCell> out) {
                         ++calls;
                         std::fill(out.begin(), out.end(), AccumulationCell{1, 1, 1, 1});
                         throw CheckpointError("torn");  // after writing into the cells
                       },
                       a->counts()),
                   CheckpointError);
      const SubpixelAccumulation reset = b->read();
      EXPECT_TRUE(std::all_of(reset.count.begin(), reset.count.end(), [](uint32_t n) { return n == 0; }));
      EXPECT_EQ(b->counts(), ReprojectionCounts{});
    }
}

TEST(CheckpointStreamed, FrameWrittenFromTheLiveStateRestoresBitIdentically) {
  const Scene scene = load_bundle(bundle_scene("builtin:cornell"), default_cache_root());
  const Camera camera(CameraSpec{}, 24, 16);
  const auto first = traced_vertices(scene, camera, 1, 2), second = traced_vertices(scene, camera, 2, 2);
  GlContext gl;
  std::map<CombineRule, FrameSnapshot> cpu_after;  // per rule: the CPU frame's state after both rounds
  for (const auto& [method, rule] :
       {std::pair{ReprojectMethod::kCpu, CombineRule::kFixed}, std::pair{ReprojectMethod::kGl, CombineRule::kFixed},
        std::pair{ReprojectMethod::kCpu, CombineRule::kVariance},
        std::pair{ReprojectMethod::kGl, CombineRule::kVariance}}) {
    SCOPED_TRACE(std::string(to_string(method)) + " " + to_string(rule));
    const fs::path dir = fresh_dir("streamed");
    CheckpointStore store(dir);
    RenderOptions o;
    o.width = 24;
    o.height = 16;
    o.spp = 16;
    o.paths_per_round = 4;
    o.mode = RenderMode::kSkip;
    o.reproject = method;
    o.subpixels = 2;
    o.min_paths = 4;
    o.combine = rule;
    FrameState a(o, camera, scene, &gl);
    std::vector<Vec3> sums;
    std::vector<uint32_t> counts;
    for (int i = 0; i < 24 * 16; ++i) {
      sums.push_back(Vec3(0.25f * float(i % 7), 0.5f, float(i) / 100.f));
      counts.push_back(4);
    }
    a.add_paths(0, 0, 24, 16, sums, counts);
    a.reproject(first);
    ASSERT_TRUE(a.finish_round());

    JobProgressRecord meta = sample_progress(1);
    meta.frame.reset();
    const FrameView view = a.view();
    const fs::path tmp = store.write_progress_file("j", meta, &view);
    EXPECT_TRUE(fs::exists(tmp));
    store.commit_progress("j", tmp);
    EXPECT_FALSE(fs::exists(tmp));
    std::vector<std::string> problems;
    const auto loaded = store.load_progress("j", &problems);
    ASSERT_TRUE(loaded) << (problems.empty() ? "" : problems[0]);
    EXPECT_EQ(loaded->counters, meta.counters);
    ASSERT_TRUE(loaded->frame);
    EXPECT_TRUE(loaded->frame->cells) << "the accumulation stays in the file until restored";
    EXPECT_TRUE(loaded->frame->accumulation.sum.empty());

    // The whole file, decoded in memory, holds the same frame as the live state's copy.
    const FrameSnapshot copy = a.save();
    uint32_t version = 0;
    const std::string payload = read_sealed(dir / "jobs" / "j" / "progress.ckpt", RecordKind::kJobProgress, &version);
    const JobProgressRecord whole = decode_job_progress(payload, version);
    EXPECT_EQ(version, kCheckpointVersion);
    ASSERT_TRUE(whole.frame);
    EXPECT_EQ(whole.frame->accumulation.sum, copy.accumulation.sum);
    EXPECT_EQ(whole.frame->accumulation.count, copy.accumulation.count);

    FrameState b(o, camera, scene, &gl);
    b.restore(*loaded->frame);
    const FrameSnapshot restored = b.save();
    EXPECT_EQ(restored.path_sum, copy.path_sum);
    EXPECT_EQ(restored.path_count, copy.path_count);
    EXPECT_EQ(restored.mprime, copy.mprime);
    EXPECT_EQ(restored.reprojected, copy.reprojected);
    EXPECT_EQ(restored.skip, copy.skip);
    EXPECT_EQ(restored.path_m2, copy.path_m2);
    EXPECT_EQ(restored.reprojected_effective, copy.reprojected_effective);
    EXPECT_EQ(restored.path_half_sum, copy.path_half_sum);
    EXPECT_EQ(copy.path_m2.empty(), rule == CombineRule::kFixed);
    // One round so far, round 0: all of its paths are the even half's.
    if (rule == CombineRule::kVariance) {
      EXPECT_EQ(copy.path_m2.size(), 2 * copy.path_count.size());
      EXPECT_EQ(copy.path_half_sum, copy.path_sum);
    }
    EXPECT_EQ(restored.paths_done, copy.paths_done);
    EXPECT_EQ(restored.accumulation.sum, copy.accumulation.sum);
    EXPECT_EQ(restored.accumulation.count, copy.accumulation.count);
    EXPECT_EQ(restored.counts, copy.counts);

    // Both continue alike: M' and the counts exactly.
    for (FrameState* f : {&a, &b}) {
      f->add_paths(0, 0, 24, 16, sums, counts);
      f->reproject(second);
      f->finish_round();
    }
    EXPECT_EQ(b.reprojected_counts(), a.reprojected_counts());
    EXPECT_EQ(b.counts(), a.counts());
    const FrameSnapshot after_a = a.save(), after_b = b.save();
    EXPECT_EQ(after_b.skip, after_a.skip);
    EXPECT_EQ(after_b.path_m2, after_a.path_m2);
    EXPECT_EQ(after_b.reprojected_effective, after_a.reprojected_effective);
    EXPECT_EQ(after_b.path_half_sum, after_a.path_half_sum);
    // ... and combine alike (the variance combination reads the halves): bit for bit on the CPU
    // back-end; within float rounding on GL, whose atomics add a round's radiance in no fixed order
    // once llvmpipe runs more than one thread (LP_NUM_THREADS, default: the cores).
    const std::vector<float> image_a = combined_image(a.images()).data, image_b = combined_image(b.images()).data;
    if (method == ReprojectMethod::kCpu) {
      EXPECT_EQ(image_b, image_a);
    }
    ASSERT_EQ(image_b.size(), image_a.size());
    for (size_t i = 0; i < image_a.size(); ++i)
      ASSERT_NEAR(image_b[i], image_a[i], 1e-5f * std::max(1.f, std::fabs(image_a[i]))) << "image value " << i;
    // ... and the GL frame decided every vertex as the CPU frame did (backend_decisions_test.cpp).
    if (method == ReprojectMethod::kCpu)
      cpu_after[rule] = after_a;
    else {
      const FrameSnapshot& cpu = cpu_after.at(rule);
      EXPECT_EQ(after_a.counts, cpu.counts);
      EXPECT_EQ(after_a.accumulation.count, cpu.accumulation.count);
      EXPECT_EQ(after_a.mprime, cpu.mprime);
      EXPECT_EQ(after_a.skip, cpu.skip);
      EXPECT_EQ(after_a.reprojected_effective, cpu.reprojected_effective);
    }
    fs::remove_all(dir);
  }
}

TEST(CheckpointStreamed, OlderFramesAreRefusedWithAReasonAndStaleTempFilesRemoved) {
  const fs::path dir = fresh_dir("oldframe");
  CheckpointStore store(dir);
  JobSpecRecord spec;
  spec.id = "j1";
  spec.seq = 1;
  spec.scene_hash = "h";
  spec.options.width = spec.options.height = 8;
  store.save_spec(spec);
  // A version-2 record with a frame: the same bytes under a version-2 seal (its frame would be of the
  // old layout; it is refused before it is read).
  const std::string payload = encode(sample_progress(2));
  std::string sealed = seal(RecordKind::kJobProgress, payload);
  const uint32_t v2 = 2;
  std::memcpy(sealed.data() + 8, &v2, 4);
  // Re-seal the header's own checksum.
  uLong crc = crc32(0L, Z_NULL, 0);
  crc = crc32(crc, reinterpret_cast<const Bytef*>(sealed.data()), 28);
  const uint32_t header_crc = uint32_t(crc);
  std::memcpy(sealed.data() + 28, &header_crc, 4);
  write_bytes(dir / "jobs" / "j1" / "progress.ckpt", sealed);
  write_bytes(dir / "jobs" / "j1" / "progress.ckpt.7.tmp", "left over");
  std::vector<std::string> problems;
  const auto jobs = store.load_jobs(&problems);
  ASSERT_EQ(jobs.size(), 1u);
  ASSERT_TRUE(jobs[0].progress);
  EXPECT_FALSE(jobs[0].progress->frame);
  EXPECT_EQ(jobs[0].progress->counters, sample_progress(2).counters);
  ASSERT_EQ(jobs[0].problems.size(), 1u);
  EXPECT_NE(jobs[0].problems[0].find("version 2"), std::string::npos) << jobs[0].problems[0];
  EXPECT_FALSE(fs::exists(dir / "jobs" / "j1" / "progress.ckpt.7.tmp"));
  fs::remove_all(dir);
}

// ---- a JobManager destroyed mid-job resumes on the same state directory ---------------------------------

// Leases, traces and commits tiles in-process like a worker would (the same TileRenderer, the
// same chunking and assembly as over gRPC).
class InProcessWorker {
 public:
  explicit InProcessWorker(JobManager& jobs) : jobs_(jobs), id_(jobs.register_worker("test", 1)) {}

  std::optional<TileLeaseInfo> lease() {
    auto d = jobs_.lease_tile(id_);
    if (auto* l = std::get_if<TileLeaseInfo>(&d)) return *l;
    return std::nullopt;
  }

  // Traces the tile and submits it; the master's answer (nullopt: refused as stale, with `why`).
  std::optional<CommitOutcome> submit(const TileLeaseInfo& l, std::string* why = nullptr) {
    if (!tracer_ || seed_ != l.seed) {
      scene_ = std::make_unique<Scene>(load_bundle(bundle_scene(l.scene_builtin), default_cache_root()));
      embree_ = std::make_unique<EmbreeScene>(*scene_);
      camera_ = std::make_unique<Camera>(l.camera, l.options.width, l.options.height);
      tracer_ = std::make_unique<PathTracer>(*embree_, *camera_, l.seed, l.options.rr);
      seed_ = l.seed;
    }
    VertexFilter f;
    f.mode = l.options.mode == RenderMode::kPathTrace ? VertexFilter::Mode::kNone : VertexFilter::Mode::kCull;
    f.subpixels = l.options.subpixels;
    const TileResult r =
        TileRenderer(*tracer_, f).render({l.rect, l.skip, l.first_sample, int(l.paths_per_pixel), l.paths});
    const TileResultIdentity identity{l.lease_id, l.job_id, l.round, l.tile_index, id_};
    const auto chunks = split_tile_result(r, identity, l.codec_bounds, {});
    TileCheck e = jobs_.expect(identity);
    if (e.verdict != TileVerdict::kExpected) {
      EXPECT_TRUE(e.stale()) << e.why;
      if (why) *why = e.why;
      return std::nullopt;
    }
    TileResultAssembler a(std::move(e.expectation));
    for (const auto& c : chunks) EXPECT_FALSE(a.add(c));
    EXPECT_TRUE(a.complete());
    return jobs_.commit(l.job_id, l.round, l.tile_index, a.take());
  }

  // Works until the job is done or has closed `until_round` rounds.
  void work(const std::string& job, int until_round = 1 << 30) {
    for (auto end = std::chrono::steady_clock::now() + 120s; std::chrono::steady_clock::now() < end;) {
      const auto s = jobs_.get(job);
      ASSERT_TRUE(s);
      ASSERT_NE(s->state, JobState::kFailed) << s->error;
      if (s->state == JobState::kDone || s->progress.round >= until_round) return;
      if (auto l = lease())
        submit(*l);
      else
        std::this_thread::sleep_for(2ms);
    }
    FAIL() << "job " << job << " did not get there within 120 s";
  }

 private:
  JobManager& jobs_;
  std::string id_;
  uint64_t seed_ = 0;
  std::unique_ptr<Scene> scene_;
  std::unique_ptr<EmbreeScene> embree_;
  std::unique_ptr<Camera> camera_;
  std::unique_ptr<PathTracer> tracer_;
};

JobRequest resume_request(ReprojectMethod method) {
  JobRequest req;
  req.options.width = 48;
  req.options.height = 40;
  req.options.spp = 32;
  req.options.paths_per_round = 4;
  req.options.min_paths = 8;
  req.options.mode = RenderMode::kSkip;
  req.options.reproject = method;
  req.options.tile_size = 16;
  req.options.seed = 5;
  req.bundle.builtin = "builtin:cornell";
  req.name = "resume";
  req.request_id = "resume-request";
  return req;
}

// M, M' and the path sums bit for bit, the combined image within float rounding; and some M' to
// compare.
void expect_same_render(const test::JobImages& a, const test::JobImages& b) {
  ASSERT_EQ(a.counts.data.size(), b.counts.data.size());
  ASSERT_NO_FATAL_FAILURE(test::expect_same_images(a, b));
  uint64_t mprime = 0;
  for (size_t i = 1; i < a.counts.data.size(); i += 2) mprime += uint64_t(a.counts.data[i]);
  EXPECT_GT(mprime, 0u) << "nothing was reprojected: the comparison would not cover M'";
}

class JobManagerResume : public ::testing::TestWithParam<ReprojectMethod> {};

TEST_P(JobManagerResume, DestroyedMidJobAndRecreatedOnTheSameStateDirFinishesIdentically) {
  const fs::path undisturbed_dir = fresh_dir("undisturbed"), resumed_dir = fresh_dir("resumed");
  MasterOptions o;
  o.checkpoint_interval_s = 0;  // after every round: the resumed round is known
  test::JobImages undisturbed;
  std::string undisturbed_id;
  uint32_t undisturbed_rounds = 0;
  {
    o.state_dir = undisturbed_dir.string();
    JobManager jobs(o);
    const auto r = jobs.submit(resume_request(GetParam()));
    ASSERT_EQ(r.error, "");
    undisturbed_id = r.id;
    InProcessWorker w(jobs);
    ASSERT_NO_FATAL_FAILURE(w.work(r.id));
    undisturbed = test::results_of(jobs, r.id);
    undisturbed_rounds = uint32_t(jobs.get(r.id)->progress.round);
  }
  ASSERT_GE(undisturbed_rounds, 4u);

  o.state_dir = resumed_dir.string();
  std::string id;
  std::optional<TileLeaseInfo> old_lease;
  uint64_t first_epoch = 0;
  {
    JobManager jobs(o);
    first_epoch = jobs.epoch();
    const auto r = jobs.submit(resume_request(GetParam()));
    ASSERT_EQ(r.error, "");
    id = r.id;
    InProcessWorker w(jobs);
    ASSERT_NO_FATAL_FAILURE(w.work(id, 2));
    // Part of round 2 is traced and committed, another tile stays leased: both are lost with the master.
    for (int i = 0; i < 2;) {
      if (auto l = w.lease()) {
        EXPECT_EQ(w.submit(*l), CommitOutcome::kCommitted);
        ++i;
      }
    }
    for (auto end = std::chrono::steady_clock::now() + 10s; !old_lease && std::chrono::steady_clock::now() < end;)
      old_lease = w.lease();
    ASSERT_TRUE(old_lease);
    EXPECT_EQ(old_lease->lease_id >> JobManager::kLeaseEpochShift, first_epoch);
  }  // the manager is destroyed mid-round

  {
    JobManager jobs(o);
    EXPECT_EQ(jobs.epoch(), first_epoch + 1);
    auto s = jobs.get(id);
    ASSERT_TRUE(s) << "the job is known again under its id";
    EXPECT_NE(s->state, JobState::kDone);
    // The same request id gives the same job (idempotency survives the restart).
    EXPECT_EQ(jobs.submit(resume_request(GetParam())).id, id);
    EXPECT_EQ(jobs.list().size(), 1u);

    InProcessWorker w(jobs);
    // A result for a lease of the killed master is dropped as stale, even for the right round and tile.
    std::string why;
    EXPECT_FALSE(w.submit(*old_lease, &why));
    EXPECT_NE(why.find("restarted"), std::string::npos) << why;
    // The resumed job goes on from round 2 (the checkpoint after round 1), not from 0.
    for (auto end = std::chrono::steady_clock::now() + 30s;
         jobs.get(id)->state != JobState::kRunning && std::chrono::steady_clock::now() < end;)
      std::this_thread::sleep_for(5ms);
    s = jobs.get(id);
    ASSERT_EQ(s->state, JobState::kRunning);
    EXPECT_EQ(s->progress.round, 2);
    const auto l = w.lease();
    ASSERT_TRUE(l);
    EXPECT_EQ(l->round, 2u);
    EXPECT_EQ(l->lease_id >> JobManager::kLeaseEpochShift, first_epoch + 1);
    EXPECT_EQ(w.submit(*l), CommitOutcome::kCommitted);
    ASSERT_NO_FATAL_FAILURE(w.work(id));
    EXPECT_EQ(jobs.get(id)->state, JobState::kDone);
    EXPECT_EQ(uint32_t(jobs.get(id)->progress.round), undisturbed_rounds);
    expect_same_render(test::results_of(jobs, id), undisturbed);
  }

  {
    // Once more: the finished job keeps its state, results and previews.
    JobManager jobs(o);
    const auto s = jobs.get(id);
    ASSERT_TRUE(s);
    EXPECT_EQ(s->state, JobState::kDone);
    EXPECT_EQ(uint32_t(s->progress.round), undisturbed_rounds);
    EXPECT_GT(s->counters.tiles_committed, 0u);
    EXPECT_TRUE(jobs.result_path(id, ResultKind::kCounts));
    EXPECT_TRUE(jobs.preview_png(id, "combined"));
    const auto again = jobs.submit(resume_request(GetParam()));
    EXPECT_EQ(again.id, id);
    // New jobs get new ids after the loaded ones.
    JobRequest other = resume_request(GetParam());
    other.request_id = "another";
    const auto r = jobs.submit(other);
    EXPECT_NE(r.id, id);
    EXPECT_GT(r.id, id);
  }
  fs::remove_all(undisturbed_dir);
  fs::remove_all(resumed_dir);
}

INSTANTIATE_TEST_SUITE_P(Reprojectors, JobManagerResume, ::testing::Values(ReprojectMethod::kCpu, ReprojectMethod::kGl),
                         [](const auto& info) { return std::string(to_string(info.param)); });

TEST(JobManagerCheckpoint, CancelledJobStaysCancelledAndTornNewestCheckpointFallsBack) {
  const fs::path dir = fresh_dir("cancel");
  MasterOptions o;
  o.checkpoint_interval_s = 0;  // after every round
  o.state_dir = dir.string();
  o.reproject_backend_override = "cpu";
  std::string cancelled, running;
  {
    JobManager jobs(o);
    JobRequest a = resume_request(ReprojectMethod::kCpu);
    a.request_id = "a";
    JobRequest b = a;
    b.request_id = "b";
    running = jobs.submit(a).id;
    cancelled = jobs.submit(b).id;  // queued behind the first
    InProcessWorker w(jobs);
    ASSERT_NO_FATAL_FAILURE(w.work(running, 3));
    EXPECT_TRUE(jobs.cancel(cancelled));
  }
  // The newest checkpoint of the running job is torn: the one before it is used. (Checkpoints are
  // written by a thread of their own; a newer one may replace an older one not yet written, so the
  // previous one is of round 2 or earlier.)
  const fs::path newest = dir / "jobs" / running / "progress.ckpt";
  const int newest_round = decode_job_progress(read_sealed(newest, RecordKind::kJobProgress)).progress.round;
  const int previous_round =
      decode_job_progress(read_sealed(dir / "jobs" / running / "progress.prev.ckpt", RecordKind::kJobProgress))
          .progress.round;
  EXPECT_EQ(newest_round, 3);
  EXPECT_GE(previous_round, 1);
  EXPECT_LT(previous_round, newest_round);
  const std::string bytes = read_bytes(newest);
  write_bytes(newest, bytes.substr(0, bytes.size() - 100));
  {
    JobManager jobs(o);
    ASSERT_TRUE(jobs.get(cancelled));
    EXPECT_EQ(jobs.get(cancelled)->state, JobState::kCancelled);
    for (auto end = std::chrono::steady_clock::now() + 30s;
         jobs.get(running)->state != JobState::kRunning && std::chrono::steady_clock::now() < end;)
      std::this_thread::sleep_for(5ms);
    EXPECT_EQ(jobs.get(running)->state, JobState::kRunning);
    EXPECT_EQ(jobs.get(running)->progress.round, previous_round);
  }
  fs::remove_all(dir);
}

// A client that saw DONE must find the job done after a crash: the finished state is on disk before
// the job reports it (the record is read the moment the job says DONE, without sleeping).
TEST(JobManagerCheckpoint, AJobIsDoneOnDiskBeforeItReportsDone) {
  const fs::path dir = fresh_dir("done-durable");
  MasterOptions o;
  o.checkpoint_interval_s = 0;
  o.state_dir = dir.string();
  o.reproject_backend_override = "cpu";
  {
    JobManager jobs(o);
    const std::string id = jobs.submit(resume_request(ReprojectMethod::kCpu)).id;
    InProcessWorker w(jobs);
    for (auto end = std::chrono::steady_clock::now() + 120s;; std::this_thread::yield()) {
      ASSERT_LT(std::chrono::steady_clock::now(), end) << "the job did not finish";
      const auto st = jobs.get(id);
      ASSERT_TRUE(st);
      ASSERT_NE(st->state, JobState::kFailed) << st->error;
      if (st->state == JobState::kDone) break;
      if (auto l = w.lease()) w.submit(*l);
    }
    const JobProgressRecord on_disk =
        decode_job_progress(read_sealed(dir / "jobs" / id / "progress.ckpt", RecordKind::kJobProgress));
    EXPECT_EQ(on_disk.state, JobState::kDone);
    EXPECT_EQ(on_disk.progress.round, jobs.get(id)->progress.round);
  }
  fs::remove_all(dir);
}

// Round checkpoints follow MasterOptions::checkpoint_interval_s: 0 after every round but the last
// (the job's end writes its final record), a long interval only after the first round, the automatic
// one somewhere between; the newest checkpoint on disk is then of the last checkpointed round.
TEST(JobManagerCheckpoint, RoundCheckpointsFollowTheInterval) {
  struct Case {
    double interval;
    const char* name;
  };
  uint32_t rounds_every = 0;
  for (const Case c : {Case{0, "every round"}, Case{3600, "an hour"}, Case{-1, "auto"}}) {
    SCOPED_TRACE(c.name);
    const fs::path dir = fresh_dir("interval");
    MasterOptions o;
    o.state_dir = dir.string();
    o.reproject_backend_override = "cpu";
    o.checkpoint_interval_s = c.interval;
    auto owner = std::make_unique<JobManager>(o);  // gone (its checkpoint thread joined) before the folder
    JobManager& jobs = *owner;
    const std::string id = jobs.submit(resume_request(ReprojectMethod::kCpu)).id;
    InProcessWorker w(jobs);
    ASSERT_NO_FATAL_FAILURE(w.work(id, 4));
    auto s = jobs.get(id);
    ASSERT_TRUE(s);
    ASSERT_EQ(s->state, JobState::kRunning);
    const uint32_t closed = uint32_t(s->progress.round);
    ASSERT_GE(closed, 4u);
    // The round's checkpoint is taken just after the round shows as closed; nothing is traced
    // meanwhile, so the round stays where it is.
    for (auto end = std::chrono::steady_clock::now() + 10s;
         c.interval == 0 && s->round_checkpoints < closed && std::chrono::steady_clock::now() < end;) {
      std::this_thread::sleep_for(5ms);
      s = jobs.get(id);
    }
    ASSERT_EQ(uint32_t(s->progress.round), closed);
    if (c.interval == 0) {
      EXPECT_EQ(s->round_checkpoints, closed);
      rounds_every = s->round_checkpoints;
    } else if (c.interval > 0) {
      EXPECT_EQ(s->round_checkpoints, 1u) << "only the first round within the hour";
    } else {
      EXPECT_GE(s->round_checkpoints, 1u);
      EXPECT_LE(s->round_checkpoints, closed);
    }
    ASSERT_NO_FATAL_FAILURE(w.work(id));
    EXPECT_EQ(jobs.get(id)->state, JobState::kDone);
    owner.reset();
    fs::remove_all(dir);
  }
  EXPECT_GE(rounds_every, 4u);
}

}  // namespace
}  // namespace epr
