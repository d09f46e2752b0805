// See checkpoint.h.
#include "master/server/checkpoint.h"

#include <fcntl.h>
#include <fmt/format.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <bit>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <initializer_list>
#include <sstream>
#include <system_error>
#include <type_traits>

#include "common/log.h"
#include "epr/v1/job_service.pb.h"
#include "wire/convert.h"

namespace epr {
namespace fs = std::filesystem;
static_assert(std::endian::native == std::endian::little, "checkpoints are written in little-endian order");

namespace {

constexpr char kMagic[8] = {'E', 'P', 'R', 'S', 'T', 'A', 'T', 'E'};

uint32_t crc32_of(std::string_view bytes) {
  uLong crc = crc32(0L, Z_NULL, 0);
  // zlib takes lengths as uInt: feed large payloads in pieces.
  for (size_t off = 0; off < bytes.size();) {
    const size_t n = std::min<size_t>(bytes.size() - off, size_t(1) << 30);
    crc = crc32(crc, reinterpret_cast<const Bytef*>(bytes.data() + off), uInt(n));
    off += n;
  }
  return uint32_t(crc);
}

// ---- payload encoding ------------------------------------------------------------------------------

class ByteWriter {
 public:
  template <class T>
  void put(const T& v) {
    static_assert(std::is_trivially_copyable_v<T>);
    out_.append(reinterpret_cast<const char*>(&v), sizeof(T));
  }
  void put_string(std::string_view s) {
    put<uint64_t>(s.size());
    out_.append(s);
  }
  template <class T>
  void put_vector(const std::vector<T>& v) {
    static_assert(std::is_trivially_copyable_v<T>);
    put<uint64_t>(v.size());
    out_.append(reinterpret_cast<const char*>(v.data()), v.size() * sizeof(T));
  }
  void reserve(size_t bytes) { out_.reserve(bytes); }
  std::string take() { return std::move(out_); }

 private:
  std::string out_;
};

class ByteReader {
 public:
  explicit ByteReader(std::string_view in) : in_(in) {}
  template <class T>
  T get() {
    static_assert(std::is_trivially_copyable_v<T>);
    need(sizeof(T));
    T v;
    std::memcpy(&v, in_.data() + pos_, sizeof(T));
    pos_ += sizeof(T);
    return v;
  }
  bool get_bool() {
    const auto b = get<uint8_t>();
    if (b > 1) throw CheckpointError("malformed payload: a flag is neither 0 nor 1");
    return b != 0;
  }
  std::string get_string() {
    const uint64_t n = get<uint64_t>();
    need(n);
    std::string s(in_.substr(pos_, n));
    pos_ += n;
    return s;
  }
  template <class T>
  std::vector<T> get_vector() {
    const uint64_t n = get<uint64_t>();
    if (n > (in_.size() - pos_) / sizeof(T)) throw CheckpointError("malformed payload: an array runs past its end");
    std::vector<T> v(n);
    std::memcpy(v.data(), in_.data() + pos_, n * sizeof(T));
    pos_ += n * sizeof(T);
    return v;
  }
  void expect_end() const {
    if (pos_ != in_.size()) throw CheckpointError("malformed payload: trailing bytes");
  }

