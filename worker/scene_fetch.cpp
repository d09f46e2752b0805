#include "worker/scene_fetch.h"

#include <fcntl.h>
#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <set>
#include <stdexcept>
#include <utility>

#include "wire/scene_bundle.h"
#include "wire/sha256.h"

namespace epr {
namespace fs = std::filesystem;
namespace {

constexpr const char* kCompleteMarker = ".complete";
constexpr const char* kEntryFile = ".entry";

fs::path scene_dir(const std::string& root, const std::string& hash) { return fs::path(root) / "scenes" / hash; }

std::optional<std::string> read_small_file(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  if (!in) return std::nullopt;
  std::string s((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  while (!s.empty() && (s.back() == '\n' || s.back() == '\r')) s.pop_back();
  return s;
}

// All of `size` bytes to `fd`; false with errno set when the disk refuses them.
bool write_all(int fd, const char* data, size_t size) {
  while (size > 0) {
    const ssize_t n = ::write(fd, data, size);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return false;
    data += n;
    size -= size_t(n);
  }
  return true;
}

// Writes `data` to `path` through a temporary file and a rename (readers never see half of it).
// The reason (with the system's error) when it cannot.
std::optional<std::string> write_atomically(const fs::path& path, const std::string& data) {
  std::random_device rd;
  const fs::path tmp = path.string() + fmt::format(".tmp-{}-{:08x}", ::getpid(), rd());
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) return fmt::format("cannot create {}: {}", tmp.string(), std::strerror(errno));
  bool ok = write_all(fd, data.data(), data.size());
  int err = ok ? 0 : errno;
  if (::close(fd) != 0 && ok) {
    ok = false;
    err = errno;
  }
  std::error_code ec;
  if (!ok) {
    fs::remove(tmp, ec);
    return fmt::format("cannot write {}: {}", tmp.string(), std::strerror(err));
  }
  fs::rename(tmp, path, ec);
  if (ec) {
    fs::remove(tmp, ec);
    return fmt::format("cannot rename {} to {}: {}", tmp.string(), path.string(), ec.message());
  }
  return std::nullopt;
}

// Bytes of the regular files below `dir`.
uint64_t folder_bytes(const fs::path& dir) {
  uint64_t n = 0;
  std::error_code ec;
  for (fs::recursive_directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    std::error_code e;
    if (it->is_regular_file(e)) n += it->file_size(e);
  }
  return n;
}

// The reason `dir` cannot hold the cache (created if missing, a file written into it), or nullopt.
std::optional<std::string> unwritable(const fs::path& dir) {
  std::error_code ec;
  fs::create_directories(dir / "scenes", ec);
  if (ec) return fmt::format("cannot create {}: {}", (dir / "scenes").string(), ec.message());
  std::string probe = (dir / "scenes" / ".write-check-XXXXXX").string();
  const int fd = ::mkstemp(probe.data());
  if (fd < 0) return fmt::format("cannot write into {}: {}", (dir / "scenes").string(), std::strerror(errno));
  ::close(fd);
  fs::remove(probe, ec);
  return std::nullopt;
}

}  // namespace

void touch_cached_scene(const std::string& cache_root, const std::string& hash) {
  if (!is_content_hash(hash)) return;
  std::error_code ec;
  fs::last_write_time(scene_dir(cache_root, hash) / kCompleteMarker, fs::file_time_type::clock::now(), ec);
}

std::vector<std::string> trim_scene_cache(const std::string& cache_root, uint64_t max_bytes, const std::string& keep) {
  struct Cached {
    fs::file_time_type used;
    std::string hash;
    uint64_t bytes;
  };
  std::vector<Cached> scenes;
  uint64_t total = 0;
  for (const std::string& hash : cached_scene_hashes(cache_root)) {
    std::error_code ec;
    const fs::path dir = scene_dir(cache_root, hash);
    const auto used = fs::last_write_time(dir / kCompleteMarker, ec);
    if (ec) continue;
    scenes.push_back({used, hash, folder_bytes(dir)});
    total += scenes.back().bytes;
  }
  std::sort(scenes.begin(), scenes.end(), [](const Cached& a, const Cached& b) { return a.used < b.used; });
  std::vector<std::string> removed;
  for (const Cached& c : scenes) {
    if (total <= max_bytes) break;
    if (c.hash == keep) continue;
    // The marker goes first: a half-removed folder is never taken for a complete scene.
    std::error_code ec;
    const fs::path dir = scene_dir(cache_root, c.hash);
    fs::remove(dir / kCompleteMarker, ec);
    fs::remove_all(dir, ec);
    total -= c.bytes;
    removed.push_back(c.hash);
  }
  return removed;
}

namespace {
// A private folder TMPDIR/epr-worker-cache-PID-XXXXXX that can hold the cache, or runtime_error
// ("no scene cache: WHY, and ...").
std::string private_cache_folder(const std::string& why) {
  std::error_code tmp_error;
  const fs::path tmp = fs::temp_directory_path(tmp_error);
  if (tmp_error)
    throw std::runtime_error(
        fmt::format("no scene cache: {}, and no temporary folder (TMPDIR): {}", why, tmp_error.message()));
  std::string tmpl = (tmp / fmt::format("epr-worker-cache-{}-XXXXXX", ::getpid())).string();
  if (!::mkdtemp(tmpl.data()))
    throw std::runtime_error(
        fmt::format("no scene cache: {}, and cannot create {}: {}", why, tmpl, std::strerror(errno)));
  if (auto err = unwritable(tmpl)) {
    std::error_code ec;
    fs::remove_all(tmpl, ec);
    throw std::runtime_error(fmt::format("no scene cache: {}, and {}", why, *err));
  }
  return tmpl;
}
}  // namespace

CacheRoot::CacheRoot(const std::string& wanted) : path_(wanted) {
  auto why = unwritable(wanted);
  if (!why) return;
  path_ = private_cache_folder(*why);
  fallback_reason_ = *why;
}

CacheRoot::~CacheRoot() {
  std::error_code ec;
  if (!fallback_.empty()) fs::remove_all(fallback_, ec);
  if (!fallback_reason_.empty()) fs::remove_all(path_, ec);
}

std::string CacheRoot::fallback() {
  std::lock_guard<std::mutex> lock(mu_);
  if (!fallback_reason_.empty()) return path_;  // already a private folder
  if (fallback_.empty()) fallback_ = private_cache_folder(fmt::format("{} cannot take the scene", path_));
  return fallback_;
}

std::string CacheRoot::fallback_if_made() const {
  std::lock_guard<std::mutex> lock(mu_);
  return fallback_;
}

struct SceneReceiver::OpenFile {
  int fd = -1;
  ~OpenFile() {
    if (fd >= 0) ::close(fd);
  }
};

bool is_content_hash(const std::string& s) {
  return s.size() == 64 &&
         std::all_of(s.begin(), s.end(), [](char c) { return (c >= '0' && c <= '9') || (c >= 'a' && c <= 'f'); });
}

std::optional<std::string> cached_scene_entry(const std::string& cache_root, const std::string& hash) {
  if (!is_content_hash(hash)) return std::nullopt;
  const fs::path dir = scene_dir(cache_root, hash);
  std::error_code ec;
  if (!fs::exists(dir / kCompleteMarker, ec)) return std::nullopt;
  const auto entry = read_small_file(dir / kEntryFile);
  if (!entry || !is_safe_relative_path(*entry) || !fs::is_regular_file(dir / *entry, ec)) return std::nullopt;
  return (dir / *entry).string();
}

std::vector<std::string> cached_scene_hashes(const std::string& cache_root) {
  std::vector<std::string> out;
  std::error_code ec;
  for (fs::directory_iterator it(fs::path(cache_root) / "scenes", ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (is_content_hash(name) && fs::exists(it->path() / kCompleteMarker, ec)) out.push_back(name);
  }
  std::sort(out.begin(), out.end());
  return out;
}

SceneReceiver::SceneReceiver(std::string cache_root, std::string expected_hash, SceneFetchLimits limits)
    : cache_root_(std::move(cache_root)), hash_(std::move(expected_hash)), limits_(limits) {
  if (!is_content_hash(hash_)) throw std::invalid_argument(fmt::format("'{}' is not a scene content hash", hash_));
}

SceneReceiver::~SceneReceiver() {
  out_.reset();
  if (!tmp_dir_.empty()) {
    std::error_code ec;
    fs::remove_all(tmp_dir_, ec);
  }
}

std::optional<std::string> SceneReceiver::fail(std::string reason) {
  error_ = std::move(reason);
  out_.reset();
  return error_;
}

std::optional<std::string> SceneReceiver::disk_fail(const std::string& what, const std::string& reason) {
  disk_failure_ = true;
  return fail(fmt::format("the worker's scene cache {}: {}: {} (this worker's disk, not the scene)", cache_root_, what,
                          reason));
}

std::optional<std::string> SceneReceiver::add(const v1::SceneChunk& chunk) {
  if (error_) return error_;
  if (finished_) return fail("chunk after the end of the scene");
  switch (chunk.part_case()) {
    case v1::SceneChunk::kManifest:
      if (have_manifest_) return fail("a second manifest");
      return add_manifest(chunk.manifest());
    case v1::SceneChunk::kData:
      if (!have_manifest_) return fail("the first chunk must be the manifest");
      return add_data(chunk.data());
    default:
      return fail("chunk without a part (unknown field?)");
  }
}

std::optional<std::string> SceneReceiver::add_manifest(const v1::SceneManifest& m) {
  if (m.content_hash() != hash_)
    return fail(fmt::format("manifest is for scene {}, asked for {}", m.content_hash(), hash_));
  if (uint64_t(m.files_size()) > limits_.max_files)
    return fail(fmt::format("{} files exceed the limit of {}", m.files_size(), limits_.max_files));
  std::set<std::string> paths;
  uint64_t total = 0;
  for (const auto& f : m.files()) {
    if (!is_safe_relative_path(f.path()))
      return fail(fmt::format("file path '{}' is not a safe relative path", f.path()));
    if (f.path() == kCompleteMarker || f.path() == kEntryFile)
      return fail(fmt::format("file path '{}' is reserved by the cache", f.path()));
    if (!paths.insert(f.path()).second) return fail(fmt::format("file '{}' listed twice", f.path()));
    if (f.size_bytes() > limits_.max_total_bytes || total + f.size_bytes() > limits_.max_total_bytes)
      return fail(fmt::format("scene exceeds the size limit of {} bytes", limits_.max_total_bytes));
    total += f.size_bytes();
    files_.emplace_back(f.path(), f.size_bytes());
  }
  if (total != m.total_bytes())
    return fail(fmt::format("total_bytes {} but the files add up to {}", m.total_bytes(), total));
  if (!paths.count(m.entry_path())) return fail(fmt::format("entry path '{}' is not one of the files", m.entry_path()));
  entry_path_ = m.entry_path();

  // A private folder: unique per receiver, also between workers of one process.
  std::random_device rd;
  const uint64_t nonce = (uint64_t(rd()) << 32) ^ rd();
  tmp_dir_ = (fs::path(cache_root_) / "scenes" / fmt::format(".tmp-{}-{}-{:016x}", hash_, ::getpid(), nonce)).string();
  std::error_code ec;
  fs::create_directories(tmp_dir_, ec);
  if (ec) return disk_fail(fmt::format("cannot create {}", tmp_dir_), ec.message());
  // Every file exists from the start (empty files get no chunks); path clashes show up here.
  for (const auto& [path, size] : files_) {
    const fs::path p = fs::path(tmp_dir_) / path;
    fs::create_directories(p.parent_path(), ec);
    if (ec) return disk_fail(fmt::format("cannot create the folder of '{}'", path), ec.message());
    const int fd = ::open(p.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd < 0) return disk_fail(fmt::format("cannot create '{}'", path), std::strerror(errno));
    ::close(fd);
  }
  have_manifest_ = true;
  current_ = 0;
  written_ = rpc::ChunkTracker(files_.empty() ? 0 : files_[0].second);
  return std::nullopt;
}

std::optional<std::string> SceneReceiver::close_current() {
  if (current_ >= files_.size()) return std::nullopt;
  if (!written_.complete())
    return fail(fmt::format("file '{}' ended after {} of {} bytes", files_[current_].first, written_.received(),
                            written_.size()));
  if (out_) {
    const int fd = std::exchange(out_->fd, -1);
    out_.reset();
    if (::close(fd) != 0)
      return disk_fail(fmt::format("cannot write '{}'", files_[current_].first), std::strerror(errno));
  }
  ++current_;
  written_ = rpc::ChunkTracker(current_ < files_.size() ? files_[current_].second : 0);
  return std::nullopt;
}

std::optional<std::string> SceneReceiver::add_data(const v1::SceneFileData& d) {
  if (d.file_index() >= files_.size()) return fail(fmt::format("file_index {} outside the manifest", d.file_index()));
  if (d.file_index() < current_) return fail(fmt::format("data for file {} after it was complete", d.file_index()));
  while (current_ < d.file_index())
    if (auto err = close_current()) return err;
  const std::string& path = files_[current_].first;
  if (d.data().size() > limits_.max_chunk_bytes)
    return fail(fmt::format("data chunk of {} bytes exceeds {}", d.data().size(), limits_.max_chunk_bytes));
  if (auto err = written_.add(d.offset(), d.data().size())) return fail(fmt::format("file '{}': {}", path, *err));
  if (!out_) {
    out_ = std::make_unique<OpenFile>();
    out_->fd = ::open((fs::path(tmp_dir_) / path).c_str(), O_WRONLY | O_TRUNC | O_CLOEXEC);
    if (out_->fd < 0) return disk_fail(fmt::format("cannot write '{}'", path), std::strerror(errno));
  }
  if (!write_all(out_->fd, d.data().data(), d.data().size()))
    return disk_fail(fmt::format("cannot write '{}'", path), std::strerror(errno));
  bytes_received_ += d.data().size();
  return std::nullopt;
}

std::optional<std::string> SceneReceiver::finish(std::string* entry_file) {
  if (error_) return error_;
  if (!have_manifest_) return fail("no manifest");
  if (finished_) return fail("finish() called twice");
  while (current_ < files_.size())
    if (auto err = close_current()) return err;

  // Content hash over the canonical serialisation (scene.proto), files in ascending path order.
  std::vector<std::pair<std::string, uint64_t>> sorted = files_;
  std::sort(sorted.begin(), sorted.end());
  Sha256 sha;
  sha.update(std::string("epr-scene-v1\n"));
  sha.update_u64le(entry_path_.size());
  sha.update(entry_path_);
  sha.update_u64le(sorted.size());
  std::vector<char> buf(1 << 20);
  for (const auto& [path, size] : sorted) {
    sha.update_u64le(path.size());
    sha.update(path);
    sha.update_u64le(size);
    std::ifstream in(fs::path(tmp_dir_) / path, std::ios::binary);
    uint64_t read = 0;
    while (in && read < size) {
      in.read(buf.data(), std::streamsize(std::min<uint64_t>(buf.size(), size - read)));
      sha.update(buf.data(), size_t(in.gcount()));
      read += uint64_t(in.gcount());
    }
    if (read != size) return disk_fail(fmt::format("cannot read back '{}'", path), std::strerror(errno));
  }
  const std::string got = sha.hex();
  if (got != hash_) return fail(fmt::format("content hash mismatch: received {}, expected {}", got, hash_));

  for (const auto& [name, text] : {std::pair{kEntryFile, entry_path_}, std::pair{kCompleteMarker, hash_}})
    if (auto err = write_atomically(fs::path(tmp_dir_) / name, text + "\n")) return disk_fail("a marker", *err);
  const fs::path dir = scene_dir(cache_root_, hash_);
  std::error_code ec;
  fs::rename(tmp_dir_, dir, ec);
  if (ec) {
    // Someone else's copy is already there (identical by hash); it may lack the entry file if
    // load_bundle wrote it.
    const std::string why = ec.message();
    fs::remove_all(tmp_dir_, ec);
    if (!fs::exists(dir / kCompleteMarker, ec))
      return disk_fail(fmt::format("cannot move the scene into {}", dir.string()), why);
    if (!fs::exists(dir / kEntryFile, ec))
      if (auto err = write_atomically(dir / kEntryFile, entry_path_ + "\n")) return disk_fail("the entry file", *err);
  }
  tmp_dir_.clear();
  finished_ = true;
  *entry_file = (dir / entry_path_).string();
  return std::nullopt;
}

}  // namespace epr
