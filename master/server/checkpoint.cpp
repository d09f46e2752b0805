// See checkpoint.h.
#include "master/server/checkpoint.h"

#include <fcntl.h>
#include <fmt/format.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <functional>
#include <initializer_list>
#include <span>
#include <system_error>
#include <type_traits>

#include "common/log.h"
#include "epr/v1/job_service.pb.h"
#include "master/server/checkpoint_payload.h"
#include "master/server/window_run.h"
#include "wire/convert.h"

namespace epr {
namespace fs = std::filesystem;
static_assert(std::endian::native == std::endian::little, "checkpoints are written in little-endian order");

namespace {

using checkpoint_io::ByteReader;
using checkpoint_io::ByteWriter;
using checkpoint_io::get_counts;
using checkpoint_io::get_frame;
using checkpoint_io::get_frame_head;
using checkpoint_io::get_progress;
using checkpoint_io::put;

constexpr char kMagic[8] = {'E', 'P', 'R', 'S', 'T', 'A', 'T', 'E'};

uLong crc32_update(uLong crc, std::string_view bytes) {
  for (size_t off = 0; off < bytes.size();) {
    const size_t n = std::min<size_t>(bytes.size() - off, size_t(1) << 30);
    crc = crc32(crc, reinterpret_cast<const Bytef*>(bytes.data() + off), uInt(n));
    off += n;
  }
  return crc;
}

uint32_t crc32_of(std::string_view bytes) { return uint32_t(crc32_update(crc32(0L, Z_NULL, 0), bytes)); }

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
std::string seal_header(RecordKind kind, uint64_t length, uint32_t crc) {
  std::string out(kSealHeaderBytes, '\0');
  std::memcpy(out.data(), kMagic, 8);
  const uint32_t version = kCheckpointVersion, k = uint32_t(kind);
  std::memcpy(out.data() + 8, &version, 4);
  std::memcpy(out.data() + 12, &k, 4);
  std::memcpy(out.data() + 16, &length, 8);
  std::memcpy(out.data() + 24, &crc, 4);
  const uint32_t header_crc = crc32_of(std::string_view(out.data(), 28));
  std::memcpy(out.data() + 28, &header_crc, 4);
  return out;
}
}  // namespace

std::string seal(RecordKind kind, std::string_view payload) {
  return seal_header(kind, payload.size(), crc32_of(payload)).append(payload);
}

namespace {
struct SealHeader {
  uint32_t version = 0;
  uint64_t length = 0;
  uint32_t crc = 0;
};

// Checks a sealed file's first kSealHeaderBytes (magic, header checksum, version, kind).
SealHeader check_header(RecordKind kind, std::string_view bytes) {
  if (bytes.size() < kSealHeaderBytes)
    throw CheckpointError(
        fmt::format("torn: {} bytes, shorter than the {}-byte header", bytes.size(), kSealHeaderBytes));
  if (std::memcmp(bytes.data(), kMagic, 8) != 0) throw CheckpointError("not a state file (bad magic)");
  SealHeader h;
  uint32_t k, header_crc;
  std::memcpy(&h.version, bytes.data() + 8, 4);
  std::memcpy(&k, bytes.data() + 12, 4);
  std::memcpy(&h.length, bytes.data() + 16, 8);
  std::memcpy(&h.crc, bytes.data() + 24, 4);
  std::memcpy(&header_crc, bytes.data() + 28, 4);
  if (crc32_of(bytes.substr(0, 28)) != header_crc) throw CheckpointError("corrupt header (checksum mismatch)");
  if (h.version < kOldestCheckpointVersion || h.version > kCheckpointVersion)
    throw CheckpointError(fmt::format("format version {}, this master reads versions {} to {}", h.version,
                                      kOldestCheckpointVersion, kCheckpointVersion));
  if (k != uint32_t(kind)) throw CheckpointError(fmt::format("record kind {}, expected {}", k, uint32_t(kind)));
  return h;
}

// A frame is read from format version kOldestFrameVersion on.
void check_progress_version(uint32_t version) {
  if (version < kOldestFrameVersion)
    throw CheckpointError(
        fmt::format("its frame is of format version {}: this master reads frames of version {} or newer (the frame's "
                    "layout or meaning changed), so the job starts again from round 0",
                    version, kOldestFrameVersion));
}
}  // namespace

std::string unseal(RecordKind kind, std::string_view bytes, uint32_t* version_out) {
  const SealHeader h = check_header(kind, bytes);
  if (version_out) *version_out = h.version;
  const std::string_view payload = bytes.substr(kSealHeaderBytes);
  if (payload.size() != h.length)
    throw CheckpointError(fmt::format("torn: the payload has {} bytes, the header says {}", payload.size(), h.length));
  if (crc32_of(payload) != h.crc) throw CheckpointError("corrupt payload (checksum mismatch)");
  return std::string(payload);
}

void write_file_atomically(const fs::path& path, std::string_view bytes) {
  const fs::path tmp = temp_of(path);
  try {
    write_and_sync(tmp, {bytes});
    rename_or_throw(tmp, path);
  } catch (...) {
    std::error_code ec;
    fs::remove(tmp, ec);  // a short file (a full disk) is left nowhere
    throw;
  }
  fsync_dir(path.parent_path().empty() ? fs::path(".") : path.parent_path());
}

std::string read_sealed(const fs::path& path, RecordKind kind, uint32_t* version) {
  std::ifstream in(path, std::ios::binary | std::ios::ate);
  if (!in) throw CheckpointError(fmt::format("'{}' is missing or unreadable", path.string()));
  std::string bytes(size_t(in.tellg()), '\0');
  in.seekg(0);
  if (!in.read(bytes.data(), std::streamsize(bytes.size())))
    throw CheckpointError(fmt::format("'{}' is unreadable", path.string()));
  try {
    return unseal(kind, bytes, version);
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
  batch_to_spec(r.batch, &spec);
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
  r.batch = batch_from_spec(spec);
  return r;
}

namespace {
// The progress record; its frame is `frame` (if given, else r.frame's).
void put_progress_record(ByteWriter& w, const JobProgressRecord& r, const FrameView* frame) {
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
  w.put<uint8_t>(frame || r.frame);
  if (frame)
    put(w, *frame);
  else if (r.frame)
    put(w, view_of(*r.frame));
  w.put<uint64_t>(r.previews.size());
  for (const auto& [layer, png] : r.previews) {
    w.put_string(layer);
    w.put_vector(png);
  }
}

// The record's fields before its frame.
void get_progress_head(ByteReader& rd, JobProgressRecord* r, uint32_t version) {
  const uint32_t state = rd.get<uint32_t>();
  if (state > uint32_t(JobState::kCancelled))
    throw CheckpointError(fmt::format("malformed payload: job state {}", state));
  r->state = JobState(state);
  r->error = rd.get_string();
  r->triangles = rd.get<uint64_t>();
  r->progress = get_progress(rd);
  r->counts = get_counts(rd);
  if (version >= 2) {
    JobCounters::visit(
        r->counters, [&](uint64_t& v) { v = rd.get<uint64_t>(); }, [&](double& v) { v = rd.get<double>(); });
    r->started_ms = rd.get<int64_t>();
    r->finished_ms = rd.get<int64_t>();
  } else {  // eight counters, the times, then the seconds
    JobCounters& c = r->counters;
    for (uint64_t* v : {&c.rays, &c.vertices_received, &c.non_finite, &c.worker_culled, &c.tiles_leased,
                        &c.tiles_committed, &c.tiles_re_leased, &c.tiles_dropped})
      *v = rd.get<uint64_t>();
    r->started_ms = rd.get<int64_t>();
    r->finished_ms = rd.get<int64_t>();
    c.seconds_tracing = rd.get<double>();
    c.seconds_reprojecting = rd.get<double>();
  }
  r->budget_exhausted = rd.get_bool();
}

void get_previews(ByteReader& rd, JobProgressRecord* r) {
  const uint64_t previews = rd.get<uint64_t>();
  for (uint64_t i = 0; i < previews; ++i) {
    std::string layer = rd.get_string();
    r->previews[layer] = rd.get_vector<unsigned char>();
  }
  rd.expect_end();
}
}  // namespace

std::string encode(const JobProgressRecord& r) {
  ByteWriter w;
  put_progress_record(w, r, nullptr);
  return w.take();
}

JobProgressRecord decode_job_progress(std::string_view payload, uint32_t version) {
  ByteReader rd(payload);
  JobProgressRecord r;
  get_progress_head(rd, &r, version);
  if (rd.get_bool()) {
    check_progress_version(version);
    r.frame = get_frame(rd, version);
  }
  get_previews(rd, &r);
  return r;
}

JobSpecRecord spec_record(const Job& job) {
  const JobRequest& q = job.request;
  return {job.id, job.seq,    job.submitted_ms,      job.scene_hash, q.options, q.camera,
          q.name, q.priority, q.time_budget_seconds, q.request_id,   q.batch};
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
  if (job.state == JobState::kDone) r.previews = job.preview.pngs;
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

namespace {
// An open file descriptor, closed with the last reference.
struct Fd {
  int fd = -1;
  explicit Fd(int f) : fd(f) {}
  Fd(const Fd&) = delete;
  Fd& operator=(const Fd&) = delete;
  ~Fd() {
    if (fd >= 0) ::close(fd);
  }
};

// Reads exactly n bytes at `offset` (fewer only at the end of the file); throws on errors.
size_t pread_full(int fd, char* buf, size_t n, uint64_t offset, const fs::path& path) {
  size_t got = 0;
  while (got < n) {
    const ssize_t k = ::pread(fd, buf + got, n - got, off_t(offset + got));
    if (k < 0 && errno == EINTR) continue;
    if (k < 0) throw CheckpointError(fmt::format("'{}' cannot be read: {}", path.string(), std::strerror(errno)));
    if (k == 0) break;
    got += size_t(k);
  }
  return got;
}

std::atomic<uint64_t> temp_counter{0};
}  // namespace

fs::path CheckpointStore::write_progress_file(const std::string& id, const JobProgressRecord& record,
                                              const FrameView* frame) const {
  const fs::path dir = job_dir(id);
  fs::create_directories(dir);
  const fs::path tmp = dir / fmt::format("progress.ckpt.{}.tmp", temp_counter.fetch_add(1));
  const int raw = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (raw < 0) throw_errno("cannot create", tmp);
  Fd fd(raw);
  try {
    uLong crc = crc32(0L, Z_NULL, 0);
    uint64_t length = 0;
    auto write_all = [&](std::string_view bytes, uint64_t offset) {
      for (size_t off = 0; off < bytes.size();) {
        const ssize_t n = ::pwrite(fd.fd, bytes.data() + off, bytes.size() - off, off_t(offset + off));
        if (n < 0 && errno == EINTR) continue;
        if (n <= 0) throw_errno("cannot write", tmp);
        off += size_t(n);
      }
    };
    // The payload in chunks after room for the header, which is written last (its length and checksum).
    ByteWriter w([&](std::string_view bytes) {
      write_all(bytes, kSealHeaderBytes + length);
      crc = crc32_update(crc, bytes);
      length += bytes.size();
    });
    put_progress_record(w, record, frame);
    w.flush();
    write_all(seal_header(RecordKind::kJobProgress, length, uint32_t(crc)), 0);
  } catch (...) {
    std::error_code ec;
    fs::remove(tmp, ec);
    throw;
  }
  return tmp;
}

void CheckpointStore::commit_progress(const std::string& id, const fs::path& written) {
  {
    const int fd = ::open(written.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) throw_errno("cannot open", written);
    const int rc = ::fsync(fd);
    const int e = errno;
    ::close(fd);
    errno = e;
    if (rc != 0) throw_errno("cannot fsync", written);
  }
  MutexLock lock(mu_);
  const fs::path dir = job_dir(id);
  const fs::path newest = dir / "progress.ckpt", previous = dir / "progress.prev.ckpt";
  // A crash between the renames leaves only the previous checkpoint, which the loader then uses.
  if (fs::exists(newest)) rename_or_throw(newest, previous);
  rename_or_throw(written, newest);
  fsync_dir(dir);
}

void CheckpointStore::save_progress(const std::string& id, const JobProgressRecord& record) {
  const fs::path tmp = write_progress_file(id, record, nullptr);
  try {
    commit_progress(id, tmp);
  } catch (...) {
    std::error_code ec;
    fs::remove(tmp, ec);
    throw;
  }
}

JobProgressRecord CheckpointStore::read_progress(const fs::path& path, std::vector<std::string>* problems) {
  const int raw = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (raw < 0) throw CheckpointError(fmt::format("'{}' is missing or unreadable", path.string()));
  auto fd = std::make_shared<Fd>(raw);
  try {
    // The header, then the payload's checksum in one pass of bounded memory; then the record,
    // its accumulation left in the file (read by FrameState::restore when the job starts).
    std::string head(kSealHeaderBytes, '\0');
    head.resize(pread_full(fd->fd, head.data(), head.size(), 0, path));
    const SealHeader h = check_header(RecordKind::kJobProgress, head);
    struct stat st {};
    if (::fstat(fd->fd, &st) != 0) throw CheckpointError("cannot stat the file");
    const uint64_t payload_bytes = uint64_t(st.st_size) - kSealHeaderBytes;
    if (payload_bytes != h.length)
      throw CheckpointError(fmt::format("torn: the payload has {} bytes, the header says {}", payload_bytes, h.length));
    {
      std::string buf(ByteWriter::kChunk, '\0');
      uLong crc = crc32(0L, Z_NULL, 0);
      for (uint64_t off = 0; off < h.length;) {
        const size_t n = pread_full(fd->fd, buf.data(), size_t(std::min<uint64_t>(buf.size(), h.length - off)),
                                    kSealHeaderBytes + off, path);
        if (n == 0) throw CheckpointError("torn: the file ends early");
        crc = crc32_update(crc, std::string_view(buf.data(), n));
        off += n;
      }
      if (uint32_t(crc) != h.crc) throw CheckpointError("corrupt payload (checksum mismatch)");
    }
    uint64_t next = kSealHeaderBytes;
    ByteReader rd(
        [&](char* dst, size_t n) {
          const size_t got = pread_full(fd->fd, dst, n, next, path);
          next += got;
          return got;
        },
        h.length);
    rd.skip_source_ = [&](uint64_t n) { next += n; };
    JobProgressRecord r;
    get_progress_head(rd, &r, h.version);
    const bool has_frame = rd.get_bool();
    if (has_frame && h.version < kOldestFrameVersion) {
      // A running job's record of an older format: its counters are kept, its frame is not (the
      // job starts again from round 0).
      if (problems)
        problems->push_back(
            fmt::format("'{}': its frame is of format version {}: this master reads frames of version "
                        "{} or newer (the frame's layout or meaning changed); starting from round 0",
                        path.string(), h.version, kOldestFrameVersion));
      return r;
    }
    if (has_frame) {
      FrameSnapshot f;
      const uint64_t cells = get_frame_head(rd, &f, h.version);
      if (f.has_accumulation) {
        const uint64_t at = kSealHeaderBytes + rd.offset();
        rd.skip(cells * sizeof(AccumulationCell));
        // The cells straight from the file (kept open: the file may be renamed meanwhile, never rewritten).
        f.cells = [fd, at, cells, path](size_t first, std::span<AccumulationCell> out) {
          if (first + out.size() > cells) throw std::logic_error("cells asked for beyond the accumulation");
          const size_t bytes = out.size_bytes();
          if (pread_full(fd->fd, reinterpret_cast<char*>(out.data()), bytes, at + first * sizeof(AccumulationCell),
                         path) != bytes)
            throw CheckpointError(fmt::format("'{}': torn: the accumulation ends early", path.string()));
        };
      }
      r.frame = std::move(f);
    }
    get_previews(rd, &r);
    return r;
  } catch (const CheckpointError& e) {
    throw CheckpointError(fmt::format("'{}': {}", path.string(), e.what()));
  }
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
      return read_progress(path, problems);
    } catch (const CheckpointError& e) {
      if (problems) problems->push_back(e.what());
    }
  }
  return std::nullopt;
}

std::optional<JobProgressRecord> CheckpointStore::load_progress_after(const std::string& id, int round) const {
  for (const char* name : {"progress.ckpt", "progress.prev.ckpt"}) {
    const fs::path path = job_dir(id) / name;
    if (!fs::exists(path)) continue;
    try {
      JobProgressRecord r = read_progress(path, nullptr);
      if (r.frame && r.progress.round == round) return r;
    } catch (const CheckpointError&) {
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
    // Temp files of checkpoints never committed (the master stopped while writing one): removed.
    for (const auto& f : fs::directory_iterator(entry.path(), ec))
      if (f.path().extension() == ".tmp") fs::remove(f.path(), ec);
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