 private:
  void need(uint64_t n) const {
    if (n > in_.size() - pos_) throw CheckpointError("malformed payload: it ends early");
  }
  std::string_view in_;
  size_t pos_ = 0;
};

void put(ByteWriter& w, const FrameProgress& p) {
  w.put<int32_t>(p.round);
  w.put(p.mean_spp);
  w.put(p.min_spp);
  w.put(p.mean_paths);
  w.put(p.mean_reprojected);
  w.put(p.pixels_active);
  w.put(p.pixels_skipped);
  w.put(p.paths_traced);
  w.put(p.paths_skipped);
}

FrameProgress get_progress(ByteReader& r) {
  FrameProgress p;
  p.round = r.get<int32_t>();
  p.mean_spp = r.get<double>();
  p.min_spp = r.get<double>();
  p.mean_paths = r.get<double>();
  p.mean_reprojected = r.get<double>();
  p.pixels_active = r.get<uint64_t>();
  p.pixels_skipped = r.get<uint64_t>();
  p.paths_traced = r.get<uint64_t>();
  p.paths_skipped = r.get<uint64_t>();
  return p;
}

void put(ByteWriter& w, const ReprojectionCounts& c) {
  for (uint64_t v : {c.accepted, c.occluded, c.backfacing, c.culled, c.not_diffuse, c.invalid, c.exact}) w.put(v);
}

ReprojectionCounts get_counts(ByteReader& r) {
  ReprojectionCounts c;
  for (uint64_t* v : {&c.accepted, &c.occluded, &c.backfacing, &c.culled, &c.not_diffuse, &c.invalid, &c.exact})
    *v = r.get<uint64_t>();
  return c;
}

void put(ByteWriter& w, const FrameSnapshot& f) {
  w.put<int32_t>(f.width);
  w.put<int32_t>(f.height);
  w.put_vector(f.path_sum);
  w.put_vector(f.path_count);
  w.put_vector(f.mprime);
  w.put_vector(f.reprojected);
  w.put_vector(f.skip);
  w.put<int32_t>(f.paths_done);
  w.put<uint8_t>(f.done);
  put(w, f.progress);
  w.put(f.seconds_reprojecting);
  w.put(f.seconds_downsampling);
  w.put<uint8_t>(f.has_accumulation);
  if (f.has_accumulation) {
    const SubpixelAccumulation& a = f.accumulation;
    w.put<int32_t>(a.width);
    w.put<int32_t>(a.height);
    w.put<int32_t>(a.subpixels);
    w.put_vector(a.sum);
    w.put_vector(a.count);
    put(w, f.counts);
  }
}

FrameSnapshot get_frame(ByteReader& r) {
  FrameSnapshot f;
  f.width = r.get<int32_t>();
  f.height = r.get<int32_t>();
  f.path_sum = r.get_vector<double>();
  f.path_count = r.get_vector<uint32_t>();
  f.mprime = r.get_vector<uint64_t>();
  f.reprojected = r.get_vector<float>();
  f.skip = r.get_vector<uint8_t>();
  f.paths_done = r.get<int32_t>();
  f.done = r.get_bool();
  f.progress = get_progress(r);
  f.seconds_reprojecting = r.get<double>();
  f.seconds_downsampling = r.get<double>();
  f.has_accumulation = r.get_bool();
  if (f.has_accumulation) {
    SubpixelAccumulation& a = f.accumulation;
    a.width = r.get<int32_t>();
    a.height = r.get<int32_t>();
    a.subpixels = r.get<int32_t>();
    a.sum = r.get_vector<float>();
    a.count = r.get_vector<uint32_t>();
    f.counts = get_counts(r);
  }
  return f;
}

// ---- files -----------------------------------------------------------------------------------------

[[noreturn]] void throw_errno(const std::string& what, const fs::path& path) {
  throw std::system_error(errno, std::generic_category(), fmt::format("{} '{}'", what, path.string()));
}

void fsync_dir(const fs::path& dir) {
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) throw_errno("cannot open folder", dir);
  const int rc = ::fsync(fd);
  ::close(fd);
  if (rc != 0) throw_errno("cannot fsync folder", dir);
}

// Writes the parts one after the other into `path` and fsyncs it (not atomic by itself).
void write_and_sync(const fs::path& path, std::initializer_list<std::string_view> parts) {
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) throw_errno("cannot create", path);
  for (std::string_view bytes : parts)
    for (size_t off = 0; off < bytes.size();) {
      const ssize_t n = ::write(fd, bytes.data() + off, bytes.size() - off);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) {
        const int e = errno;
        ::close(fd);
        errno = e;
        throw_errno("cannot write", path);
      }
      off += size_t(n);
    }
  if (::fsync(fd) != 0) {
    const int e = errno;
    ::close(fd);
    errno = e;
    throw_errno("cannot fsync", path);
  }
  if (::close(fd) != 0) throw_errno("cannot close", path);
}

void rename_or_throw(const fs::path& from, const fs::path& to) {
  if (::rename(from.c_str(), to.c_str()) != 0) throw_errno("cannot rename to", to);
}

fs::path temp_of(const fs::path& path) { return fs::path(path.string() + ".tmp"); }

}  // namespace

// ---- sealing ---------------------------------------------------------------------------------------

namespace {
std::string seal_header(RecordKind kind, std::string_view payload) {
  std::string out(kSealHeaderBytes, '\0');
  std::memcpy(out.data(), kMagic, 8);
  const uint32_t version = kCheckpointVersion, k = uint32_t(kind), crc = crc32_of(payload);
  const uint64_t length = payload.size();
  std::memcpy(out.data() + 8, &version, 4);
  std::memcpy(out.data() + 12, &k, 4);
  std::memcpy(out.data() + 16, &length, 8);
  std::memcpy(out.data() + 24, &crc, 4);
  const uint32_t header_crc = crc32_of(std::string_view(out.data(), 28));
  std::memcpy(out.data() + 28, &header_crc, 4);
  return out;
}
}  // namespace

std::string seal(RecordKind kind, std::string_view payload) { return seal_header(kind, payload).append(payload); }

std::string unseal(RecordKind kind, std::string_view bytes, uint32_t* version_out) {
  if (bytes.size() < kSealHeaderBytes)
    throw CheckpointError(
        fmt::format("torn: {} bytes, shorter than the {}-byte header", bytes.size(), kSealHeaderBytes));
  if (std::memcmp(bytes.data(), kMagic, 8) != 0) throw CheckpointError("not a state file (bad magic)");
  uint32_t version, k, crc, header_crc;
  uint64_t length;
  std::memcpy(&version, bytes.data() + 8, 4);
  std::memcpy(&k, bytes.data() + 12, 4);
  std::memcpy(&length, bytes.data() + 16, 8);
  std::memcpy(&crc, bytes.data() + 24, 4);
  std::memcpy(&header_crc, bytes.data() + 28, 4);
  if (crc32_of(bytes.substr(0, 28)) != header_crc) throw CheckpointError("corrupt header (checksum mismatch)");
  if (version < kOldestCheckpointVersion || version > kCheckpointVersion)
    throw CheckpointError(fmt::format("format version {}, this master reads versions {} to {}", version,
                                      kOldestCheckpointVersion, kCheckpointVersion));
  if (version_out) *version_out = version;
  if (k != uint32_t(kind)) throw CheckpointError(fmt::format("record kind {}, expected {}", k, uint32_t(kind)));
  const std::string_view payload = bytes.substr(kSealHeaderBytes);
  if (payload.size() != length)
    throw CheckpointError(fmt::format("torn: the payload has {} bytes, the header says {}", payload.size(), length));
  if (crc32_of(payload) != crc) throw CheckpointError("corrupt payload (checksum mismatch)");
  return std::string(payload);
}

void write_file_atomically(const fs::path& path, std::string_view bytes) {
  const fs::path tmp = temp_of(path);
  write_and_sync(tmp, {bytes});
  rename_or_throw(tmp, path);
  fsync_dir(path.parent_path().empty() ? fs::path(".") : path.parent_path());
}

std::string read_sealed(const fs::path& path, RecordKind kind, uint32_t* version) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw CheckpointError(fmt::format("'{}' is missing or unreadable", path.string()));
  std::ostringstream ss;
  ss << in.rdbuf();
  try {
    return unseal(kind, ss.str(), version);
  } catch (const CheckpointError& e) {
    throw CheckpointError(fmt::format("'{}': {}", path.string(), e.what()));
  }
}

// ---- records ---------------------------------------------------------------------------------------

std::string encode(const JobSpecRecord& r) {
  RenderOptions o = r.options;
  o.eye.reset();  // the camera below is the one the job runs with
  o.look.reset();
  o.up.reset();
  o.fov.reset();
  v1::JobSpec spec = to_job_spec(o, SceneBundleData{}, r.camera);
  spec.clear_scene();  // stored once per hash (scenes/)
  spec.set_name(r.name);
  spec.set_priority(r.priority);
  spec.set_request_id(r.request_id);
  if (r.time_budget_seconds) spec.set_time_budget_seconds(*r.time_budget_seconds);
  ByteWriter w;
  w.put_string(r.id);
  w.put(r.seq);
  w.put(r.submitted_ms);
  w.put_string(r.scene_hash);
  w.put_string(spec.SerializeAsString());
  return w.take();
}

JobSpecRecord decode_job_spec(std::string_view payload) {
  ByteReader rd(payload);
  JobSpecRecord r;
  r.id = rd.get_string();
  r.seq = rd.get<uint64_t>();
  r.submitted_ms = rd.get<int64_t>();
  r.scene_hash = rd.get_string();
  v1::JobSpec spec;
  if (!spec.ParseFromString(rd.get_string())) throw CheckpointError("malformed payload: the job spec does not parse");
  rd.expect_end();
  if (r.id.empty() || r.id.find('/') != std::string::npos || r.id == "." || r.id == "..")
    throw CheckpointError("malformed payload: unusable job id");
  if (auto err = from_job_spec(spec, &r.options, &r.camera))
    throw CheckpointError("the stored job spec is invalid: " + *err);
  r.name = spec.name();
  r.priority = spec.priority();
  r.request_id = spec.request_id();
  if (spec.has_time_budget_seconds()) r.time_budget_seconds = spec.time_budget_seconds();
  return r;
}

std::string encode(const JobProgressRecord& r) {
  ByteWriter w;
  if (r.frame) {  // one allocation for the arrays
    const FrameSnapshot& f = *r.frame;
    w.reserve(4096 + f.path_sum.size() * 8 + f.path_count.size() * 4 + f.mprime.size() * 8 + f.reprojected.size() * 4 +
              f.skip.size() + f.accumulation.sum.size() * 4 + f.accumulation.count.size() * 4);
  }
  w.put<uint32_t>(uint32_t(r.state));
  w.put_string(r.error);
  w.put(r.triangles);
  put(w, r.progress);
  put(w, r.counts);
  JobCounters::visit(
      r.counters, [&](uint64_t v) { w.put(v); }, [&](double v) { w.put(v); });
  w.put(r.started_ms);
  w.put(r.finished_ms);
  w.put<uint8_t>(r.budget_exhausted);
  w.put<uint8_t>(r.frame.has_value());
  if (r.frame) put(w, *r.frame);
  w.put<uint64_t>(r.previews.size());
  for (const auto& [layer, png] : r.previews) {
    w.put_string(layer);
    w.put_vector(png);
  }
  return w.take();
}

JobProgressRecord decode_job_progress(std::string_view payload, uint32_t version) {
  ByteReader rd(payload);
  JobProgressRecord r;
  const uint32_t state = rd.get<uint32_t>();
  if (state > uint32_t(JobState::kCancelled))
    throw CheckpointError(fmt::format("malformed payload: job state {}", state));
  r.state = JobState(state);
  r.error = rd.get_string();
  r.triangles = rd.get<uint64_t>();
  r.progress = get_progress(rd);
  r.counts = get_counts(rd);
  if (version >= 2) {
    JobCounters::visit(
        r.counters, [&](uint64_t& v) { v = rd.get<uint64_t>(); }, [&](double& v) { v = rd.get<double>(); });
    r.started_ms = rd.get<int64_t>();
    r.finished_ms = rd.get<int64_t>();
  } else {  // eight counters, the times, then the seconds
    JobCounters& c = r.counters;
    for (uint64_t* v : {&c.rays, &c.vertices_received, &c.non_finite, &c.worker_culled, &c.tiles_leased,
                        &c.tiles_committed, &c.tiles_re_leased, &c.tiles_dropped})
      *v = rd.get<uint64_t>();
    r.started_ms = rd.get<int64_t>();
    r.finished_ms = rd.get<int64_t>();
    c.seconds_tracing = rd.get<double>();
    c.seconds_reprojecting = rd.get<double>();
  }
  r.budget_exhausted = rd.get_bool();
  if (rd.get_bool()) r.frame = get_frame(rd);
  const uint64_t previews = rd.get<uint64_t>();
  for (uint64_t i = 0; i < previews; ++i) {
    std::string layer = rd.get_string();
    r.previews[layer] = rd.get_vector<unsigned char>();
  }
  rd.expect_end();
  return r;
}

JobSpecRecord spec_record(const Job& job) {
  const JobRequest& q = job.request;
  return {job.id,   job.seq, job.submitted_ms, job.scene_hash,        q.options,
          q.camera, q.name,  q.priority,       q.time_budget_seconds, q.request_id};
}

JobProgressRecord progress_record(const Job& job) {
  JobProgressRecord r;
  r.state = job.state;
  r.error = job.error;
  r.triangles = job.triangles;
  r.progress = job.progress;
  r.counts = job.counts;
  r.counters = job.counters;
  r.started_ms = job.started_ms;
  r.finished_ms = job.finished_ms;
  r.budget_exhausted = job.budget_exhausted;
  if (job.state == JobState::kDone) r.previews = job.previews;
  return r;
}

// ---- the store -------------------------------------------------------------------------------------

CheckpointStore::CheckpointStore(fs::path dir) : dir_(std::move(dir)) {
  fs::create_directories(dir_ / "jobs");
  fs::create_directories(dir_ / "scenes");
}

uint64_t CheckpointStore::next_epoch() {
  MutexLock lock(mu_);
  uint64_t epoch = 0;
  try {
    const std::string p = read_sealed(dir_ / "epoch", RecordKind::kEpoch);
    ByteReader rd(p);
    epoch = rd.get<uint64_t>();
    rd.expect_end();
  } catch (const CheckpointError& e) {
    // No file: the first run in this folder. A torn or corrupt one is replaced (lease ids carry a clock
    // part too, so a counter that starts again cannot repeat them), but not silently.
    std::error_code ec;
    if (fs::exists(dir_ / "epoch", ec))
      logger("master")->warn("state file {} is unreadable ({}); replaced, the run counter starts again at 1",
                             (dir_ / "epoch").string(), e.what());
    epoch = 0;
  }
  ++epoch;
  ByteWriter w;
  w.put(epoch);
  write_file_atomically(dir_ / "epoch", seal(RecordKind::kEpoch, w.take()));
  return epoch;
}

void CheckpointStore::save_scene(const std::string& hash, const SceneBundleData& bundle) {
  MutexLock lock(mu_);
  const fs::path path = dir_ / "scenes" / (hash + ".scene");
  if (fs::exists(path)) {
    try {
      read_sealed(path, RecordKind::kScene);
      return;
    } catch (const CheckpointError&) {
      // Torn or corrupt: write it again.
    }
  }
  v1::SceneBundle b;
  to_proto(bundle, &b);
  write_file_atomically(path, seal(RecordKind::kScene, b.SerializeAsString()));
}

SceneBundleData CheckpointStore::load_scene(const std::string& hash) const {
  const fs::path path = dir_ / "scenes" / (hash + ".scene");
  v1::SceneBundle b;
  if (!b.ParseFromString(read_sealed(path, RecordKind::kScene)))
    throw CheckpointError(fmt::format("'{}': the scene bundle does not parse", path.string()));
  SceneBundleData data;
  if (b.source_case() == v1::SceneBundle::kBuiltin)
    data.builtin = b.builtin();
  else if (b.source_case() == v1::SceneBundle::kFiles)
    data = from_proto(b.files());
  else
    throw CheckpointError(fmt::format("'{}': the scene bundle has neither files nor a built-in", path.string()));
  if (content_hash(data) != hash)
    throw CheckpointError(fmt::format("'{}': content does not match its hash", path.string()));
  return data;
}

void CheckpointStore::save_spec(const JobSpecRecord& spec) {
  MutexLock lock(mu_);
  const fs::path dir = job_dir(spec.id);
  fs::create_directories(dir);
  write_file_atomically(dir / "spec.ckpt", seal(RecordKind::kJobSpec, encode(spec)));
}

void CheckpointStore::save_progress(const std::string& id, const JobProgressRecord& record) {
  const std::string payload = encode(record);
  const std::string header = seal_header(RecordKind::kJobProgress, payload);
  MutexLock lock(mu_);
  const fs::path dir = job_dir(id);
  fs::create_directories(dir);
  const fs::path newest = dir / "progress.ckpt", previous = dir / "progress.prev.ckpt", tmp = temp_of(newest);
  write_and_sync(tmp, {header, payload});
  // A crash between the renames leaves only the previous checkpoint, which the loader then uses.
  if (fs::exists(newest)) rename_or_throw(newest, previous);
  rename_or_throw(tmp, newest);
  fsync_dir(dir);
}

void CheckpointStore::remove_job(const std::string& id) {
  MutexLock lock(mu_);
  std::error_code ec;
  fs::remove_all(job_dir(id), ec);
}

std::optional<JobProgressRecord> CheckpointStore::load_progress(const std::string& id,
                                                                std::vector<std::string>* problems) const {
  for (const char* name : {"progress.ckpt", "progress.prev.ckpt"}) {
    const fs::path path = job_dir(id) / name;
    if (!fs::exists(path)) continue;
    try {
      uint32_t version = 0;
      std::string payload = read_sealed(path, RecordKind::kJobProgress, &version);
      return decode_job_progress(payload, version);
    } catch (const CheckpointError& e) {
      if (problems) problems->push_back(e.what());
    }
  }
  return std::nullopt;
}

std::vector<CheckpointStore::LoadedJob> CheckpointStore::load_jobs(std::vector<std::string>* problems) const {
  MutexLock lock(mu_);
  std::vector<LoadedJob> out;
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(dir_ / "jobs", ec)) {
    if (!entry.is_directory()) continue;
    const fs::path spec_path = entry.path() / "spec.ckpt";
    LoadedJob job;
    try {
      job.spec = decode_job_spec(read_sealed(spec_path, RecordKind::kJobSpec));
    } catch (const CheckpointError& e) {
      if (problems) problems->push_back(fmt::format("job folder '{}' skipped: {}", entry.path().string(), e.what()));
      continue;
    }
    if (job.spec.id != entry.path().filename().string()) {
      if (problems)
        problems->push_back(fmt::format("job folder '{}' holds job {}: skipped", entry.path().string(), job.spec.id));
      continue;
    }
    job.progress = load_progress(job.spec.id, &job.problems);
    out.push_back(std::move(job));
  }
  std::sort(out.begin(), out.end(), [](const LoadedJob& a, const LoadedJob& b) { return a.spec.seq < b.spec.seq; });
  return out;
}

}  // namespace epr
